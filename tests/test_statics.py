"""Whole-structure loads on hand-built structures with answers computed by hand: a cantilever chain
from one stud, a loaded tower on one stud, a bridge, stairs that tip, and the cheap single-part rule
against the whole program."""

from __future__ import annotations

import numpy as np
import pytest

from factory import Pose
from factory.connections import STUD_RADIUS
from factory.physics.check import CheckConfig, check, check_units
from factory.physics.mass import GRAVITY, part_mass_properties
from factory.physics.clutch import holds_alone
from factory.physics.load_model import LoadConfig, load_model
from factory.physics.load_program import to_lp
from factory.physics.statics import judge
from factory.physics.lp import solve_highs
from factory.physics.structure import Structure
from ldraw_support import at, part

I3 = np.eye(3)

pytestmark = pytest.mark.usefixtures("isolated_cache")


def weight(name):
    return part_mass_properties(part(name))[0] * GRAVITY


def judge_last(s: Structure, cfg=LoadConfig()):
    return judge(load_model(s.placed, s.connections, s.floor_y(), [len(s) - 1], s.links, cfg), cfg)


def one_stud_load(w_n, d_ldu, cfg=LoadConfig()):
    """The load on one stud carrying weight w at horizontal distance d from its centre (d >= r): the
    far rim point pushes, the other three pull with C/4 each; moments about the centre give
    w d = (w + 3C/4) r + (C/4) r at capacity, i.e. s = w (d - r) / (C r)."""
    return w_n * (d_ldu - STUD_RADIUS) / (cfg.clutch_n * STUD_RADIUS)


def cantilever(arms: int) -> Structure:
    """A 14-brick tower of 2x4 bricks, then 1x8 bricks outward, each hung by its end socket on the
    last stud of the one below (the first on the tower top's stud at x = 30)."""
    s = Structure([at("3001", 0, -24 * k, 0) for k in range(14)])
    for k in range(arms):
        s.add(at("3008", 100 + 140 * k, -24 * 13 - 24 * (k + 1), -10))
    return s


def test_cantilever_chain_fails_at_the_computed_arm_length():
    w = weight("3008")
    # k arms have their centre of mass 70 k LDU beyond the tower's stud (arm centres at 70, 210, ...).
    expected = [one_stud_load(k * w, 70.0 * k) for k in (1, 2)]
    first_failing = next(k for k in range(1, 10) if one_stud_load(k * w, 70.0 * k) > 1)
    assert first_failing == 2
    one, two = judge_last(cantilever(1)), judge_last(cantilever(2))
    assert one.stands and one.load == pytest.approx(expected[0], rel=1e-6)
    assert not two.stands and two.reason == "overload"
    assert two.load == pytest.approx(expected[1], rel=1e-6)
    # The connection that fails is the tower top's stud under the first arm, and only that one.
    assert [(f.stud_part, f.socket_part) for f in two.failing] == [(13, 14)]
    assert np.allclose(two.failing[0].stud, [30, -24 * 13, -10])
    # Through the checker, with the second arm as the candidate: it holds alone (its own stud
    # carries one arm), but the structure does not.
    s = cantilever(1)
    (v,) = check(s, part("3008"), [Pose(I3, [240, -24 * 15, -10])], floor_y=24.0)
    assert v.clutch and v.reason == "overload" and v.failing[0].socket_part == 14


def test_tower_on_one_stud_holds_a_centred_top_and_not_an_offset_one():
    # A 1x1 brick on a 2x4 base, then 2x2 bricks on it: centred on its stud (their centre tube),
    # the weight goes straight down (compression only, free); hung off-centre by a corner socket the
    # one stud must carry the moment.
    tower = [at("3001", 0, 0, 0), at("3005", 10, -24, 10)]
    centred = Structure(tower + [at("3003", 10, -48 - 24 * k, 10) for k in range(6)])
    v = judge_last(centred)
    assert v.stands and v.load == pytest.approx(0.0, abs=1e-9)
    # 1x2 bricks hung by one end socket on the 1x1's stud: their centre 10 LDU beyond it along x.
    # With a weak clutch the answer crosses 1 at a known height.
    cfg = LoadConfig(clutch_n=0.015)
    w = weight("3004")
    for n in (1, 2, 3, 4):
        s = Structure(tower + [at("3004", 20, -48 - 24 * k, 10) for k in range(n)])
        v = judge_last(s, cfg)
        want = one_stud_load(n * w, 10.0, cfg)
        assert v.load == pytest.approx(want, rel=1e-6)
        assert v.stands == (want <= 1)
    assert one_stud_load(1 * w, 10.0, cfg) < 1 < one_stud_load(3 * w, 10.0, cfg)


def test_a_bridge_stands_on_two_piers_and_one_pier_does_not_hold_its_span():
    piers = [at("3003", x, -24 * k, 0) for x in (-60, 60) for k in range(3)]
    # A 1x8 brick across the piers, its end sockets on the piers' studs at x = -70 and 70.
    deck = at("3008", 0, -72, -10)
    bridge = Structure(piers + [deck])
    v = judge_last(bridge)
    assert v.stands and v.load < 0.05
    # A 2x4 brick on the middle of the deck: still carried by compression at both ends.
    loaded = Structure(piers + [deck, at("3001", 0, -96, 0)])
    assert judge_last(loaded).stands
    # Only one pier: the deck hangs 7 studs out from it on two studs under a weak clutch.
    one = Structure([p for p in piers if p.pose.t[0] < 0] + [deck])
    weak = judge_last(one, LoadConfig(clutch_n=0.005))
    assert not weak.stands and weak.reason in ("overload", "unstable")


def test_stairs_shifted_one_stud_per_layer_tip_when_the_centre_of_mass_leaves_the_base():
    s = Structure([at("3001", 0, 0, 0)])
    m = load_model(s.placed, s.connections, s.floor_y(), [0])
    edge = m.ground_pos[:, 0].max()  # the base's support reaches this far (inset collision pieces)
    for n in range(2, 8):
        s.add(at("3001", 20 * (n - 1), -24 * (n - 1), 0))
        com_x = 10.0 * (n - 1)  # equal bricks, each one stud further
        v = judge_last(s)
        assert v.stands == (com_x <= edge), (n, com_x, edge, v)
        if not v.stands:
            assert v.reason == "unstable" and v.load is None
            break
    else:
        pytest.fail("the stairs never tipped")


def test_single_part_rule_agrees_with_the_program_for_one_body():
    # The closed form (vertical connections) against the one-body program, on random placements of
    # a part's weight over random stud sets, sitting and hanging, near the limit too.
    rng = np.random.default_rng(5)
    cfg = LoadConfig()
    agree = 0
    for trial in range(300):
        n = int(rng.integers(1, 5))
        studs = np.column_stack([rng.integers(-2, 3, n) * 20.0, np.zeros(n), rng.integers(-2, 3, n) * 20.0])
        studs = np.unique(studs, axis=0)
        hanging = bool(trial % 3 == 0)
        conns = [(hanging, p, np.array([0.0, -1.0, 0.0])) for p in studs]
        com = np.array([rng.normal() * 30, -10.0, rng.normal() * 30])
        mass = float(rng.uniform(0.001, 0.2))
        fast = holds_alone(mass, com, conns, cfg=cfg)
        # The same through the general program: give one connection a tiny tilt so the closed form
        # is not taken.
        tilted = [(h, p, n / np.linalg.norm(n)) for h, p, n in
                  [(h, p, a + np.array([1e-9, 0, 0])) for h, p, a in conns]]
        tilted[0] = (tilted[0][0], tilted[0][1], np.array([2e-3, -1.0, 0.0]) / np.linalg.norm([2e-3, -1.0, 0.0]))
        slow = holds_alone(mass, com, tilted, cfg=cfg)
        agree += fast == slow
    assert agree >= 297  # a 0.1 degree tilt may flip a case within ~0.2% of its limit


def test_hanging_part_needs_its_studs_clutch_and_a_weak_clutch_fails_it():
    # A 2x2 plate hung by its four studs under a brick that overhangs the base, clear of the ground.
    base = Structure([at("3001", 0, 0, 0), at("3001", 60, -24, 0)])
    plate = [at("3022", 60, 0, 0)]
    (held,) = check_units(base, [plate], floor_y=24.0)
    assert held.clutch and held.ok and held.connections == 4
    weak = LoadConfig(clutch_n=weight("3022") / 4 * 0.9)  # four studs hold 90% of its weight
    (fails,) = check_units(base, [plate], config=CheckConfig(loads=weak), floor_y=24.0)
    assert fails.reason == "clutch" and fails.clutch is False
    # Laid on the ground instead (no fixed floor: the object rests on its new lowest point), the
    # lower brick carries the base above it: the base now hangs on two studs.
    (lower,) = check_units(Structure([at("3001", 0, 0, 0)]), [[at("3001", 60, 24, 0)]],
                           config=CheckConfig(loads=LoadConfig(clutch_n=0.005)))
    assert lower.clutch and lower.reason == "overload"
    assert {(f.stud_part, f.socket_part) for f in lower.failing} == {(1, 0)}


def test_program_is_feasible_whenever_the_component_does_not_tip():
    # With every capacity scaled by s, a large enough s makes the connections rigid: the program
    # of a standing structure always has a solution, which the batched solver relies on.
    s = cantilever(2)
    lp = to_lp(load_model(s.placed, s.connections, s.floor_y(), [len(s) - 1]))
    res = solve_highs(lp)
    assert res.status == "optimal" and max(lp.residuals(res.x)) < 1e-7


@pytest.mark.parametrize("floor_y", [24.0, None])
def test_a_units_model_from_the_structures_load_base_is_the_component_holding_it(floor_y):
    """`LoadBase.model` (the new part's component found from its new connections) equals the model
    `load_model` builds of the whole set of parts from the new part as seed: two towers standing
    apart, a brick joining the second only, a brick bridging both, and a link from a brick
    laid on the ground to the first tower."""
    from factory.physics.check import _unit_connections
    from factory.physics.load_model import LoadBase, Link

    s = Structure([at("3001", 0, 0, 0), at("3001", 0, -24, 0), at("3001", 200, 0, 0), at("3001", 200, -24, 0)])
    base = LoadBase(s.placed, s.connections, floor_y, s.links)
    for unit, links in (([at("3001", 200, -48, 10)], []), ([at("3008", 100, -48, 0)], []),
                        ([at("3001", 100, 0, 100)], [Link(4, 0, (50.0, 0.0, 50.0))])):
        conns = _unit_connections(s, [(p.part, p.pose) for p in unit])
        got = base.model(unit, conns, links)
        want = load_model(s.placed + unit, s.connections + conns, floor_y, [len(s)], links)
        assert got.parts.tolist() == want.parts.tolist()
        for field in want.__dataclass_fields__:
            assert np.array_equal(getattr(got, field), getattr(want, field)), field


def test_clutch_case_keys_round_each_position_and_axis_alone():
    """`holds_alone_many` keys a case by its connections relative to its centre of mass, rounded
    (`clutch._alone_key`, which rounds all of a case's rows at once): the key is the one rounding
    each connection by itself gives, on random cases with positions off the grid."""
    from factory.physics.clutch import _alone_key

    rng = np.random.default_rng(7)
    for _ in range(200):
        com = rng.normal(size=3) * 40
        conns = [(bool(rng.integers(2)), rng.normal(size=3) * 40 + rng.normal(size=3) * 1e-7,
                  rng.normal(size=3)) for _ in range(int(rng.integers(0, 6)))]
        ground = rng.normal(size=(int(rng.integers(0, 4)), 3)) * 40
        by_row = tuple((h, tuple(np.round(p - com, 6).tolist()), tuple(np.round(n, 9).tolist())) for h, p, n in conns)
        key = _alone_key(0.00234, com, conns, ground)
        assert key[1] == by_row and key[0] == 0.00234
        assert key[2] == tuple(map(tuple, np.round(ground - com, 6).tolist()))
