"""Helpers of tests that start processes: `torchrun` (a module under `torch.distributed.run
--standalone` from the checkout, one torch thread per process), the /proc readers `children_of`,
`alive` and `_cmdline`, and `assert_workers_end_with_killed_parent`, which kills a command with
SIGKILL once its workers have started and asserts that they end too (Linux only: they read
/proc)."""

from __future__ import annotations

from pathlib import Path


def torchrun(module: str, *argv: str, processes: int = 2, timeout: float = 600):
    """`torchrun --standalone --nproc_per_node PROCESSES -m MODULE ARGV` from the checkout (one
    torch thread per process; --standalone: a free port, so concurrent test runs do not meet);
    the finished process (stdout and stderr as text; the processes' lines may interleave)."""
    import os
    import subprocess
    import sys

    root = Path(__file__).resolve().parents[1]
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", str(processes),
           "-m", module, *argv]
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(root)}
    return subprocess.run(cmd, cwd=root, env=env, capture_output=True, text=True, timeout=timeout)


def children_of(pid: int) -> list[int]:
    """Live (not zombie) processes whose parent is `pid`, from /proc."""
    found = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                stat = (d / "stat").read_text()
            except OSError:
                continue
            fields = stat.rsplit(")", 1)[1].split()
            if int(fields[1]) == pid and fields[0] != "Z":
                found.append(int(d.name))
    return found


def alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def _cmdline(pid: int) -> bytes:
    """A process's command line; empty when it ended meanwhile (a short-lived child of the command)."""
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes()
    except (FileNotFoundError, ProcessLookupError):
        return b""


def assert_workers_end_with_killed_parent(proc, marker: bytes, workers: int = 2, settle: float = 0.0,
                                          grace: float = 10.0) -> None:
    """Wait for `workers` children of `proc` whose command line holds `marker`, kill `proc` with
    SIGKILL (after `settle` seconds), and assert that they end within `grace` seconds."""
    import os
    import signal
    import time

    found: list[int] = []
    try:
        deadline = time.time() + 120
        while len(found) < workers:
            found = [p for p in children_of(proc.pid) if marker in _cmdline(p)]
            assert proc.poll() is None, "the command ended before its workers started"
            assert time.time() < deadline, f"no {workers} workers within 120 s"
            time.sleep(0.05)
        time.sleep(settle)
    finally:
        proc.kill()
        proc.wait()
    deadline = time.time() + grace
    while any(alive(p) for p in found) and time.time() < deadline:
        time.sleep(0.1)
    left = [p for p in found if alive(p)]
    for p in left:
        os.kill(p, signal.SIGKILL)
    assert not left, f"workers {left} outlived their killed parent"
