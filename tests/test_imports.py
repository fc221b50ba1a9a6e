"""Imports run one way: factory <- the dataset contract (factory.dataset) <- eval <- pipelines <- train.

`factory` (LDraw to renders) imports nothing above it, not even the contract; the contract imports
only `factory`; `eval` reads datasets through the contract and imports neither `pipelines` nor
`train`; the dataset builder (`pipelines/dataset/`) writes through the contract and imports no
`eval`; `pipelines` (command lines such as `make bench` may score with `eval`) imports no `train`;
`train` may use all of them. Every import of every module counts, those inside functions too.
"""

from __future__ import annotations

import ast
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
            for line, names in _imports(path, root):
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
