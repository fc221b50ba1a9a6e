"""The one sub-assembly walk (`factory.ldraw.subassembly.walk`) on the real designs: every part in its
assembly's frame, every finished sub-assembly attached in its parent's, and the two callers (the
physics replay, `factory.replay.verify_model`, and the design dataset source,
`pipelines.dataset.sources.manual_steps`) see the same steps, units and placements."""

from __future__ import annotations

import numpy as np
import pytest

from factory.ldraw import build_steps, get_reader
from factory.ldraw.subassembly import PartsStep, UnitDone, frame_inverse, walk
from factory.pose import Pose
from factory.replay import verify_model
from pipelines.dataset.sources import manual_steps
from ldraw_support import LDRAW, MODELS, needs_ldraw

DESIGNS = ["car.ldr", "4915-1-MiniConstruction.mpd", "6716-1 - Covered Wagon.mpd", "40448 - Vintage Car.mpd",
           "10156-1 - LEGO Truck.mpd", "6861-1 - X1 Patrol Craft.mpd"]


def _walked(name):
    reader = get_reader(str(LDRAW))
    frames: dict[str, Pose] = {}
    steps = build_steps(reader, reader.open_model(MODELS / name), frames)
    return steps, frames, list(walk(steps, frames))


def _close(a: Pose, b: Pose, tol: float = 1e-6) -> bool:
    return np.allclose(a.R, b.R, rtol=0, atol=tol) and np.allclose(a.t, b.t, rtol=0, atol=tol)


def test_frame_inverse_is_exact_where_transposing_is_not():
    r = np.array([[0.707107, 0, 0.707107], [0, 1, 0], [-0.707107, 0, 0.707107]])  # as real files round it
    frame = Pose(r, np.array([120.0, -48.0, 400.0]))
    assert _close(frame_inverse(frame) @ frame, Pose.identity(), 1e-12)
    off = frame.inverse() @ frame
    assert not _close(off, Pose.identity(), 1e-7)  # the transpose is off by about 1e-6 here


@needs_ldraw
@pytest.mark.parametrize("name", DESIGNS)
def test_walk_places_every_part_in_its_frame_and_reassembles_the_model(name):
    steps, frames, events = _walked(name)
    seen = [e.step for e in events if isinstance(e, PartsStep)]
    assert seen == steps  # every build step once, in build order
    model_poses = {}  # every part's pose in the model frame, rebuilt from the local poses and units
    placed: dict[str, list] = {}
    for e in events:
        if isinstance(e, PartsStep):
            assert _close(frames[e.step.assembly] @ e.to_local, Pose.identity(), 1e-9)
            placed.setdefault(e.step.assembly, []).extend(
                (id(p), e.to_local @ p.pose) for p in e.step.parts)
            model_poses.update((id(p), p.pose) for p in e.step.parts)
        else:
            assert e.parent == e.tag.rsplit("/", 1)[0]
            assert _close(frames[e.parent] @ e.to_parent, frames[e.tag], 1e-9)
            placed.setdefault(e.parent, []).extend((k, e.to_parent @ q) for k, q in placed.pop(e.tag))
    main = frames.get("main", Pose.identity())
    assert set(placed) == {"main"} and len(placed["main"]) == sum(len(s.parts) for s in steps)
    for k, local in placed["main"]:
        assert _close(main @ local, model_poses[k], 1e-6)
    units = [e.tag for e in events if isinstance(e, UnitDone)]
    assert len(units) == len(set(units)) and (name == "car.ldr") == (not units)


@pytest.mark.slow
@needs_ldraw
@pytest.mark.parametrize("name", ["car.ldr", "4915-1-MiniConstruction.mpd"])
def test_replay_and_dataset_source_walk_alike(name):
    """verify_model's records and manual_steps' steps follow the walk: the same parts in the same
    steps at the same local poses, and for every finished sub-assembly one unit record and one
    module step with its parts at their poses in the parent's frame, in the same order."""
    steps, frames, events = _walked(name)
    records = list(verify_model(MODELS / name, str(LDRAW)))
    rows, _, _ = manual_steps(MODELS / name, str(LDRAW), physics=False)
    expected = []  # (kind, assembly, poses) per walk event, as the rows must show it
    placed: dict[str, list[Pose]] = {}
    for e in events:
        if isinstance(e, PartsStep):
            new = [e.to_local @ p.pose for p in e.step.parts]
            expected.append(("part", e.step.assembly, new))
            placed.setdefault(e.step.assembly, []).extend(new)
        else:
            new = [e.to_parent @ q for q in placed.pop(e.tag)]
            expected.append(("module", e.parent, new))
            placed.setdefault(e.parent, []).extend(new)
    assert [(s.kind, s.assembly, len(s.new)) for s in rows] == [(k, a, len(n)) for k, a, n in expected]
    for s, (_, _, poses) in zip(rows, expected):
        assert all(_close(p.pose, q, 1e-9) for p, q in zip(s.new, poses))
    assert [r["assembly"] for r in records if r.get("unit")] == [e.tag for e in events if isinstance(e, UnitDone)]
    parts = [(r["step"], r["index"], r["part"]) for r in records if not r.get("unit")]
    assert parts == [(s.index, i, p.part) for s in steps for i, p in enumerate(s.parts)]
    # Every part or unit held by a joint says by which kinds; the Mini Construction's boom, dipper
    # stick and bucket go on by click hinges (their `clh` primitives), and the hinges hold them.
    held = [r for r in records if r.get("joints")]
    assert held and not any(r["reason"] == "unsupported-connection" for r in records)
    if name.startswith("4915"):
        assert all(r["reason"] is None for r in held if r.get("unit")), [r for r in held if r.get("unit")]
        units = {r["assembly"].rsplit("/", 1)[-1]: r["joints"][0] for r in held if r.get("unit")}
        assert {k.split(" - ")[-1].split(".")[0]: v for k, v in units.items()} == {
            "Boom": "click-hinge", "Dipper Stick": "click-hinge", "Bucket": "click-hinge"}
