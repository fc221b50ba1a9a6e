"""Library resolution: search order, case and separators, confinement, clear misses."""

from __future__ import annotations

import os

import pytest

from factory.errors import LDrawError, LDrawMissingFileError, LDrawUnsafePathError
from factory.ldraw import Library, Reader, build_steps, get_reader
from factory.ldraw.library import check_reference

from ldraw_support import BOX, LDRAW, needs_ldraw


def model(write, text, name="m.ldr"):
    return write(name, "0 Model\n" + text)


def test_lookup_is_case_insensitive_with_either_separator(mini_library, write):
    reader = Reader(Library.from_dir(mini_library))
    m = model(write, "1 4 0 0 0 1 0 0 0 1 0 0 0 1 CUBE.DAT\n1 4 0 0 0 1 0 0 0 1 0 0 0 1 S\\CubeS01.dat\n")
    steps = build_steps(reader, reader.open_model(m))
    assert [p.part for p in steps[0].parts] == ["cube.dat", "s/cubes01.dat"]


def test_search_order_mpd_block_then_model_folder_then_library(mini_library, write):
    reader = Reader(Library.from_dir(mini_library))
    # A model-folder cube.dat shadows the library's: LDraw searches the model's folder first.
    write("cube.dat", "0 Local cube\n0 !LDRAW_ORG Unofficial_Part\n0 BFC CERTIFY CCW\n1 16 0 0 0 2 0 0 0 2 0 0 0 2 box.dat\n")
    m = model(write, "1 4 0 0 0 1 0 0 0 1 0 0 0 1 cube.dat\n")
    res = reader.resolve(reader.open_model(m).main.refs[0], reader.open_model(m).main, reader.open_model(m))
    assert res.origin == "model" and res.file.description == "Local cube"
    # An MPD block of the same name wins over both.
    mpd = write(
        "m.mpd",
        "0 FILE main.ldr\n1 4 0 0 0 1 0 0 0 1 0 0 0 1 cube.dat\n0 FILE cube.dat\n0 Block cube\n"
        "0 !LDRAW_ORG Unofficial_Part\n1 16 0 0 0 3 0 0 0 3 0 0 0 3 box.dat\n",
    )
    mm = reader.open_model(mpd)
    res = reader.resolve(mm.main.refs[0], mm.main, mm)
    assert res.origin == "mpd" and res.file.description == "Block cube"


def test_primitive_resolves_from_p_and_hires_from_p48(mini_library, write):
    (mini_library / "p" / "48" / "hires.dat").write_text(BOX)
    reader = Reader(Library.from_dir(mini_library))
    assert reader.part("box.dat").file.description == "Box"
    assert reader.part("48\\hires.dat").origin == "library"


@pytest.mark.parametrize("name", ["../secret.dat", "/etc/passwd", "C:\\ldraw\\x.dat", "parts/./a.dat", "a//b.dat"])
def test_references_that_escape_are_refused(name):
    with pytest.raises(LDrawUnsafePathError):
        check_reference(name, "m.ldr", 3)


def test_escaping_reference_in_a_model_names_file_and_line(mini_library, write, tmp_path):
    (tmp_path / "outside.dat").write_text(BOX)
    reader = Reader(Library.from_dir(mini_library))
    m = model(write, "1 4 0 0 0 1 0 0 0 1 0 0 0 1 ..\\outside.dat\n", name="sub/m.ldr")
    with pytest.raises(LDrawUnsafePathError) as err:
        build_steps(reader, reader.open_model(m))
    assert str(err.value).startswith(f"{m}:2: ")


def test_symlink_out_of_the_library_is_refused(mini_library, tmp_path):
    (tmp_path / "elsewhere.dat").write_text(BOX)
    os.symlink(tmp_path / "elsewhere.dat", mini_library / "parts" / "link.dat")
    reader = Reader(Library.from_dir(mini_library))
    with pytest.raises(LDrawUnsafePathError, match="outside"):
        reader.part("link.dat")


def test_missing_file_names_referencing_line_and_suggests(mini_library, write):
    reader = Reader(Library.from_dir(mini_library))
    m = model(write, "\n1 4 0 0 0 1 0 0 0 1 0 0 0 1 cueb.dat\n")
    with pytest.raises(LDrawMissingFileError) as err:
        build_steps(reader, reader.open_model(m))
    msg = str(err.value)
    assert msg.startswith(f"{m}:3: cannot find 'cueb.dat'")
    assert "did you mean cube.dat" in msg


def test_suggestions_never_show_names_outside_the_library(tmp_path, write):
    """'did you mean' listed file names from folders linked out of the library (a `p` linked to
    someone's home, say): suggestions come only from what the library would read."""
    lib = tmp_path / "lib"
    (lib / "parts").mkdir(parents=True)
    (lib / "parts" / "cube.dat").write_text(BOX)
    outside = tmp_path / "private"
    outside.mkdir()
    (outside / "cuba_secret.dat").write_text(BOX)
    (outside / "cubes_secret.dat").write_text(BOX)
    os.symlink(outside, lib / "p")  # a whole searched folder outside
    os.symlink(outside / "cubes_secret.dat", lib / "parts" / "cubx_secret.dat")  # one file outside
    reader = Reader(Library.from_dir(lib))
    m = model(write, "1 4 0 0 0 1 0 0 0 1 0 0 0 1 cube_secret.dat\n")
    with pytest.raises(LDrawMissingFileError) as err:
        build_steps(reader, reader.open_model(m))
    assert "secret" not in str(err.value).split("cannot find")[1].split("'", 2)[2]
    assert "cube.dat" in str(err.value)


def test_library_folder_must_look_like_one(tmp_path):
    with pytest.raises(LDrawError, match="expected folders 'parts' and 'p'"):
        Library.from_dir(tmp_path)
    with pytest.raises(LDrawError, match="does not exist"):
        Library.from_dir(tmp_path / "nope")


def test_ldrawdir_is_used_when_no_folder_is_given(mini_library, monkeypatch):
    monkeypatch.setenv("LDRAWDIR", str(mini_library))
    assert str(mini_library) in get_reader().library.description
    monkeypatch.delenv("LDRAWDIR")
    assert get_reader().library.description == "embedded default library"


def test_reader_is_shared_per_library(mini_library):
    assert get_reader(mini_library) is get_reader(str(mini_library) + "/")


@needs_ldraw
def test_colours_from_ldconfig_including_direct_colours():
    from factory.ldraw import ColourTable

    table = ColourTable.parse((LDRAW / "LDConfig.ldr").read_text())
    red = table.get(4)
    assert red.name == "Red" and red.rgba[:3] == pytest.approx((0xB4 / 255, 0, 0))
    assert table.get(47).rgba[3] == pytest.approx(128 / 255)
    direct = table.get(0x2FF8000)
    assert direct.rgba == pytest.approx((1.0, 128 / 255, 0.0, 1.0))
    assert 0x2FF8000 in table and 12345 not in table


def _zip_of(folder, path, top="ldraw/"):
    """The library `folder` zipped as LDraw's complete.zip lays it out (every file under `top`)."""
    import zipfile

    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        for p in sorted(folder.rglob("*")):
            if p.is_file():
                z.write(p, top + p.relative_to(folder).as_posix())
    return path


@needs_ldraw
@pytest.mark.parametrize("top", ["ldraw/", ""])
def test_a_zip_library_is_read_in_place_like_its_folder(tmp_path, top):
    """`--ldraw` takes LDraw's complete.zip (files under ldraw/) or a zip of a library's contents,
    read in place: a model's steps and a part's geometry are the same as from the folder."""
    import numpy as np

    from factory.ldraw import read_steps
    from factory.parts import load_part
    from ldraw_support import MODELS

    zipped = Reader(Library.from_path(_zip_of(LDRAW, tmp_path / "complete.zip", top)))
    folder = Reader(Library.from_path(LDRAW))
    assert zipped.library.description.startswith("LDraw library in ")
    car = MODELS / "car.ldr"
    steps_zip = [s.to_json() for s in read_steps(car, tmp_path / "complete.zip")]
    assert steps_zip == [s.to_json() for s in read_steps(car, LDRAW)] and steps_zip
    for name in ("3001", "3039", "6141"):
        a, b = load_part(zipped, name).flat, load_part(folder, name).flat
        assert np.array_equal(a.triangles, b.triangles) and np.array_equal(a.colours, b.colours)
    assert zipped.colours.colours.keys() == folder.colours.colours.keys()  # LDConfig.ldr read from the zip
    with pytest.raises(LDrawMissingFileError, match="complete.zip"):
        zipped.part("no_such_part.dat")


def test_a_zip_that_is_no_library_or_a_file_that_is_no_zip_is_refused(tmp_path, mini_library):
    import zipfile

    with zipfile.ZipFile(tmp_path / "other.zip", "w") as z:
        z.writestr("docs/readme.txt", "hello")
    with pytest.raises(LDrawError, match="not an LDraw library: expected folders 'parts' and 'p'"):
        Library.from_path(tmp_path / "other.zip")
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(LDrawError, match="is a file but not a zip archive"):
        Library.from_path(tmp_path / "notes.txt")
    with pytest.raises(LDrawError, match="does not exist"):
        Library.from_path(tmp_path / "missing")
    assert Reader(Library.from_path(_zip_of(mini_library, tmp_path / "mini.zip", ""))).part("cube.dat")


_FORKED = {}  # what forked workers inherit, as the preparation's pool does


def _read_all(rounds):
    import hashlib
    digest = hashlib.sha256()
    for _ in range(rounds):
        for name in _FORKED["names"]:
            digest.update(_FORKED["source"].lookup(name).read())
    return digest.hexdigest()


@needs_ldraw
def test_forked_workers_read_one_zip_library_at_once(tmp_path):
    """Library preparation forks workers that all read the same opened zip: each must read its own
    members whole (sharing the parent's open file, their reads moved one another's file offset and
    zlib refused the data on the lent machine's 16 workers)."""
    import multiprocessing

    from factory.ldraw.library import ZipSource

    source = ZipSource(_zip_of(LDRAW, tmp_path / "complete.zip"), "test")
    _FORKED.update(source=source, names=sorted(k for k in source._members if k.startswith("parts/"))[:120])
    expected = _read_all(3)
    with multiprocessing.get_context("fork").Pool(4) as pool:
        got = pool.map(_read_all, [3] * 16, chunksize=1)
    assert got == [expected] * 16
