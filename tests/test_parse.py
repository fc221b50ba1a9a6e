"""LDraw line parsing: every line type, BFC state, steps, MPD blocks, colours and malformed lines."""

from __future__ import annotations

import numpy as np
import pytest

from factory.errors import LDrawReadError, LDrawSyntaxError
from factory.ldraw.parse import Poly, Ref, Step, decode, parse_colour, parse_lines, split_mpd


def parse(text: str):
    return parse_lines(text.splitlines(), "t.ldr", "t.ldr")


def test_all_line_types_parse():
    f = parse(
        "0 A title\n0 !LDRAW_ORG Part UPDATE 2020-01\n"
        "1 4 1 2 3 1 0 0 0 1 0 0 0 1 s\\Sub Part.dat\n"
        "2 24 0 0 0 1 1 1\n3 16 0 0 0 1 0 0 0 1 0\n"
        "4 16 0 0 0 1 0 0 1 1 0 0 1 0\n5 24 0 0 0 1 0 0 0 1 0 1 1 0\n"
        "0 STEP\n0 ROTSTEP 0 90 0 ABS\n"
    )
    kinds = [type(it).__name__ if not isinstance(it, Poly) else f"Poly{it.kind}" for it in f.items]
    assert kinds == ["Ref", "Poly2", "Poly3", "Poly4", "Poly5", "Step", "Step"]
    ref = f.items[0]
    assert ref.name == "s/sub part.dat" and ref.colour == 4
    assert ref.pos.tolist() == [1, 2, 3] and np.allclose(ref.matrix, np.eye(3))
    assert f.items[6].rotstep and not f.items[5].rotstep
    assert f.description == "A title" and f.is_part


def test_a_flexible_element_is_marked_by_its_keyword_or_ldcad_path():
    # LDCad writes a chain, hose or string as a path and its generated segments; authors also
    # keyword such sub-models `flexible`.
    assert parse("0 Chain\n0 !KEYWORDS flexible, chain\n").flexible
    assert parse("0 Hose\n0 !LDCAD CONTENT [type=path] [addFallBack=default] [looped=false]\n").flexible
    assert parse("0 Shock\n0 !LDCAD CONTENT [type=spring]\n").flexible
    assert not parse("0 Brick\n0 !KEYWORDS chain, flexibles\n").flexible
    assert not parse("0 Group\n0 !LDCAD CONTENT [type=group]\n").flexible
    assert not parse("0 Plain\n0 !CATEGORY Brick\n").flexible


def test_crlf_and_lf_give_the_same_items():
    body = "0 T\r\n0 BFC CERTIFY CCW\r\n3 16 0 0 0 1 0 0 0 1 0\r\n"
    a = parse_lines(decode(body.encode(), "a").splitlines(), "a", "a")
    b = parse_lines(decode(body.replace("\r\n", "\n").encode(), "b").splitlines(), "b", "b")
    assert np.array_equal(a.items[0].points, b.items[0].points)
    assert a.certified and b.certified


def test_cw_files_are_stored_counter_clockwise():
    ccw = parse("0 BFC CERTIFY CCW\n3 16 0 0 0 1 0 0 0 1 0\n").items[0].points
    cw = parse("0 BFC CERTIFY CW\n3 16 0 0 0 1 0 0 0 1 0\n").items[0].points
    assert np.array_equal(cw, ccw[::-1])


def test_bfc_invertnext_applies_to_the_next_reference_only():
    f = parse(
        "0 BFC CERTIFY CCW\n0 BFC INVERTNEXT\n1 16 0 0 0 1 0 0 0 1 0 0 0 1 a.dat\n"
        "1 16 0 0 0 1 0 0 0 1 0 0 0 1 b.dat\n0 BFC NOCLIP\n0 BFC CLIP\n"
    )
    assert [r.invert for r in f.refs] == [True, False]


def test_uncertified_file_is_marked():
    assert not parse("3 16 0 0 0 1 0 0 0 1 0\n").certified
    assert not parse("0 BFC NOCERTIFY\n3 16 0 0 0 1 0 0 0 1 0\n").certified


def test_moved_to_stub_is_recognised_in_either_case():
    assert parse("0 ~Moved to 3023b\n1 16 0 0 0 1 0 0 0 1 0 0 0 1 3023b.dat\n").moved_to == "3023b.dat"
    assert parse("0 ~Moved To 3665A\n").moved_to == "3665a.dat"


@pytest.mark.parametrize(
    "token, code", [("4", 4), ("0x2FF0000", 0x2FF0000), ("#2FF0000", 0x2FF0000), ("16", 16)]
)
def test_colour_codes(token, code):
    assert parse_colour(token, "f", 1) == code


@pytest.mark.parametrize(
    "line, expected",
    [
        ("1 4 0 0 0 1 0 0 0 1 0 0 0", "type 1 (reference) needs colour"),
        ("1 4 0 0 0 1 0 0 0 x 0 0 0 1 a.dat", "expected a number, got 'x'"),
        ("3 16 0 0 0 1 0 0", "type 3 (triangle) needs a colour and 3 points"),
        ("4 16 0 0 0 1 0 0 0 1 0 0 1 0 9", "type 4 (quad)"),
        ("2 16 0 0 0", "type 2 (line)"),
        ("5 24 0 0 0 1 0 0", "type 5 (optional line)"),
        ("7 16 0 0 0", "unknown line type '7'"),
        ("3 red 0 0 0 1 0 0 0 1 0", "expected a colour code"),
        ("3 16 0 0 nan 1 0 0 0 1 0", "finite"),
        ("3 16 0 0 1e30 1 0 0 0 1 0", "finite"),
        ("0 BFC CERTIFY SIDEWAYS", "unknown BFC option"),
    ],
)
def test_malformed_lines_name_file_line_and_expectation(line, expected):
    with pytest.raises(LDrawSyntaxError) as err:
        parse_lines(["0 title", "", line], "model.ldr", "model.ldr")
    assert expected in str(err.value)
    assert str(err.value).startswith("model.ldr:3: ")


def test_certify_after_geometry_is_an_error():
    with pytest.raises(LDrawSyntaxError, match="before the first geometry"):
        parse("3 16 0 0 0 1 0 0 0 1 0\n0 BFC CERTIFY CCW\n")


def test_overlong_line_is_refused():
    with pytest.raises(LDrawSyntaxError, match="characters long"):
        parse("0 " + "x" * 10000)


def test_binary_data_is_refused():
    with pytest.raises(LDrawReadError, match="binary"):
        decode(b"\x89PNG\r\n\x1a\n\x00\x00\x00IHDR", "image.dat")


def test_latin1_text_is_accepted():
    assert "Müller" in decode("0 Author: Müller\n".encode("latin-1"), "a.dat")


def test_mpd_blocks_keep_names_with_spaces_and_line_numbers():
    text = (
        "0 FILE main model.ldr\n0 Main\n1 16 0 0 0 1 0 0 0 1 0 0 0 1 sub part.ldr\n0 NOFILE\n"
        "0 FILE Sub Part.ldr\n0 Sub\n3 16 0 0 0 1 0 0 0 1 0\n"
        "0 !DATA picture.png\n0 !: iVBORw0KGgo=\n"
    )
    blocks = split_mpd(text)
    assert [b.name for b in blocks] == ["main model.ldr", "Sub Part.ldr", "!data:picture.png"]
    assert blocks[1].first_line == 6
    sub = parse_lines(blocks[1].lines, "x.mpd#Sub Part.ldr", "sub part.ldr", blocks[1].first_line)
    assert isinstance(sub.items[0], Poly) and sub.items[0].line == 7


def test_plain_file_is_one_block():
    blocks = split_mpd("0 Title\n3 16 0 0 0 1 0 0 0 1 0\n")
    assert len(blocks) == 1 and blocks[0].name == ""


def test_steps_and_refs_keep_their_lines():
    f = parse("0 T\n1 16 0 0 0 1 0 0 0 1 0 0 0 1 a.dat\n0 STEP\n")
    assert isinstance(f.items[0], Ref) and f.items[0].line == 2
    assert isinstance(f.items[1], Step) and f.items[1].line == 3
