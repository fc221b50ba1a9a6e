"""BC-Bench's released layout, in and out (`pipelines.bcbench`, `pipelines.export --format bcbench`).

The import is tested on a hand-made release (`make_release`: no network), laid out as BC-Bench's
evaluation scripts read it, with tiny PNGs; the export on the session's tiny build; and the round
trip ours -> export -> import on the scorer: the same targets, the same baseline answers and the
same scores in strict and paper modes.
"""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from PIL import Image

from eval.data import iter_rows, load_targets
from eval.predict import predict_file
from eval.score import score_file
from ldraw_support import LDRAW, needs_ldraw
from pipelines.bcbench import (
    EXTENSION,
    VIEW_NAMES,
    BCBenchError,
    import_bcbench,
    read_bcbench,
    six_views,
)
from factory.dataset.schema import SCHEMA

ROOT = Path(__file__).resolve().parents[1]

# -- a hand-made release -------------------------------------------------------------------------
NAS = "/shared/nas/data/m1/jiateng5/BrickComposer"
"""The absolute prefix of the released pose files' image paths (a machine of theirs, not this one):
the import finds the files again under SRC by their trailing folders."""
MAC = "/Users/jiateng5/research/BrickLink_data_statistics/reasoning"
"""The absolute prefix of the released tasks.json image paths."""
TEST_OBJ = "1704_Tiny_Car"
TRAIN_OBJ = "2001_Small_House"
VIEW = "340"
"""`view_folder` of the released tasks (a camera setting; step folders are step_<k:04d>_<view>)."""

I3 = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
RY90 = [[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]]
RY180 = [[-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]]

# Per object, its steps: k (step number), bricks (part, LDraw colour, (x, y, z) LDU, transform rows),
# cells (per brick, its catalog candidate cells), catalog (catalog_brick_count), and the flags:
# blank (a manual step that adds no brick), selection_only (a task with no pose record), module
# (a multi-brick step; `ground_truth` is 'module "<name>"').
RELEASE = {
    TEST_OBJ: [
        dict(k=0, bricks=[("3001.dat", 4, (0.0, -24.0, 0.0), I3)], cells=[[(1, 2)]], catalog=8),
        dict(k=1, blank=True),
        dict(k=2, module="front_axle", bricks=[("3023.dat", 1, (-10.0, -32.0, 20.0), RY90),
                                               ("3023.dat", 1, (10.0, -32.0, 20.0), RY90)],
             cells=[[(1, 3), (1, 4)], [(1, 3), (1, 4)]], catalog=7),
        dict(k=3, bricks=[("3062b.dat", 14, (0.0, -56.0, 0.0), RY90)], cells=[[(1, 1)]], catalog=5),
        dict(k=4, selection_only=True, bricks=[("3023.dat", 1, (0.0, -64.0, 0.0), I3)], cells=[[(1, 2)]], catalog=4),
    ],
    TRAIN_OBJ: [
        dict(k=0, bricks=[("3003.dat", 15, (0.0, -24.0, 0.0), I3)], cells=[[(2, 1)]], catalog=9),
        dict(k=1, bricks=[("3039.DAT", 4, (0.0, -48.0, 10.0), RY180)], cells=[[(1, 6)]], catalog=8),
    ],
}
SYSTEM = "You are a LEGO assembly expert. Poses are in LDraw units."


def _png(rgb, size=(30, 20)) -> bytes:
    buf = io.BytesIO()
    Image.new("RGB", size, rgb).save(buf, format="PNG")
    return buf.getvalue()


def _answer(bricks) -> str:
    """A gpt turn in the format BC-Bench's pose parser documents."""
    blocks = []
    for n, (_, _, (x, y, z), R) in enumerate(bricks, 1):
        rows = "\n".join("[" + ", ".join(f"{v:g}" for v in r) + "]" for r in R)
        blocks.append(f"Brick {n}:\nTranslation: x={x:g}, y={y:g}, z={z:g}\nRotation:\n{rows}")
    return "\n\n".join(blocks)


def make_release(src: Path) -> Path:
    """BC-Bench's layout as its scripts read it, under `src`:

    - src/LlamaFactory/data/Designer_supervision_assembly_{testing,training}.json: the pose sets,
      LLaMA-Factory ShareGPT lists. A record: `system` (system prompt), `conversations`
      ([{"from": "human", "value": text with one <image> per image}, {"from": "gpt", "value":
      the answer}]), `images` (absolute paths of their machine: before views, after views, one part
      render per brick, the 7-view axes composite). The folder of images[0] is the step folder
      `step_<k:04d>`; its parent folder's name is the object.
    - src/Designer_supervision/data/<object>/step_<k:04d>/brick_pose.json: `is_blank` (a manual step
      adding no brick: skipped), `bricks`: `brick_name` (part file), `ldraw_color` (LDraw code),
      `x`, `y`, `z` (translation, LDU, y down), `transform` (3x3 rotation as rows; the scorer takes
      R_gt @ g for the part's symmetries g, so it maps the part's frame to the model's).
    - src/reasoning/tasks_with_color/<object>/tasks.json: {"tasks": [...]}, a task: `step_k` (the
      step, 0-based), `view_folder` (camera setting), `is_blank`, `ground_truth` (the part, or
      'module "name"' for a multi-brick step), `gt_bricks` (part files, one per brick),
      `gt_position` (per brick, `candidate_positions`: the 1-based catalog cells holding an
      equivalent brick), `catalog_brick_count` (cells in the catalog), `input_images` (`original`,
      `target`: six per-view images each; `catalog_remaining` and `catalog_remaining_no_caption`:
      the catalog with and without part labels), `task_dir` (the step folder with the composites).
    - src/reasoning/tasks_with_color/test.json: the test steps, "<object>/step_<k:04d>_<view>".
    """
    pose_sets = {"testing": [], "training": []}
    for obj, steps in RELEASE.items():
        tasks = []
        for s in steps:
            k = s["k"]
            bricks = s.get("bricks", [])
            step = f"step_{k:04d}"
            step_dir = src / "Designer_supervision" / "data" / obj / step
            names = ["original_orthogonal_views.png", "target_orthogonal_views.png",
                     *([f"brick_{n}.png" for n in range(1, len(bricks) + 1)] or ["part.png"]),
                     "current_state_axes.png"]
            if not s.get("selection_only"):
                step_dir.mkdir(parents=True, exist_ok=True)
                for i, name in enumerate(names):
                    (step_dir / name).write_bytes(_png((40 * i % 256, 100, 200 - 20 * k)))
                (step_dir / "brick_pose.json").write_text(json.dumps({
                    "is_blank": bool(s.get("blank")),
                    "bricks": [{"brick_name": p, "ldraw_color": c, "x": t[0], "y": t[1], "z": t[2], "transform": R}
                               for p, c, t, R in bricks]}, indent=1))
                human = ("Image 1 (before):<image>\nImage 2 (after):<image>\nBrick renders:"
                         + "<image>" * (len(names) - 3) + "\nAxes:<image>\nGive the pose of each brick.")
                record = {"system": SYSTEM,
                          "conversations": [{"from": "human", "value": human},
                                            {"from": "gpt", "value": _answer(bricks)}],
                          "images": [f"{NAS}/Designer_supervision/data/{obj}/{step}/{n}" for n in names]}
                pose_sets["testing" if obj == TEST_OBJ else "training"].append(record)
            task_dir = src / "reasoning" / "tasks_with_color" / obj / f"{step}_{VIEW}"
            task_dir.mkdir(parents=True, exist_ok=True)
            for name in ("catalog_remaining.png", "catalog_remaining_no_caption.png", "original_orthogonal_views.png",
                         "target_orthogonal_views.png"):
                (task_dir / name).write_bytes(_png((250, 250, 10 * k)))
            mac = f"{MAC}/tasks_with_color/{obj}/{step}_{VIEW}"
            if s.get("blank"):
                tasks.append({"step_k": k, "view_folder": VIEW, "is_blank": True, "ground_truth": "", "gt_bricks": []})
                continue
            tasks.append({
                "step_k": k,
                "view_folder": VIEW,
                "is_blank": False,
                "ground_truth": f'module "{s["module"]}"' if "module" in s else bricks[0][0],
                "gt_bricks": [b[0] for b in bricks],
                "gt_position": [{"candidate_positions": [{"row": r, "col": c} for r, c in cells]}
                                for cells in s["cells"]],
                "catalog_brick_count": s["catalog"],
                "input_images": {
                    "original": [f"{MAC}/step_wise_orthogonal_views/{obj}/{step}/original_{v}.png"
                                 for v in VIEW_NAMES.values()],
                    "target": [f"{MAC}/step_wise_orthogonal_views/{obj}/{step}/target_{v}.png"
                               for v in VIEW_NAMES.values()],
                    "catalog_remaining": f"{mac}/catalog_remaining.png",
                    "catalog_remaining_no_caption": f"{mac}/catalog_remaining_no_caption.png",
                },
                "task_dir": mac,
            })
        (src / "reasoning" / "tasks_with_color" / obj / "tasks.json").write_text(json.dumps({"tasks": tasks}, indent=1))
    (src / "reasoning" / "tasks_with_color" / "test.json").write_text(json.dumps(
        [f"{TEST_OBJ}/step_{s['k']:04d}_{VIEW}" for s in RELEASE[TEST_OBJ]]))
    data = src / "LlamaFactory" / "data"
    data.mkdir(parents=True, exist_ok=True)
    for name, records in pose_sets.items():
        (data / f"Designer_supervision_assembly_{name}.json").write_text(json.dumps(records, indent=1))
    return src


@pytest.fixture
def release(tmp_path) -> Path:
    return make_release(tmp_path / "release")


def _env() -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    env.setdefault("MUJOCO_GL", "egl")
    return env


def _run(*args, timeout=300):
    return subprocess.run([sys.executable, "-m", *args], cwd=ROOT, env=_env(), capture_output=True, text=True,
                          timeout=timeout)


def _rows(out, split=None):
    return list(iter_rows(out, split))


# -- import ------------------------------------------------------------------------------------------
def test_import_steps_targets_blank_count_and_splits(release, tmp_path):
    out = tmp_path / "imported"
    s = import_bcbench(release, out)
    assert s["steps"] == {"train": 2, "test": 3} and s["objects"] == {"train": 1, "test": 1}
    assert s["blank_steps_skipped"] == 1
    assert s["skipped"] == {"pose_only": 0, "selection_only": 1}
    assert s["tasks"] == ["selection", "pose"]
    assert s["split_from"] == {"not in test.json": 2, "split list": 3}
    assert s["symmetry"].startswith("none") and s["parts_not_in_library"] == []
    info = json.loads((out / "meta" / "info.json").read_text())
    assert info["blank_steps_skipped"] == 1 and info["bcbench_import"]["blank_steps_skipped"] == 1
    assert info["counts"]["test"]["steps"] == 3 and info["tasks"] == ["selection", "pose"]
    assert sorted(p.name for p in (out / "data").iterdir()) == ["test-00000-of-00001.parquet",
                                                              "train-00000-of-00001.parquet"]
    schema = pq.ParquetFile(out / "data" / "test-00000-of-00001.parquet").schema_arrow
    assert schema.equals(SCHEMA) and schema.metadata[b"huggingface"] == SCHEMA.metadata[b"huggingface"]
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary folder left

    targets = load_targets(out, "test")
    assert [t.id for t in targets] == [f"{TEST_OBJ}/000", f"{TEST_OBJ}/002", f"{TEST_OBJ}/003"]
    by_k = {s["k"]: s for s in RELEASE[TEST_OBJ]}
    for t, k in zip(targets, (0, 2, 3)):
        assert t.object_id == TEST_OBJ
        want = by_k[k]
        assert [(b.part, b.colour) for b in t.bricks] == [(p, c) for p, c, _, _ in want["bricks"]]
        for b, (_, _, xyz, R), cells in zip(t.bricks, want["bricks"], want["cells"]):
            assert b.cells == frozenset(cells)
            np.testing.assert_array_equal(b.t, xyz)
            np.testing.assert_array_equal(b.R, R)
            assert b.symmetry.order == 1 and b.symmetry.continuous_axis is None
    train = load_targets(out, "train")
    assert [b.part for t in train for b in t.bricks] == ["3003.dat", "3039.dat"]  # names normalised

    rows = {r["step_index"]: r for r in _rows(out, "test")}
    assert rows[2]["step_kind"] == "module" and rows[0]["step_kind"] == "part"
    assert rows[0]["num_steps"] == 5 and rows[0]["source"] == "bcbench" and rows[0]["isometric"] is None
    # the module step's two part renders are one image, the prompt's placeholders follow
    with Image.open(io.BytesIO(rows[2]["part"]["bytes"])) as im:
        assert im.width > 2 * 30
    user = rows[2]["pose_messages"][1]["content"]
    assert [p["index"] for p in user if p["type"] == "image"] == [0, 1, 2, 3]
    assert rows[2]["pose_messages"][0]["content"][0]["text"] == SYSTEM
    assert rows[2]["pose_answer"].startswith("Brick 1:\nTranslation: x=-10")
    assert rows[0]["selection_answer"] == "3001.dat, row 1, col 2"
    assert rows[2]["selection_answer"] == "3023.dat, row 1, col 3\n3023.dat, row 1, col 4"
    # catalog: the target cells are known, the other cells up to catalog_brick_count are not
    cat = {(e["row"], e["col"]): (e["part"], e["colour"]) for e in rows[0]["catalog_parts"]}
    assert len(cat) == 8 and cat[(1, 2)] == ("3001.dat", 4) and cat[(2, 2)] == ("", -1)
    catalog_png = (release / "reasoning" / "tasks_with_color" / TEST_OBJ / f"step_0000_{VIEW}" /
                   "catalog_remaining.png").read_bytes()
    assert rows[0]["catalog"]["bytes"] == catalog_png


def test_import_symmetry_needs_a_library(release, tmp_path):
    plain = import_bcbench(release, tmp_path / "plain")
    assert "no LDraw library" in plain["symmetry"]
    assert {b.symmetry.order for t in load_targets(tmp_path / "plain", None) for b in t.bricks} == {1}
    # and the scorer says so, in its JSON and its table
    pred = tmp_path / "o.jsonl"
    predict_file(tmp_path / "plain", "baseline:oracle", pred, split="test")
    result = score_file(tmp_path / "plain", pred, "test", "paper")
    assert len(result["notes"]) == 1 and "without symmetry" in result["notes"][0]
    r = _run("eval.score", "--data", str(tmp_path / "plain"), "--pred", str(pred))
    assert r.returncode == 0 and "note: parts scored without symmetry" in r.stdout
    with_lib = import_bcbench(release, tmp_path / "lib", ldraw="embedded")
    assert not with_lib["symmetry"].startswith("none")
    pred = tmp_path / "l.jsonl"
    predict_file(tmp_path / "lib", "baseline:oracle", pred, split="test")
    assert "notes" not in score_file(tmp_path / "lib", pred, "test", "paper")


@needs_ldraw
def test_import_symmetry_from_the_ldraw_library(release, tmp_path):
    out = tmp_path / "sym"
    s = import_bcbench(release, out, ldraw=LDRAW)
    assert str(LDRAW.resolve()) in s["symmetry"] and s["parts_not_in_library"] == []
    sym = {b.part: b.symmetry for t in load_targets(out, None) for b in t.bricks}
    assert sym["3001.dat"].order == 2 and sym["3023.dat"].order == 2 and sym["3039.dat"].order == 1
    assert sym["3062b.dat"].continuous_axis == (0.0, -1.0, 0.0)
    row = next(r for r in _rows(out, "test") if r["step_index"] == 0)
    assert row["bricks"][0]["size_cm"] == [3.2, 1.12, 1.6] and row["bricks"][0]["colour_name"] == "Red"
    # the 2x4 brick turned half a turn about y is the same placement: right only with its symmetry
    pred = tmp_path / "turned.jsonl"
    pred.write_text(json.dumps({"id": f"{TEST_OBJ}/000", "task": "pose",
                                "text": "Brick 1:\nTranslation:\nx=0.0, y=-24.0, z=0.0\nRotation:\n"
                                        "[-1.0, 0.0, 0.0]\n[0.0, 1.0, 0.0]\n[0.0, 0.0, -1.0]"}) + "\n")
    import_bcbench(release, tmp_path / "plain")
    with_sym = score_file(out, pred, "test", "paper", only_predicted=True)["paper"]["overall"]
    without = score_file(tmp_path / "plain", pred, "test", "paper", only_predicted=True)["paper"]["overall"]
    assert with_sym["rotation_error_deg"] == 0.0 and with_sym["step_success"] == 1.0
    assert without["rotation_error_deg"] == pytest.approx(180.0) and without["step_success"] == 0.0


@pytest.mark.slow
def test_command_line_import_then_predict_and_score(release, tmp_path):
    out = tmp_path / "cli"
    r = _run("pipelines.bcbench", "import", str(release), str(out))
    assert r.returncode == 0, r.stderr
    assert "imported 5 steps of 2 objects (2 train, 3 test" in r.stdout and "blank steps skipped: 1" in r.stdout
    scores = {}
    for model in ("oracle", "random", "heuristic"):
        pred = tmp_path / f"{model}.jsonl"
        r = _run("eval.predict", "--data", str(out), "--model", f"baseline:{model}", "--out", str(pred),
                 "--no-progress")
        assert r.returncode == 0, r.stderr
        r = _run("eval.score", "--data", str(out), "--pred", str(pred), "--json")
        assert r.returncode == 0, r.stderr
        scores[model] = json.loads(r.stdout)
    for mode in ("strict", "paper"):
        assert scores["oracle"][mode]["overall"]["selection_accuracy"] == 1.0
        assert scores["oracle"][mode]["overall"]["step_success"] == 1.0
        assert scores["random"][mode]["overall"]["step_success"] < 1.0
    # the scores quoted in docs/reference/bcbench-layout.md and the report
    print({m: {mode: scores[m][mode]["overall"] for mode in ("strict", "paper")} for m in scores})


def test_pose_only_release_imports_the_pose_task(release, tmp_path):
    import shutil

    shutil.rmtree(release / "reasoning")
    s = import_bcbench(release, tmp_path / "pose")
    # no split list: the pose files' names (testing, training) place the steps
    assert s["tasks"] == ["pose"] and s["steps"] == {"train": 2, "test": 3}
    assert s["split_from"] == {"pose file name": 5}
    row = _rows(tmp_path / "pose", "test")[0]
    assert row["selection_messages"] == [] and row["catalog"] is None and row["bricks"][0]["cells"] == []
    assert json.loads((tmp_path / "pose" / "meta" / "info.json").read_text())["tasks"] == ["pose"]


@pytest.mark.parametrize("damage, names", [
    (lambda src: _edit(src / "Designer_supervision" / "data" / TEST_OBJ / "step_0003" / "brick_pose.json",
                       lambda d: d["bricks"][0].update(transform=[[1, 0, 0], [0, 1, 0]])),
     ["step_0003/brick_pose.json", "bricks[0].transform", "3x3 rotation"]),
    (lambda src: _edit(src / "Designer_supervision" / "data" / TEST_OBJ / "step_0000" / "brick_pose.json",
                       lambda d: d["bricks"][0].update(x="ten")),
     ["step_0000/brick_pose.json", "bricks[0].x", "a finite number", "'ten'"]),
    (lambda src: (src / "Designer_supervision" / "data" / TEST_OBJ / "step_0003" / "current_state_axes.png").unlink(),
     ["Designer_supervision_assembly_testing.json", "[3].images[3]", "an existing image", "current_state_axes.png"]),
    (lambda src: _edit(src / "LlamaFactory" / "data" / "Designer_supervision_assembly_testing.json",
                       lambda d: d[0]["conversations"][0].update(value="no placeholders")),
     ["Designer_supervision_assembly_testing.json", "[0].conversations[0].value", "one <image> per image (4)"]),
    (lambda src: _edit(src / "reasoning" / "tasks_with_color" / TEST_OBJ / "tasks.json",
                       lambda d: d["tasks"][0]["gt_position"][0]["candidate_positions"][0].update(row=0)),
     [f"{TEST_OBJ}/tasks.json", "tasks[0].gt_position[0].candidate_positions[0].row", "1-based row"]),
    (lambda src: _edit(src / "reasoning" / "tasks_with_color" / TEST_OBJ / "tasks.json",
                       lambda d: d["tasks"][0].update(gt_bricks=["3002.dat"])),
     [f"{TEST_OBJ}/tasks.json", "tasks[0].gt_bricks", "expected the parts of", "3001.dat", "3002.dat"]),
    (lambda src: (src / "reasoning" / "tasks_with_color" / "test.json").write_text("{not json"),
     ["tasks_with_color/test.json", "not valid JSON"]),
])
def test_bad_input_is_named_and_nothing_is_written(release, tmp_path, damage, names):
    damage(release)
    out = tmp_path / "bad"
    with pytest.raises(BCBenchError) as err:
        import_bcbench(release, out)
    for name in names:
        assert name in str(err.value), str(err.value)
    assert not out.exists() and not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def _edit(path: Path, change) -> None:
    data = json.loads(path.read_text())
    change(data)
    path.write_text(json.dumps(data))


@pytest.mark.slow
def test_command_line_errors_are_one_line(release, tmp_path):
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "x").write_text("")
    for args, message in (
        ([str(release), str(tmp_path / "full")], "exists and is not empty"),
        ([str(tmp_path / "nowhere"), str(tmp_path / "o")], "not a folder"),
        ([str(release), str(tmp_path / "o"), "--ldraw", str(tmp_path)], "not an LDraw library"),
    ):
        r = _run("pipelines.bcbench", "import", *args, timeout=120)
        assert r.returncode == 2 and r.stderr.count("\n") == 1 and message in r.stderr, r.stderr
        assert not (tmp_path / "o").exists()


# -- export ------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def exported(tiny_dataset, tmp_path_factory) -> Path:
    dest = tmp_path_factory.mktemp("bcbench") / "dest"
    r = _run("pipelines.export", str(tiny_dataset), "--format", "bcbench", str(dest))
    assert r.returncode == 0, r.stderr
    return dest


def test_six_views_cuts_only_our_composite():
    assert six_views(_png((255, 255, 255), (100, 60))) is None


def test_export_layout_as_bcbench_scripts_read_it(tiny_dataset, exported):
    info = json.loads((tiny_dataset / "meta" / "info.json").read_text())
    did = info["dataset_id"]
    rows = {r["step_id"]: r for r in _rows(tiny_dataset)}
    registry = json.loads((exported / "dataset_info.json").read_text())
    for split in ("train", "test"):
        records = json.loads((exported / f"{did}_pose_{split}.json").read_text())
        assert len(records) == info["counts"][split]["steps"]
        assert registry[f"{did}_pose_{split}"]["columns"]["messages"] == "conversations"
        keys = json.loads((exported / "tasks" / f"{split}.json").read_text())
        assert len(keys) == len(records)
        for rec in records:
            row = rows[rec["id"]]
            human = rec["conversations"][0]
            assert human["from"] == "human" and human["value"].count("<image>") == len(rec["images"]) == 4
            assert rec["conversations"][1] == {"from": "gpt", "value": row["pose_answer"]}
            assert all(not Path(p).is_absolute() and (exported / p).is_file() for p in rec["images"])
            # the pose script: the step folder is the first image's; step_k the number after "step_"
            step_dir = exported / Path(rec["images"][0]).parent
            assert int(step_dir.name.split("_")[1]) == row["step_index"] and step_dir.parent.name == row["object_id"]
            assert f"{row['object_id']}/{step_dir.name}" in keys
            bp = json.loads((step_dir / "brick_pose.json").read_text())
            assert bp["is_blank"] is False and len(bp["bricks"]) == len(row["bricks"])
            for b, want in zip(bp["bricks"], row["bricks"]):
                assert (b["brick_name"], b["ldraw_color"]) == (want["part"], want["colour"])
                assert [b["x"], b["y"], b["z"]] == want["T"] and b["transform"] == want["R"]
            assert (step_dir / "original_orthogonal_views.png").read_bytes() == row["before"]["bytes"]
    for obj_dir in sorted(p for p in (exported / "tasks").iterdir() if p.is_dir()):
        tasks = json.loads((obj_dir / "tasks.json").read_text())["tasks"]
        for task in tasks:
            row = rows[task[EXTENSION]["step_id"]]
            assert task["step_k"] == row["step_index"] and task["is_blank"] is False
            assert task["gt_bricks"] == [b["part"] for b in row["bricks"]]
            assert task["ground_truth"].startswith('module "') == (len(row["bricks"]) > 1)
            for b, pos in zip(row["bricks"], task["gt_position"]):
                assert {"row": b["row"], "col": b["col"]} in pos["candidate_positions"]
            assert task["catalog_brick_count"] == len(row["catalog_parts"])
            # the selection scripts: run.py reads the per-view files of the step folder,
            # evaluate_with_color.py the composites in task_dir and the catalog path
            step_dir = obj_dir / f"step_{task['step_k']:04d}_{task['view_folder']}"
            for prefix in ("original", "target"):
                for v in ("Back", "Bottom", "Left", "Right", "Up", "front"):
                    with Image.open(step_dir / f"{prefix}_{v}.png") as im:
                        assert im.size == (128, 128)
            assert (exported / task["task_dir"] / "target_orthogonal_views.png").is_file()
            assert (exported / task["input_images"]["catalog_remaining"]).read_bytes() == row["catalog"]["bytes"]
            assert len(task["input_images"]["original"]) == 6


def test_six_views_are_the_composite_tiles(tiny_dataset):
    row = _rows(tiny_dataset)[0]
    views = six_views(row["before"]["bytes"])
    with Image.open(io.BytesIO(row["before"]["bytes"])) as im:
        a = np.asarray(im.convert("RGB"))
    strip = (a.shape[0] - 2) // 2 - 128
    np.testing.assert_array_equal(views["Top"], a[strip:strip + 128, :128])
    np.testing.assert_array_equal(views["Left"], a[-128:, -128:])


def test_export_refuses_a_folder_that_is_not_empty(tiny_dataset, tmp_path):
    (tmp_path / "dest").mkdir()
    (tmp_path / "dest" / "keep.txt").write_text("mine")
    r = _run("pipelines.export", str(tiny_dataset), "--format", "bcbench", str(tmp_path / "dest"), timeout=120)
    assert r.returncode == 2 and "not empty" in r.stderr
    assert [p.name for p in (tmp_path / "dest").iterdir()] == ["keep.txt"]


@pytest.mark.slow
def test_round_trip_gives_the_same_targets_answers_and_scores(tiny_dataset, exported, tmp_path):
    back = tmp_path / "back"
    s = import_bcbench(exported, back, ldraw="embedded", dataset_id="brick-factory-synth")
    assert s["blank_steps_skipped"] == 0 and s["skipped"] == {"pose_only": 0, "selection_only": 0}
    ours, theirs = load_targets(tiny_dataset, None), load_targets(back, None)
    assert [t.id for t in ours] == [t.id for t in theirs]
    for a, b in zip(ours, theirs):
        assert a.object_id == b.object_id and len(a.bricks) == len(b.bricks)
        for x, y in zip(a.bricks, b.bricks):
            assert (x.part, x.colour, x.cells) == (y.part, y.colour, y.cells)
            np.testing.assert_array_equal(x.R, y.R)
            np.testing.assert_array_equal(x.t, y.t)
            assert x.symmetry.continuous_axis == y.symmetry.continuous_axis
            np.testing.assert_array_equal(np.array(x.symmetry.rotations), np.array(y.symmetry.rotations))
    keep = ("split", "assembly", "step_kind", "num_steps", "catalog_parts", "selection_answer", "pose_answer",
            "before", "after", "part", "axes", "catalog")
    for a, b in zip(_rows(tiny_dataset), _rows(back)):
        assert {k: a[k] for k in keep} == {k: b[k] for k in keep}
    for model in ("baseline:oracle", "baseline:random", "baseline:heuristic"):
        pred, again = tmp_path / "ours.jsonl", tmp_path / "theirs.jsonl"
        predict_file(tiny_dataset, model, pred, split=None)
        predict_file(back, model, again, split=None)
        assert pred.read_text() == again.read_text()  # the same answers from the imported folder
        assert score_file(tiny_dataset, pred, None, "both") == score_file(back, pred, None, "both")
    # and through the command line, in both modes, per split
    present = json.loads((tiny_dataset / "meta" / "info.json").read_text())["splits_present"]
    assert present
    for split in present:
        for model in ("baseline:oracle", "baseline:random"):
            pred = tmp_path / f"{split}.jsonl"
            predict_file(tiny_dataset, model, pred, split=split)
            r1 = _run("eval.score", "--data", str(tiny_dataset), "--pred", str(pred), "--split", split, "--json")
            r2 = _run("eval.score", "--data", str(back), "--pred", str(pred), "--split", split, "--json")
            assert r1.returncode == 0 and r2.returncode == 0, r1.stderr + r2.stderr
            assert json.loads(r1.stdout) == json.loads(r2.stdout)
            assert set(json.loads(r1.stdout)) >= {"strict", "paper"}


def test_read_bcbench_finds_the_files(release):
    data = read_bcbench(release)
    assert [p.name for p in data.pose_files] == ["Designer_supervision_assembly_testing.json",
                                                 "Designer_supervision_assembly_training.json"]
    assert len(data.task_files) == 2 and [p.name for p in data.split_lists] == ["test.json"]
    assert [(s.object, s.step_k, s.split) for s in data.steps] == [
        (TEST_OBJ, 0, "test"), (TEST_OBJ, 2, "test"), (TEST_OBJ, 3, "test"), (TRAIN_OBJ, 0, "train"),
        (TRAIN_OBJ, 1, "train")]
    assert data.ignored_files == []
    # absolute paths of their machine found again under SRC
    assert all(release in p.parents for s in data.steps for p in [*s.images, s.catalog])
    assert data.num_steps == {TEST_OBJ: 5, TRAIN_OBJ: 2}


def test_blank_steps_need_no_images(release, tmp_path):
    """As BC-Bench's pose script, a blank step is skipped before its images are looked at."""
    (release / "Designer_supervision" / "data" / TEST_OBJ / "step_0001" / "target_orthogonal_views.png").unlink()
    s = import_bcbench(release, tmp_path / "out")
    assert s["blank_steps_skipped"] == 1 and s["steps"]["test"] == 3


def test_other_sharegpt_files_of_a_release_are_ignored_and_listed(release, tmp_path):
    """A selection set in LLaMA-Factory's format (3 images) beside the pose sets is not a pose set."""
    sel = [{"conversations": [{"from": "human", "value": "<image><image><image>pick"}, {"from": "gpt", "value": "x"}],
            "images": [f"{MAC}/tasks_with_color/{TEST_OBJ}/step_0000_{VIEW}/{n}.png" for n in "abc"]}]
    (release / "LlamaFactory" / "data" / "selection_training.json").write_text(json.dumps(sel))
    s = import_bcbench(release, tmp_path / "out")
    assert s["ignored_json"] == ["LlamaFactory/data/selection_training.json"] and s["steps"]["test"] == 3


def test_training_runs_on_an_imported_release(release, tmp_path):
    """`make train` reads an imported BC-Bench set as it reads our own: the conversations' images
    are all there (a step's `before`, `after`, `part`, `axes` and `catalog`)."""
    pytest.importorskip("torch")
    pytest.importorskip("transformers")
    from train.__main__ import main

    data = tmp_path / "imported"
    import_bcbench(release, data, ldraw="embedded")
    run = tmp_path / "run"
    argv = ["--data", str(data), "--outdir", str(run), "--steps", "2", "--batch-size", "2", "--lora", "0",
            "--lr", "1e-3", "--save-every", "2", "--workers", "0", "--eval-limit", "1", "--max-new-tokens", "8",
            "--no-progress"]
    assert main(argv) == 0
    summary = json.loads((run / "train_summary.json").read_text())
    assert summary["steps"] == 2 and summary["examples"] == 4
    metrics = json.loads((run / "metrics.json").read_text())
    assert set(metrics["after"]) >= {"strict", "paper"} and metrics["after"]["paper"]["counts"]["steps"] == 1
