"""Verify a design: replay an LDraw model's build steps through the physics checks (`factory.verify`).

`tower.ldr` (beside this file) stacks four bricks of the embedded library, one per step. Each
placement is checked (connected, clear of the others, held, pressable into place, standing);
with `faults=True` every accepted brick is also checked shifted, lifted and turned, and the
checker should reject those. A copy of the tower with its top brick lifted off its studs shows a
rejected placement. Guide: docs/guides/verify-a-design.md.

    python examples/verify_design.py out/examples
"""

import argparse
import json
from pathlib import Path

import factory

TOWER = Path(__file__).with_name("tower.ldr")


def main(out_dir):
    found = factory.verify(TOWER, faults=True)  # ldraw="complete.zip" reads real parts
    for p in found.placements:
        print(f"step {p['step']}: {p['part']} stud pairs {p['stud_pairs']}, reason {p['reason'] or 'accepted'}")
    summary = found.summary
    print(f"accepted {summary['accepted']} of {summary['placements']}; lifted bricks rejected: "
          f"{summary['faults']['lift']['rejected']:.0%}")
    assert not found.rejected

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    lines = TOWER.read_text().splitlines()
    top = max(i for i, line in enumerate(lines) if line.startswith("1 "))
    lines[top] = lines[top].replace(" -72 ", " -80 ")  # the top brick 8 LDU above its studs
    broken = out / "tower_lifted.ldr"
    broken.write_text("\n".join(lines) + "\n")
    bad = factory.verify(broken)
    print(f"{broken.name}: rejected {[(r['step'], r['reason']) for r in bad.rejected]}")
    assert [r["reason"] for r in bad.rejected] == ["no-connection"]
    (out / "verification.json").write_text(json.dumps(found.to_json(), indent=1))
    return found


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out_dir", nargs="?", default="out/examples", help="output folder (default out/examples)")
    main(ap.parse_args().out_dir)
