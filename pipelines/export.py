"""Export a built dataset for other trainers and benchmarks:
`python -m pipelines.export DATA --format llamafactory|bcbench DEST` (DATA: the dataset folder read).

`llamafactory` writes, under DEST:
- `images/{object_id}/{step:03d}_{name}.png`: the rows' PNG bytes as they are (each written once,
  shared by both tasks);
- `{dataset_id}_{task}_{split}.json` for task `selection` and `pose`: ShareGPT records
  {"messages": [{"role": "user", "content": "<image>...<image>\\n" + prompt},
  {"role": "assistant", "content": answer}], "system": ..., "images": [paths relative to DEST]},
  one `<image>` per image, in the order of the images list;
- `dataset_info.json` registering each file (formatting `sharegpt`, role/content tags), so
  LLaMA-Factory takes `dataset_dir: DEST` and `dataset: {dataset_id}_selection_train,...`.
  DEST may be a LLaMA-Factory data folder already in use: an existing `dataset_info.json` is
  merged into, every entry of its own kept; an entry of the same name that registers something
  else is refused before anything is written (export under another dataset id or folder).
Files are streamed (one object's rows at a time), so memory stays small on 40K steps.

`bcbench` writes BC-Bench's released layout (pose ShareGPT JSON, step folders with brick_pose.json,
tasks.json per object, split lists), paths relative to DEST: `pipelines.bcbench.write_bcbench`.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from eval.data import iter_file, shard_files
from factory.atomic import write_atomic
from factory.cli import ArgumentParser, run_guarded
from factory.dataset.info import read_info
from factory.dataset.tasks import TASKS
from pipelines.bcbench import write_bcbench
from pipelines.dataset.config import check_name

FORMATS = ("llamafactory", "bcbench")


def _user_text(messages) -> str:
    for m in messages:
        if m["role"] == "user":
            return "\n".join(c["text"] for c in m["content"] if c["type"] == "text")
    raise ValueError("conversation has no user message")


def _system(messages, default: str) -> str:
    """The task's own system text (an imported BC-Bench pose task keeps BC-Bench's), else `default`."""
    for m in messages:
        if m["role"] == "system":
            return "\n".join(c["text"] for c in m["content"] if c["type"] == "text")
    return default


def _answer(messages) -> str:
    for m in messages:
        if m["role"] == "assistant":
            return "\n".join(c["text"] for c in m["content"] if c["type"] == "text")
    raise ValueError("conversation has no assistant message")


def export_llamafactory(out, dest, splits=("train", "test"), tasks=TASKS) -> dict:
    """Write the LLaMA-Factory files; returns {dataset name: record count}. Each file is written
    atomically: images through `write_atomic`, the record files to a temporary name renamed when
    complete, `dataset_info.json` last."""
    out, dest = Path(out), Path(dest)
    meta = read_info(out)
    did = check_name(meta.dataset_id, "dataset_id", f"{out / 'meta' / 'info.json'}: ")
    ours = {f"{did}_{t}_{split}": _entry(f"{did}_{t}_{split}") for split in splits for t in tasks}
    _merged_registry(dest / "dataset_info.json", ours)  # refuse a clash before writing anything
    dest.mkdir(parents=True, exist_ok=True)
    counts: dict[str, int] = {}
    for split in splits:
        files = shard_files(out, split) if split in meta.splits_present else []  # no rows: empty files
        names = {t: f"{did}_{t}_{split}" for t in tasks}
        finals = {t: dest / f"{names[t]}.json" for t in tasks}
        tmps = {t: p.with_name(f".{p.name}.{os.getpid()}.tmp") for t, p in finals.items()}
        handles = {t: open(tmps[t], "w", encoding="utf-8") for t in tasks}
        first = {t: True for t in tasks}
        try:
            for h in handles.values():
                h.write("[\n")
            for f in files:
                for row in iter_file(f):
                    check_name(row["object_id"], "object_id", f"{f}: ")  # paths stay under dest
                    folder = dest / "images" / row["object_id"]
                    folder.mkdir(parents=True, exist_ok=True)
                    paths = {}
                    for t in tasks:
                        for name in row[f"{t}_images"]:
                            if name not in paths:
                                rel = f"images/{row['object_id']}/{row['step_index']:03d}_{name}.png"
                                write_atomic(dest / rel, row[name]["bytes"])
                                paths[name] = rel
                    for t in tasks:
                        msgs = row[f"{t}_messages"]
                        if not msgs:  # a step without this task (an imported BC-Bench pose-only step)
                            continue
                        imgs = [paths[n] for n in row[f"{t}_images"]]
                        rec = {
                            "id": f"{row['step_id']}/{t}",
                            "messages": [
                                {"role": "user", "content": "<image>" * len(imgs) + "\n" + _user_text(msgs)},
                                {"role": "assistant", "content": _answer(msgs)},
                            ],
                            "system": _system(msgs, row["system"]),
                            "images": imgs,
                        }
                        handles[t].write(("" if first[t] else ",\n") + json.dumps(rec, ensure_ascii=False))
                        first[t] = False
                        counts[names[t]] = counts.get(names[t], 0) + 1
            for h in handles.values():
                h.write("\n]\n")
        except BaseException:
            for t, h in handles.items():
                h.close()
                tmps[t].unlink(missing_ok=True)
            raise
        for t, h in handles.items():
            h.close()
            os.replace(tmps[t], finals[t])
        for t in tasks:
            counts.setdefault(names[t], 0)
    registry = _merged_registry(dest / "dataset_info.json", ours)
    write_atomic(dest / "dataset_info.json", (json.dumps(registry, indent=2, sort_keys=True) + "\n").encode())
    return counts


def _entry(name: str) -> dict:
    """The `dataset_info.json` entry of one exported file."""
    return {
        "file_name": f"{name}.json",
        "formatting": "sharegpt",
        "columns": {"messages": "messages", "system": "system", "images": "images"},
        "tags": {"role_tag": "role", "content_tag": "content", "user_tag": "user", "assistant_tag": "assistant"},
    }


def _merged_registry(path: Path, ours: dict) -> dict:
    """`path`'s registry (empty when absent) with `ours` added; every other entry is kept. A file
    that is not a JSON object, or an entry of one of our names registering something else, is a
    `ValueError` naming the file (nothing of the user's is overwritten)."""
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        return dict(ours)
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not UTF-8 text; expected LLaMA-Factory's dataset_info.json (a JSON object)") from None
    try:
        registry = json.loads(text)
    except json.JSONDecodeError as e:
        raise ValueError(f"{path}:{e.lineno}: {e.msg}; expected LLaMA-Factory's dataset_info.json "
                         "(a JSON object); fix or move it") from None
    if not isinstance(registry, dict):
        raise ValueError(f"{path}:1: expected a JSON object of dataset entries, got {type(registry).__name__}")
    clash = sorted(n for n in ours if n in registry and registry[n] != ours[n])
    if clash:
        raise ValueError(f"{path}: already registers {clash[0]!r} as something else; export to another "
                         "folder or under another dataset id (nothing was written)")
    return {**registry, **ours}


def main(argv: list[str] | None = None) -> int:
    ap = ArgumentParser(prog="python -m pipelines.export", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data", help="the dataset folder to export (written by pipelines.synth or pipelines.designs)")
    ap.add_argument("--format", choices=FORMATS, required=True)
    ap.add_argument("dest", help="output folder")
    ap.add_argument("--splits", default="train,test", help="comma-separated (default train,test)")
    ap.add_argument("--tasks", help="llamafactory: comma-separated (default selection,pose); bcbench writes both")
    args = ap.parse_args(argv)

    def body() -> int:
        if not (Path(args.data) / "meta" / "info.json").exists():
            print(f"error: {args.data} has no meta/info.json (not a finished dataset build)", file=sys.stderr)
            return 2
        splits = [s for s in args.splits.split(",") if s]
        if args.format == "bcbench":
            if args.tasks is not None:
                print("error: --tasks applies to --format llamafactory; bcbench writes both tasks", file=sys.stderr)
                return 2
            summary = write_bcbench(args.data, args.dest, splits)
            print(", ".join(f"{s}: {v['steps']} steps of {v['objects']} objects" for s, v in summary["splits"].items())
                  + f" -> {args.dest}")
            return 0
        tasks = [t for t in (args.tasks or "selection,pose").split(",") if t]
        bad = [t for t in tasks if t not in TASKS]
        if bad:
            print(f"error: unknown task {bad[0]!r}; valid: {', '.join(TASKS)}", file=sys.stderr)
            return 2
        registry = Path(args.dest) / "dataset_info.json"
        kept = _merged_registry(registry, {}) if registry.is_file() else {}
        counts = export_llamafactory(args.data, args.dest, splits, tasks)
        print(", ".join(f"{k}: {v}" for k, v in counts.items()) + f" -> {args.dest}")
        others = sorted(set(kept) - set(counts))
        if others:
            print(f"merged into {registry}: kept its {len(others)} other entr{'y' if len(others) == 1 else 'ies'} "
                  f"({', '.join(others[:5])}{', ...' if len(others) > 5 else ''})")
        return 0

    return run_guarded(body, {OSError: 2, ValueError: 2})


if __name__ == "__main__":
    sys.exit(main())
