"""A design's part drawn where no part can be counts once: the parts drawn right beside it
afterwards are judged without it (`factory.drawn_wrong`)."""

from __future__ import annotations

from factory.replay import verify_model
from ldraw_support import LDRAW, needs_ldraw

I3 = "1 0 0 0 1 0 0 0 1"


def _design(tmp_path, *steps: str):
    model = tmp_path / "design.ldr"
    model.write_text("0 Design\n" + "".join(f"{s}\n0 STEP\n" for s in steps))
    return model


BASE = (f"1 4 0 0 0 {I3} 3001.dat\n1 4 0 0 40 {I3} 3001.dat",  # two 2x4 bricks: an 80 x 80 base
        f"1 1 -20 -24 0 {I3} 3003.dat")                         # a 2x2 brick on its left front
WRONG = f"1 2 17 -24 3 {I3} 3003.dat"  # drawn 3 LDU left of and 3 LDU behind its studs: into the brick beside it


def test_a_part_drawn_right_beside_one_drawn_wrong_is_accepted_once(tmp_path):
    right = f"1 14 20 -24 40 {I3} 3003.dat"  # on its studs, where the one drawn wrong reaches 3 LDU in
    records = list(verify_model(_design(tmp_path, *BASE, WRONG, right), faults=True))
    plain = [r for r in records if "fault" not in r]
    assert [r["reason"] for r in plain] == [None, None, None, "collision", None]
    assert plain[3]["max_penetration_ldu"] > 2.0 and "seated_ldu" not in plain[3]  # too far off to seat
    assert plain[4]["judged_without"] == [3] and "judged_without" not in plain[3]
    # Its faults are judged against every part, the one drawn wrong too: each still rejected.
    faults = [r for r in records if r.get("fault") and r["step"] == plain[4]["step"]]
    assert faults and all(r["reason"] is not None for r in faults)

    # Without the part drawn wrong in the design, the same part is accepted as it is.
    alone = [r for r in verify_model(_design(tmp_path, *BASE, right)) if "fault" not in r]
    assert alone[-1]["reason"] is None and "judged_without" not in alone[-1]


def test_a_part_that_also_meets_a_part_drawn_right_is_still_rejected(tmp_path):
    # It reaches 4 LDU into the one drawn right before it (too far to seat) and into the one drawn wrong.
    both = f"1 14 -20 -24 36 {I3} 3003.dat"
    plain = [r for r in verify_model(_design(tmp_path, *BASE, WRONG, both)) if "fault" not in r]
    assert plain[3]["reason"] == "collision" and plain[4]["reason"] == "collision"
    assert "judged_without" not in plain[4]


def test_a_part_drawn_wrong_is_not_excused_by_another(tmp_path):
    # A second brick drawn into the first one drawn wrong, and into the base beneath it, is rejected.
    sunk = f"1 14 20 -20 40 {I3} 3003.dat"  # 4 LDU down: too far to seat
    plain = [r for r in verify_model(_design(tmp_path, *BASE, WRONG, sunk)) if "fault" not in r]
    assert plain[4]["reason"] == "collision" and "judged_without" not in plain[4]


@needs_ldraw
def test_a_part_overlapping_beyond_its_joint_counts_as_drawn_wrong(tmp_path):
    # A Technic pin pushed 3 LDU too deep into the hole of a Technic brick: on the hole's axis but
    # not seated, so no joint is judged and its verdict names the connection first
    # (`unsupported-connection`) while its collar overlaps the brick. A brick drawn on its studs
    # where the pin's end reaches is judged without it.
    z = "0 0 1 0 1 0 -1 0 0"  # the pin's axis along the hole's
    base = (BASE[0], f"1 1 0 -24 10 {I3} 3700.dat")
    brick = f"1 14 0 -24 40 {I3} 3003.dat"
    deep = [r for r in verify_model(_design(tmp_path, *base, f"1 0 0 -14 17 {z} 2780.dat", brick), ldraw=LDRAW)
            if "fault" not in r]
    assert deep[3]["reason"] == "unsupported-connection" and deep[3]["collision"]
    assert deep[3]["max_penetration_ldu"] > 2.0 and deep[3]["joints"] == ["technic-pin"]
    assert deep[4]["reason"] is None and deep[4]["judged_without"] == [3]

    # The pin drawn right, in its hole to the collar: the brick meets it, and is rejected.
    right = [r for r in verify_model(_design(tmp_path, *base, f"1 0 0 -14 20 {z} 2780.dat", brick), ldraw=LDRAW)
             if "fault" not in r]
    assert right[3]["reason"] is None
    assert right[4]["reason"] == "collision" and "judged_without" not in right[4]


def _mpd(tmp_path, main: str, sub: str, header: str):
    model = tmp_path / "design.mpd"
    model.write_text(f"0 FILE main.ldr\n0 Design\n{main}0 FILE segment.ldr\n0 Segment\n{header}{sub}\n")
    return model


def test_a_part_meeting_only_a_flexible_element_is_judged_without_it(tmp_path):
    # A flexible element (a chain, a hose) is drawn as rigid segments along a curve; the part it
    # bends aside for meets them where drawn. Here its one segment, a 1x2 plate, hangs 6 LDU above
    # the studs a 2x2 brick is then pressed onto: the brick's top and studs reach 6 LDU into it.
    main = (f"{BASE[0]}\n{BASE[1]}\n0 STEP\n1 7 0 0 0 {I3} segment.ldr\n0 STEP\n"
            f"1 14 20 -24 40 {I3} 3003.dat\n0 STEP\n")
    segment = f"1 2 20 -30 40 {I3} 3023.dat"
    flexible = [r for r in verify_model(_mpd(tmp_path, main, segment, "0 !KEYWORDS flexible, chain\n"))
                if "fault" not in r]
    rigid = [r for r in verify_model(_mpd(tmp_path, main, segment, "")) if "fault" not in r]
    for records in (flexible, rigid):
        # The plate in its own frame, then the segment as one unit: held by nothing, but not
        # overlapping the parts before it (not drawn wrong).
        assert [r.get("unit", False) for r in records] == [False, False, False, False, True, False]
        assert records[4]["reason"] == "no-connection" and not records[4]["collision"]
    assert rigid[5]["reason"] == "collision" and rigid[5]["max_penetration_ldu"] > 4.0
    assert flexible[5]["reason"] is None and flexible[5]["judged_without"] == [3]


def test_a_part_drawn_off_the_stud_grid_is_named_so(tmp_path):
    # The WRONG brick stands 3 LDU along and 3 across off the studs under it (4.2 LDU): too far to
    # seat, and no real brick goes there. A 1x2 plate half a stud across from the studs under it
    # (its long walls on them) is off by 10 LDU; one on the grid but sunk 5 LDU into the bricks is
    # drawn wrong, not off the grid.
    plain = [r for r in verify_model(_design(tmp_path, *BASE, WRONG)) if "fault" not in r]
    assert plain[3]["reason"] == "collision" and abs(plain[3]["off_grid_ldu"] - 18 ** 0.5) < 0.01
    assert all("off_grid_ldu" not in r for r in plain[:3])  # accepted: never named

    across = f"1 2 0 -8 0 {I3} 3023.dat"  # 1x2 plate along x, its long walls on the rows of studs at z = -10 and 10
    plain = [r for r in verify_model(_design(tmp_path, BASE[0], across)) if "fault" not in r]
    assert plain[-1]["reason"] == "collision" and plain[-1]["off_grid_ldu"] == 10.0

    sunk = f"1 2 0 -3 10 {I3} 3023.dat"  # on the grid, 5 LDU into the bricks: drawn wrong, not off the grid
    plain = [r for r in verify_model(_design(tmp_path, BASE[0], sunk)) if "fault" not in r]
    assert plain[-1]["reason"] == "collision" and "off_grid_ldu" not in plain[-1]
