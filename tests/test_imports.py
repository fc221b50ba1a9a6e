"""Imports run one way: factory <- the dataset contract (factory.dataset) <- eval <- pipelines <- train.

`factory` (LDraw to renders) imports nothing above it, not even the contract; the contract imports
only `factory`; `eval` reads datasets through the contract and imports neither `pipelines` nor
`train`; the dataset builder (`pipelines/dataset/`) writes through the contract and imports no
`eval`; `pipelines` (command lines such as `make bench` may score with `eval`) imports no `train`;
`train` may use all of them. Every import of every module counts, those inside functions too.
"""

from __future__ import annotations

import ast
import io
import re
import tokenize
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("factory", "eval", "pipelines", "train")
CONTRACT = "factory.dataset"

ALLOWED = {
    "factory": ("factory",),
    CONTRACT: ("factory", CONTRACT),
    "eval": ("factory", CONTRACT, "eval"),
    "pipelines.dataset": ("factory", CONTRACT, "pipelines", "pipelines.dataset"),
    "pipelines": ("factory", CONTRACT, "eval", "pipelines", "pipelines.dataset"),
    "train": ("factory", CONTRACT, "eval", "pipelines", "pipelines.dataset", "train"),
}
"""Per layer (the longest key that is a prefix of a module's name), the layers it may import."""
FACADE = {"factory/__init__.py": ("pipelines.dataset",)}
"""Imports up the layers a file may make: `factory`'s top-level names load the dataset builder on
first use (`factory.build_dataset`); no module of the library imports it."""


def _module_name(path: Path, root: Path = ROOT) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _layer(module: str) -> str | None:
    """The layer a dotted module name belongs to, or None for one outside the project."""
    best = None
    for key in ALLOWED:
        if module == key or module.startswith(key + "."):
            if best is None or len(key) > len(best):
                best = key
    return best


def _imports(path: Path, root: Path):
    """(line, names) of every import in the file, at any depth: the module, and for `from M import
    a` also `M.a` (`from factory import dataset` imports the contract)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    name = _module_name(path, root)
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, [alias.name]
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative: resolve against the module's package
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                module = ".".join([*base, node.module] if node.module else base)
            else:
                module = node.module
            yield node.lineno, [module, *(f"{module}.{a.name}" for a in node.names)]


def violations(root: Path = ROOT) -> list[str]:
    """`file:line: A imports B (A may import only ...)` for every import against the direction."""
    out = []
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            own = _layer(_module_name(path, root))
            if own is None:
                continue
            facade = FACADE.get(str(path.relative_to(root)), ())
            for line, names in _imports(path, root):
                if names[0] in facade:
                    continue
                for module in names:
                    target = _layer(module)
                    if target is not None and target not in ALLOWED[own]:
                        out.append(f"{path.relative_to(root)}:{line}: {own} imports {module} "
                                   f"({own} may import only {', '.join(ALLOWED[own])})")
                        break
    return out


def test_imports_run_one_way():
    found = violations()
    assert not found, "imports against factory <- factory.dataset <- eval <- pipelines <- train:\n" + "\n".join(found)


@pytest.mark.parametrize("package, source, bad", [
    ("eval", "from pipelines.dataset import prompts\n", "pipelines.dataset"),
    ("eval", "def f():\n    import train.processor\n", "train.processor"),
    ("factory/render", "from factory.dataset.schema import SCHEMA\n", "factory.dataset.schema"),
    ("factory/dataset", "from eval.parse import normalise_part\n", "eval.parse"),
    ("pipelines/dataset", "from eval.baselines import format_pose\n", "eval.baselines"),
    ("pipelines", "from train import feedback\n", "train"),
])
def test_an_import_against_the_direction_is_named(tmp_path, package, source, bad):
    """The checker finds an import against the direction, in a function too, naming file and line."""
    for p in PACKAGES:
        (tmp_path / p).mkdir()
    folder = tmp_path / package
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "mod.py").write_text("import json\n\n" + source)
    found = violations(tmp_path)
    assert len(found) == 1, found
    line = 3 if source.startswith(("from", "import")) else 4
    assert found[0].startswith(f"{package}/mod.py:{line}: ") and bad in found[0]


def test_allowed_imports_pass(tmp_path):
    for p in PACKAGES:
        (tmp_path / p).mkdir()
    (tmp_path / "train" / "a.py").write_text("from pipelines.dataset.shards import WRITER_OPTIONS\nimport eval.data\n")
    (tmp_path / "eval" / "b.py").write_text("from factory.dataset import TASKS\nfrom factory import Pose\nimport numpy\n")
    (tmp_path / "pipelines" / "c.py").write_text("from eval.score import score\n")
    assert violations(tmp_path) == []


# -- imports at the top ----------------------------------------------------------------------------

OPTIONAL = {
    "jax": "[jax]", "jaxlib": "[jax]", "ray": "[ray]",
    "torch": "[train]", "transformers": "[train]", "peft": "[train]", "accelerate": "[train]",
    "matplotlib": "[train], [bench]", "datasets": "[dev]",
    "tokenizers": "transformers' own", "safetensors": "transformers' own",
    "torchvision": "none: probed, absent on CPU machines (eval.processor)",
}
"""Top-level packages that are not core dependencies (the extra or package that brings each): an
import of one of them may sit inside a function without a comment."""


def _comment_lines(source: str) -> tuple[set[int], set[int]]:
    """(lines that carry a comment, lines that are only a comment)."""
    carry, only = set(), set()
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.COMMENT:
            carry.add(tok.start[0])
            if not tok.line[: tok.start[1]].strip():
                only.add(tok.start[0])
    return carry, only


def _import_blocks(body: list):
    """Runs of consecutive import statements in a statement list."""
    run = []
    for stmt in body:
        if isinstance(stmt, (ast.Import, ast.ImportFrom)):
            run.append(stmt)
            continue
        if run:
            yield run
        run = []
    if run:
        yield run


def unexplained_imports(root: Path = ROOT) -> list[str]:
    """`file:line: import ...` for every import inside a function that is neither of an optional
    package (`OPTIONAL`) nor explained by a comment: on one of its block's lines (a run of
    consecutive imports) or on a comment line right above the block."""
    out = []
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            rel = path.relative_to(root).as_posix()
            source = path.read_text()
            tree = ast.parse(source, filename=str(path))
            carry, only = _comment_lines(source)
            funcs = [n for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))]
            bodies = [body for f in funcs for n in ast.walk(f)
                      for body in (getattr(n, "body", None), getattr(n, "orelse", None), getattr(n, "finalbody", None))
                      if isinstance(body, list)]
            seen = set()
            for body in bodies:
                for block in _import_blocks(body):
                    first, last = block[0].lineno, block[-1].end_lineno
                    explained = (first - 1) in only or any(line in carry for line in range(first, last + 1))
                    for node in block:
                        if id(node) in seen:  # a nested function's body is walked from each enclosing one
                            continue
                        seen.add(id(node))
                        if isinstance(node, ast.Import):
                            names = [a.name for a in node.names]
                        else:
                            names = ["."] if node.level else [node.module]
                        if explained or all(n.split(".")[0] in OPTIONAL for n in names):
                            continue
                        out.append(f"{rel}:{node.lineno}: {ast.get_source_segment(source, node)}")
    return out


def test_imports_sit_at_the_top_unless_a_comment_says_why():
    found = unexplained_imports()
    assert not found, ("imports inside functions, not of an optional package and with no comment saying why "
                       "(move them to the top of the file, or say why not):\n" + "\n".join(found))


def test_optional_packages_are_not_core_dependencies():
    core = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    names = {re.split(r"[<>=!~\[; ]", d, maxsplit=1)[0].lower().replace("-", "_") for d in core}
    assert not names & set(OPTIONAL), names & set(OPTIONAL)


@pytest.mark.parametrize("source, flagged", [
    ("def f():\n    import json\n", True),
    ("class C:\n    def m(self):\n        if self:\n            from factory.pose import Pose\n", True),
    ("def f():\n    def g():\n        import json\n", True),
    ("def f():\n    try:\n        import json\n    except ImportError:\n        pass\n", True),
    ("def f():\n    import torch\n    import jax.numpy as jnp\n", False),
    ("def f():\n    import torch\n    import json\n", True),
    ("def f():\n    import json  # lazy: a reason\n", False),
    ("def f():\n    # lazy: a reason\n    import json\n    from factory import gpus\n", False),
    ("def f():\n    x = 1  # a comment on another line\n    import json\n", True),
    ("import json\n\nif json:\n    import os\n", False),
])
def test_an_unexplained_import_in_a_function_is_named(tmp_path, source, flagged):
    for p in PACKAGES:
        (tmp_path / p).mkdir()
    (tmp_path / "eval" / "mod.py").write_text(source)
    found = unexplained_imports(tmp_path)
    assert bool(found) == flagged, found
    if flagged:
        assert found[0].startswith("eval/mod.py:")


def _runtime_imports(path: Path, root: Path) -> set[str]:
    """The project modules a file imports when it runs (not under `if TYPE_CHECKING:`): for `from
    M import a`, `M.a` where that is a module, else `M`."""
    tree = ast.parse(path.read_text(), filename=str(path))
    typing_only = {id(n) for node in ast.walk(tree) if isinstance(node, ast.If)
                   and isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING"
                   for body in node.body for n in ast.walk(body)}
    name = _module_name(path, root)
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    out = set()
    for node in ast.walk(tree):
        if id(node) in typing_only or not isinstance(node, (ast.Import, ast.ImportFrom)):
            continue
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
            continue
        if node.level:
            base = package.split(".")
            module = ".".join([*base[: len(base) - (node.level - 1)], *([node.module] if node.module else [])])
        else:
            module = node.module
        for a in node.names:
            sub = f"{module}.{a.name}"
            out.add(sub if (root / Path(*sub.split("."))).with_suffix(".py").exists()
                    or (root / Path(*sub.split(".")) / "__init__.py").exists() else module)
    return {m for m in out if _layer(m) is not None and m != name and not name.startswith(m + ".")}


def mutual_imports(root: Path = ROOT) -> list[str]:
    """`A <-> B` for every two modules that import each other (a package's `__init__` importing
    its own modules, and a module importing a package above it, are not counted)."""
    graph = {}
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            graph[_module_name(path, root)] = _runtime_imports(path, root)
    return sorted(f"{a} <-> {b}" for a, deps in graph.items() for b in deps
                  if a < b and a in graph.get(b, ()) and not a.startswith(b + ".") and not b.startswith(a + "."))


def test_no_two_modules_import_each_other():
    assert mutual_imports() == []


def test_two_modules_importing_each_other_are_named(tmp_path):
    pkg = tmp_path / "factory"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("from factory.a import f\n")
    (pkg / "a.py").write_text("from factory import b, c\n\ndef f():\n    return b, c\n")
    (pkg / "b.py").write_text("def g():\n    from factory.a import f  # lazily: still a cycle\n    return f\n")
    (pkg / "c.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from factory.a import f\n")
    assert mutual_imports(tmp_path) == ["factory.a <-> factory.b"]
