"""A design's part drawn a little off its connection is judged seated on it (`physics.seat`)."""

from __future__ import annotations

import numpy as np
import pytest

from ldraw_support import LDRAW, needs_ldraw
from factory.physics.seat import SEAT_LDU, seat_offset
from factory.physics.structure import Placed, Structure
from factory.parts import load_part
from factory.pose import Pose
from factory.replay import verify_model

I3 = "1 0 0 0 1 0 0 0 1"


def _plain(records):
    return [r for r in records if "fault" not in r]


@pytest.mark.parametrize("at, moved", [("0 -25 10", 1.0), ("1 -24 10", 1.0), ("1.2 -25.2 10", float(np.hypot(1.2, 1.2))),
                                       ("0 -27 10", 3.0), ("2 -24 12", float(np.hypot(2.0, 2.0)))])
def test_a_brick_drawn_off_the_studs_is_judged_on_them(tmp_path, at, moved):
    model = tmp_path / "off.ldr"
    model.write_text(f"0 Off\n1 4 0 0 0 {I3} 3001.dat\n0 STEP\n1 1 {at} {I3} 3004.dat\n0 STEP\n")
    records = list(verify_model(model, faults=True))
    plain = _plain(records)
    assert [r["reason"] for r in plain] == [None, None]
    assert plain[1]["seated_ldu"] == pytest.approx(moved, abs=1e-3)
    assert "seated_ldu" not in plain[0]
    # Its faults move it from where it is seated, and are still faults.
    faults = [r for r in records if r.get("fault") in ("lift", "shift")]
    assert len(faults) == 2 and all(r["reason"] is not None for r in faults)


def test_a_brick_drawn_farther_off_is_not_seated(tmp_path):
    model = tmp_path / "far.ldr"
    far = SEAT_LDU + 1.0
    model.write_text(f"0 Far\n1 4 0 0 0 {I3} 3001.dat\n0 STEP\n1 1 0 {-24 - far} 10 {I3} 3004.dat\n0 STEP\n")
    plain = _plain(verify_model(model))
    assert plain[1]["reason"] == "no-connection" and "seated_ldu" not in plain[1]


def test_a_part_drawn_on_its_studs_needs_no_seat(embedded_reader):
    base = Structure([Placed(load_part(embedded_reader, "3001"), 4, Pose(np.eye(3), [0, 0, 0]))])
    on = Placed(load_part(embedded_reader, "3004"), 1, Pose(np.eye(3), [0, -24, 10]))
    assert seat_offset(base, [on]) is None
    beside = Placed(on.part, 1, Pose(np.eye(3), [200, -24, 0]))
    assert seat_offset(base, [beside]) is None


@needs_ldraw
def test_a_pin_drawn_beside_its_hole_is_seated_in_it(tmp_path):
    # A Technic brick's hole is 10 LDU under its top, along Z; a pin drawn 1.5 LDU above that
    # line (as hand-drawn designs do) is judged in the hole.
    model = tmp_path / "pin.ldr"
    model.write_text(f"0 Pin\n1 4 0 0 0 {I3} 3700.dat\n0 STEP\n"
                     f"1 0 0 8.5 10 0 0 1 0 1 0 -1 0 0 2780.dat\n0 STEP\n")
    plain = _plain(verify_model(model, ldraw=LDRAW))
    assert plain[1]["seated_ldu"] == pytest.approx(1.5, abs=1e-3)
    assert plain[1]["joints"] == ["technic-pin"] and plain[1]["reason"] in (None, "unsupported-connection")
