"""Models into build steps: real models with CRLF, MPD submodels and moved parts; hand-made cases."""

from __future__ import annotations

import numpy as np
import pytest

from factory.errors import LDrawCycleError, LDrawLimitError
from factory.ldraw import Reader, build_steps
from factory.ldraw.model import is_submodel
from factory.ldraw.reader import Resolved
from factory.pose import Pose

from ldraw_support import MODELS, needs_ldraw


def flattened_part_count(reader: Reader, res: Resolved) -> int:
    """Parts in the fully flattened model, counted independently of the step builder."""
    total = 0
    for ref in res.file.refs:
        child = reader.resolve(ref, res.file, res.model)
        total += flattened_part_count(reader, child) if is_submodel(child) else 1
    return total


@needs_ldraw
def test_car_steps(real_reader):
    model = real_reader.open_model(MODELS / "car.ldr")
    steps = build_steps(real_reader, model)
    assert [len(s.parts) for s in steps[:3]] == [5, 10, 3]
    assert all(s.assembly == "main" for s in steps)
    first = steps[0].parts[4]
    assert first.part == "4315.dat" and first.colour == 0
    assert first.pose.allclose(Pose(np.diag([-1.0, 1.0, -1.0]), [0, 0, 90]))
    total = sum(len(s.parts) for s in steps)
    assert total == flattened_part_count(real_reader, Resolved(model.main, "k", "mpd", model))


@needs_ldraw
def test_mpd_submodels_expand_in_place_with_instance_tags(real_reader):
    path = MODELS / "4915-1-MiniConstruction.mpd"
    assert b"\r\n" in path.read_bytes(), "the real model uses CRLF line endings"
    model = real_reader.open_model(path)
    steps = build_steps(real_reader, model)
    total = sum(len(s.parts) for s in steps)
    assert total == flattened_part_count(real_reader, Resolved(model.main, "k", "mpd", model))
    assert [s.index for s in steps] == list(range(len(steps)))
    tags = [s.assembly for s in steps]
    house = "main/4915 - Mini Construction - House.ldr#1"
    side = house + "/4915 - Mini Construction - Side.ldr"
    assert tags.count(side + "#1") == tags.count(side + "#2") == 4
    # The house's own steps before the first side come first; both sides precede the next house step.
    first_side = tags.index(side + "#1")
    assert tags[first_side - 1] == house and tags[first_side + 8] == house
    # A submodel's parts are at their final pose in the model frame: the house is placed at
    # (0, -24, 20) unrotated; its second step's 3020 sits at (0, -8, -20) in the house.
    second = steps[tags.index(house) + 1].parts[0]
    assert second.part == "3020.dat" and second.colour == 14
    assert np.allclose(second.pose.t, [0, -32, 0])
    # Moved-part stubs keep the name the model uses.
    assert any(p.part == "3023.dat" for s in steps for p in s.parts)


@needs_ldraw
def test_submodel_colour_and_pose_compose(real_reader, write):
    path = write(
        "t.mpd",
        "0 FILE main.ldr\n0 Main\n1 4 100 0 0 0 0 1 0 1 0 -1 0 0 wing.ldr\n0 STEP\n"
        "1 1 0 0 0 1 0 0 0 1 0 0 0 1 3001.dat\n0 STEP\n0 STEP\n"
        "0 FILE wing.ldr\n0 Wing\n1 16 20 0 0 1 0 0 0 1 0 0 0 1 3003.dat\n0 STEP\n"
        "1 15 0 -24 0 1 0 0 0 1 0 0 0 1 3003.dat\n0 STEP\n"
        "0 FILE unused.ldr\n0 Never referenced\n1 4 0 0 0 1 0 0 0 1 0 0 0 1 nonexistent.dat\n",
    )
    steps = build_steps(real_reader, real_reader.open_model(path))
    assert [(s.assembly, len(s.parts)) for s in steps] == [
        ("main/wing.ldr#1", 1), ("main/wing.ldr#1", 1), ("main", 1)
    ]
    wing_part = steps[0].parts[0]
    assert wing_part.colour == 4  # 16 inherits the submodel's colour
    assert np.allclose(wing_part.pose.t, [100, 0, -20])  # R(0,0,1/0,1,0/-1,0,0) @ (20,0,0) + (100,0,0)
    assert steps[1].parts[0].colour == 15


def test_submodel_cycle_and_blowup_are_refused(embedded_reader, write):
    cyc = write("c.mpd", "0 FILE a.ldr\n1 16 0 0 0 1 0 0 0 1 0 0 0 1 b.ldr\n0 FILE b.ldr\n1 16 0 0 0 1 0 0 0 1 0 0 0 1 a.ldr\n")
    with pytest.raises(LDrawCycleError, match="a.ldr -> b.ldr -> a.ldr"):
        build_steps(embedded_reader, embedded_reader.open_model(cyc))
    blocks = ["0 FILE m0.ldr\n1 4 0 0 0 1 0 0 0 1 0 0 0 1 3001.dat\n"]
    for i in range(1, 25):
        blocks.insert(0, f"0 FILE m{i}.ldr\n" + f"1 16 0 0 0 1 0 0 0 1 0 0 0 1 m{i-1}.ldr\n" * 2)
    bomb = write("bomb.mpd", "".join(blocks))
    with pytest.raises(LDrawLimitError, match="more than 200,000 parts"):
        build_steps(embedded_reader, embedded_reader.open_model(bomb))


def test_steps_without_parts_are_dropped(embedded_reader, write):
    path = write("e.ldr", "0 Empty steps\n0 STEP\n0 STEP\n1 4 0 0 0 1 0 0 0 1 0 0 0 1 3001.dat\n0 STEP\n0 STEP\n")
    steps = build_steps(embedded_reader, embedded_reader.open_model(path))
    assert len(steps) == 1 and steps[0].index == 0


def test_step_json_matches_the_command_line_format(embedded_reader, write):
    path = write("j.ldr", "1 4 10 -24 0 0 0 1 0 1 0 -1 0 0 3001.dat\n")
    (step,) = build_steps(embedded_reader, embedded_reader.open_model(path))
    assert step.to_json() == {
        "step": 0,
        "assembly": "main",
        "parts": [{"part": "3001.dat", "color": 4, "R": [[0, 0, 1], [0, 1, 0], [-1, 0, 0]], "T": [10, -24, 0]}],
    }


@pytest.mark.parametrize("matrix, what", [
    ("0 0 0 0 0 0 0 0 0", "all zero"),
    ("1 0 0 0 1 0 0 0 0", "rank-deficient"),
    ("2 0 0 0 2 0 0 0 2", "scaled"),
    ("1 0.5 0 0 1 0 0 0 1", "sheared"),
    ("-1 0 0 0 1 0 0 0 1", "mirrored"),
])
def test_a_placement_that_is_not_a_rotation_is_refused_with_its_line(embedded_reader, write, matrix, what):
    from factory.errors import LDrawPlacementError

    # The corner plate 2420 is not its own mirror image through any of its axis planes.
    path = write("m.ldr", f"0 model\n1 4 0 0 0 1 0 0 0 1 0 0 0 1 3001.dat\n1 4 0 -24 0 {matrix} 2420.dat\n")
    with pytest.raises(LDrawPlacementError, match=r"m\.ldr:3: .*rotation") as err:
        build_steps(embedded_reader, embedded_reader.open_model(path))
    assert what and err.value.line == 3
    # a submodel is placed the same way
    mpd = write("s.mpd", f"0 FILE a.ldr\n1 16 0 0 0 {matrix} b.ldr\n0 FILE b.ldr\n1 4 0 0 0 1 0 0 0 1 0 0 0 1 3001.dat\n")
    with pytest.raises(LDrawPlacementError, match=r"s\.mpd#a\.ldr:2: "):
        build_steps(embedded_reader, embedded_reader.open_model(mpd))


@pytest.mark.parametrize("matrix", ["-1 0 0 0 1 0 0 0 1", "0 0 1 0 1 0 1 0 0", "1 0 0 0 -1 0 0 0 1"])
def test_a_part_that_is_its_own_mirror_image_may_be_placed_mirrored(embedded_reader, write, matrix):
    # A design mirrors a hinge brick into its other half (vehicle_084 of ../shared/designs): for a
    # part symmetric through one of its axis planes the mirroring matrix times that reflection is a
    # rotation that puts the same shape in the same place.
    from factory.ldraw.model import _mirror_plane

    path = write("m.ldr", f"0 model\n1 4 0 -24 0 {matrix} 3001.dat\n")
    (step,) = build_steps(embedded_reader, embedded_reader.open_model(path))
    R = step.parts[0].pose.R
    assert np.isclose(np.linalg.det(R), 1.0) and np.allclose(R @ R.T, np.eye(3))
    m = np.array(matrix.split(), float).reshape(3, 3)
    points = embedded_reader.flatten(embedded_reader.part("3001.dat")).triangles.reshape(-1, 3)
    placed = {tuple(np.round(p, 6)) for p in points @ R.T}
    assert placed == {tuple(np.round(p, 6)) for p in points @ m.T}  # the same shape
    assert _mirror_plane(embedded_reader, embedded_reader.part("2420.dat")) is None


def test_rotations_written_to_six_decimals_are_accepted(embedded_reader, write):
    path = write("r.ldr", "1 4 0 0 0 0.707107 0 0.707107 0 1 0 -0.707107 0 0.707107 3001.dat\n")
    assert len(build_steps(embedded_reader, embedded_reader.open_model(path))[0].parts) == 1


@needs_ldraw
def test_every_real_model_places_its_parts_by_rotations(real_reader):
    for path in sorted(MODELS.glob("*.*")):
        if path.suffix.lower() in (".ldr", ".mpd"):
            assert build_steps(real_reader, real_reader.open_model(path))


def test_a_nearly_orthonormal_placement_is_taken_as_the_nearest_rotation(embedded_reader, write):
    """Real files turn parts by approximate matrices (10156's minifig arms: rows (1, 0.17, 0) and
    (-0.17, 1, 0)); the part is placed by the nearest rotation."""
    path = write("n.ldr", "1 4 0 0 0 1 0.17 0 -0.17 1 0 0 0 1 3001.dat\n")
    pose = build_steps(embedded_reader, embedded_reader.open_model(path))[0].parts[0].pose
    r = np.asarray(pose.R)
    assert np.allclose(r @ r.T, np.eye(3), atol=1e-12) and np.linalg.det(r) == pytest.approx(1.0)
    assert np.degrees(np.arctan2(r[0, 1], r[0, 0])) == pytest.approx(np.degrees(np.arctan(0.17)), abs=1e-9)
