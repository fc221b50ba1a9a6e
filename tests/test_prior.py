"""Usage priors: family folding, fitting from designs, the file, and the parts a library gives."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

from factory.ldraw import Library, Reader, get_reader
from factory.prior import Prior, PriorError, family, fit_prior, load_prior, unprinted
from factory.prior.choose import MINIFIGURE, NO_CONNECTOR, NOT_IN_LIBRARY, choose_parts, embedded_choice
from ldraw_support import LDRAW, LIBRARY_ZIP, needs_ldraw
from factory.prior.prior import DEFAULT_PRIOR, OTHER, PartUse
from factory.sampler import DEFAULT_PARTS, SamplerConfig
from factory.sampler.from_prior import configure

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("name, fam", [
    ("3068bp01", "3068"), ("3068b.dat", "3068"), ("3062b", "3062"), ("3062a", "3062"), ("3626bpr0001", "3626"),
    ("973pat0001", "973"), ("3829c01", "3829c01"), ("u9057", "u9057"), ("4070", "4070"), ("PARTS\\3001.DAT", "3001"),
    ("30104k02", "30104k02"), ("2412b", "2412"),
])
def test_part_families_fold_prints_and_revisions(name, fam):
    assert family(name) == fam


def test_unprinted_keeps_the_revision():
    assert unprinted("3068bp01") == "3068b" and unprinted("3001") == "3001"


DESIGN_A = """0 Design A
0 Name: a.ldr
0 !LICENSE Redistributable under CCAL version 2.0 : see CAreadme.txt
1 4 0 0 0 1 0 0 0 1 0 0 0 1 3023.dat
1 4 0 -8 0 1 0 0 0 1 0 0 0 1 3023.dat
1 4 0 -16 0 1 0 0 0 1 0 0 0 1 old3023.dat
1 4 0 -24 0 1 0 0 0 1 0 0 0 1 3001.dat
0 FILE old3023.dat
0 ~Moved to 3023
1 16 0 0 0 1 0 0 0 1 0 0 0 1 3023.dat
"""
# A design's own `~Moved to` stub (old3023) counts as its target; a printed tile no library holds
# stands for its unprinted base; colour 16 in the main model is no colour.
DESIGN_B = """0 Design B
0 Name: b.mpd
0 FILE b.mpd
1 1 0 0 0 1 0 0 0 1 0 0 0 1 3001.dat
1 16 0 -24 0 1 0 0 0 1 0 0 0 1 3068bp01.dat
"""


@pytest.fixture
def designs(write):
    a = write("designs/a.mpd", "0 FILE a.ldr\n" + DESIGN_A.split("\n", 1)[1].replace("0 Name: a.ldr\n", ""))
    b = write("designs/b.mpd", DESIGN_B)
    return a, b


def test_a_prior_fitted_from_two_small_designs_gives_the_expected_weights(designs):
    """Each design weighs the same: shares 3023 3/4 and 3001 1/4 in A, 3001 1/2 and 3068 1/2 in B."""
    reader = get_reader(None)
    prior = fit_prior(designs, reader, temper=1.0)
    weights = {p.family: p.weight for p in prior.parts}
    assert weights == pytest.approx({"3023": 0.375, "3001": 0.375, "3068": 0.25})
    by = {p.family: p for p in prior.parts}
    assert by["3023"].placements == 3 and by["3023"].designs == 1 and by["3023"].part == "3023"
    assert by["3068"].part == "3068b" and by["3068"].connection == "studs"  # the print stands for its base
    assert dict(prior.colours) == pytest.approx({4: 0.5, 1: 0.5})  # B's colour-16 tile is no colour
    assert [d.file for d in prior.designs] == ["a.mpd", "b.mpd"] and prior.designs[0].licence.startswith("Redis")
    # temper 0.5: the square roots of the shares, normalised
    half = {p.family: p.weight for p in fit_prior(designs, reader, temper=0.5).parts}
    z = 2 * math.sqrt(0.375) + math.sqrt(0.25)
    assert half == pytest.approx({"3023": math.sqrt(0.375) / z, "3001": math.sqrt(0.375) / z, "3068": 0.5 / z})
    # only the designs that state a licence
    assert [d.file for d in fit_prior(designs, reader, require_licence=True).designs] == ["a.mpd"]


def test_a_prior_file_round_trips_and_a_bad_one_names_the_file(tmp_path, designs):
    prior = fit_prior(designs, get_reader(None))
    path = tmp_path / "p.json"
    path.write_text(prior.dumps())
    assert load_prior(path) == prior and load_prior(path).digest() == prior.digest()
    data = json.loads(prior.dumps())
    for bad, match in [("{", "p.json:1: not JSON"), (json.dumps({**data, "version": 99}), "format version 99"),
                       (json.dumps({**data, "format": "x"}), "not a prior"),
                       (prior.dumps().replace('"weight": 0.', '"weight": -0.', 1), "finite, >= 0"),
                       (json.dumps({**data, "parts": [{"family": "x"}]}), "malformed prior")]:
        path.write_text(bad)
        with pytest.raises(PriorError, match=match) as info:
            load_prior(path)
        assert str(path) in str(info.value)
    with pytest.raises(PriorError, match="cannot read the prior"):
        load_prior(tmp_path / "missing.json")


def test_the_shipped_prior_is_the_embedded_default():
    """Without a library the sampler draws the shipped prior's parts the embedded library holds, with
    its weights: the round plate, the grille, the headlight brick, the cheese slope among them."""
    prior = load_prior()
    assert len(prior.designs) >= 80 and all(d.licence for d in prior.designs)
    parts, colours = embedded_choice(prior)
    assert DEFAULT_PARTS == parts and SamplerConfig().parts == parts and SamplerConfig().prior.startswith("default ")
    names = dict(parts)
    for wanted in ("3023", "6141", "2412b", "4070", "54200", "3062b", "99781"):
        assert wanted in names
    assert names["3023"] > names["3001"] > 0  # the plate 1 x 2 is drawn more than the brick 2 x 4
    assert {c for c, _ in colours} <= {c for c, _ in prior.colours}


def _prior(*uses) -> Prior:
    total = sum(u[1] for u in uses)
    parts = tuple(PartUse(family(n), n, w / total, 1, 1, connection=kind) for n, w, kind in uses)
    return Prior(parts, ((4, 1.0), (999999, 1.0)), (("studs", 1.0),), (), 1.0)


def test_parts_a_library_cannot_give_are_listed_with_their_reason(mini_library):
    """A part the library lacks and a part with no studs, no sockets and no joint connector (the
    mini library's 'brick' is a solid cube) are left out, each with why; the colours the library
    lacks too."""
    reader = Reader(Library.from_dir(mini_library))
    have = reader.library.part_names()
    prior = _prior(("3001", 2.0, "studs"), ("973", 1.0, "minifigure"), (have[0], 1.0, "studs"))
    choice = choose_parts(prior, reader)
    reasons = {left.part: left.reason for left in choice.left_out}
    assert reasons == {"3001": NOT_IN_LIBRARY, "973": NOT_IN_LIBRARY, have[0]: NO_CONNECTOR}
    assert choice.parts == () and choice.used_weight == 0


def test_with_a_library_the_sampler_draws_the_prior_parts_it_holds(real_reader, tmp_path):
    """By the prior's name, else another member of its family the library holds (3062a -> 3062b);
    a part it lacks and a minifigure piece held in a hand (a sword) are left out, and the config
    names the prior."""
    prior = _prior(("3023b", 3.0, "studs"), ("3062a", 1.0, "studs"), ("no_such_part", 1.0, "studs"),
                   ("2530", 1.0, "minifigure"))
    path = tmp_path / "p.json"
    path.write_text(prior.dumps())
    config, choice = configure(SamplerConfig(), real_reader, path)
    assert dict(config.parts) == pytest.approx({"3023b": 0.5, "3062b": 1 / 6})
    assert {left.part for left in choice.left_out} == {"no_such_part", "2530"}
    assert config.prior == f"p.json sha256:{prior.digest()[:16]}" and dict(config.colours) == {4: 1.0}


@pytest.mark.slow
def test_the_prior_command_fits_and_the_sampler_draws_from_the_file(designs, tmp_path):
    out = subprocess.run([sys.executable, "-m", "pipelines.prior", str(designs[0].parent), "--out",
                          str(tmp_path / "p.json"), "--temper", "1"], capture_output=True, text=True, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    assert "2 designs, 6 placements, 3 part families" in out.stdout and "[2/2] b.mpd" in out.stderr
    prior = load_prior(tmp_path / "p.json")
    grown = subprocess.run([sys.executable, "-m", "pipelines.sample", "--n", "1", "--min-steps", "2", "--max-steps",
                            "3", "--prior", str(tmp_path / "p.json"), "--out", str(tmp_path / "o"), "--no-progress"],
                           capture_output=True, text=True, cwd=ROOT)
    assert grown.returncode == 0, grown.stderr
    config = json.loads((tmp_path / "o" / "summary.json").read_text())["config"]
    assert config["parts"] == {"3023": 0.375, "3001": 0.375, "3068b": 0.25}  # on the embedded library
    assert config["prior"] == prior.label(tmp_path / "p.json") and config["colours"] == {"4": 0.5, "1": 0.5}
    bad = subprocess.run([sys.executable, "-m", "pipelines.sample", "--n", "1", "--prior", str(designs[0]),
                          "--out", str(tmp_path / "x")], capture_output=True, text=True, cwd=ROOT)
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "not JSON" in bad.stderr


def test_a_zip_library_and_its_folder_grow_the_same_objects(tmp_path, real_reader):
    """LDraw's complete.zip read in place and the same files unpacked: object for object the same."""
    import zipfile

    from factory.sampler import Sampler

    root = Path(real_reader.library.source.root)
    with zipfile.ZipFile(tmp_path / "complete.zip", "w", zipfile.ZIP_DEFLATED) as z:
        for f in sorted(root.rglob("*")):
            if f.is_file():
                z.write(f, "ldraw/" + f.relative_to(root).as_posix())
    config = SamplerConfig(parts=(("3001", 1.0), ("3023b", 2.0), ("3003", 1.0), ("3069b", 0.5)),
                           colours=((4, 1.0), (1, 1.0)), min_steps=4, max_steps=6, prior="")
    a = [s.to_json(steps=True) for s in Sampler(config, root).sample_many(range(2))]
    b = [s.to_json(steps=True) for s in Sampler(config, tmp_path / "complete.zip").sample_many(range(2))]
    assert a == b and all(x["steps"] >= 4 for x in a)


def test_the_data_card_names_the_prior_the_parts_were_drawn_from():
    from dataclasses import replace

    from pipelines.dataset import DatasetConfig
    from pipelines.dataset.card import dataset_card

    counts = {s: {"objects": 1, "steps": 2, "bytes": 3} for s in ("train", "test")}
    info = {"splits_present": ["train", "test"], "config_hash": "0123456789abcdef", "total": {"steps": 4},
            "counts": counts, "statistics": {}, "schema_version": 1}
    config = DatasetConfig.synthetic(2)
    assert f"usage prior `{SamplerConfig().prior}`" in dataset_card(config, info)
    given = DatasetConfig.synthetic(2, sampler=replace(SamplerConfig(), prior=""))
    assert "as the build's config lists them" in dataset_card(given, info)


def test_parts_held_by_joints_are_drawn_as_often_as_designs_place_them(real_reader):
    """Tempering flattens the weights of rare parts, and most parts held by joints alone (pins,
    axles, beams) are rare: the sampler draws them together at the designs' share of placements
    held so (`joint_share`), whatever their tempered weights, the stud parts keeping their weights
    among themselves."""
    from factory.prior.choose import joint_share

    uses = (("3023b", 5.0, "studs"), ("3001", 3.0, "studs"), ("3673", 1.0, OTHER), ("3707", 1.0, OTHER),
            ("3062b", 1.0, "side studs"))
    total = sum(w for _, w, _ in uses)
    prior = Prior(tuple(PartUse(family(n), n, w / total, 1, 1, connection=kind) for n, w, kind in uses),
                  ((4, 1.0),), (("studs", 0.6), ("side studs", 0.1), (OTHER, 0.1), ("minifigure", 0.2)), (), 1.0)
    assert joint_share(prior) == pytest.approx(0.1)  # of studs, side studs, joints and minifigure pieces
    weights = dict(choose_parts(prior, real_reader).parts)
    drawn = sum(weights.values())
    assert (weights["3673"] + weights["3707"]) / drawn == pytest.approx(0.1)
    assert weights["3673"] == pytest.approx(weights["3707"])
    assert weights["3023b"] / weights["3001"] == pytest.approx(5 / 3)


@needs_ldraw
def test_a_part_held_by_a_bar_or_a_rims_grip_is_a_joint_part_a_tyre_is_not():
    """A part's connection kind is judged as the sampler attaches it: with no studs and no
    sockets, a part whose bar (the control stick 4593) or hub (the rim 4624) the sampler finds in
    its drawing is held by joints, as a pin drawn with connector primitives (2780) is, and is drawn
    at the designs' share of such parts (`choose.joint_share`); a tyre (3641), held by its shape,
    has none; a tile (2431), whose underside bar is not how it is held, connects by its sockets."""
    from factory.prior.fit import connection_kind

    reader = get_reader(str(LDRAW))
    kinds = {n: connection_kind(reader, n)[0] for n in ("4593", "4624", "2780", "3641", "2431", "3023")}
    assert kinds == {"4593": OTHER, "4624": OTHER, "2780": OTHER, "3641": "no connector", "2431": "studs",
                     "3023": "studs"}


def test_minifigure_pieces_with_a_place_are_drawn_those_held_in_a_hand_listed(tmp_path):
    """A torso, an arm and a hat have places of their own on a figure (`factory.minifig.SLOTS`):
    the sampler draws them; a bow and a sword are held where each piece's grip is: left out, with
    why."""
    if not LIBRARY_ZIP.is_file():
        pytest.skip(f"LDraw's complete.zip is not at {LIBRARY_ZIP}")
    reader = Reader(Library.from_path(LIBRARY_ZIP))
    prior = _prior(("3001", 4.0, "studs"), ("973", 1.0, "minifigure"), ("3818", 1.0, "minifigure"),
                   ("4485", 1.0, "minifigure"), ("4499", 1.0, "minifigure"), ("2530", 1.0, "minifigure"))
    choice = choose_parts(prior, reader)
    assert [n for n, _ in choice.parts] == ["3001", "973", "3818", "4485"]
    assert {left.part: left.reason for left in choice.left_out} == {"4499": MINIFIGURE, "2530": MINIFIGURE}


@needs_ldraw
def test_a_library_part_is_decomposed_where_it_is_first_drawn_not_before(tmp_path, monkeypatch):
    """Growing from a library's parts does not decompose all of them first (the prior's 1,071
    parts of LDraw's library would take hours on a cold cache here): a part's collision pieces are
    made where it is first drawn, so a part too rare to be drawn is never decomposed, and the
    command says how parts are prepared."""
    from factory.parts import load_part
    from factory.physics.geometry import is_prepared

    prior = _prior(("3001", 1.0, "studs"), ("3003", 1e-5, "studs"))
    path = tmp_path / "p.json"
    path.write_text(prior.dumps())
    cache = tmp_path / "cache"
    env = {**__import__("os").environ, "BRICK_FACTORY_CACHE": str(cache)}
    grown = subprocess.run([sys.executable, "-m", "pipelines.sample", "--n", "1", "--min-steps", "3", "--max-steps",
                            "3", "--ldraw", str(LDRAW), "--prior", str(path), "--out", str(tmp_path / "o"),
                            "--workers", "1", "--no-progress"], capture_output=True, text=True, cwd=ROOT, env=env)
    assert grown.returncode == 0, grown.stderr
    placed = [line.split()[-1] for line in (tmp_path / "o" / "object_00000.ldr").read_text().splitlines()
              if line.startswith("1 ")]
    assert placed == ["3001.dat"] * 3
    monkeypatch.setenv("BRICK_FACTORY_CACHE", str(cache))
    reader = get_reader(str(LDRAW))
    assert is_prepared(load_part(reader, "3001")) and not is_prepared(load_part(reader, "3003"))
    assert "collision pieces are made where a part is first drawn" in grown.stderr
