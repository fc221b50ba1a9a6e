"""Grow objects: sample physics-verified assemblies one brick at a time (`factory.grow`).

Each object is grown from the embedded part library by the sampler: every step draws candidate
placements and keeps one that passes the physics checks. The objects are written as LDraw files
(one part and one `0 STEP` per step) and read back. Guide: docs/guides/grow-objects.md.

    python examples/grow_objects.py out/examples
"""

import argparse
from pathlib import Path

import factory


def main(out_dir):
    out = Path(out_dir) / "objects"
    out.mkdir(parents=True, exist_ok=True)
    config = factory.SamplerConfig(seed=7, min_steps=6, max_steps=6)  # 6 bricks each: seconds
    objects = factory.grow(3, config)  # objects 0, 1, 2: the same for (seed, index) on any machine
    for i, obj in enumerate(objects):
        path = obj.to_ldr(out / f"object_{i:05d}.ldr")
        print(f"{path.name}: {len(obj.steps)} steps, density {obj.density:.2f}, ended by {obj.end_reason}")
        last = obj.steps[-1]
        print(f"  last: {last.part} in colour {last.colour} at {last.pose.t} LDU; rejected candidates {last.rejected}")
    back = factory.Assembly.from_ldr(out / "object_00000.ldr")  # steps back from the file
    assert back.same_as(objects[0])
    return objects


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out_dir", nargs="?", default="out/examples", help="output folder (default out/examples)")
    main(ap.parse_args().out_dir)
