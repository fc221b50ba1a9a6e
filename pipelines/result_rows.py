"""Appending measured figures to `bench/results/*.jsonl` (the rows `pipelines.results` renders).

    append_rows("builds", [{"what": "make synth N=8 (...)", "wall_s": 41.3, "steps": 160}])

Each row is checked as `pipelines.results.read_rows` checks it (the required keys, at least one
numeric figure), with stricter rules for what is written now: `what` a non-empty text, `note`
text, every other value a finite number (a figure under a key naming its unit). Missing keys are
filled: `date` today (UTC), `machine` this machine in words (`describe_machine`), `revision` the
checkout's commit (`revision`). A caller timing something long takes the revision when it starts
and puts it in its rows.

Concurrent runs: the rows of one call are written with one `write` to a file opened for appending
while holding an exclusive `flock` on it, so rows of two runs never interleave and a row is never
split; a file whose last line lacks its newline gets one first.
"""

from __future__ import annotations

import datetime
import fcntl
import json
import os
import re
import subprocess
import sys
from collections import Counter
from pathlib import Path

from factory import gpus
from factory.atomic import write_atomic
from pipelines import results
from pipelines.dataset.usage import cpu_model
from pipelines.results import ResultsError, figures

STEM = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")
NOT_CODE = ("bench/results", "docs/results.md")
"""Paths whose changes do not make a checkout '+dirty': the rows and the page they render into
(a run appending rows would otherwise mark every later run's rows dirty until they are committed)."""


def revision(root: Path | None = None) -> str | None:
    """The commit checked out at `root` (default the repository holding this code) as
    `git rev-parse --short HEAD`, with `+dirty` when a tracked file differs from it (untracked files
    and `NOT_CODE` do not count); None when `root` is not the top of a git checkout or git is
    missing or fails. Git runs with `GIT_OPTIONAL_LOCKS=0`: it takes no lock on the index, so it
    never gets in the way of git commands run beside it."""
    root = Path(root or results.ROOT).resolve()
    env = {**os.environ, "GIT_OPTIONAL_LOCKS": "0"}

    def git(*args: str) -> str | None:
        try:
            r = subprocess.run(["git", *args], cwd=root, env=env, capture_output=True, text=True, timeout=30)
        except (OSError, subprocess.SubprocessError):
            return None
        return r.stdout if r.returncode == 0 else None

    out = git("rev-parse", "--show-toplevel", "--short", "HEAD")
    lines = (out or "").split()
    if len(lines) != 2 or Path(lines[0]).resolve() != root:
        return None  # not a checkout, or a checkout above this code (an installed copy inside one)
    status = git("status", "--porcelain", "--untracked-files=no", "--", ".",
                 *(f":(exclude){p}" for p in NOT_CODE))
    return lines[1] + ("+dirty" if status else "")


def short_cpu(model: str | None) -> str | None:
    """A CPU model name without its trademarks, core count and clock: 'AMD EPYC 7B13'."""
    if not model:
        return None
    text = re.sub(r"\((R|TM|tm|r)\)|\bCPU\b|\bProcessor\b|\b\d+-Core\b|@\s*[\d.]+\s*GHz", " ", model)
    return " ".join(text.split()) or None


def describe_machine(cpus: int | None, cpu_model: str | None, gpu_models: list[str]) -> str:
    """A machine in the words of the rows so far: '1x NVIDIA H200, 16 cores' (the GPUs by model,
    in the driver's order, and the logical CPUs), or '2 AMD EPYC 7B13 cores, no GPU'."""
    cores = f"{cpus} cores" if cpus else "? cores"
    if gpu_models:
        return ", ".join(f"{n}x {m}" for m, n in Counter(gpu_models).items()) + f", {cores}"
    cpu = short_cpu(cpu_model)
    return f"{cpus or '?'} {cpu} cores, no GPU" if cpu else f"{cores}, no GPU"


def this_machine() -> str:
    """`describe_machine` of this machine (the GPUs the NVIDIA driver lists)."""
    return describe_machine(os.cpu_count(), cpu_model(), gpus.models())


def today() -> str:
    return datetime.datetime.now(datetime.timezone.utc).date().isoformat()


def complete(row: dict, where: str, machine: str | None = None) -> dict:
    """`row` with `date`, `machine` and `revision` filled where missing, checked; raises
    `ResultsError` naming `where` and the problem."""
    if not isinstance(row, dict):
        raise ResultsError(f"{where}: not a row (a dict of figures), got {type(row).__name__}")
    full = dict(row)
    if "date" not in full:
        full["date"] = today()
    if "machine" not in full:
        full["machine"] = machine if machine is not None else this_machine()
    if "revision" not in full:
        full["revision"] = revision()
    what = full.get("what")
    if not isinstance(what, str) or not what.strip():
        raise ResultsError(f"{where}: 'what' must name the measurement (a non-empty text), got {what!r}")
    where = f"{where} ({what!r})"
    if not isinstance(full["date"], str) or not re.fullmatch(r"\d{4}-\d{2}-\d{2}", full["date"]):
        raise ResultsError(f"{where}: 'date' must be YYYY-MM-DD, got {full['date']!r}")
    if not isinstance(full["machine"], str) or not full["machine"].strip():
        raise ResultsError(f"{where}: 'machine' must describe the machine (a non-empty text)")
    if full["revision"] is not None and not isinstance(full["revision"], str):
        raise ResultsError(f"{where}: 'revision' must be a commit (text) or None, got {full['revision']!r}")
    if "note" in full and not isinstance(full["note"], str):
        raise ResultsError(f"{where}: 'note' must be text, got {full['note']!r}")
    figs = figures(full)
    bad = [k for k in full if k not in results.TEXT and k not in figs]
    if bad:
        raise ResultsError(f"{where}: {', '.join(f'{k}={full[k]!r}' for k in bad)}: not a number "
                           "(figures are numbers under keys naming their unit, e.g. wall_s)")
    if not figs:
        raise ResultsError(f"{where}: no numeric figure (a row needs at least one, e.g. wall_s or steps_per_s)")
    try:
        json.dumps(full, allow_nan=False)
    except ValueError:
        raise ResultsError(f"{where}: a figure is not finite (NaN or infinity)") from None
    first = {k: full[k] for k in results.REQUIRED}  # the order of the rows so far: the keys, figures, note
    return {**first, **{k: v for k, v in full.items() if k not in first and k != "note"},
            **({"note": full["note"]} if "note" in full else {})}


def append_rows(stem: str, rows: list[dict], results_dir: str | os.PathLike | None = None,
                machine: str | None = None) -> Path:
    """Append `rows` to `results_dir/stem.jsonl` (default the repository's bench/results), each
    completed and checked (`complete`) before any is written; returns the file. `machine`: the
    description for rows without one (default `this_machine()`)."""
    if not isinstance(stem, str) or not STEM.match(stem) or stem.endswith(".jsonl"):
        raise ResultsError(f"result file stem must be a plain name such as 'builds', got {stem!r}")
    folder = Path(results_dir) if results_dir is not None else results.RESULTS
    path = folder / f"{stem}.jsonl"
    rows = list(rows)
    if machine is None and any("machine" not in r for r in rows if isinstance(r, dict)):
        machine = this_machine()
    if any(isinstance(r, dict) and "revision" not in r for r in rows):
        rev = revision()
        rows = [{"revision": rev, **r} if isinstance(r, dict) else r for r in rows]
    full = [complete(r, f"{path} row {i + 1} of {len(rows)}", machine) for i, r in enumerate(rows)]
    if not full:
        return path
    data = "".join(json.dumps(r, ensure_ascii=False, allow_nan=False) + "\n" for r in full).encode()
    folder.mkdir(parents=True, exist_ok=True)
    fd = os.open(path, os.O_RDWR | os.O_APPEND | os.O_CREAT, 0o666)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)  # held until closed: another run's rows wait, whole
        size = os.fstat(fd).st_size
        if size and os.pread(fd, 1, size - 1) != b"\n":
            data = b"\n" + data
        view = memoryview(data)
        while view:
            view = view[os.write(fd, view):]
    finally:
        os.close(fd)
    return path


def write_page(results_dir: str | os.PathLike) -> Path | None:
    """Re-render `docs/results.md` when `results_dir` is the repository's bench/results (the
    page shows those rows only); returns the page written, or None. A row elsewhere that no longer
    reads is reported on stderr, not raised: the rows just appended are kept either way."""
    if Path(results_dir).resolve() != results.RESULTS.resolve():
        return None
    try:
        write_atomic(results.PAGE, results.render(results.RESULTS).encode())
    except ResultsError as exc:
        print(f"results: {results.PAGE} not re-rendered: {exc}", file=sys.stderr)
        return None
    return results.PAGE
