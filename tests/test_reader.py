"""Flattening: winding through mirrors and INVERTNEXT, colour inheritance, studs, hostile input."""

from __future__ import annotations

import numpy as np
import pytest

from factory.errors import LDrawCycleError, LDrawLimitError, LDrawReadError
from factory.ldraw import Library, Reader
from factory.ldraw.reader import is_other_connector, is_stud_primitive
from factory.parts import load_part


def lib_reader(mini_library):
    return Reader(Library.from_dir(mini_library))


def add_part(root, name, body, certify=True):
    head = "0 Part\n0 !LDRAW_ORG Part\n" + ("0 BFC CERTIFY CCW\n" if certify else "")
    (root / "parts" / name).write_text(head + body)


def test_mirrored_and_inverted_references_keep_outward_winding(mini_library):
    add_part(mini_library, "mirror.dat", "1 16 0 0 0 -5 0 0 0 5 0 0 0 5 box.dat\n")
    add_part(
        mini_library,
        "hollow.dat",
        "1 16 0 0 0 4 0 0 0 4 0 0 0 4 box.dat\n0 BFC INVERTNEXT\n1 16 0 0 0 2 0 0 0 2 0 0 0 2 box.dat\n",
    )
    reader = lib_reader(mini_library)
    # A box scaled by (-5, 5, 5) has volume 1000; the mirror must not flip its sign.
    assert load_part(reader, "mirror").volume_ldu3 == pytest.approx(1000)
    t = reader.flatten(reader.part("mirror.dat")).triangles
    assert np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum() / 6 == pytest.approx(1000)
    # A box of side 8 with an inverted box of side 4 inside: 512 - 64.
    assert load_part(reader, "hollow").volume_ldu3 == pytest.approx(448)


def test_colour_16_inherits_and_explicit_colours_stay(mini_library):
    add_part(mini_library, "two.dat", "1 16 0 0 0 1 0 0 0 1 0 0 0 1 box.dat\n1 4 5 0 0 1 0 0 0 1 0 0 0 1 box.dat\n")
    add_part(mini_library, "holder.dat", "1 14 0 0 0 1 0 0 0 1 0 0 0 1 two.dat\n")
    flat = lib_reader(mini_library).flatten(lib_reader(mini_library).part("holder.dat"))
    assert sorted(set(flat.colours.tolist())) == [4, 14]


def test_uncertified_geometry_marks_the_part(mini_library):
    add_part(mini_library, "loose.dat", "3 16 0 0 0 1 0 0 0 1 0\n", certify=False)
    add_part(mini_library, "user.dat", "1 16 0 0 0 1 0 0 0 1 0 0 0 1 loose.dat\n1 16 0 0 0 1 0 0 0 1 0 0 0 1 box.dat\n")
    reader = lib_reader(mini_library)
    assert reader.flatten(reader.part("box.dat")).certified
    assert not reader.flatten(reader.part("user.dat")).certified


def test_studs_are_found_through_groups_with_their_axes(mini_library):
    (mini_library / "p" / "stud.dat").write_text("0 Stud\n0 BFC CERTIFY CCW\n" + "3 16 0 0 0 1 0 0 0 0 1\n")
    (mini_library / "p" / "stud4.dat").write_text("0 Tube\n0 BFC CERTIFY CCW\n3 16 0 0 0 1 0 0 0 0 1\n")
    (mini_library / "p" / "stug-1x2.dat").write_text(
        "0 Group\n1 16 -10 0 0 1 0 0 0 1 0 0 0 1 stud.dat\n1 16 10 0 0 1 0 0 0 1 0 0 0 1 stud.dat\n"
    )
    # The group placed on top, and one stud on the side pointing +X (a SNOT brick), and a tube.
    add_part(
        mini_library,
        "snot.dat",
        "1 16 0 0 0 1 0 0 0 1 0 0 0 1 stug-1x2.dat\n1 16 10 12 0 0 -1 0 1 0 0 0 0 1 stud.dat\n"
        "1 16 0 4 0 1 0 0 0 5 0 0 0 1 stud4.dat\n",
    )
    studs = load_part(lib_reader(mini_library), "snot").studs
    got = sorted((c.pos, c.axis) for c in studs)
    assert got == sorted([((-10.0, 0.0, 0.0), (0.0, -1.0, 0.0)), ((10.0, 0.0, 0.0), (0.0, -1.0, 0.0)),
                          ((10.0, 12.0, 0.0), (1.0, 0.0, 0.0))])


@pytest.mark.parametrize("name", ["stud.dat", "stud2a.dat", "48/stud-logo4.dat", "stud10.dat", "stud2.dat"])
def test_stud_primitive_names(name):
    assert is_stud_primitive(name)


@pytest.mark.parametrize("name", ["stud3.dat", "stud4.dat", "stud4a.dat", "stud12.dat", "stug-1x2.dat", "filstud3.dat"])
def test_underside_and_group_primitives_are_not_studs(name):
    assert not is_stud_primitive(name)


def test_non_stud_connectors_keep_their_axis_once_through_groups(mini_library):
    # A peg hole primitive 2 LDU deep along its Y, drawn twice inside a beam hole primitive (one
    # connector, not three), which a part places turned so that the hole runs along Z.
    (mini_library / "p" / "peghole.dat").write_text("0 Peg hole\n3 16 0 0 0 8 0 0 0 2 8\n")
    (mini_library / "p" / "beamhole.dat").write_text(
        "0 Beam hole\n1 16 0 -10 0 1 0 0 0 1 0 0 0 1 peghole.dat\n1 16 0 8 0 1 0 0 0 1 0 0 0 1 peghole.dat\n"
    )
    add_part(mini_library, "beam.dat", "1 16 20 10 0 1 0 0 0 0 1 0 -1 0 beamhole.dat\n"
                                       "1 16 20 10 0 1 0 0 0 0 1 0 -1 0 beamhole.dat\n")
    (conn,) = load_part(lib_reader(mini_library), "beam").flat.other_connectors
    assert sorted(map(tuple, conn[:2].round(6) + 0.0)) == [(20.0, 10.0, -10.0), (20.0, 10.0, 10.0)]
    assert np.allclose(np.abs(conn[2]), [0, 0, 1])


@pytest.mark.parametrize("name", ["peghole.dat", "axlehole.dat", "connect.dat", "clh4.dat", "wpin.dat",
                                  "clip3.dat", "beamhole.dat"])
def test_other_connector_primitive_names(name):
    assert is_other_connector(name)


@pytest.mark.parametrize("name", ["stud.dat", "box.dat", "4-4cyli.dat", "3673.dat"])
def test_other_primitives_are_not_other_connectors(name):
    assert not is_other_connector(name)


def test_technic_and_hinge_connectors_sit_on_their_axes(real_reader):
    def conns(name):
        return [(tuple(sorted(map(tuple, c[:2].round(3) + 0.0))), tuple(np.abs(c[2]).round(3) + 0.0))
                for c in load_part(real_reader, name).flat.other_connectors]

    z, x = (0.0, 0.0, 1.0), (1.0, 0.0, 0.0)
    # Technic brick 1 x 2 with hole: the hole runs along Z through (0, 10), one peg hole 2 LDU deep
    # at each face.
    assert sorted(conns("3700")) == [(((0.0, 10.0, -10.0), (0.0, 10.0, -8.0)), z),
                                     (((0.0, 10.0, 8.0), (0.0, 10.0, 10.0)), z)]
    # Technic pin: two halves of 20 LDU along X from its collar at the origin.
    assert sorted(conns("3673")) == [(((-20.0, 0.0, 0.0), (0.0, 0.0, 0.0)), x),
                                     (((0.0, 0.0, 0.0), (20.0, 0.0, 0.0)), x)]
    # Dual-finger hinge plate: the hinge axis runs along Z, 10 LDU past the plate's end, 2 below its top.
    assert sorted(conns("44302")) == [(((30.0, 2.0, -8.5), (30.0, 2.0, -3.0)), z),
                                      (((30.0, 2.0, 3.0), (30.0, 2.0, 8.5)), z)]
    assert conns("3001") == []


def test_reference_cycle_is_reported_with_its_chain(mini_library):
    add_part(mini_library, "a.dat", "1 16 0 0 0 1 0 0 0 1 0 0 0 1 b.dat\n")
    add_part(mini_library, "b.dat", "1 16 0 0 0 1 0 0 0 1 0 0 0 1 a.dat\n")
    reader = lib_reader(mini_library)
    with pytest.raises(LDrawCycleError, match=r"a\.dat -> b\.dat -> a\.dat"):
        reader.flatten(reader.part("a.dat"))


@pytest.mark.parametrize("base, levels, copies, message", [
    # Twenty levels, each placing the one below twice: 2^20 boxes, 12 million triangles.
    ("1 16 0 0 0 1 0 0 0 1 0 0 0 1 box.dat\n", 20, 2, "more than 2,000,000 triangles"),
    # Edge lines (type 2, and optional lines, type 5) count against a budget as triangles do:
    # nine tiny files, each placing the one below ten times, expand to 2 x 10^8 edges.
    ("2 24 0 0 0 1 0 0\n5 24 0 0 0 0 1 0 1 1 0 -1 1 0\n", 8, 10, "more than 4,000,000 edge"),
])
def test_exponential_expansion_is_refused_before_it_is_expanded(mini_library, base, levels, copies, message):
    add_part(mini_library, "l0.dat", base)
    for i in range(1, levels + 1):
        add_part(mini_library, f"l{i}.dat", f"1 16 0 0 0 1 0 0 0 1 0 0 0 1 l{i-1}.dat\n" * copies)
    reader = lib_reader(mini_library)
    with pytest.raises(LDrawLimitError, match=message):
        reader.flatten(reader.part(f"l{levels}.dat"))
    assert not reader._flat, "nothing may be expanded before the count is checked"


def test_deep_nesting_is_refused(mini_library):
    add_part(mini_library, "d0.dat", "1 16 0 0 0 1 0 0 0 1 0 0 0 1 box.dat\n")
    for i in range(1, 80):
        add_part(mini_library, f"d{i}.dat", f"1 16 0 0 0 1 0 0 0 1 0 0 0 1 d{i-1}.dat\n")
    reader = lib_reader(mini_library)
    with pytest.raises(LDrawLimitError, match="nest more than 64 levels"):
        reader.flatten(reader.part("d79.dat"))


def test_binary_and_oversized_files_are_refused(mini_library, monkeypatch):
    (mini_library / "parts" / "png.dat").write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR" * 10)
    (mini_library / "parts" / "big.dat").write_text("0 x\n" * 100)
    reader = lib_reader(mini_library)
    with pytest.raises(LDrawReadError, match="binary"):
        reader.part("png.dat")
    import factory.ldraw.parse as parse

    monkeypatch.setattr(parse, "MAX_FILE_BYTES", 100)
    with pytest.raises(LDrawReadError, match="400 bytes"):
        reader.part("big.dat")


def test_unreadable_file_is_a_clear_error(mini_library):
    (mini_library / "parts" / "dir.dat").mkdir()
    (mini_library / "parts" / "noperm.dat").write_text("0 x\n")
    (mini_library / "parts" / "noperm.dat").chmod(0)
    reader = lib_reader(mini_library)
    import os

    if os.geteuid() != 0:  # root reads anything; the folder case below still applies
        with pytest.raises(LDrawReadError, match="cannot read"):
            reader.part("noperm.dat")
    from factory.errors import LDrawMissingFileError

    with pytest.raises(LDrawMissingFileError):
        reader.part("dir.dat")


def test_flattened_parts_are_cached_per_reader(mini_library):
    reader = lib_reader(mini_library)
    assert load_part(reader, "cube") is load_part(reader, "CUBE.DAT")
    assert reader.flatten(reader.part("cube.dat")) is reader.flatten(reader.part("cube.dat"))
