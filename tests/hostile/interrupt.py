"""Ctrl-C a small build at random moments, resume it, and compare it with an uninterrupted build.

    python tests/hostile/interrupt.py --out /tmp/interrupt [--early 20] [--late 10] [--seed 0]

Each try starts `python -m pipelines.synth` (the issue's small build) in its own session with
SIGINT at its default (as from a terminal), sends SIGINT to the whole process group (what Ctrl-C
does) after a random delay (`--early` tries within the first 2 s, while the command starts;
`--late` tries between 2 s and 0.9 of the reference build's wall time), then runs the same command again
without interruption. A try passes when the interrupted run exits 130 (or 0 if it finished
first), prints no traceback and exactly one `error: interrupted...` line (other stderr lines are
the build's own notes), and the resumed folder has the reference's files byte for byte. Prints a
markdown table; exits 1 when any try failed.
"""

from __future__ import annotations

import argparse
import filecmp
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
BUILD = ["--n", "3", "--min-steps", "5", "--max-steps", "8", "--size", "64", "--tile", "32",
         "--objects-per-shard", "2", "--workers", "1", "--no-progress"]
"""The build the issue interrupted (`S`)."""
NOTES = ("physics:", "growth:")
"""Lines a build writes to stderr as it starts (not about the interruption)."""


@dataclass
class Try:
    delay: float | str
    status: int | None
    stderr: str
    resumed_status: int | None = None
    differing: tuple[str, ...] = ()

    @property
    def problem(self) -> str | None:
        lines = [ln for ln in self.stderr.splitlines() if ln.strip() and not ln.startswith(NOTES)]
        if self.status not in (0, 130):
            return f"exit {self.status}"
        if "Traceback" in self.stderr:
            return "traceback"
        if self.status == 130 and (len(lines) != 1 or not lines[0].startswith("error: interrupted")):
            return f"{len(lines)} lines: {lines[-1][:80] if lines else ''}"
        if self.resumed_status != 0:
            return f"resume exit {self.resumed_status}"
        if self.differing:
            return f"differs: {', '.join(self.differing[:3])}"
        return None


def _env() -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    return env


def _command(out: Path, python: str, build: list[str] = BUILD) -> list[str]:
    return [python, "-m", "pipelines.synth", *build, "--out", str(out)]


def _files(out: Path) -> list[str]:
    """What a build guarantees byte for byte (markers and timings hold seconds)."""
    return sorted(p.relative_to(out).as_posix() for p in out.rglob("*")
                  if p.is_file() and not p.relative_to(out).as_posix().startswith("meta/shards/")
                  and p.name != "timings.json")


def differing(a: Path, b: Path) -> tuple[str, ...]:
    fa, fb = _files(a), _files(b)
    if fa != fb:
        return tuple(sorted(set(fa) ^ set(fb)))
    return tuple(f for f in fa if not filecmp.cmp(a / f, b / f, shallow=False))


def reference(out: Path, python: str = sys.executable, build: list[str] = BUILD) -> float:
    """Build the uninterrupted reference into `out`; returns its wall time."""
    shutil.rmtree(out, ignore_errors=True)
    t0 = time.perf_counter()
    subprocess.run(_command(out, python, build), cwd=ROOT, env=_env(), check=True, capture_output=True, timeout=600)
    return time.perf_counter() - t0


FIRST_SHARD = "first-shard"
"""`interrupt_once`'s moment right after the build's first shard is recorded (`meta/shards`): in
the middle of building, however fast the machine."""


def _wait_for_first_shard(out: Path, p: subprocess.Popen, limit: float = 120.0) -> None:
    end = time.monotonic() + limit
    while time.monotonic() < end and p.poll() is None:
        if any((out / "meta" / "shards").glob("*")):
            return
        time.sleep(0.02)


def interrupt_once(out: Path, delay, ref: Path, python: str = sys.executable, build: list[str] = BUILD) -> Try:
    """Ctrl-C `build` (synth's arguments less --out) after `delay` seconds, or at `FIRST_SHARD`,
    resume it, compare the folder with `ref` (the same build, uninterrupted)."""
    shutil.rmtree(out, ignore_errors=True)
    p = subprocess.Popen(_command(out, python, build), cwd=ROOT, env=_env(), stdout=subprocess.DEVNULL,
                         stderr=subprocess.PIPE, text=True, start_new_session=True,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        if delay == FIRST_SHARD:
            _wait_for_first_shard(out, p)
        else:
            time.sleep(delay)
        try:
            os.killpg(p.pid, signal.SIGINT)
        except ProcessLookupError:
            pass
        _, err = p.communicate(timeout=120)
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait()
    result = Try(delay, p.returncode, err)
    r = subprocess.run(_command(out, python, build), cwd=ROOT, env=_env(), capture_output=True, text=True,
                       timeout=600)
    result.resumed_status = r.returncode
    if r.returncode == 0:
        result.differing = differing(ref, out)
    return result


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True)
    ap.add_argument("--early", type=int, default=20, help="tries in the first 2 s (default 20)")
    ap.add_argument("--late", type=int, default=10, help="tries after 2 s (default 10)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    work = Path(args.out)
    ref = work / "reference"
    wall = reference(ref)
    rng = random.Random(args.seed)
    delays = sorted(rng.uniform(0.0, 2.0) for _ in range(args.early))
    delays += sorted(rng.uniform(2.0, max(2.5, 0.9 * wall)) for _ in range(args.late))  # while it builds
    print(f"reference build: {wall:.1f} s\n")
    print("| delay (s) | exit | resume | result |")
    print("|---:|---:|---:|---|")
    failed = 0
    for k, d in enumerate(delays):
        t = interrupt_once(work / f"try{k:02d}", d, ref)
        failed += t.problem is not None
        print(f"| {d:.2f} | {t.status} | {t.resumed_status} | {t.problem or 'ok'} |", flush=True)
        if t.problem is None:
            shutil.rmtree(work / f"try{k:02d}", ignore_errors=True)
    print(f"\n{len(delays) - failed} of {len(delays)} tries clean")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
