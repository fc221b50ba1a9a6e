"""Parsing model outputs: tolerant of wording, never raising, and exact on the formats we write."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from eval.baselines import format_pose, format_selection
from eval.metrics import StepTarget, score_step
from eval.parse import PoseAnswer, Selection, clean, parse_pose, parse_selection, strip_think

POSE = """Brick 1:
Translation:
x=-10.0, y=-8.0, z=-20.0
Rotation:
[0.0, 0.0, -1.0]
[0.0, 1.0, 0.0]
[1.0, 0.0, 0.0]
"""
R_POSE = np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])
T_POSE = np.array([-10.0, -8.0, -20.0])


def check_pose(answers: dict, n: int, t=T_POSE, r=R_POSE):
    assert n in answers, answers
    assert np.allclose(answers[n].t, t) and np.allclose(answers[n].R, r)


# -- fuzz: nothing raises ---------------------------------------------------------------------

FRAGMENTS = [
    "<think>", "</think>", "< THINK >", "</ think>", "<think><think>", "```", "```json\n", "**", "`",
    "Brick 1:", "Brick 2:", "brick 999999:", "### Brick 3 (3001.dat):", "Translation:", "Rotation:",
    "x=", "y=", "z=", "X:", ", ", "\n", "\r\n", "[", "]", "[[", "]]", "(", ")", "row", "ROW", "Row:",
    "col", "column", "Col:", ".dat", "3023.dat", "3001", ", row 6, col 3", "nan", "NaN", "inf", "-inf",
    "1e309", "-1e-400", "1" * 400, "9" * 5000, "0." + "0" * 300 + "1", "1e", "1.2.3", "--5", "+-3",
    "\u2212", "\uff13", "\u0663", "\U0001f9f1", "\x00", "\ud800", "\u202e", "Answer:", "- ", "1. ",
    "e", "E+", " " * 50, "\t",
]
NUMBERS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(min_value=-(10**30), max_value=10**30).map(str),
    st.floats(min_value=-1e6, max_value=1e6).map(lambda v: f"{v:.3e}"),
)
ADVERSARIAL = st.lists(
    st.one_of(st.sampled_from(FRAGMENTS), NUMBERS, st.text(max_size=12)), max_size=80
).map("".join)
ANY_TEXT = st.one_of(st.text(max_size=400), ADVERSARIAL)
FUZZ = settings(max_examples=1200, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _check_outputs(text):
    sels = parse_selection(text)
    assert isinstance(sels, list)
    for s in sels:
        assert isinstance(s, Selection) and isinstance(s.row, int) and isinstance(s.col, int)
    poses = parse_pose(text)
    assert isinstance(poses, dict)
    for n, p in poses.items():
        assert isinstance(n, int) and isinstance(p, PoseAnswer)
        assert p.t.shape == (3,) and p.R.shape == (3, 3)
        assert np.all(np.isfinite(p.t)) and np.all(np.isfinite(p.R))


@FUZZ
@given(ANY_TEXT)
def test_fuzz_parsers_never_raise(text):
    _check_outputs(text)


@pytest.mark.slow
@settings(FUZZ, max_examples=1000)
@given(st.lists(st.sampled_from(POSE.splitlines(keepends=True)) | ADVERSARIAL, max_size=20).map("".join))
def test_fuzz_shuffled_and_truncated_blocks(text):
    """Lines of a valid answer shuffled, repeated, cut and mixed with junk."""
    _check_outputs(text)
    _check_outputs(text[: len(text) // 2])


STEP = StepTarget("s", "o", ())


@settings(max_examples=800, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.lists(
        st.sampled_from(["1e308", "1e309", "nan", "-0", "", "1" * 320, "0.5", "x", "[", "]"]), min_size=12, max_size=12
    )
)
def test_fuzz_number_slots(values):
    """Every number slot of a block filled with edge values: complete and finite, or absent."""
    template = "Brick 1:\nTranslation:\nx={}, y={}, z={}\nRotation:\n[{}, {}, {}]\n[{}, {}, {}]\n[{}, {}, {}]\n"
    text = template.format(*values)
    _check_outputs(text)
    fine = all(v in ("1e308", "-0", "0.5") for v in values)
    assert (1 in parse_pose(text)) == fine
    score_step(STEP, text, text)  # the scorer takes any text too


@pytest.mark.parametrize(
    "text",
    [
        "a" * 10**6,
        "row 1 col 2 " * 80_000,
        "[" * 10**6,
        "[1, " + " " * 10**6,
        "x=1, " * 200_000,
        "<think>" * 140_000,
        "</think>" * 120_000,
        "Brick 1:\n" * 100_000,
        "1" * 10**6,
        "1.0, 2.0, 3.0\n" * 70_000,
        ("3023.dat" + " " * 90) * 10_000 + "row 1, col 1",
    ],
    ids=lambda t: repr(t[:12]),
)
def test_huge_inputs_are_fast(text):
    """No catastrophic backtracking on a megabyte of hostile text (0.2-3.4 s of CPU each on the
    development machine; 80,000 selections are the dearest). CPU seconds, not wall: with other
    jobs on its two cores, 'row 1 col 2 ' * 80_000 took 5.5 s of wall while this process waited
    for a core."""
    start = time.process_time()
    _check_outputs(text)
    assert time.process_time() - start < 5.0


# -- round trips ------------------------------------------------------------------------------


def random_rotation(q):
    w, x, y, z = np.asarray(q) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


QUATS = st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(lambda q: np.linalg.norm(q) > 0.1)
TRANS = st.lists(st.floats(-1e4, 1e4), min_size=3, max_size=3)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.tuples(TRANS, QUATS), min_size=1, max_size=4))
def test_pose_round_trip(poses):
    poses = [(np.array(t), random_rotation(q)) for t, q in poses]
    parsed = parse_pose(format_pose(poses))
    assert sorted(parsed) == list(range(1, len(poses) + 1))
    for n, (t, r) in enumerate(poses, start=1):
        assert np.allclose(parsed[n].t, t, atol=1e-6, rtol=0) and np.allclose(parsed[n].R, r, atol=1e-6, rtol=0)


PART_NAMES = st.from_regex(r"[0-9]{3,5}[a-z]?(p[0-9]{2})?", fullmatch=True)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(PART_NAMES, st.integers(1, 999), st.integers(1, 6)), max_size=5))
def test_selection_round_trip(picks):
    parsed = parse_selection(format_selection(picks))
    assert parsed == [Selection(p + ".dat", r, c) for p, r, c in picks]


def test_formats_match_the_brief():
    assert format_pose([(T_POSE, R_POSE)]) == POSE.strip()
    assert format_selection([("3023", 6, 3)]) == "3023.dat, row 6, col 3"
    assert "-0.0" not in format_pose([(np.array([-0.0, 1e-9, -1e-9]), -np.eye(3) * 0.0)])


# -- tolerance: selection ---------------------------------------------------------------------


@pytest.mark.parametrize(
    "text, expected",
    [
        ("3023.dat, row 6, col 3", [("3023.dat", 6, 3)]),
        ("  3023.DAT ,ROW 6 ,  COL 3  ", [("3023.dat", 6, 3)]),
        ("3023, Row:6, Col:3", [("3023.dat", 6, 3)]),
        ("3023.dat row 6 column 3", [("3023.dat", 6, 3)]),
        ("**3023.dat**, **row 6**, **col 3**", [("3023.dat", 6, 3)]),
        ("Looking at the grid, the red box is a 1x2 plate.\n\nAnswer: 3023.dat, row 6, col 3.", [("3023.dat", 6, 3)]),
        ("```\n3023.dat, row 6, col 3\n3001.dat, row 1, col 2\n```", [("3023.dat", 6, 3), ("3001.dat", 1, 2)]),
        ("- 3023.dat, row 6, col 3\n- 3001.dat, row 1, col 2", [("3023.dat", 6, 3), ("3001.dat", 1, 2)]),
        ("<think>maybe 3001.dat, row 1, col 1</think>\n3023.dat, row 6, col 3", [("3023.dat", 6, 3)]),
        ("<think>a<think>b</think>3001.dat, row 1, col 1</think>3023.dat, row 6, col 3", [("3023.dat", 6, 3)]),
        ("reasoning opened in the prompt 3001.dat, row 1, col 1</think>3023.dat, row 6, col 3", [("3023.dat", 6, 3)]),
        ("I pick 3023.dat at row 6, col 3 since it matches.", [("3023.dat", 6, 3)]),
        ("3001.dat, row 1, col 2 looked close, but no.\nAnswer:\n3023.dat, row 6, col 3", [("3023.dat", 6, 3)]),
        ("row 6, col 3", [("", 6, 3)]),
        ("col 3, row 6", [("", 6, 3)]),
        ("\uff13\uff10\uff12\uff13.dat, row \uff16, col \uff13", [("3023.dat", 6, 3)]),
    ],
)
def test_selection_tolerance(text, expected):
    assert parse_selection(text) == [Selection(*e) for e in expected]


@pytest.mark.parametrize(
    "text",
    ["", "I cannot tell.", "<think>3023.dat, row 6, col 3", "3023.dat, row six, col 3", "narrow 6, col 3",
     "3023.dat, row 1234567, col 3", None, 42],
)
def test_selection_unparseable(text):
    assert parse_selection(text) == []


# -- tolerance: pose --------------------------------------------------------------------------


@pytest.mark.parametrize(
    "text",
    [
        POSE,
        POSE.upper(),
        POSE.replace("Brick 1:\n", ""),
        "Let me think about the translation and rotation.\n" + POSE.replace("Brick 1:\n", ""),
        "<think>Brick 1:\nTranslation:\nx=0, y=0, z=0\nRotation:\n[1,0,0]\n[0,1,0]\n[0,0,1]</think>" + POSE,
        "```\n" + POSE + "```",
        "**Brick 1:**\n**Translation:**\n`x = -10.0 , y = -8.0 , z = -20.0`\n"
        "**Rotation:**\n[0,0,-1]\n[0, 1, 0]\n[1,0,0]",
        POSE.replace("-10.0", "-1.0E+1").replace("-20.0", "-2e1").replace("1.0]", "1.]"),
        POSE.replace("x=-10.0, y=-8.0, z=-20.0", "z=-20, x=-10, y=-8"),
        POSE.replace("x=-10.0, y=-8.0, z=-20.0", "x: -10\ny: -8\nz: -20"),
        POSE.replace("[0.0, 0.0, -1.0]\n[0.0, 1.0, 0.0]\n[1.0, 0.0, 0.0]", "[[0, 0, -1], [0, 1, 0], [1, 0, 0]]"),
        POSE.replace("[0.0, 0.0, -1.0]\n[0.0, 1.0, 0.0]\n[1.0, 0.0, 0.0]", "0 0 -1\n0 1 0\n1 0 0"),
        "Translation: [-10, -8, -20]\nRotation: [[0, 0, -1], [0, 1, 0], [1, 0, 0]]",
        "Translation: (x, y, z) = (-10, -8, -20)\nRotation: [0, 0, -1], [0, 1, 0], [1, 0, 0]",
        "Brick 1: Translation: x=-10 LDU, y=-8 LDU, z=-20 LDU Rotation: [0,0,-1] [0,1,0] [1,0,0]",
        "Rotation:\n[0, 0, -1]\n[0, 1, 0]\n[1, 0, 0]\nTranslation:\nx=-10, y=-8, z=-20",
        POSE.replace("-", "\u2212"),
        POSE.replace("\n", "\r\n"),
        POSE.replace("\n", "\n\n   "),
    ],
)
def test_pose_tolerance(text):
    check_pose(parse_pose(text), 1)


def test_pose_several_blocks_by_number():
    two = POSE.replace("Brick 1", "Brick 2").replace("-10.0", "30.0")
    answers = parse_pose("Here are the poses.\n\n" + two + "\n" + POSE)
    assert sorted(answers) == [1, 2]
    check_pose(answers, 1)
    check_pose(answers, 2, t=[30.0, -8.0, -20.0])
    # a revised block replaces the earlier one
    answers = parse_pose(POSE + "\nWait, correction:\n" + POSE.replace("-10.0", "-30.0"))
    check_pose(answers, 1, t=[-30.0, -8.0, -20.0])
    # a later broken block does not erase an earlier good one
    check_pose(parse_pose(POSE + "\n" + "Brick 1:\nTranslation:\nx=1"), 1)


@pytest.mark.parametrize(
    "text",
    [
        "",
        "no idea",
        POSE.replace("y=-8.0, ", ""),
        POSE.replace("-8.0", "nan"),
        POSE.replace("-8.0", "inf"),
        POSE.replace("-8.0", "1e400"),
        POSE.replace("[1.0, 0.0, 0.0]", "[1.0, 0.0]"),
        POSE.replace("[0.0, 1.0, 0.0]", "[0.0, NaN, 0.0]"),
        POSE[: POSE.index("[1.0")],
        "<think>" + POSE,
        POSE.replace("x=-10.0, y=-8.0, z=-20.0", "x=-10.0, y=-8.0, z=" + "9" * 400),
    ],
)
def test_pose_incomplete_or_non_finite_is_absent(text):
    assert parse_pose(text) == {}


def test_incomplete_block_absent_others_kept():
    broken = POSE.replace("Brick 1", "Brick 2").replace("z=-20.0", "z=")
    answers = parse_pose(POSE + "\n" + broken)
    assert sorted(answers) == [1]


def test_clean_and_think():
    assert strip_think("a<think>b</think>c<think>d<think>e</think>f</think>g") == "acg"
    assert strip_think("x</think>y") == "y"
    assert strip_think("x<think>y") == "x"
    assert strip_think("a</think>b</think>c") == "c"
    assert clean("```python\n**a** `b`\n```") == "\na b\n"
    assert clean(None) == "" and clean(b"bytes") == ""
    assert math.isfinite(parse_pose("x=1,y=2,z=3 [1,0,0][0,1,0][0,0,1]")[1].t[0])
