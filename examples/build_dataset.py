"""Build a dataset: grow objects, render every step, write sharded Parquet (`factory.build_dataset`).

A tiny synthetic build (3 objects of 2-3 bricks, 128-pixel views) of the same kind as `make synth`:
one row per assembly step, with the images and prompts of BC-Bench's two tasks (brick selection
and pose estimation) and their answers. `datasets.load_dataset` reads the folder as it is.
Guide: docs/guides/build-a-dataset.md.

    python examples/build_dataset.py out/examples
"""

import argparse
from pathlib import Path

import factory


def build(out_dir) -> Path:
    """The tiny dataset in OUT_DIR/synth (built once; a re-run finds it complete)."""
    sampler = factory.SamplerConfig(min_steps=2, max_steps=3, candidates_per_step=16)
    config = factory.DatasetConfig.synthetic(3, seed=0, sampler=sampler, size=128, tile=64, objects_per_shard=1)
    data = Path(out_dir) / "synth"
    factory.build_dataset(config, data, progress=False)
    return data


def main(out_dir):
    import datasets  # Hugging Face datasets reads the folder as it is

    data = build(out_dir)
    ds = datasets.load_dataset(str(data))
    print(ds)
    row = ds["train"][0]
    print(row["step_id"], "pose answer:", row["pose_answer"])
    prompt = next(c["text"] for c in row["pose_messages"][1]["content"] if c["type"] == "text")
    print(prompt.splitlines()[0], f"({len(row['pose_images'])} images)")
    row["after"].save(Path(out_dir) / "after.png")  # the six views, the new brick in a red box
    return data


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out_dir", nargs="?", default="out/examples", help="output folder (default out/examples)")
    main(ap.parse_args().out_dir)
