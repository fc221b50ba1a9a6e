"""Run every command line that reads models against every hostile input; print a markdown table.

    python tests/hostile/run.py --out /tmp/hostile [--quick] [--timeout 60] [--mem-mb 4096]

The corpus is generated into OUT/corpus (tests/hostile/generate.py). Each (case, command) runs in
its own subprocess with a wall-time limit and an address-space limit (RLIMIT_AS, set in the child
before exec), `LDRAWDIR` and `--ldraw` pointing at the generated library, and its own output
folder and cache under OUT. Peak RSS is the child's `ru_maxrss` from `os.wait4`.

A case passes when the command ends within the limits with exit status 0 or 2 and writes at most
one line to stderr (the product's `error: ...` line; no traceback). The exit status is 0 when
every case passed, 1 otherwise.
"""

from __future__ import annotations

import argparse
import os
import resource
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]

COMMANDS: dict[str, list[str]] = {
    "steps": ["-m", "factory.ldraw", "steps", "{model}", "--ldraw", "{ldraw}"],
    "verify": ["-m", "pipelines.verify", "{model}", "--ldraw", "{ldraw}"],
    "render": ["-m", "pipelines.render", "{model}", "--step", "0", "--out", "{work}/render", "--ldraw", "{ldraw}"],
    "designs": ["-m", "pipelines.designs", "{model}", "--out", "{work}/designs", "--ldraw", "{ldraw}",
                "--no-progress"],
}
"""Every command line that reads a model file; `{work}` is the case's own output folder."""

QUICK_COMMANDS = ("steps", "verify")


@dataclass
class Result:
    case: str
    command: str
    status: int | None
    """Exit status; None when the wall-time limit killed it; negative: killed by that signal."""
    seconds: float
    peak_rss_mb: float
    stderr: str
    timed_out: bool

    @property
    def stderr_lines(self) -> list[str]:
        return [ln for ln in self.stderr.splitlines() if ln.strip()]

    @property
    def first_line(self) -> str:
        lines = self.stderr_lines
        if not lines:
            return ""
        # Show the exception line of a traceback, not its "Traceback (most recent call last):".
        first = lines[-1] if lines[0].startswith("Traceback") else lines[0]
        return first if len(first) <= 160 else first[:157] + "..."

    @property
    def problem(self) -> str | None:
        """Why the case failed, or None when it passed."""
        if self.timed_out:
            return "time limit"
        if self.status is None or self.status < 0:
            return f"killed by signal {-(self.status or 0)}"
        if any(ln.startswith("Traceback") for ln in self.stderr_lines):
            return "traceback"
        if "MemoryError" in self.stderr:
            return "memory limit"
        if self.status not in (0, 2):
            return f"exit {self.status}"
        if len(self.stderr_lines) > 1:
            return f"{len(self.stderr_lines)} stderr lines"
        return None


def _limits(mem_bytes: int):
    def apply() -> None:
        os.setsid()  # own process group, so a timeout kills its workers too
        resource.setrlimit(resource.RLIMIT_AS, (mem_bytes, mem_bytes))
        resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
    return apply


def run_one(case: str, model: Path, command: str, ldraw: Path, work: Path, timeout: float = 60.0,
            mem_mb: int = 4096, python: str = sys.executable) -> Result:
    """Run one command on one model under the limits; never raises for the child's failures."""
    work.mkdir(parents=True, exist_ok=True)
    args = [python] + [a.format(model=model, ldraw=ldraw, work=work) for a in COMMANDS[command]]
    env = dict(os.environ, LDRAWDIR=str(ldraw), BRICK_FACTORY_CACHE=str(work / "cache"),
               PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH", "")])),
               OMP_NUM_THREADS="1", JAX_PLATFORMS=os.environ.get("JAX_PLATFORMS", "cpu"))
    err_path = work / f"{command}.stderr"
    with open(err_path, "wb") as err, open(os.devnull, "wb") as null:
        start = time.monotonic()
        proc = subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=null, stderr=err, cwd=ROOT, env=env,
                                preexec_fn=_limits(mem_mb << 20))
        timed_out = False
        rusage = None
        status = None
        while True:
            pid, raw, rusage = os.wait4(proc.pid, os.WNOHANG)
            if pid == proc.pid:
                status = os.waitstatus_to_exitcode(raw)
                break
            if time.monotonic() - start > timeout:
                timed_out = True
                try:
                    os.killpg(proc.pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
                _, raw, rusage = os.wait4(proc.pid, 0)
                status = None
                break
            time.sleep(0.05)
        seconds = time.monotonic() - start
        proc.returncode = status if status is not None else -9  # reaped here, not by Popen
    # Workers of the command may still hold the group after its leader exited: end them too.
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass
    stderr = err_path.read_bytes().decode("utf-8", "replace")
    return Result(case, command, status, seconds, rusage.ru_maxrss / 1024.0, stderr, timed_out)


def run_all(out: str | os.PathLike, quick: bool = False, timeout: float = 60.0, mem_mb: int = 4096,
            cases: list[str] | None = None, commands: list[str] | None = None,
            progress=None) -> list[Result]:
    """Generate the corpus under `out` and run the commands on its cases (all, or the quick
    subset: `generate.QUICK` cases x `QUICK_COMMANDS`)."""
    sys.path.insert(0, str(ROOT))
    sys.path.insert(0, str(HERE))
    import generate

    out = Path(out)
    corpus = generate.generate(out / "corpus", big=not quick and (cases is None or any(
        c in ("long_line_50mb", "many_triangles", "many_parts") for c in cases)))
    ldraw = out / "corpus" / "ldraw"
    names = cases or (list(generate.QUICK) if quick else list(corpus))
    cmds = commands or (list(QUICK_COMMANDS) if quick else list(COMMANDS))
    results = []
    for case in names:
        for command in cmds:
            r = run_one(case, corpus[case], command, ldraw, out / "work" / case / command, timeout, mem_mb)
            results.append(r)
            if progress:
                progress(r)
    return results


def table(results: list[Result], timeout: float, mem_mb: int) -> str:
    rows = [f"Limits per case: {timeout:g} s wall time, {mem_mb:,} MB address space (RLIMIT_AS).", "",
            "| case | command | exit | seconds | peak RSS (MB) | verdict | first stderr line |",
            "|---|---|---|---|---|---|---|"]
    for r in results:
        status = "timeout" if r.timed_out else str(r.status)
        verdict = r.problem or "ok"
        first = r.first_line.replace("|", "\\|")
        rows.append(f"| {r.case} | {r.command} | {status} | {r.seconds:.1f} | {r.peak_rss_mb:.0f} | {verdict} | "
                    f"{first} |")
    failed = [r for r in results if r.problem]
    rows += ["", f"{len(results) - len(failed)} of {len(results)} passed."]
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", required=True, help="working folder (corpus, outputs, caches)")
    parser.add_argument("--quick", action="store_true", help="a small subset: a few cases, steps and verify")
    parser.add_argument("--timeout", type=float, default=60.0, help="wall-time limit per case, seconds")
    parser.add_argument("--mem-mb", type=int, default=4096, help="address-space limit per case, MB")
    parser.add_argument("--case", action="append", help="run only this case (repeatable)")
    parser.add_argument("--command", action="append", choices=sorted(COMMANDS), help="only this command")
    args = parser.parse_args(argv)

    def progress(r: Result) -> None:
        print(f"{r.case:22} {r.command:8} {('timeout' if r.timed_out else r.status)!s:>7} "
              f"{r.seconds:6.1f}s {r.peak_rss_mb:6.0f}MB {r.problem or 'ok'}", file=sys.stderr, flush=True)

    results = run_all(args.out, args.quick, args.timeout, args.mem_mb, args.case, args.command, progress)
    print(table(results, args.timeout, args.mem_mb))
    return 0 if all(r.problem is None for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
