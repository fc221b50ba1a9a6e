"""Physics checks on small structures built inline from the embedded library: enumeration, every
rejection rule, the cache, and verdict parity of the CPU reference and the batched JAX backend."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from factory import Pose, load_part
from factory.physics.check import CheckConfig, check, check_units
from factory.physics.geometry import DecompositionConfig, cache_dir, collision_shape
from factory.physics.load_model import LoadConfig
from factory.physics import attach, collide
from factory.physics.attach import attachment_arrays, feasible_poses
from factory.physics.structure import Placed, Structure, align, canonical_key, match
from factory.symmetry import rotation_about
from factory.physics.check_state import DEFAULT
from ldraw_support import at, part

ROOT = Path(__file__).resolve().parents[1]
I3 = np.eye(3)


pytestmark = pytest.mark.usefixtures("isolated_cache")


def test_enumeration_connects_every_pose_and_drops_symmetric_duplicates():
    base = Structure([at("3001", 0, 0, 0)])
    poses = feasible_poses(base, part("3001"))
    assert poses and all(base.connections_with(part("3001"), p) for p in poses)
    keys = [canonical_key(part("3001"), p) for p in poses]
    assert len(set(keys)) == len(keys)
    # A 2x2 brick is 4-fold symmetric: each of its placements is found once, not four times.
    two = feasible_poses(Structure([at("3003", 0, 0, 0)]), part("3003"))
    spots_2x2 = {tuple(np.round(p.t, 3)) for p in two}
    assert len(two) == len(spots_2x2)
    # The exact stack is among them, on top and hanging below.
    assert any(np.allclose(p.t, [0, -24, 0]) and np.allclose(p.R, I3) for p in poses)
    assert any(np.allclose(p.t, [0, 24, 0]) for p in poses)


def _plain_loop(structure, p):
    """The definition written pose by pose: every (connector, free target, turn), deduplicated."""
    stud_busy, sock_busy = structure.occupied()
    sp, sa, _ = structure.studs
    kp, ka, _ = structure.sockets
    plans = [(np.array(c.pos), np.array(c.axis), sp[~stud_busy], sa[~stud_busy]) for c in p.sockets]
    plans += [(np.array(c.pos), np.array(c.axis), kp[~sock_busy], ka[~sock_busy]) for c in p.studs]
    seen, out = set(), []
    for q, b, targets, axes in plans:
        for t, a in zip(targets, axes):
            for k in range(4):
                r = np.round(rotation_about(a if not np.allclose(np.abs(a), [0, 1, 0]) else (0, 1, 0), 90.0 * k)
                             @ align(b, a), 12)
                pose = Pose(r, t - r @ q)
                key = canonical_key(p, pose)
                if key not in seen:
                    seen.add(key)
                    out.append(pose)
    return out


def test_vectorised_enumeration_matches_the_plain_loop():
    s = Structure([at("3001", 0, 0, 0), at("3022", 10, -8, 10, colour=1)])
    for name in ("3001", "3039", "3022"):
        mine, theirs = feasible_poses(s, part(name)), _plain_loop(s, part(name))
        assert len(mine) == len(theirs) > 0
        assert all(a.allclose(b) for a, b in zip(mine, theirs))


def test_enumeration_matches_the_plain_loop_with_side_studs(real_reader):
    """Connectors on several axes (side studs of 87087 and 4070, both faces of 3956) on a
    structure with side studs free, sockets taken and a turned part: the same poses in the same
    order as the plain loop."""
    from factory import load_part

    real = {n: load_part(real_reader, n) for n in ("3001", "87087", "4070", "3956", "3023")}
    turn = rotation_about((0, 1, 0), 90.0)
    s = Structure([Placed(real["3001"], 4, Pose(np.eye(3), [0, 0, 0])),
                   Placed(real["87087"], 1, Pose(np.eye(3), [0, -24, 0])),
                   Placed(real["4070"], 14, Pose(turn, [20, -24, 0])),
                   Placed(real["3023"], 2, Pose(turn, [-10, -8, 0]))])
    assert len(s.studs[1]) and (np.abs(s.studs[1][:, 1]) < 0.5).any()  # a side stud is there
    for name in ("87087", "4070", "3956", "3023"):
        mine, theirs = feasible_poses(s, real[name]), _plain_loop(s, real[name])
        assert len(mine) == len(theirs) > 0
        assert all(a.allclose(b) for a, b in zip(mine, theirs))


def _occupied_from_scratch(structure):
    """Every stud and socket of two different parts that coincide with the same axis (`match` of
    all of them at once, the definition)."""
    sp, sa, so = structure.studs
    kp, ka, ko = structure.sockets
    studs, socks = np.zeros(len(sp), bool), np.zeros(len(kp), bool)
    for i, j in match(sp, sa, kp, ka):
        if so[i] != ko[j]:
            studs[i] = socks[j] = True
    return studs, socks


def test_occupied_masks_kept_as_parts_come_match_the_definition():
    """A structure of bricks, plates and a slope grown at random attachments (overlaps allowed:
    parts covering several others' studs, studs under sockets of two parts): after every part,
    the occupied masks kept by `add` equal `match` of all studs and sockets; a caller changing the
    masks it got does not change the structure's."""
    rng = np.random.default_rng(3)
    names = ("3001", "3020", "3022", "3039", "3003")
    s = Structure([at("3001", 0, 0, 0)])
    for k in range(40):
        p = part(names[k % len(names)])
        r, t = attachment_arrays(s, p)
        i = int(rng.integers(len(t)))
        s.add(Placed(p, 4, Pose(r[i], t[i])))
        studs, socks = s.occupied()
        want_studs, want_socks = _occupied_from_scratch(s)
        assert np.array_equal(studs, want_studs) and np.array_equal(socks, want_socks)
    assert studs.sum() > 40 and socks.sum() > 40
    studs[:] = True  # a copy: the structure's masks stay
    assert not s.occupied()[0].all()


def test_first_rows_packed_and_sorted_paths_agree_with_the_definition():
    """`_first_rows` on integer rows (packed into one number when their spans fit, else sorted)
    and on float rows: each distinct row's first index, ascending, and each row's group (the rank
    of its first occurrence), as a dict over the rows in order gives them."""
    rng = np.random.default_rng(0)
    cases = [rng.integers(-3, 4, size=(500, 4)), rng.integers(0, 2, size=(7, 1)),
             np.concatenate([rng.integers(-2**40, 2**40, size=(50, 3)), rng.integers(0, 3, size=(50, 1))], axis=1),
             np.round(rng.integers(0, 3, size=(300, 3)) * 0.1, 9)]
    cases.append(np.concatenate([cases[2], cases[2][::-1]]))  # spans too wide to pack: the sorted path
    assert attach._packed(cases[2]) is None and attach._packed(cases[0]) is not None
    for keys in cases:
        seen: dict[tuple, int] = {}
        group = np.array([seen.setdefault(tuple(row), len(seen)) for row in keys.tolist()])
        firsts = np.array([group.tolist().index(g) for g in range(len(seen))])
        got_firsts, got_group = attach._first_rows(keys)
        assert np.array_equal(got_firsts, firsts) and np.array_equal(got_group, group)


def test_occupied_studs_are_not_offered():
    stack = Structure([at("3001", 0, 0, 0), at("3001", 0, -24, 0)])
    poses = feasible_poses(stack, part("3001"))
    # The lower brick's studs are all covered: nothing may sit on them (y = -24 spots).
    assert not any(np.isclose(p.t[1], -24) for p in poses)


def test_stacked_brick_is_accepted():
    (v,) = check(Structure([at("3001", 0, 0, 0)]), part("3001"), [Pose(I3, [0, -24, 0])])
    assert v.ok and v.connections == 8 and not v.collision and v.stable and v.load <= 1


def test_each_rejection_rule():
    base = Structure([at("3001", 0, 0, 0)])
    brick = part("3001")
    shifted, lifted, inside, below_floor = check(
        base, brick,
        [Pose(I3, [10, -24, 0]), Pose(I3, [0, -32, 0]), Pose(I3, [0, 0, 0]), Pose(I3, [0, 24, 0])],
        config=CheckConfig(), colour=4,
    )
    assert shifted.reason == "collision" and shifted.max_penetration_ldu > 3
    assert lifted.reason == "no-connection" and not lifted.touching
    assert inside.reason == "collision"
    # Hanging under the first brick is fine in the air, but the sampler's ground is fixed.
    (hang,) = check_units(base, [[Placed(brick, 4, Pose(I3, [0, 24, 0]))]], floor_y=24.0)
    assert hang.reason == "collision"
    assert below_floor.reason is None  # without a fixed ground the object rests on its new bottom
    # Tipping: a tower leaning out over its base.
    lean = Structure([at("3001", 0, 0, 0), at("3001", 60, -24, 0)])
    (tip,) = check(lean, brick, [Pose(I3, [120, -48, 0])])
    assert tip.reason == "unstable" and tip.load is None
    # A brick under the first one's end, on the ground: it stands, and with a clutch too weak
    # for the first brick's weight the first brick, now carried by its two studs, is overloaded.
    weak = CheckConfig(loads=LoadConfig(clutch_n=0.005))
    (pull,) = check_units(base, [[at("3001", 60, 24, 0)]], config=weak)
    assert pull.reason == "overload" and pull.failing
    (held,) = check_units(base, [[at("3001", 60, 24, 0)]])
    assert held.clutch and held.reason is None


def test_unknown_backend_is_refused():
    with pytest.raises(ValueError, match="unknown check backend 'bullet'; valid choices: cpu, jax"):
        check(Structure([at("3001", 0, 0, 0)]), part("3001"), [Pose.identity()], backend="bullet")


def test_decompositions_are_cached_on_disk(tmp_path, monkeypatch):
    monkeypatch.setenv("BRICK_FACTORY_CACHE", str(tmp_path))
    cfg = DecompositionConfig(inset_ldu=0.3)  # a config no other test uses: a fresh entry
    first = collision_shape(part("3039"), cfg)
    # Two entries: the decomposition and its pieces made faithful (named by the shape's key).
    files = sorted(cache_dir().glob("*.npz"), key=lambda f: f.stem != first.key)
    assert len(files) == 2 and files[0].stem == first.key
    # A new Part object (as in a new process) reads the entry instead of decomposing again.
    from factory.parts import Part

    clone = Part(name="3039.dat", description="", moved_to=None, flat=part("3039").flat)
    mtimes = [f.stat().st_mtime_ns for f in files]
    again = collision_shape(clone, cfg)
    assert [f.stat().st_mtime_ns for f in files] == mtimes
    assert all(np.allclose(a, b) for a, b in zip(first.body, again.body))
    # A damaged entry is recomputed and replaced: the refined one alone (from the decomposition's
    # entry), then both.
    for damaged in (files[:1], files):
        for f in damaged:
            f.write_bytes(b"not a zip")
        clone2 = Part(name="3039.dat", description="", moved_to=None, flat=part("3039").flat)
        repaired = collision_shape(clone2, cfg)
        assert len(repaired.body) == len(first.body)
        for f in files:
            with np.load(f) as data:
                assert int(data["n"]) == len(first.body)


def test_inset_pieces_stay_inside_the_part():
    for name in ("3001", "3039", "3665", "3024"):
        shape = collision_shape(part(name))
        lo, hi = part(name).bbox
        for piece in shape.body + shape.studs:
            assert np.all(piece >= lo + 0.2) and np.all(piece <= hi - 0.2)


def _random_candidates(rng, n):
    """Structures and candidates of every kind: valid, colliding, floating, overhanging."""
    cases = []
    names = ["3001", "3003", "3004", "3022", "3039", "3010"]
    while len(cases) < n:
        parts = [at(rng.choice(names), 0, 0, 0)]
        for _ in range(rng.integers(1, 4)):
            s = Structure(parts)
            cand = part(rng.choice(names))
            poses = feasible_poses(s, cand)
            good = [p for p in poses if p.t[1] < parts[-1].pose.t[1]]  # build upward
            if not good:
                break
            parts.append(Placed(cand, 4, good[rng.integers(len(good))]))
        s = Structure(parts)
        cand = part(rng.choice(names))
        poses = feasible_poses(s, cand)
        picks = [poses[i] for i in rng.choice(len(poses), size=min(6, len(poses)), replace=False)]
        extra = [
            Pose(picks[0].R, picks[0].t + [10, 0, 0]),  # colliding or floating
            Pose(picks[0].R, picks[0].t + [0, -8, 0]),  # floating
            Pose(picks[0].R, picks[0].t + [0, 0, 0]),
            Pose(I3, [rng.choice([-100, 100]), -24 * len(parts), 0]),  # far overhang or floating
        ]
        cases.append((s, cand, picks + extra))
    return cases


@pytest.mark.slow
def test_cpu_and_jax_backends_agree_on_200_candidates():
    pytest.importorskip("jax")
    rng = np.random.default_rng(7)
    total, reasons = 0, set()
    for s, cand, poses in _random_candidates(rng, 24):
        a = check(s, cand, poses, backend="cpu", colour=4)
        b = check(s, cand, poses, backend="jax", colour=4)
        assert [v.reason for v in a] == [v.reason for v in b]
        total += len(poses)
        reasons |= {v.reason for v in a}
    assert total >= 200
    assert {None, "collision", "no-connection"} <= reasons


def test_verify_command_on_the_example_model():
    out = subprocess.run(
        [sys.executable, "-m", "pipelines.verify", "factory/data/examples/tower.mpd", "--faults", "--json"],
        cwd=ROOT, capture_output=True, text=True, timeout=600,
    )
    assert out.returncode == 0, out.stderr
    lines = [json.loads(x) for x in out.stdout.splitlines()]
    plain = [r for r in lines if "fault" not in r and "summary" not in r]
    assert {"step", "index", "part", "color", "collision", "max_penetration_ldu", "connected",
            "connections", "stable", "buildable", "approach", "blocked_by", "reason"} <= set(plain[0])
    assert all(r["buildable"] for r in plain[1:] if r["connected"] and not r.get("unit"))
    assert all(r["reason"] is None for r in plain)
    assert [r for r in plain if r.get("unit")][0]["part"] == "roof.ldr#1"
    summary = lines[-1]["summary"]
    assert summary["fidelity"] == 1.0 and summary["not_buildable"] == 0
    assert summary["faults"]["shift"]["rejected"] == 1.0
    assert summary["faults"]["lift"]["right_reason"] == 1.0


def test_faults_of_a_part_hanging_from_a_later_part_of_its_step(tmp_path):
    from factory.replay import verify_model

    # Step 2 lists a 1x1 plate first: it hangs under the 2x4 plate listed after it in the same
    # step (which sits on the 2x2 brick). Its faults move it off that plate's sockets.
    model = tmp_path / "hang.ldr"
    model.write_text("0 Hanging\n"
                     "1 4 0 -24 0 1 0 0 0 1 0 0 0 1 3003.dat\n0 STEP\n"
                     "1 4 30 -24 10 1 0 0 0 1 0 0 0 1 3024.dat\n"
                     "1 4 0 -32 0 1 0 0 0 1 0 0 0 1 3020.dat\n0 STEP\n")
    records = list(verify_model(model, faults=True))
    plain = [r for r in records if "fault" not in r]
    assert [r["reason"] for r in plain] == [None, None, None]
    top = [r for r in records if r.get("fault") and r["step"] == 1 and r["index"] == 0]
    assert {r["fault"] for r in top} >= {"shift", "lift"}
    assert all(r["reason"] is not None for r in top if r["fault"] in ("shift", "lift"))


def test_turning_a_symmetric_part_is_no_fault():
    p = part("3003")
    pose = Pose(I3, [0, -24, 0])
    turned = Pose(rotation_about((0, -1, 0), 90) @ I3, [0, -24, 0])
    assert canonical_key(p, pose) == canonical_key(p, turned)


@pytest.mark.parametrize("name, held_otherwise, offers_other", [
    ("3001", False, False),   # brick: studs and sockets only
    ("3068b", False, True),   # tile: sockets only, so it can only sit on studs
    ("3938", True, True),     # hinge top: studs, no sockets; held by its hinge
    ("3937", False, True),    # hinge base: sockets, no studs; offers the hinge
    ("3641", True, True),     # tyre: neither
    ("6157", True, True),     # wheel holder: Technic pins
])
def test_which_parts_may_be_held_by_connections_not_modelled(real_reader, name, held_otherwise, offers_other):
    from factory.physics import unmodelled

    p = load_part(real_reader, name)
    assert (unmodelled.held_otherwise(p), unmodelled.offers_other(p)) == (held_otherwise, offers_other)


@pytest.mark.slow
def test_a_pin_is_a_joint_only_in_the_hole(real_reader):
    # A Technic beam 1 (18654: one pin hole along Y through its centre, 20 LDU long) and a friction
    # pin (2780: two 20 LDU halves along X from its collar) turned to run along Y, half in the hole.
    # Parts chosen for cheap collision pieces (a few seconds of coacd each).
    beam, pin = load_part(real_reader, "18654"), load_part(real_reader, "2780")
    base = Structure([Placed(beam, 4, Pose.identity())])
    along_y = rotation_about((0, 0, 1), 90)
    real, shifted, sideways = check(base, pin, [Pose(along_y, [0, -10, 0]), Pose(along_y, [10, -10, 0]),
                                                Pose(along_y, [0, -10, 8])])
    # A Technic pin joint (the pin's `connect` primitives on the hole's axis: the half in the
    # hole, not the half ending at its mouth), which the shifted pin is not.
    assert real.reason is None and [(l.kind, l.point, l.axis) for l in real.joints] == [
        ("technic-pin", (0.0, 0.0, 0.0), (0.0, 1.0, 0.0))], real
    from factory.ldraw.other_connectors import CONNECTOR_KINDS
    from factory.physics.unmodelled import joint_kind

    assert {CONNECTOR_KINDS[k] for k in pin.flat.other_kinds} == {"pin"}
    assert {CONNECTOR_KINDS[k] for k in beam.flat.other_kinds} == {"pin-hole"}
    assert joint_kind(pin, real.pose, beam, Pose.identity()) == "technic-pin"
    assert joint_kind(pin, shifted.pose, beam, Pose.identity()) is None
    # Both parts have Technic connectors, as before; but off the hole's axis the pin is judged like
    # any part: it runs into the beam.
    assert shifted.reason == "collision" and sideways.reason == "collision"


def test_hinge_halves_are_excused_only_on_one_axis(real_reader):
    from factory.physics.unmodelled import may_hold

    dual, single = load_part(real_reader, "44302"), load_part(real_reader, "44301")
    # Both hinge axes run along Z 10 LDU past the plate's end: turned about Y and 60 LDU on, the
    # single finger sits between the two (the plates lie end to end).
    end_to_end = rotation_about((0, 1, 0), 180)
    at_home = Pose.identity()
    assert may_hold(single, Pose(end_to_end, [60, 0, 0]), dual, at_home)
    assert not may_hold(single, Pose(end_to_end, [70, 0, 0]), dual, at_home)
    assert not may_hold(single, Pose(end_to_end, [60, -8, 0]), dual, at_home)
    assert not may_hold(single, Pose(rotation_about((0, 1, 0), 90) @ end_to_end, [60, 0, 0]), dual, at_home)
    # A tyre has no connector primitives: judged by its shape (no studs, no sockets), as before.
    assert may_hold(load_part(real_reader, "3641"), Pose(I3, [500, 0, 0]), dual, at_home)


def test_turn_faults_only_where_the_part_fills_another_box():
    from factory.physics.unmodelled import world_box

    turn = rotation_about((0, -1, 0), 90)
    square, long = part("3003"), part("3001")
    pose = Pose(I3, [0, -24, 0])
    assert np.allclose(world_box(square, pose), world_box(square, Pose(turn, pose.t)), atol=1.0)
    assert not np.allclose(world_box(long, pose), world_box(long, Pose(turn, pose.t)), atol=1.0)


def test_connections_at_many_poses_are_those_found_one_pose_at_a_time():
    # The batched finder (two tree queries for all poses) against `match` on each pose's
    # connectors, on every feasible attachment of several part types to a mixed structure: same
    # connections, same order.
    from factory.physics.structure import connections_at, connectors, match

    def one_pose(s, p, pose):
        sp, sa, so = s.studs
        kp, ka, ko = s.sockets
        cp, ca = connectors(p, pose, "sockets")
        out = [(int(so[i]), len(s), sp[i], sa[i]) for i, _ in match(sp, sa, cp, ca)]
        cp, ca = connectors(p, pose, "studs")
        return out + [(len(s), int(ko[k]), cp[i], ca[i]) for i, k in match(cp, ca, kp, ka)]

    base = Structure([at("3001", 0, 0, 0), at("3020", 10, -24, 0), at("3003", -30, 8, 20),
                      at("3069b", 0, -32, 0), at("3040b", 40, 0, 0)])
    total = 0
    for name in ("3001", "3020", "3069b", "3040b", "3665", "3003"):
        poses = feasible_poses(base, part(name))
        want = [one_pose(base, part(name), p) for p in poses]
        got = connections_at(base, part(name), np.array([p.R for p in poses]), np.array([p.t for p in poses]))
        assert len(got) == len(want)
        for g, w in zip(got, want):
            assert [(a, b) for a, b, *_ in g] == [(a, b) for a, b, *_ in w]
            for (_, _, gp, ga), (_, _, wp, wa) in zip(g, w):
                np.testing.assert_allclose(gp, wp, atol=1e-9)
                np.testing.assert_allclose(ga, wa, atol=1e-9)
        total += sum(map(len, want))
    assert total > 300


def test_shared_meshes_put_every_piece_where_the_part_has_it():
    """Pieces equal up to a translation share one MJCF mesh placed by its geom's position: every
    geom's vertices in the compiled scene are its piece's vertices at the part's pose."""
    import mujoco

    from factory.physics.collide import CollisionScene
    from factory.pose import points_to_mujoco

    turn = rotation_about([0, 1, 0], np.pi / 2)
    structure = Structure([at("3001", 0, 0, 0), at("3001", 10, -24, 20, R=turn), at("3020", 0, -48, 0)])
    scene = CollisionScene(structure, [(part("3003"), Pose.identity())], floor_y=0.0)
    m, d = scene.model, scene.data
    mujoco.mj_kinematics(m, d)
    stud_meshes = set(m.geom_dataid[scene.is_stud].tolist())
    assert np.count_nonzero(scene.is_stud) == 28 and len(stud_meshes) <= 2  # every stud is one shape
    g = 0
    order = [i for i in range(m.ngeom) if i != mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "floor")]
    for idx, placed in enumerate(structure.placed):
        shape = collision_shape(placed.part)
        for verts in (*shape.body, *shape.studs):
            gid = order[g]
            g += 1
            assert scene.owner[gid] == idx
            mid = m.geom_dataid[gid]
            local = m.mesh_vert[m.mesh_vertadr[mid]:m.mesh_vertadr[mid] + m.mesh_vertnum[mid]]
            world = local @ d.geom_xmat[gid].reshape(3, 3).T + d.geom_xpos[gid]
            want = points_to_mujoco(placed.pose.apply(verts))
            # the same point set (MuJoCo keeps mesh vertices as float32, in its own order): 1e-7 m = 0.00025 LDU
            gap = np.linalg.norm(world[:, None] - want[None], axis=-1)
            assert gap.min(axis=1).max() < 1e-7 and gap.min(axis=0).max() < 1e-7


@pytest.mark.parametrize("damage", ["empty", "truncated"])
def test_an_empty_or_truncated_cache_entry_is_decomposed_again(tmp_path, monkeypatch, damage):
    monkeypatch.setenv("BRICK_FACTORY_CACHE", str(tmp_path))
    from factory.parts import Part

    cfg = DecompositionConfig(inset_ldu=0.31)  # a fresh entry (and a fresh Part: no memo)
    first = collision_shape(Part(name="3039.dat", description="", moved_to=None, flat=part("3039").flat), cfg)
    files = sorted(cache_dir().glob("*.npz"))
    assert len(files) == 2
    for f in files:
        f.write_bytes(b"" if damage == "empty" else f.read_bytes()[: f.stat().st_size // 2])
    clone = Part(name="3039.dat", description="", moved_to=None, flat=part("3039").flat)
    again = collision_shape(clone, cfg)
    assert len(again.body) == len(first.body)
    for f in files:  # and replaced
        with np.load(f) as data:
            assert int(data["n"]) == len(first.body)


def test_an_unwritable_cache_is_worked_without(tmp_path, monkeypatch, capsys):
    blocker = tmp_path / "not-a-folder"
    blocker.write_text("a file where the cache folder would be")
    monkeypatch.setenv("BRICK_FACTORY_CACHE", str(blocker / "cache"))
    from factory.parts import Part

    clone = Part(name="3039.dat", description="", moved_to=None, flat=part("3039").flat)
    shape = collision_shape(clone, DecompositionConfig(inset_ldu=0.32))
    assert len(shape.body) >= 1
    assert "cache" in capsys.readouterr().err


def test_a_scene_built_from_kept_bodies_is_the_scene_built_afresh():
    """Structure parts' MJCF bodies and piece faces are kept as a structure grows
    (`DEFAULT.bodies`), and a candidate unit's pieces (`DEFAULT.unit_pieces`); a scene built
    from them has the same model, geom owners, piece faces and answers as one built with nothing
    kept."""
    from factory.physics import collide
    from factory.physics.collide import CollisionScene

    turn = rotation_about([0, 1, 0], np.pi / 2)
    placed = [at("3001", 0, 0, 0), at("3001", 10, -24, 20, R=turn), at("3020", 0, -48, 0), at("3039", 20, -56, 0)]
    unit = [(part("3003"), Pose.identity())]
    poses = [Pose(I3, np.array([x, -56.0, z])) for x in (-20, 0, 10) for z in (-10, 0, 20)]
    poses.append(Pose(I3, np.array([200.0, -24.0, 200.0])))  # clear of everything
    DEFAULT.bodies.clear()
    for n in range(1, len(placed) + 1):  # one scene a step, as the sampler builds them
        kept = CollisionScene(Structure(placed[:n]), unit, floor_y=0.0)
    assert len(DEFAULT.bodies) == len(placed)
    DEFAULT.bodies.clear()
    DEFAULT.unit_pieces.clear()
    fresh = CollisionScene(Structure(placed), unit, floor_y=0.0)
    for name in ("geom_pos", "geom_quat", "geom_dataid", "body_pos", "body_quat", "mesh_vert", "geom_size"):
        assert np.array_equal(getattr(kept.model, name), getattr(fresh.model, name)), name
    for name in ("owner", "is_stud", "inset", "_s_planes", "_s_piece", "_s_owner", "_s_centre", "_s_box",
                 "_c_planes", "_c_piece", "_c_centre", "_c_box"):
        assert np.array_equal(getattr(kept, name), getattr(fresh, name)), name
    assert kept.info == fresh.info
    assert len(np.unique(fresh._s_piece)) == len(fresh._s_centre)
    answers = [(kept.penetration(p, set()), fresh.penetration(p, set())) for p in poses]
    assert all(a == b for a, b in answers)
    assert any(a[0] > 0 for a, _ in answers) and any(a[0] == 0 for a, _ in answers)
    # A part at another index (another structure that holds it elsewhere) is written anew.
    other = CollisionScene(Structure([placed[1]]), unit, floor_y=0.0)
    assert set(other.owner[other.owner >= 0].tolist()) == {0}


def test_the_deepest_overlap_asks_only_the_studs_that_could_raise_it():
    """`collide._deepest` gives the definition's number (every stud asked; one in a hollow counts
    0) on random contact sets, asking each stud at most once and none that lies under a deeper
    overlap already found."""
    from factory.physics.collide import _deepest

    rng = np.random.default_rng(7)
    saved = 0
    for trial in range(3000):
        n = int(rng.integers(0, 12))
        overlap = np.round(rng.normal(0.2, 0.6, n), int(rng.integers(1, 4)))  # ties too
        kind = rng.integers(0, 3, n)  # 0: left out, 1: plain, 2: a stud on a body
        plain = (kind == 1) & (overlap > 0)
        studs = np.flatnonzero((kind == 2) & (overlap > 0))
        answers = {int(i): bool(rng.random() < 0.5) for i in studs}
        o = overlap.copy()
        for i in studs:
            if not answers[int(i)]:
                o[i] = min(o[i], 0.0)
        over = plain.copy()
        over[studs] = True
        over &= o > 0
        want = float(o[over].max()) if over.any() else 0.0
        asked = []
        got = _deepest(overlap, plain, studs, lambda i: asked.append(i) or answers[i])
        assert got == want and len(asked) == len(set(asked)) <= len(studs)
        floor = float(overlap[plain].max()) if plain.any() else 0.0
        assert all(overlap[i] > floor for i in asked)
        saved += len(studs) - len(asked)
    assert saved > 1000


def test_depths_inside_pieces_measured_only_where_a_box_holds_the_point():
    """The coincidence test measures a point only against pieces whose box holds it: the same
    depths as against every face of every piece, wherever the point is inside one."""
    placed = [at("3001", 0, 0, 0), at("4070", 40, -24, 0), at("6141", 0, -32, 10), at("3062b", -30, -24, 10),
              at("2412b", 60, -32, 0)]
    planes, piece, _, centres, boxes = collide._joined_pieces(
        [collide._pieces([(p.pose, collision_shape(p.part), i)]) for i, p in enumerate(placed)])
    rng = np.random.default_rng(5)
    lo, hi = boxes[:, 0].min(axis=0) - 5, boxes[:, 1].max(axis=0) + 5
    points = np.concatenate([rng.uniform(lo, hi, (400, 3)), centres])
    every = points @ planes[:, :3].T + planes[:, 3]
    expected = np.stack([-every[:, piece == k].max(axis=1) for k in range(len(centres))])
    got = collide._inside_depth(planes, piece, boxes, points)
    inside = expected > 0
    assert inside.sum() > 50 and (~inside).sum() > 50
    assert np.allclose(got[inside], expected[inside])
    assert np.all(got[~inside] <= 0)


@pytest.mark.parametrize("eps", [0.0, 1e-9, 1e-8, 1e-5, 1e-3, 0.3])
def test_align_takes_a_vector_onto_one_almost_opposite(eps):
    # A joint's axis laid on a target's the other way round: 1e-8 off opposite, float arithmetic
    # rounds b @ a to -1 while their cross product is not zero (a sampled object divided by zero).
    from factory.physics.structure import align

    b = np.array([0.0, 1.0, 0.0])
    a = -b + np.array([eps, 0.0, eps / 2])
    a /= np.linalg.norm(a)
    r = align(b, a)
    assert np.allclose(r @ b, a, atol=1e-9) and np.allclose(r @ r.T, np.eye(3)) and np.isclose(np.linalg.det(r), 1.0)
