"""What a build keeps of a grown object (`factory.sampler.record`, `pipelines.dataset.spool`) is
read back as data only: a planted pickle or a hostile record in a build's spool never runs and
never changes the data; a record holds only the known value types and round-trips exactly."""

from __future__ import annotations

import json
import pickle
import sys

import numpy as np
import pytest

from factory.sampler import Sampler, record
from pipelines.dataset import build, spool
from dataset_support import tiny_dataset_config
from test_dataset import _assert_identical


class _Planted:
    """A pickle that, when loaded, writes a file (what `os.system('touch ...')` would do)."""

    def __init__(self, path):
        self.path = str(path)

    def __reduce__(self):
        return (exec, (f"open({self.path!r}, 'w').write('ran')",))


@pytest.fixture(scope="module")
def grown():
    config = tiny_dataset_config()
    return Sampler(config.sampler, config.ldraw).sample(1)


def test_a_record_round_trips_exactly(grown):
    back = record.loads(record.dumps(grown))
    assert back.same_as(grown, atol=0) and back.index == grown.index and back.seed == grown.seed
    assert back.density == grown.density and back.end_reason == grown.end_reason
    for a, b in zip(grown.steps, back.steps):
        assert a.rejected == b.rejected and (a.checked, a.feasible, a.draws, a.density) == (b.checked, b.feasible, b.draws, b.density)
        assert np.array_equal(a.pose.R, b.pose.R) and np.array_equal(a.pose.t, b.pose.t)
        va, vb = a.verdict, b.verdict
        assert (va.reason, va.load, va.connections, va.blocked_by, va.failing, va.held_by) == \
               (vb.reason, vb.load, vb.connections, vb.blocked_by, vb.failing, vb.held_by)
        assert np.array_equal(va.pose.R, vb.pose.R)
    assert record.dumps(back) == record.dumps(grown)


@pytest.mark.parametrize("doc, message", [
    ({"format": record.FORMAT, "value": {"$type": "system", "fields": {}}}, "unknown type 'system'"),
    ({"format": record.FORMAT, "value": {"$type": "Pose", "fields": {"R": [1], "t": [0, 0, 0], "x": 1}}}, "no field 'x'"),
    ({"format": record.FORMAT, "value": {"$type": "Pose", "fields": {"R": [1, 0, 0, 0, 1, 0, 0, 0, 1], "t": [0, 0, 0]}}}, "expected an Assembly"),
    ({"format": record.FORMAT, "value": {"$array": "object", "shape": [1], "data": [1]}}, "bad array header"),
    ({"value": 1}, "not a record"),
])
def test_a_foreign_record_is_refused(doc, message):
    with pytest.raises(record.RecordError, match=message):
        record.loads(json.dumps(doc).encode())
    with pytest.raises(record.RecordError, match="not JSON"):
        record.loads(b"\x80\x04\x95")  # a pickle's first bytes


@pytest.mark.slow
def test_a_planted_pickle_or_record_in_the_spool_never_runs(tiny_dataset, tmp_path):
    """Anyone who can write to a shared output folder could run code as the next user of it: the
    spool was read with `pickle.loads`. A planted pickle (under the old name and the new one) and
    a record naming a type outside the known ones are now ignored: the objects are grown again,
    the data are the same and nothing ran."""
    ran = tmp_path / "ran"
    out = tmp_path / "planted"
    folder = spool.folder(out)
    folder.mkdir(parents=True)
    payload = pickle.dumps(_Planted(ran))
    (folder / "0000000.pkl").write_bytes(payload)
    spool.spool_path(out, 1).write_bytes(payload)
    hostile = {"version": spool.SPOOL_VERSION, "seconds": 1.0,
               "assembly": {"format": record.FORMAT, "value": {"$type": "exec", "fields": {"source": "x"}}}}
    spool.spool_path(out, 2).write_text(json.dumps(hostile))
    assert spool.get(out, 1, 0) is None and spool.get(out, 2, 0) is None
    build(tiny_dataset_config(), out, batch=2, progress=False)
    assert not ran.exists()
    _assert_identical(tiny_dataset, out)


def test_no_code_loads_pickles_from_files():
    """No `pickle.load(s)`, `torch.load` without `weights_only=True` or `allow_pickle=True` in the
    project's source: every file a build or a user can have written is read as data."""
    from pathlib import Path
    import re

    root = Path(__file__).resolve().parents[1]
    bad = re.compile(r"\bpickle\.loads?\(|\bcloudpickle\.loads?\(|\bdill\.loads?\(|\bmarshal\.loads?\(|\bshelve\.open\(|"
                     r"\bjoblib\.load\(|\bread_pickle\(|allow_pickle\s*=\s*True|\byaml\.(unsafe_)?load\(")
    hits = []
    for path in sorted(root.glob("*/**/*.py")):
        if ".venv" in path.parts or path.name == Path(__file__).name:
            continue
        text = path.read_text(encoding="utf-8")
        for n, line in enumerate(text.splitlines(), 1):
            if bad.search(line):
                hits.append(f"{path.relative_to(root)}:{n}: {line.strip()}")
        for m in re.finditer(r"\btorch\.load\((?:[^()]|\([^()]*\))*\)", text, re.S):
            if not re.search(r"weights_only\s*=\s*True", m.group(0)):
                hits.append(f"{path.relative_to(root)}:{text[:m.start()].count(chr(10)) + 1}: {m.group(0)[:80]}")
    assert not hits, "\n".join(hits)
