"""Every command and snippet of the README and the guides runs, and so does every example.

- `examples/*.py` run as scripts (`python examples/X.py OUT`), into one temporary folder, in name
  order (`evaluate.py` and `train_tiny.py` reuse the dataset `build_dataset.py` wrote there).
- Every line of a fenced sh/bash/console block of README.md, docs/quickstart.md and
  docs/guides/*.md is validated: `python -m M ARGS` by M's own argument parser (M's `main(argv)`,
  stopped right after its `parse_args`), with every `[optional]` part in and each `a|b`
  alternative tried, and every `--flag` spelled in full (argparse would take a prefix);
  `make T VAR=...` by the Makefile (T one of its targets, each VAR one it reads) and the commands
  `make -n` prints for it, parsed the same way; `torchrun` by torch's own parser; `export VAR=...`
  by the code reading VAR; and every repository path a command names exists.
- `HOW` says how each command also runs for real: a `Run` (in one workspace folder standing for
  the repository root, its required arguments only, placeholders such as MODEL replaced by real
  inputs and sizes scaled down by the command's own flags), or, for the heavy ones (minutes, a GPU,
  data this checkout does not hold), why it is validated only. A command without an entry fails.
- Every fenced python block is exec'd in a fresh folder, with the `SNIPPETS` substitutions
  (placeholder paths to real inputs, sizes scaled down), each of which must still match the snippet.
"""

from __future__ import annotations

import argparse
import ast
import contextlib
import importlib
import importlib.util
import io
import os
import re
import shlex
import subprocess
import sys
import types
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from ldraw_support import LDRAW, SHARED, needs_ldraw

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", ROOT / "docs" / "quickstart.md", *sorted((ROOT / "docs" / "guides").glob("*.md"))]
SHELL = {"sh", "bash", "console", "shell"}
EXAMPLES = sorted((ROOT / "examples").glob("*.py"))
SLOW_EXAMPLES = {"train_tiny.py"}  # torch, a tiny model built and trained, then answering: about 15 s
MAKEFILE = (ROOT / "Makefile").read_text()
MAKE_TARGETS = set(re.findall(r"^([A-Za-z][\w.-]*)\s*:(?!=)", MAKEFILE, re.M))
REPO_DIRS = ("examples", "tests", "docs", "factory", "pipelines", "eval", "train", "bench", "mjcf_templates")
PARSE_VALUES = {"N": "2", "K": "3"}
"""Placeholders that stand for numbers, as parsed (other placeholders are strings to a parser)."""


# -- the docs' blocks and commands ------------------------------------------------------------------
@dataclass(frozen=True)
class Block:
    doc: str
    line: int
    lang: str
    text: str


def doc_blocks() -> list[Block]:
    found = []
    for path in DOCS:
        lines = path.read_text().splitlines()
        i = 0
        while i < len(lines):
            m = re.match(r"^```(\w*)\s*$", lines[i])
            if not m:
                i += 1
                continue
            j = i + 1
            while not lines[j].startswith("```"):
                j += 1
            found.append(Block(str(path.relative_to(ROOT)), i + 1, m.group(1), "\n".join(lines[i + 1:j])))
            i = j + 1
    return found


@dataclass(frozen=True)
class Command:
    doc: str
    line: int
    text: str
    """As written, continuation lines joined, its comment dropped."""

    @property
    def where(self) -> str:
        return f"{self.doc}:{self.line}"

    @property
    def argv(self) -> Argv:
        return Argv.of(self.text)


@dataclass
class Argv:
    """A command line's shapes: `required` (optional `[...]` parts left out, each `a|b` its first),
    `variants` (every optional part in, one per alternative), and `named` (flags a free-form part
    names, e.g. `[any python -m train setting: --lr, --batch-size, ...]`)."""

    required: list[str]
    variants: list[list[str]]
    named: list[str] = field(default_factory=list)

    @classmethod
    def of(cls, text: str) -> Argv:
        items: list[tuple[str, bool]] = []
        named: list[str] = []
        group: list[str] | None = None
        for tok in shlex.split(text):
            assert tok != "|", f"a shell pipeline in {text!r}: not supported here"
            if tok == "...":
                continue
            if group is None and tok.startswith("["):
                group, tok = [], tok[1:]
            if group is None:
                items.append((tok, False))
                continue
            closed = tok.endswith("]")
            group.append(tok.rstrip("]"))
            if closed:
                if group[0] == "any" or any("..." in t for t in group):  # free-form: only its flags
                    named += [t.rstrip(",") for t in group if t.startswith("--")]
                else:
                    items += [(t, True) for t in group]
                group = None
        assert group is None, f"unclosed [ in {text!r}"

        def pick(tok: str, i: int) -> str:  # alternative i of `a|b|c` (its last when there are fewer)
            alternatives = tok.split("|")
            return alternatives[min(i, len(alternatives) - 1)]

        n = max([len(t.split("|")) for t, _ in items] or [1])
        required = [pick(t, 0) for t, optional in items if not optional]
        return cls(required, [[pick(t, i) for t, _ in items] for i in range(n)], named)


def doc_commands() -> list[Command]:
    found = []
    for block in doc_blocks():
        if block.lang not in SHELL:
            continue
        lines = block.text.splitlines()
        i = 0
        while i < len(lines):
            start, text = i, lines[i]
            while text.rstrip().endswith("\\"):
                i += 1
                text = text.rstrip()[:-1] + " " + lines[i].strip()
            i += 1
            if block.lang == "console":
                if not text.startswith("$ "):
                    continue  # output
                text = text[2:]
            text = re.sub(r"\s+", " ", re.sub(r"(^|\s)#.*$", "", text)).strip()
            if text:
                found.append(Command(block.doc, block.line + 1 + start, text))
    return found


COMMANDS = doc_commands()
UNIQUE = list({c.text: c for c in reversed(COMMANDS)}.values())[::-1]  # the first place each is shown


# -- validating a command line without running it ---------------------------------------------------
class _Parsed(BaseException):
    """Raised right after a command's `parse_args` succeeded: stops its `main` before any work."""

    def __init__(self, parser):
        self.parser = parser


def _is_python(prog: str) -> bool:
    return prog in ("python", "python3", ".venv/bin/python")


def command_main(module: str):
    """The `main(argv)` that `python -m module` runs."""
    mod = importlib.import_module(module)
    if hasattr(mod, "__path__"):  # a package: its __main__
        mod = importlib.import_module(module + ".__main__")
    return mod.main


def option_strings(parser: argparse.ArgumentParser) -> set[str]:
    found = set(parser._option_string_actions)
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                found |= option_strings(sub)
    return found


def parse_module_argv(module: str, argv: list[str], named=(), where: str = "") -> None:
    """`python -m module *argv` parsed by the module's own parser, and every flag in full."""
    if module == "torch.distributed.run":
        return parse_torchrun(argv, where)
    if module == "pytest":
        return None  # `make test`: pytest's own options
    main = command_main(module)
    original = argparse.ArgumentParser.parse_args

    def stop(self, args=None, namespace=None):
        original(self, args, namespace)
        raise _Parsed(self)

    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            argparse.ArgumentParser.parse_args = stop
            try:
                main(list(argv))
            finally:
                argparse.ArgumentParser.parse_args = original
    except _Parsed as parsed:
        known = option_strings(parsed.parser)
        unknown = [t.split("=")[0] for t in argv if t.startswith("--") and t.split("=")[0] not in known]
        unknown += [f for f in named if f not in known]
        assert not unknown, f"{where}: {module} has no flag(s) {unknown} (a prefix is not enough)"
        return None
    except SystemExit as exc:
        pytest.fail(f"{where}: `{module} {shlex.join(argv)}` is refused by its parser (exit {exc.code}): "
                    f"{err.getvalue().strip()}")
    pytest.fail(f"{where}: {module}'s main returned without parsing its arguments")


def parse_torchrun(argv: list[str], where: str) -> None:
    from torch.distributed.run import get_args_parser

    parser = get_args_parser()
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err):
            args = parser.parse_args(argv)
    except SystemExit:
        pytest.fail(f"{where}: torchrun refuses {argv}: {err.getvalue().strip()}")
    own = argv[:argv.index("-m")] if "-m" in argv else argv
    unknown = [t for t in own if t.startswith("--") and t not in option_strings(parser)]
    assert not unknown, f"{where}: torchrun has no flag(s) {unknown}"
    assert args.module, f"{where}: torchrun without -m MODULE"
    parse_module_argv(args.training_script, args.training_script_args, where=where)


def check_make(args: list[str], where: str) -> None:
    targets = [a for a in args if "=" not in a]
    variables = [a.split("=", 1)[0] for a in args if "=" in a]
    assert targets, f"{where}: make without a target"
    missing = [t for t in targets if t not in MAKE_TARGETS]
    assert not missing, f"{where}: the Makefile has no target(s) {missing}; it has {sorted(MAKE_TARGETS)}"
    unread = [v for v in variables if f"$({v})" not in MAKEFILE]
    assert not unread, f"{where}: the Makefile reads no variable(s) {unread}"
    # -n: print the commands, run none; -o: take the installed venv's stamp as made (no `setup` run)
    # Under `make test` the suite inherits make's variables: without them (and --no-print-directory)
    # the nested make prints "Entering directory" lines among the commands.
    env = {k: v for k, v in os.environ.items() if k not in ("MAKEFLAGS", "MAKELEVEL", "MFLAGS")}
    out = subprocess.run(["make", "--no-print-directory", "-n", "-o", ".venv/.installed", *args], cwd=ROOT,
                         capture_output=True, text=True, timeout=60, env=env)
    assert out.returncode == 0, f"{where}: make -n {shlex.join(args)}: {out.stderr.strip()}"
    lines = [shlex.split(line) for line in out.stdout.splitlines() if line.strip()]
    assert lines, f"{where}: make {shlex.join(args)} runs nothing"
    for toks in lines:
        assert _is_python(toks[0]) and toks[1] == "-m", f"{where}: make runs {toks}: not a python -m command"
        parse_module_argv(toks[2], toks[3:], where=f"{where} (make -n: {shlex.join(toks)})")


def check_paths(tokens: list[str], where: str) -> None:
    for tok in tokens:
        for part in re.split(r"[=,]", tok):
            if "/" in part and part.split("/")[0] in REPO_DIRS:
                assert list(ROOT.glob(part)), f"{where}: {part} is not in the repository"
            if part.startswith("../shared/") and SHARED.is_dir():
                rest = part[len("../shared/"):]
                assert list(SHARED.glob(rest)), f"{where}: {part} matches nothing in {SHARED}"


def env_read_by_code(var: str) -> bool:
    code = [p for d in ("factory", "pipelines", "eval", "train") for p in (ROOT / d).rglob("*.py")]
    return any(var in p.read_text() for p in code)


def validate(cmd: Command) -> None:
    shape = cmd.argv
    for tokens in dict.fromkeys(map(tuple, [shape.required, *shape.variants])):
        tokens = [PARSE_VALUES.get(t, t) for t in tokens]
        check_paths(tokens, cmd.where)
        while tokens and re.fullmatch(r"[A-Z_]+=\S*", tokens[0]):  # VAR=value command
            tokens = tokens[1:]
        prog, rest = tokens[0], tokens[1:]
        if prog == "export":
            for assignment in rest:
                var = assignment.split("=")[0]
                assert env_read_by_code(var), f"{cmd.where}: no code reads ${var}"
        elif prog == "make":
            check_make(rest, cmd.where)
        elif prog == "torchrun":
            parse_torchrun(rest, cmd.where)
        elif _is_python(prog):
            assert rest[:1] == ["-m"] and len(rest) > 1, f"{cmd.where}: `{cmd.text}`: python -m MODULE expected"
            parse_module_argv(rest[1], rest[2:], shape.named, cmd.where)
        else:
            pytest.fail(f"{cmd.where}: `{prog}`: no way to check this program here (tests/test_docs_commands.py)")


# -- how each command runs for real -----------------------------------------------------------------
@dataclass(frozen=True)
class Run:
    """A doc command run for real in the workspace: its required arguments, each token equal to a
    key of `subs` (or its part after `=`) replaced, then the flags of `scale` set (the doc's value
    replaced, or the flag added; None: a bare flag). `first`: later commands read what it writes, so
    it runs when the workspace is made, in the order of `first` (1, then 2). `writes`: paths it must
    leave. `ldraw`: reads ../shared."""

    subs: dict = field(default_factory=dict)
    scale: dict = field(default_factory=dict)
    first: int = 0
    writes: tuple = ()
    ldraw: bool = False


LDRAW_DIR, LIBRARY_ZIP = str(LDRAW), str(SHARED / "ldraw_library.zip")
TINY_SYNTH = {"--n": "3", "--min-steps": "2", "--max-steps": "3", "--candidates": "16", "--size": "128",
              "--tile": "64", "--objects-per-shard": "1", "--workers": "1", "--no-progress": None}
"""`make synth`'s 8 objects of 20-90 bricks take minutes: 3 objects of 2-3 bricks, 128 px views."""
SHORT = {"--n": "1", "--min-steps": "4", "--max-steps": "4", "--no-progress": None}
"""One object of 4 bricks (an object of up to 90 takes 20 s)."""
TOWER = "examples/tower.ldr"
HEAVY_SYNTH = "8 or 700 objects of 20-90 bricks (minutes); pipelines.synth runs scaled down (build-a-dataset.md)"
TWO_GPUS = "two GPUs; tests/test_train_ddp.py runs torchrun on the CPU"
HEAVY_TRAIN = "200 training steps and a whole evaluation; examples/train_tiny.py trains the same way for 3 steps"

HOW: dict[str, Run | str] = {
    # README.md
    "make synth N=8": HEAVY_SYNTH,
    "make test": "the test suite itself",
    ".venv/bin/python -m pipelines.sample --n 10 --seed 0 --out out/objects":
        Run(scale=SHORT, first=1, writes=("out/objects/summary.json",)),
    ".venv/bin/python -m pipelines.verify examples/tower.ldr --faults": Run(),
    "make synth N=700": HEAVY_SYNTH,
    "make train": HEAVY_TRAIN,
    ".venv/bin/python -m eval.predict --data out/synth --model baseline:heuristic --out preds.jsonl":
        Run(first=2, writes=("preds.jsonl",)),
    ".venv/bin/python -m eval.score --data out/synth --pred preds.jsonl --json": Run(),
    "make bench": "times every part of the factory (many minutes); tests/test_bench.py runs its quick mode",
    # docs/quickstart.md
    ".venv/bin/python -m eval.score --data out/synth --pred preds.jsonl": Run(),
    ".venv/bin/python -m pipelines.sample --n 4 --seed 0 --out out/objects": Run(scale=SHORT),
    ".venv/bin/python -m pipelines.verify out/objects/object_00000.ldr --json": Run(),
    # docs/guides/build-a-dataset.md
    "python -m pipelines.synth --n 8 --out out/synth [--seed 0] [--runner local|ray] [--workers 2]":
        Run(scale=TINY_SYNTH, first=1, writes=("out/synth/meta/info.json",)),
    "python -m pipelines.designs ../shared/ldraw_models/*.ldr ../shared/ldraw_models/*.mpd --out out/designs "
    "--ldraw ../shared/ldraw [--no-physics]":
        "every design of ../shared through the physics replay (minutes); tests/test_dataset_designs.py builds designs",
    "python -m pipelines.feedback --data out/designs --pred preds.jsonl --out out/designs-fb":
        "needs out/designs and a model's wrong pose answers on its train split; tests/test_feedback_dataset.py runs it",
    "python -m pipelines.export out/synth --format llamafactory out/synth-lf":
        Run(writes=("out/synth-lf/dataset_info.json",)),
    "python -m pipelines.export out/synth --format bcbench out/synth-bcbench": Run(writes=("out/synth-bcbench",)),
    "python -m pipelines.bcbench import ../bcbench-release out/bcbench --ldraw ../shared/ldraw":
        "needs BC-Bench's released data beside the checkout; tests/test_bcbench.py imports a hand-made release",
    # docs/guides/gpus-and-clusters.md
    "make train GPUS=2 [MODEL=...] [DATA=out/synth] [STEPS=200] ...": TWO_GPUS,
    "torchrun --standalone --nproc_per_node 2 -m train --data out/synth --outdir checkpoints/run "
    "[any python -m train flag]": TWO_GPUS,
    # docs/guides/grow-objects.md
    "python -m pipelines.sample --n 700 --seed 0 --out out/objects": Run(scale=SHORT),
    "python -m pipelines.sample --n 50 --seed 0 --out DIR --min-steps 20 --max-steps 20 --density-weight 0":
        Run(subs={"DIR": "out/objects-20"}, scale={"--n": "1", "--no-progress": None}, first=1,
            writes=("out/objects-20/summary.json",)),
    "python -m pipelines.sample --n 1000 --seed 0 --out DIR --check-backend jax --batch 64":
        Run(subs={"DIR": "out/objects-jax"}, scale=SHORT, writes=("out/objects-jax/object_00000.ldr",)),
    'python -m factory.sampler.histogram "on=A/summary.json" "off=B/summary.json" --out density.png':
        Run(subs={"A/summary.json": "out/objects/summary.json", "B/summary.json": "out/objects-20/summary.json"},
            writes=("density.png",)),
    # docs/guides/ldraw-library.md
    "export LDRAWDIR=~/Downloads/complete.zip": "sets the library of the commands below (the code reads $LDRAWDIR)",
    ".venv/bin/python -m pipelines.parts --prepare":
        "prepares every part of the usage prior from LDraw's whole library (minutes); verify-a-design.md's "
        "--designs line runs it for one model's parts",
    ".venv/bin/python -m pipelines.sample --n 16 --out out/objects":
        "objects of real parts need LDraw's whole library and each part prepared first (minutes)",
    ".venv/bin/python -m pipelines.distance out/objects ../my_designs": Run(subs={"../my_designs": "examples"}),
    ".venv/bin/python -m factory.ldraw steps model.mpd --ldraw ~/ldraw --json":
        Run(subs={"model.mpd": TOWER, "~/ldraw": LDRAW_DIR}, ldraw=True),
    ".venv/bin/python -m factory.ldraw part 3001 --ldraw ~/ldraw --json": Run(subs={"~/ldraw": LDRAW_DIR}, ldraw=True),
    ".venv/bin/python -m pipelines.render model.mpd --ldraw ~/ldraw --step 3 --out out/step3":
        Run(subs={"model.mpd": TOWER, "~/ldraw": LDRAW_DIR}, writes=("out/step3/after.png",), ldraw=True),
    # docs/guides/train.md
    "make designs": "every design of ../shared through the physics replay (minutes); tests/test_dataset_designs.py",
    "make train RECIPE=staged [DESIGNS=out/designs] [DATA=out/synth] [OUTDIR=checkpoints/run] "
    "[MODEL=/models/Qwen2.5-VL-3B-Instruct] [STAGE_STEPS=200,100,200] [TASKS=selection,pose] [LORA=auto]":
        "three trainings and their evaluations (minutes); tests/test_train_recipe.py runs the recipe small",
    "python -m train.recipe --designs out/designs --synthetic out/synth --outdir checkpoints/run [--model PATH] "
    "[--stage-steps 200,100,200] [--feedback-weights 1,1] [--synthetic-weights 1,1,1] [--feedback-limit N] "
    "[--eval-limit N] [any python -m train setting: --lr, --batch-size, --max-pixels, ...]":
        "three trainings and their evaluations (minutes); tests/test_train_recipe.py runs the recipe small",
    "make train MODEL=/models/Qwen2.5-VL-3B-Instruct DATA=out/synth STEPS=2000": "a real checkpoint and a GPU",
    ".venv/bin/python -m eval.predict --data out/synth --model hf:checkpoints/run/final --out preds.jsonl":
        "needs a trained checkpoint; examples/train_tiny.py trains one and answers through hf:",
    # docs/guides/verify-a-design.md
    "python -m pipelines.verify MODEL [--ldraw DIR] [--check-backend cpu|jax] --json [--faults]":
        Run(subs={"MODEL": TOWER}),
    "python -m pipelines.render MODEL --ldraw DIR --step K --out out/stepK":
        Run(subs={"MODEL": TOWER, "DIR": LDRAW_DIR, "K": "3"}, writes=("out/stepK/after.png",), ldraw=True),
    "python -m pipelines.parts --ldraw ../shared/ldraw_library.zip --designs MODEL.mpd --prepare":
        Run(subs={"../shared/ldraw_library.zip": LIBRARY_ZIP, "MODEL.mpd": TOWER}, scale={"--workers": "1"},
            ldraw=True),
}


def real_argv(cmd: Command, run: Run) -> list[str]:
    toks = []
    for t in cmd.argv.required:
        key, eq, value = t.partition("=")
        toks.append(run.subs.get(t, key + eq + run.subs.get(value, value) if eq else t))
    for flag, value in run.scale.items():
        if flag in toks:
            if value is not None:
                toks[toks.index(flag) + 1] = value
        else:
            toks += [flag] + ([] if value is None else [value])
    assert _is_python(toks[0]) and toks[1] == "-m", f"{cmd.where}: only python -m commands run here"
    return toks[2:]


def run_for_real(cmd: Command, run: Run, workspace: Path) -> tuple[int, str]:
    """Run the command's module in this process, in `workspace`: (exit status, its output)."""
    module, *argv = real_argv(cmd, run)
    out = io.StringIO()
    with contextlib.chdir(workspace), contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        try:
            status = command_main(module)(argv)
        except SystemExit as exc:
            status = exc.code
    return int(status or 0), f"{module} {shlex.join(argv)}\n{out.getvalue()}"


@pytest.fixture(scope="module")
def workspace(tmp_path_factory):
    """The folder doc commands run in, standing for the repository root (`examples` linked in),
    with a cache of its own and no $LDRAWDIR; the commands whose Run is `first` have run there
    (each once): {command text: (status, output)}."""
    ws = tmp_path_factory.mktemp("docs")
    (ws / "examples").symlink_to(ROOT / "examples")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("BRICK_FACTORY_CACHE", str(ws / ".cache"))
        mp.setenv("MPLBACKEND", "Agg")
        mp.delenv("LDRAWDIR", raising=False)
        done = {}
        for cmd in sorted((c for c in UNIQUE if isinstance(HOW.get(c.text), Run) and HOW[c.text].first),
                          key=lambda c: HOW[c.text].first):
            done[cmd.text] = run_for_real(cmd, HOW[cmd.text], ws)
            assert done[cmd.text][0] == 0, f"{cmd.where}: {done[cmd.text][1][-3000:]}"
        yield ws, done


# -- tests: the examples ----------------------------------------------------------------------------
def test_examples_are_short_documented_scripts():
    assert {p.name for p in EXAMPLES} >= {"grow_objects.py", "verify_design.py", "build_dataset.py", "evaluate.py",
                                          "train_tiny.py"}
    for path in EXAMPLES:
        tree = ast.parse(path.read_text())
        assert ast.get_docstring(tree), f"{path.name}: no module docstring saying what it shows"
        mains = [n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name == "main"]
        assert mains and [a.arg for a in mains[0].args.args] == ["out_dir"], f"{path.name}: no def main(out_dir)"
        assert "argparse" in path.read_text() and 'if __name__ == "__main__":' in path.read_text(), path.name
        assert len(path.read_text().splitlines()) <= 80, f"{path.name}: keep an example short"


@pytest.fixture(scope="module")
def examples_out(tmp_path_factory):
    return tmp_path_factory.mktemp("examples")


@pytest.mark.multiproc
@pytest.mark.parametrize("script", [pytest.param(p, marks=[pytest.mark.slow] if p.name in SLOW_EXAMPLES else [],
                                                 id=p.name) for p in EXAMPLES])
def test_example_runs(script, examples_out):
    # The session's part cache (content-keyed, written atomically): a fresh one made each example
    # decompose the embedded parts again.
    env = {**os.environ, "MPLBACKEND": "Agg",
           "HF_DATASETS_CACHE": str(examples_out / ".hf"),
           "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
    env.pop("LDRAWDIR", None)
    proc = subprocess.run([sys.executable, str(script), str(examples_out)], cwd=examples_out, env=env,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, f"{script.name}:\n{proc.stdout[-2000:]}\n{proc.stderr[-4000:]}"


# -- tests: the shell commands -------------------------------------------------------------------------
def test_the_docs_show_commands():
    assert len(COMMANDS) > 30 and {c.doc for c in COMMANDS} >= {"README.md", "docs/quickstart.md"}


@pytest.mark.parametrize("cmd", [pytest.param(c, marks=[pytest.mark.multiproc] if c.text.startswith("make ") else [],
                                              id=f"{c.where} {c.text[:60]}") for c in UNIQUE])  # make -n: a process
def test_doc_command_is_valid(cmd):
    validate(cmd)


def test_every_command_is_run_or_has_a_reason():
    missing = [f"{c.where}: {c.text}" for c in UNIQUE if not HOW.get(c.text)]
    assert not missing, ("commands with no entry in HOW (tests/test_docs_commands.py): give each a Run, or why it "
                         "is validated only:\n" + "\n".join(missing))
    stale = [text for text in HOW if text not in {c.text for c in UNIQUE}]
    assert not stale, f"HOW entries no doc shows any more: {stale}"


RUNS = [pytest.param(c, marks=[needs_ldraw] if HOW[c.text].ldraw else [], id=f"{c.where} {c.text[:60]}")
        for c in UNIQUE if isinstance(HOW.get(c.text), Run)]


@pytest.mark.parametrize("cmd", RUNS)
def test_doc_command_runs(cmd, workspace):
    ws, done = workspace
    run = HOW[cmd.text]
    status, output = done[cmd.text] if run.first else run_for_real(cmd, run, ws)
    assert status == 0, f"{cmd.where}: `{cmd.text}` failed:\n{output[-4000:]}"
    for path in run.writes:
        assert (ws / path).exists(), f"{cmd.where}: `{cmd.text}` wrote no {path}:\n{output[-2000:]}"


# -- tests: the python snippets -------------------------------------------------------------------------
def _processor_folder(ws: Path, out: Path) -> str:
    """A checkpoint's processor (the TRL snippet's MODEL): the tiny Qwen2-VL's, trained on out/synth."""
    from eval.processor import save_processor
    from train.tiny import dataset_texts, make_processor, train_tokenizer

    save_processor(make_processor(train_tokenizer(dataset_texts([ws / "out" / "synth"]))), out)
    return str(out)


@dataclass(frozen=True)
class Snippet:
    """How a python block runs: `subs` (text found in it -> its stand-in), `links` (workspace paths
    it reads), `names` ((workspace, folder) -> names it uses but does not define), `ldraw`."""

    subs: tuple = ()
    links: tuple = ()
    names: object = None
    ldraw: bool = False


SNIPPETS = {
    ("README.md", 1): Snippet(subs=(
        ("factory.grow(8, factory.SamplerConfig(seed=7))",
         "factory.grow(2, factory.SamplerConfig(seed=7, min_steps=3, max_steps=3))"),
        ("factory.DatasetConfig.synthetic(8, seed=0)",
         "factory.DatasetConfig.synthetic(1, seed=0, sampler=factory.SamplerConfig(min_steps=2, max_steps=2, "
         "candidates_per_step=16), size=64, tile=32)"))),
    ("docs/quickstart.md", 1): Snippet(links=("out/synth",)),
    ("docs/guides/grow-objects.md", 1): Snippet(subs=(
        ("seed=7)", "seed=7, min_steps=5, max_steps=5)"), ("range(1000)", "range(2)"),
        ("factory.grow(8, cfg", "factory.grow(2, cfg"))),
    ("docs/guides/ldraw-library.md", 1): Snippet(subs=(('"/path/to/ldraw"', repr(LDRAW_DIR)),
                                                       ('"model.mpd"', repr(TOWER))), ldraw=True),
    ("docs/guides/train.md", 1): Snippet(names=lambda ws, tmp: {"MODEL": _processor_folder(ws, tmp / "model"),
                                                               "RUN": str(tmp / "run")}),
}
"""(doc, its n-th python block from 1) -> how it runs; a block not listed runs as written."""


def python_blocks() -> dict[tuple[str, int], Block]:
    """(doc, n) -> the doc's n-th python block."""
    found: dict[tuple[str, int], Block] = {}
    for block in doc_blocks():
        if block.lang == "python":
            found[(block.doc, 1 + sum(doc == block.doc for doc, _ in found))] = block
    return found


def test_snippet_table_names_python_blocks():
    stale = set(SNIPPETS) - set(python_blocks())
    assert not stale, f"SNIPPETS keys naming no python block of the docs: {stale}"


SNIPPET_RUNS = [pytest.param(block, SNIPPETS.get(key, Snippet()), id=f"{block.doc}:{block.line}",
                             marks=[needs_ldraw] if SNIPPETS.get(key, Snippet()).ldraw else [])
                for key, block in python_blocks().items()]


def _trl_stub():
    """TRL is not a dependency: a stand-in `trl` whose SFTConfig keeps its arguments."""
    trl = types.ModuleType("trl")
    trl.SFTConfig = type("SFTConfig", (), {"__init__": lambda self, **kw: self.__dict__.update(kw)})
    return trl


@pytest.mark.parametrize("block, how", SNIPPET_RUNS)
def test_doc_snippet_runs(block, how, workspace, tmp_path, monkeypatch):
    import PIL.Image

    ws, _ = workspace
    code = block.text
    for old, new in how.subs:
        assert old in code, f"{block.doc}:{block.line}: the snippet no longer holds {old!r} (SNIPPETS)"
        code = code.replace(old, new)
    (tmp_path / "examples").symlink_to(ROOT / "examples")
    for rel in how.links:
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).symlink_to(ws / rel)
    monkeypatch.setattr(PIL.Image.Image, "show", lambda self, *a, **k: None)  # no image viewer
    if "datasets" in code:  # its Arrow cache in the test's folder, not the user's
        import datasets.config

        monkeypatch.setattr(datasets.config, "HF_DATASETS_CACHE", str(tmp_path / ".hf"))
    if "trl" in code and importlib.util.find_spec("trl") is None:
        monkeypatch.setitem(sys.modules, "trl", _trl_stub())
    names = {"__name__": "__doc_snippet__", **(how.names(ws, tmp_path) if how.names else {})}
    monkeypatch.chdir(tmp_path)
    exec(compile(code, f"{block.doc}:{block.line}", "exec"), names)  # noqa: S102
    if "to_trl" in names:  # the TRL mapping on a real row: prompt, the answer, the images
        import pyarrow.parquet as pq

        row = pq.read_table(sorted((ws / "out" / "synth").glob("**/train-*.parquet"))[0]).slice(0, 1).to_pylist()[0]
        mapped = names["to_trl"](row)
        assert mapped["completion"][0]["role"] == "assistant" and len(mapped["images"]) == len(row["pose_images"])
        assert names["args"].output_dir == names["RUN"]
