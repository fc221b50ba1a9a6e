"""Run every command line that reads models against every hostile input; print a markdown table.

    python tests/hostile/run.py --out /tmp/hostile [--quick] [--timeout 60] [--mem-mb 4096]

The corpus is generated into OUT/corpus (tests/hostile/generate.py). Each (case, command) runs in
its own subprocess with a wall-time limit and an address-space limit (RLIMIT_AS, set in the child
before exec), `LDRAWDIR` and `--ldraw` pointing at the generated library, and its own output
folder and cache under OUT. Peak RSS is the child's `ru_maxrss` from `os.wait4`.

A case passes when the command ends within the limits with exit status 0 or 2 and writes at most
one line to stderr (the product's `error: ...` line; no traceback). The `EXTRA` cases are about
a flag, a zip given as the library, a pickle planted in a build's spool, or a predictions file
with singular rotations or huge translations; each runs one command under the same limits, and
some have a check of their own (the planted pickle never ran; every score stays finite and fails
every step). The exit status is 0 when every case passed, 1 otherwise.
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

SMALL_BUILD = ["--n", "2", "--min-steps", "3", "--max-steps", "4", "--size", "64", "--tile", "32",
               "--objects-per-shard", "1", "--workers", "1", "--no-progress"]
"""The build the cases below that need a dataset use (and the spool case plants its pickle into)."""

PLAIN_MODEL = "mirrored"
"""A corpus model the flag and library cases read (any model refused after its library is read: the
case is about the flag or the library)."""

EXTRA: dict[str, tuple[str, list[str]]] = {
    "zip_escape": ("a zip library with a member named ../escape.dat",
                   ["-m", "factory.ldraw", "steps", "{model}", "--ldraw", "{zip}"]),
    "zip_link": ("a zip library with a member stored as a symbolic link",
                 ["-m", "factory.ldraw", "steps", "{model}", "--ldraw", "{zip}"]),
    "zip_bomb": ("a zip library whose 3001.dat inflates to 64 MB of spaces (64 KB in the archive)",
                 ["-m", "factory.ldraw", "steps", "{model}", "--ldraw", "{zip}"]),
    "flag_weight_word": ("--parts 3001:abc",
                         ["-m", "pipelines.sample", "--n", "1", "--out", "{work}/s", "--parts", "3001:abc"]),
    "flag_weight_huge": ("--parts 3001:1e308,3003:1e308 (their sum overflows)",
                         ["-m", "pipelines.synth", "--n", "1", "--out", "{work}/s", "--no-progress",
                          "--parts", "3001:1e308,3003:1e308"]),
    "predict_nan": ("render --predict 'nan 0 0 1 0 0 0 1 0 0 0 1'",
                    ["-m", "pipelines.render", "{model}", "--step", "0", "--out", "{work}/r", "--ldraw", "{ldraw}",
                     "--predict", "nan 0 0 1 0 0 0 1 0 0 0 1"]),
    "predict_huge": ("render --predict '1e308 0 0 1 0 0 0 1 0 0 0 1'",
                     ["-m", "pipelines.render", "{model}", "--step", "0", "--out", "{work}/r", "--ldraw", "{ldraw}",
                      "--predict", "1e308 0 0 1 0 0 0 1 0 0 0 1"]),
    "predict_word": ("render --predict hello",
                     ["-m", "pipelines.render", "{model}", "--step", "0", "--out", "{work}/r", "--ldraw", "{ldraw}",
                      "--predict", "hello"]),
    "predict_singular": ("render --predict with the zero matrix",
                         ["-m", "pipelines.render", "{model}", "--step", "0", "--out", "{work}/r", "--ldraw",
                          "{ldraw}", "--predict", "0 0 0 0 0 0 0 0 0 0 0 0"]),
    "spool_pickle": ("a pickle that runs code, planted in an unfinished build's spool, then the build resumed",
                     ["-m", "pipelines.synth", *SMALL_BUILD, "--out", "{work}/build"]),
    "score_singular": ("the oracle's answers with every rotation [0,0,0] x3, scored in all modes",
                       ["-m", "eval.score", "--data", "{dataset}", "--pred", "{work}/pred.jsonl", "--mode", "all",
                        "--json"]),
    "score_huge_translation": ("the oracle's answers with x = 1e308, scored in all modes",
                               ["-m", "eval.score", "--data", "{dataset}", "--pred", "{work}/pred.jsonl", "--mode",
                                "all", "--json"]),
}
"""Cases about a flag, a library, a build folder or a predictions file rather than a model: each
one command line (`{model}` is `PLAIN_MODEL`; `{dataset}` a small build made once per run)."""


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
    own_problem: str | None = None
    """What a case's own check found (`_extra_problem`)."""

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
        if self.own_problem:
            return self.own_problem
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
            mem_mb: int = 4096, python: str = sys.executable, args: list[str] | None = None) -> Result:
    """Run one command on one model under the limits (or the command line `args`); never raises
    for the child's failures. Its stdout is kept in WORK/score.stdout."""
    work.mkdir(parents=True, exist_ok=True)
    args = [python] + (args if args is not None else
                       [a.format(model=model, ldraw=ldraw, work=work) for a in COMMANDS[command]])
    env = dict(os.environ, LDRAWDIR=str(ldraw), BRICK_FACTORY_CACHE=str(work / "cache"),
               PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH", "")])),
               OMP_NUM_THREADS="1", JAX_PLATFORMS=os.environ.get("JAX_PLATFORMS", "cpu"))
    err_path = work / f"{command}.stderr"
    with open(err_path, "wb") as err, open(work / "score.stdout", "wb") as null:
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


class _Planted:
    """A pickle whose loading writes a file (what `os.system` in `__reduce__` would do)."""

    def __init__(self, path: str):
        self.path = path

    def __reduce__(self):
        return (exec, (f"open({self.path!r}, 'w').write('ran')",))


def _prepare_extra(case: str, work: Path, corpus: Path, dataset: Path | None) -> None:
    """What a case needs in its folder before its command runs."""
    import json
    import pickle
    import re
    import zipfile

    work.mkdir(parents=True, exist_ok=True)
    if case.startswith("zip_"):
        # The corpus library as LDraw's complete.zip lays it out (under ldraw/), plus the case's member.
        with zipfile.ZipFile(work / "library.zip", "w", zipfile.ZIP_DEFLATED) as z:
            for p in sorted((corpus / "ldraw").rglob("*")):
                if p.is_file() and not p.is_symlink() and p.name != "3001.dat" and p.stat().st_size < 1 << 20:
                    z.write(p, "ldraw/" + p.relative_to(corpus / "ldraw").as_posix())
            brick = (corpus / "ldraw" / "parts" / "3001.dat").read_bytes()
            if case == "zip_bomb":
                brick += b" " * (64 << 20)
            z.writestr("ldraw/parts/3001.dat", brick)
            if case == "zip_escape":
                z.writestr("ldraw/../escape.dat", b"0 outside\n")
            if case == "zip_link":
                link = zipfile.ZipInfo("ldraw/parts/link.dat")
                link.external_attr = (0o120777 << 16)
                z.writestr(link, "/etc/passwd")
    elif case == "spool_pickle":
        spool = work / "build" / "meta" / "spool"
        spool.mkdir(parents=True, exist_ok=True)
        payload = pickle.dumps(_Planted(str(work / "RAN")))
        for name in ("0000000.pkl", "0000000.json", "0000001.json"):
            (spool / name).write_bytes(payload)
    elif case.startswith("score_") and dataset is not None:
        lines = [json.loads(ln) for ln in (dataset.parent / "oracle.jsonl").read_text().splitlines() if ln.strip()]
        for ln in lines:
            if ln["task"] != "pose":
                continue
            if case == "score_singular":
                ln["text"] = re.sub(r"Rotation:\n(\[[^\n]*\]\n?){3}", "Rotation:\n[0, 0, 0]\n[0, 0, 0]\n[0, 0, 0]\n",
                                    ln["text"])
            else:
                ln["text"] = re.sub(r"x=[-0-9.e]+", "x=1e308", ln["text"])
        (work / "pred.jsonl").write_text("".join(json.dumps(ln) + "\n" for ln in lines))


def _extra_problem(case: str, r: Result, work: Path) -> str | None:
    """A case's own check beyond `Result.problem`: what the output must say."""
    import json

    if case == "spool_pickle":
        return "the planted pickle ran" if (work / "RAN").exists() else None
    if case.startswith("score_"):
        try:
            result = json.loads((work / "score.stdout").read_text(), parse_constant=lambda c: 1 / 0)
        except (ValueError, ZeroDivisionError, OSError):
            return "no valid JSON on stdout"
        for mode in ("strict", "paper", "bc"):
            overall = result[mode]["overall"]
            if overall["step_success"] != 0.0:
                return f"{mode}: step success {overall['step_success']}"
            if not isinstance(overall["translation_error_ldu"], float):
                return f"{mode}: translation error {overall['translation_error_ldu']}"
    return None


def _dataset(out: Path, python: str = sys.executable) -> Path:
    """A small build and the oracle's answers for it (the scoring cases start from them)."""
    data = out / "dataset" / "synth"
    if not (data / "meta" / "info.json").exists():
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH", "")])))
        subprocess.run([python, "-m", "pipelines.synth", *SMALL_BUILD, "--out", str(data)], cwd=ROOT, env=env,
                       check=True, capture_output=True)
        subprocess.run([python, "-m", "eval.predict", "--data", str(data), "--model", "baseline:oracle", "--out",
                        str(data.parent / "oracle.jsonl"), "--no-progress"], cwd=ROOT, env=env, check=True,
                       capture_output=True)
    return data


def run_extra(out: str | os.PathLike, cases: list[str] | None = None, timeout: float = 60.0, mem_mb: int = 4096,
              progress=None) -> list[Result]:
    """The `EXTRA` cases (all, or `cases`), each under the same limits as the model cases."""
    sys.path.insert(0, str(HERE))
    import generate

    out = Path(out)
    corpus = out / "corpus"
    models = generate.generate(corpus, big=False)
    names = [c for c in (cases or list(EXTRA)) if c in EXTRA]
    dataset = _dataset(out) if any(c.startswith("score_") for c in names) else None
    results = []
    for case in names:
        work = out / "work" / case
        _prepare_extra(case, work, corpus, dataset)
        fields = {"model": models[PLAIN_MODEL], "ldraw": corpus / "ldraw", "work": work, "zip": work / "library.zip",
                  "dataset": dataset}
        r = run_one(case, models[PLAIN_MODEL], "extra", corpus / "ldraw", work, timeout, mem_mb,
                    args=[a.format(**fields) for a in EXTRA[case][1]])
        own = _extra_problem(case, r, work)
        if own and not r.problem:
            r.stderr += f"\n(check) {own}"
            r.own_problem = own
        results.append(r)
        if progress:
            progress(r)
    return results


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
    parser.add_argument("--case", action="append", help="run only this case, a model case or an EXTRA one "
                                                        "(repeatable)")
    parser.add_argument("--command", action="append", choices=sorted(COMMANDS), help="only this command")
    args = parser.parse_args(argv)

    def progress(r: Result) -> None:
        print(f"{r.case:22} {r.command:8} {('timeout' if r.timed_out else r.status)!s:>7} "
              f"{r.seconds:6.1f}s {r.peak_rss_mb:6.0f}MB {r.problem or 'ok'}", file=sys.stderr, flush=True)

    # --case picks from both lists; without it, every model case and (unless --quick or
    # --command narrows the run to model commands) every EXTRA case.
    model_cases = [c for c in args.case if c not in EXTRA] if args.case else None
    extra_cases = [c for c in args.case if c in EXTRA] if args.case else (
        [] if args.quick or args.command else list(EXTRA))
    results = []
    if model_cases is None or model_cases:
        results += run_all(args.out, args.quick, args.timeout, args.mem_mb, model_cases, args.command, progress)
    if extra_cases:
        results += run_extra(args.out, extra_cases, args.timeout, args.mem_mb, progress)
    print(table(results, args.timeout, args.mem_mb))
    return 0 if all(r.problem is None for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
