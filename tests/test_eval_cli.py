"""The evaluation command lines on a real (tiny) dataset: predict, score, world feedback, HF models.

`eval.predict` writes answers of the baselines and of a local checkpoint; `eval.score` reads them
back. The baselines bound what the scorer must report (the oracle is perfect, chance is not), and
the file checks are what keeps a broken predictions file from being scored as a worse model.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from eval import predict as predict_cli
from eval import score as score_cli
from eval.data import iter_rows, load_targets, step_target
from eval.metrics import score_step

REPO = Path(__file__).resolve().parents[1]


def _env() -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    env.setdefault("MUJOCO_GL", "egl")
    return env


def _cli(module: str, *args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", module, *map(str, args)], cwd=REPO, env=_env(), check=False,
                          capture_output=True, text=True, timeout=300)


def _predict(data, model, out, *extra) -> Path:
    rc = predict_cli.main(["--data", str(data), "--model", model, "--out", str(out), "--no-progress", *extra])
    assert rc == 0
    return Path(out)


def _lines(path) -> list[dict]:
    return [json.loads(line) for line in Path(path).read_text().splitlines() if line.strip()]


@pytest.fixture(scope="module")
def test_ids(tiny_dataset) -> list[str]:
    return [s.id for s in load_targets(tiny_dataset, "test")]


# -- baselines through both command lines ------------------------------------------------------


@pytest.mark.slow
def test_oracle_scores_perfect_through_the_command_lines(tiny_dataset, tmp_path, test_ids):
    pred = tmp_path / "oracle.jsonl"
    p = _cli("eval.predict", "--data", tiny_dataset, "--model", "baseline:oracle", "--out", pred, "--no-progress")
    assert p.returncode == 0, p.stderr
    assert len(_lines(pred)) == 2 * len(test_ids)
    s = _cli("eval.score", "--data", tiny_dataset, "--pred", pred, "--json")
    assert s.returncode == 0, s.stderr
    result = json.loads(s.stdout)
    assert result["split"] == "test" and "feedback" not in result
    for mode in ("strict", "paper"):
        r = result[mode]
        assert r["mode"] == mode
        assert r["overall"]["selection_accuracy"] == 1.0
        assert r["overall"]["step_success"] == 1.0
        assert r["overall"]["translation_error_ldu"] == pytest.approx(0.0, abs=1e-6)
        assert r["overall"]["rotation_error_deg"] == pytest.approx(0.0, abs=1e-4)
        assert r["counts"]["missing_predictions"] == 0
        assert r["counts"]["unparseable"] == 0
        assert r["counts"]["steps"] == len(test_ids)
    table = _cli("eval.score", "--data", tiny_dataset, "--pred", pred, "--mode", "paper")
    assert table.returncode == 0 and "paper overall" in table.stdout and "strict" not in table.stdout
    every = _cli("eval.score", "--data", tiny_dataset, "--pred", pred, "--mode", "all", "--json")
    assert every.returncode == 0, every.stderr
    bc = json.loads(every.stdout)["bc"]  # BC-Bench's released scorer (eval.bc)
    assert bc["mode"] == "bc" and bc["overall"]["step_success"] == 1.0
    assert bc["overall"]["selection_accuracy"] == 1.0 and bc["counts"]["steps"] == len(test_ids)
    table = _cli("eval.score", "--data", tiny_dataset, "--pred", pred, "--mode", "all")
    assert table.returncode == 0 and all(f"{m} overall" in table.stdout for m in ("strict", "paper", "bc"))


def test_bc_mode_reads_names_so_the_random_baseline_must_not_leak_them(tiny_dataset, tmp_path):
    """BC-Bench's scorer counts a selection whose part name is right: a baseline writing the
    target's own name would score 1.0 there. The random baseline names what lies in its cell."""
    from eval.data import catalog_of
    from eval.parse import normalise_part, parse_selection

    pred = _predict(tiny_dataset, "baseline:random", tmp_path / "r.jsonl", "--seed", "0")
    r = score_cli.score_file(tiny_dataset, pred, "test", "all")
    assert set(r) >= {"strict", "paper", "bc"} and r["bc"]["overall"]["step_success"] < 1.0
    texts = {rec["id"]: rec["text"] for rec in _lines(pred) if rec["task"] == "selection"}
    checked = 0
    for row in iter_rows(tiny_dataset, "test"):
        catalog = catalog_of(row)
        for pick in parse_selection(texts[row["step_id"]]):
            assert pick.part == normalise_part(catalog[(pick.row, pick.col)][0])
            checked += 1
    assert checked >= len(texts)


def test_random_is_below_oracle_and_the_same_seed_writes_the_same_bytes(tiny_dataset, tmp_path):
    a = _predict(tiny_dataset, "baseline:random", tmp_path / "a.jsonl", "--seed", "3")
    b = _predict(tiny_dataset, "baseline:random", tmp_path / "b.jsonl", "--seed", "3")
    c = _predict(tiny_dataset, "baseline:random", tmp_path / "c.jsonl", "--seed", "4")
    assert a.read_bytes() == b.read_bytes()
    assert a.read_bytes() != c.read_bytes()
    # a step's answer does not depend on which other steps were asked
    first = _predict(tiny_dataset, "baseline:random", tmp_path / "d.jsonl", "--seed", "3", "--limit", "1")
    assert _lines(first) == _lines(a)[:2]
    r = score_cli.score_file(tiny_dataset, a, "test", "paper")
    assert set(r) == {"split", "split_steps", "scored_steps", "paper"}
    assert r["paper"]["overall"]["step_success"] < 1.0
    assert r["paper"]["counts"]["missing_predictions"] == 0


def test_heuristic_runs_and_scores(tiny_dataset, tmp_path, test_ids):
    pred = _predict(tiny_dataset, "baseline:heuristic", tmp_path / "h.jsonl", "--split", "train")
    lines = _lines(pred)
    assert [ln["task"] for ln in lines[:2]] == ["selection", "pose"]
    r = score_cli.score_file(tiny_dataset, pred, "train")
    for mode in ("strict", "paper"):
        assert 0.0 <= r[mode]["overall"]["selection_accuracy"] <= 1.0
        assert r[mode]["counts"]["unparseable"] == 0
        assert r[mode]["overall"]["translation_error_ldu"] is not None
    # every first step of an object is answered at the origin, later ones stacked on the one before
    first = next(ln for ln in lines if ln["task"] == "pose" and ln["id"].endswith("/000"))
    assert "x=0.0, y=-24.0, z=0.0" in first["text"]


def test_library_calls_over_every_split(tiny_dataset, tmp_path):
    out = tmp_path / "all.jsonl"
    summary = predict_cli.predict_file(tiny_dataset, "baseline:oracle", out, split=None, feedback=True)
    n = len(load_targets(tiny_dataset, None))
    assert summary == {"lines": 2 * n, "steps": n, "revised": 0, "path": str(out)}
    r = score_cli.score_file(tiny_dataset, out, split=None)
    assert r["split"] is None and r["paper"]["counts"]["steps"] == n and r["strict"]["overall"]["step_success"] == 1.0


def test_tasks_and_limit(tiny_dataset, tmp_path):
    pred = _predict(tiny_dataset, "baseline:oracle", tmp_path / "p.jsonl", "--tasks", "pose", "--limit", "2")
    lines = _lines(pred)
    assert [ln["task"] for ln in lines] == ["pose", "pose"]
    r = score_cli.score_file(tiny_dataset, pred, "test", "strict")["strict"]
    # missing selections count as missing (and score 0 selection) but do not fail the pose steps
    assert r["counts"]["missing_predictions"] == r["counts"]["steps"] + (r["counts"]["steps"] - 2)
    assert r["overall"]["selection_accuracy"] == 0.0
    only = score_cli.score_file(tiny_dataset, pred, "test", "strict", only_predicted=True)
    assert only["scored_steps"] == 2 and only["split_steps"] == r["counts"]["steps"]
    assert only["strict"]["counts"]["missing_predictions"] == 2  # the two selections not asked for


def test_limit_spreads_over_the_split(tiny_dataset, tmp_path):
    rows = [t.id for t in load_targets(tiny_dataset, "train")]
    pred = _predict(tiny_dataset, "baseline:oracle", tmp_path / "p.jsonl", "--split", "train", "--limit", "2")
    ids = [ln["id"] for ln in _lines(pred) if ln["task"] == "pose"]
    assert ids == [rows[0], rows[len(rows) // 2]]
    assert len({i.split("/")[0] for i in ids}) == 2  # two objects, not the first object's first steps


# -- bad input ---------------------------------------------------------------------------------


def test_unknown_model_lists_the_choices(tiny_dataset, tmp_path, capsys):
    rc = predict_cli.main(["--data", str(tiny_dataset), "--model", "gpt:5", "--out", str(tmp_path / "x.jsonl")])
    err = capsys.readouterr().err
    assert rc == 2 and err.startswith("error: unknown model 'gpt:5'")
    for choice in ("baseline:random", "baseline:oracle", "baseline:heuristic", "hf:PATH"):
        assert choice in err
    assert not (tmp_path / "x.jsonl").exists()
    rc = predict_cli.main(["--data", str(tmp_path), "--model", "baseline:oracle", "--out", str(tmp_path / "x.jsonl")])
    assert rc == 2 and "not a dataset folder" in capsys.readouterr().err


def test_score_errors_name_the_file_and_line(tiny_dataset, tmp_path, test_ids):
    sid = test_ids[0]
    good = json.dumps({"id": sid, "task": "selection", "text": "3001.dat, row 1, col 1"})
    pred = tmp_path / "bad.jsonl"
    pred.write_text(good + "\n\n" + json.dumps({"id": "nope/000", "task": "pose", "text": ""}) + "\n")
    p = _cli("eval.score", "--data", tiny_dataset, "--pred", pred)
    assert p.returncode == 2
    assert p.stderr.strip() == f"error: {pred}:3: step id 'nope/000' is not in the split"
    assert "Traceback" not in p.stderr


@pytest.mark.parametrize("line, message", [
    ("{not json", "not JSON"),
    ("[1, 2]", "expected a JSON object"),
    ('{"id": "ID", "text": "x"}', "missing key(s) task"),
    ('{"id": "ID", "task": "grasp", "text": "x"}', "unknown task 'grasp'"),
    ('{"id": "ID", "task": "pose", "text": 3}', "text must be a string"),
    ('{"id": "ID", "task": "selection", "text": "x"}', "second selection answer"),
    ('{"id": "ID", "task": "selection", "text": "x", "revised": true}', "only pose answers are revised"),
])
def test_score_rejects_bad_lines(tiny_dataset, tmp_path, test_ids, capsys, line, message):
    pred = tmp_path / "p.jsonl"
    first = json.dumps({"id": test_ids[0], "task": "selection", "text": "x"})
    pred.write_text(first + "\n" + line.replace("ID", test_ids[0]) + "\n")
    rc = score_cli.main(["--data", str(tiny_dataset), "--pred", str(pred)])
    err = capsys.readouterr().err
    assert rc == 2 and err.startswith(f"error: {pred}:2: ") and message in err, err


def test_revised_pose_needs_an_original(tiny_dataset, tmp_path, test_ids):
    pred = tmp_path / "p.jsonl"
    pred.write_text(json.dumps({"id": test_ids[0], "task": "pose", "text": "x", "revised": True}) + "\n")
    with pytest.raises(score_cli.PredictionsError, match=r"p\.jsonl:1: revised pose .* without an original"):
        score_cli.score_file(tiny_dataset, pred)


def test_missing_predictions_count_as_wrong(tiny_dataset, tmp_path, test_ids):
    pred = tmp_path / "one.jsonl"
    oracle = _lines(_predict(tiny_dataset, "baseline:oracle", tmp_path / "o.jsonl"))
    pred.write_text("".join(json.dumps(ln) + "\n" for ln in oracle[:2]))  # the first step only
    r = score_cli.score_file(tiny_dataset, pred, "test", "paper")["paper"]
    n = len(test_ids)
    assert r["counts"]["missing_predictions"] == 2 * (n - 1)
    assert r["overall"]["step_success"] == pytest.approx(1 / n)  # one object holds every test step
    assert r["counts"]["failures"]["unparseable"] == sum(len(s.bricks) for s in load_targets(tiny_dataset)[1:])


# -- world feedback ----------------------------------------------------------------------------


def test_feedback_revises_failed_steps_and_is_scored_apart(tiny_dataset, tmp_path, test_ids):
    pred = _predict(tiny_dataset, "baseline:random", tmp_path / "fb.jsonl", "--feedback", "--seed", "1")
    lines = _lines(pred)
    revised = [ln for ln in lines if ln.get("revised")]
    originals = {ln["id"]: ln["text"] for ln in lines if ln["task"] == "pose" and not ln.get("revised")}
    assert len(originals) == len(test_ids)
    failed = [s.id for s in load_targets(tiny_dataset)
              if not score_step(s, None, originals[s.id], "paper").success]
    assert failed and [ln["id"] for ln in revised] == failed  # one revision per failed step, in order
    assert all(ln["task"] == "pose" and ln["text"] != originals[ln["id"]] for ln in revised)  # a new draw
    r = score_cli.score_file(tiny_dataset, pred)
    fb = r["feedback"]
    assert fb["revised_steps"] == len(revised)
    assert set(fb["fixed"]) == {"strict", "paper"}
    for mode in ("strict", "paper"):
        assert fb[mode]["counts"]["steps"] == len(test_ids)
        assert fb[mode]["overall"]["selection_accuracy"] == r[mode]["overall"]["selection_accuracy"]
    assert "after world feedback" in score_cli.format_table(r)
    # the oracle is never wrong, so it is never revised
    oracle = _predict(tiny_dataset, "baseline:oracle", tmp_path / "o.jsonl", "--feedback")
    assert not any(ln.get("revised") for ln in _lines(oracle))


def test_feedback_example_renders_the_prediction_in_red(tiny_dataset):
    from PIL import Image

    from eval.baselines import format_pose, oracle
    from eval.feedback import assembly_rows, before_rows, feedback_columns, feedback_example
    from factory.ldraw import get_reader
    from factory.render import Renderer

    rows = list(iter_rows(tiny_dataset, "test", feedback_columns()))
    row = rows[-1]
    target = step_target(row)
    renderer = Renderer(get_reader(None))
    wrong = format_pose([(b.t + np.array([40.0, 0.0, 0.0]), b.R) for b in target.bricks])
    fb = feedback_example(row, wrong, before_rows(rows, row), renderer, 96, scene=assembly_rows(rows, row))
    assert fb is not None
    messages, images, errors = fb
    assert [m["role"] for m in messages][-3:] == ["user", "assistant", "user"]
    assert messages[-2]["content"] == [{"type": "text", "text": wrong}]
    n_image_parts = sum(p["type"] == "image" for m in messages for p in m["content"])
    assert n_image_parts == len(images) == 5 and messages[-1]["content"][0] == {"type": "image"}
    assert len(errors) == len(target.bricks)
    assert errors[0]["translation_error"] == pytest.approx(40.0) and errors[0]["rotation_error"] < 1e-6
    # Executed: each brick's outcome and settled pose, said in one sentence.
    from factory.dataset.prompts import settle_sentence
    from factory.physics.settle import OUTCOMES

    assert errors[0]["outcome"] in OUTCOMES and len(errors[0]["settled_T"]) == 3
    text = messages[-1]["content"][1]["text"]
    assert f"Brick 1: {settle_sentence(errors[0])}. Translation error 40.0 LDU" in text
    assert "red outline" in text
    static = feedback_example(row, wrong, before_rows(rows, row), renderer, 96, scene=assembly_rows(rows, row),
                              physics=False)
    assert "outcome" not in static.errors[0]
    assert "Brick 1: translation error 40.0 LDU" in static.messages[-1]["content"][1]["text"]
    render = images[-1]
    assert isinstance(render, Image.Image) and render.mode == "RGB"
    a = np.asarray(render).astype(int)
    red = (a[..., 0] > 180) & (a[..., 1] < 80) & (a[..., 2] < 80)
    assert red.sum() > 50
    # a right answer and one that does not parse get no feedback
    assert feedback_example(row, oracle(target)["pose"], before_rows(rows, row), renderer, 96) is None
    assert feedback_example(row, "no idea", before_rows(rows, row), renderer, 96) is None
    renderer.close()


def test_a_model_is_asked_again_with_the_feedback_chat(tiny_dataset):
    """The model path of --feedback: the revision prompt carries the feedback image and turn."""
    from eval.baselines import format_pose, oracle

    first = load_targets(tiny_dataset)[0]
    wrong = format_pose([(b.t + np.array([999.0, 0.0, 0.0]), b.R) for b in first.bricks])

    class Scripted:
        """Wrong by far at first, right when given feedback."""

        def __init__(self):
            self.calls = []

        def predict(self, messages, images, max_new_tokens):
            self.calls.append((messages, images))
            return oracle(first)["pose"] if len(images) == 5 else wrong

    model = Scripted()
    records = list(predict_cli.iter_predictions(tiny_dataset, predict_cli.ModelPredictor(model), tasks=("pose",),
                                                feedback=True, limit=1))
    assert [(r["task"], r.get("revised", False)) for r in records] == [("pose", False), ("pose", True)]
    messages, images = model.calls[-1]
    assert len(images) == 5 and sum(p["type"] == "image" for m in messages for p in m["content"]) == 5
    assert messages[-2] == {"role": "assistant", "content": [{"type": "text", "text": wrong}]}
    assert "Your previous answer was executed in the simulator" in messages[-1]["content"][-1]["text"]
    answers = {(r["id"], r["task"]): r["text"] for r in records if not r.get("revised")}
    result = score_cli.score_predictions(load_targets(tiny_dataset), answers, {first.id: records[1]["text"]})
    assert result["feedback"]["fixed"] == {"strict": 1, "paper": 1}


# -- Hugging Face checkpoints -------------------------------------------------------------------

@pytest.fixture(scope="module")
def tiny_checkpoint(tiny_dataset, tmp_path_factory) -> Path:
    """The trainer's tiny random Qwen2-VL (`train.tiny`), its tokenizer trained on the test prompts."""
    pytest.importorskip("transformers")
    pytest.importorskip("tokenizers")
    from train.tiny import build_tiny_model, dataset_texts

    texts = dataset_texts([tiny_dataset], "test")
    return Path(build_tiny_model(tmp_path_factory.mktemp("ckpt") / "tiny", texts, vocab_size=512))


def test_hf_checkpoint_answers_deterministically(tiny_dataset, tiny_checkpoint, tmp_path):
    args = ("--limit", "2", "--max-new-tokens", "6", "--device", "cpu")
    a = _predict(tiny_dataset, f"hf:{tiny_checkpoint}", tmp_path / "a.jsonl", *args)
    lines = _lines(a)
    assert [(ln["task"]) for ln in lines] == ["selection", "pose"] * 2
    assert all(isinstance(ln["text"], str) for ln in lines)
    b = _predict(tiny_dataset, f"hf:{tiny_checkpoint}", tmp_path / "b.jsonl", *args)
    assert a.read_bytes() == b.read_bytes()
    r = score_cli.score_file(tiny_dataset, a, "test", "paper")["paper"]
    assert r["counts"]["missing_predictions"] == 2 * (r["counts"]["steps"] - 2)


@pytest.mark.filterwarnings("ignore::FutureWarning")  # peft on transformers 5
def test_hf_predictor_in_memory_and_lora_adapter(tiny_dataset, tiny_checkpoint, tmp_path):
    peft = pytest.importorskip("peft")
    from eval.chat import task_chat
    from eval.hf import HFPredictor

    loaded = HFPredictor.from_path(tiny_checkpoint, device="cpu")
    row = next(iter_rows(tiny_dataset, "test", ["step_id", "selection_messages", "selection_images",
                                                "selection_answer", "before", "after", "catalog"]))
    messages, images, _ = task_chat(row, "selection")
    text = loaded.predict(messages, images, 5)
    same = HFPredictor(loaded.model, loaded.processor)  # what the trainer wraps
    assert same.predict(messages, images, 5) == text
    assert len(loaded.predict_batch([(messages, images), (messages, images)], 5)) == 2
    # a LoRA adapter folder: the base comes from its config, the processor from the base
    lora = peft.get_peft_model(loaded.model, peft.LoraConfig(r=2, target_modules=["q_proj", "v_proj"]))
    lora.peft_config["default"].base_model_name_or_path = str(tiny_checkpoint)
    lora.save_pretrained(tmp_path / "adapter")
    adapter = HFPredictor.from_path(tmp_path / "adapter", device="cpu")
    assert isinstance(adapter.model, peft.PeftModel)
    assert adapter.predict(messages, images, 5) == text  # LoRA starts as the identity (B = 0)


def test_hf_bad_checkpoint_is_a_clean_error(tiny_dataset, tmp_path, capsys):
    rc = predict_cli.main(["--data", str(tiny_dataset), "--model", f"hf:{tmp_path}", "--out",
                           str(tmp_path / "x.jsonl"), "--device", "cpu"])
    assert rc == 2 and "neither a model" in capsys.readouterr().err


def test_score_json_is_valid_json_for_a_huge_translation(tiny_dataset, tmp_path):
    """A translation of 1e300 or 1e308 is wrong, its error capped (`TRANSLATION_CAP_LDU`) and
    counted: the split's mean stays a finite number (it was null, after a RuntimeWarning on
    stderr), and nothing but the JSON is printed."""
    from eval.metrics import TRANSLATION_CAP_LDU

    lines = _lines(_predict(tiny_dataset, "baseline:oracle", tmp_path / "o.jsonl"))
    for k, ln in enumerate(ln for ln in lines if ln["task"] == "pose"):
        huge = "1e300" if k % 2 else "1e308"
        ln["text"] = re.sub(r"y=[-0-9.e]+", f"y=-{huge}", re.sub(r"x=[-0-9.e]+", f"x={huge}", ln["text"]))
    pred = tmp_path / "huge.jsonl"
    pred.write_text("".join(json.dumps(ln) + "\n" for ln in lines))
    r = _cli("eval.score", "--data", tiny_dataset, "--pred", pred, "--mode", "all", "--json")
    assert r.returncode == 0 and not r.stderr.strip(), r.stderr
    result = json.loads(r.stdout, parse_constant=lambda c: pytest.fail(f"{c} in the JSON"))
    bricks = sum(len(s.bricks) for s in load_targets(tiny_dataset, "test"))
    for mode in ("strict", "paper", "bc"):
        assert result[mode]["overall"]["translation_error_ldu"] == TRANSLATION_CAP_LDU, mode
        assert result[mode]["overall"]["step_success"] == 0.0
        assert result[mode]["counts"]["capped_translations"] == bricks


@pytest.mark.parametrize("rows", [[[0, 0, 0]] * 3, [[1, 1, 1]] * 3, [[2, 0, 0], [0, 2, 0], [0, 0, 2]]])
def test_a_matrix_that_is_no_rotation_scores_wrong_in_every_mode(tiny_dataset, tmp_path, rows):
    """The oracle's translation with rotation rows [0,0,0] x3 (or [1,1,1] x3) scored step success 1
    and 0 degrees in strict, paper and bc (0.857 over a test split where the oracle scores 1.0): a
    singular or scaled matrix has no rotation to score. Now every step fails, 180 degrees, and the
    bricks are counted as degenerate."""
    lines = _lines(_predict(tiny_dataset, "baseline:oracle", tmp_path / "o.jsonl"))
    rotation = "Rotation:\n" + "\n".join("[" + ", ".join(map(str, row)) + "]" for row in rows)
    for ln in lines:
        if ln["task"] == "pose":
            blocks = ln["text"].split("\n\n")
            ln["text"] = "\n\n".join(b[:b.index("Rotation:")] + rotation for b in blocks)
    pred = tmp_path / "singular.jsonl"
    pred.write_text("".join(json.dumps(ln) + "\n" for ln in lines))
    r = _cli("eval.score", "--data", tiny_dataset, "--pred", pred, "--mode", "all", "--json")
    assert r.returncode == 0, r.stderr
    result = json.loads(r.stdout)
    bricks = sum(len(s.bricks) for s in load_targets(tiny_dataset, "test"))
    for mode in ("strict", "paper", "bc"):
        c = result[mode]["counts"]
        assert result[mode]["overall"]["step_success"] == 0.0, mode
        assert result[mode]["overall"]["rotation_error_deg"] == 180.0
        assert c["degenerate_rotations"] == c["failures"]["degenerate"] == bricks and c["projected_rotations"] == 0
