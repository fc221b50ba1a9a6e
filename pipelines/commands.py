"""`brick-factory COMMAND ...`: one console script for every command line of the project.

Each command is the module's own command line (`brick-factory synth ...` is `python -m
pipelines.synth ...`, arguments and exit status alike). Modules are named here as strings and run
by name, so this dispatcher imports none of them (`eval` and `train` stay out of `pipelines`'
imports); it first checks that the installed packages are ours (`install_check`).
"""

from __future__ import annotations

import runpy
import sys

from pipelines import install_check

COMMANDS: dict[str, tuple[str, str]] = {
    "ldraw": ("factory.ldraw", "read LDraw models and parts: steps, part"),
    "sample": ("pipelines.sample", "grow objects, written as .ldr files"),
    "prior": ("pipelines.prior", "fit a usage prior (part, colour, connection frequencies) to real designs"),
    "parts": ("pipelines.parts", "which parts of a library the factory can use, and preparing them"),
    "distance": ("pipelines.distance", "how far objects or a dataset are from real designs"),
    "verify": ("pipelines.verify", "physics checks of a model's placements"),
    "render": ("pipelines.render", "the image set of one build step"),
    "synth": ("pipelines.synth", "the synthetic dataset (the main job)"),
    "designs": ("pipelines.designs", "human designs into dataset rows"),
    "export": ("pipelines.export", "a dataset for LLaMA-Factory or in BC-Bench's layout"),
    "bcbench": ("pipelines.bcbench", "BC-Bench's released layout into our dataset format"),
    "predict": ("eval.predict", "answer a dataset split with a model or a baseline"),
    "score": ("eval.score", "BC-Bench metrics of a predictions file"),
    "feedback": ("pipelines.feedback", "world-feedback correction rows from a model's wrong pose answers"),
    "train": ("train", "fine-tune a vision-language model"),
    "recipe": ("train.recipe", "the staged recipe: designs, + world feedback, + synthetic data"),
    "bench": ("pipelines.bench", "the benchmark report (make bench)"),
    "bench-physics": ("pipelines.bench_physics", "physics checks per second, CPU and GPU"),
}
"""Command -> (module run as `python -m`, what it does)."""

PROG = "brick-factory"


def usage() -> str:
    width = max(map(len, COMMANDS))
    lines = [f"usage: {PROG} COMMAND [ARGS ...]   ({PROG} COMMAND --help for a command's arguments)", "",
             "commands:"]
    lines += [f"  {name:<{width}}  {what}" for name, (_module, what) in COMMANDS.items()]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else list(argv)
    if not args or args[0] in ("-h", "--help", "help"):
        print(usage())
        return 0 if args else 2
    name, rest = args[0], args[1:]
    # Once per command, before its module (and `factory`) is imported: the installed `factory` is
    # ours (the name is also factory_boy's). Not at import time, where every worker process and
    # library import would hash the installed files again.
    install_check.check()
    if name not in COMMANDS:
        print(f"{PROG}: unknown command {name!r}; valid: {', '.join(COMMANDS)}", file=sys.stderr)
        return 2
    module = COMMANDS[name][0]
    sys.argv = [f"{PROG} {name}", *rest]
    try:
        runpy.run_module(module, run_name="__main__", alter_sys=True)
    except SystemExit as exc:  # the command's own exit status
        code = exc.code
        if code is None or isinstance(code, int):
            return int(code or 0)
        print(code, file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
