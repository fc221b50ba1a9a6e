"""A part body's decomposition into inset convex pieces (`_decomposed`, settings
`DecompositionConfig`): the faithful pieces of its own faces (`faithful`) where they can be found,
else coacd's, run in a child process bounded in time (`coacd_seconds`, a second try at `COARSE`
settings) and memory (`COACD_MEMORY_BYTES`) and snapped to the part's vertices (`_snap`); and its
disk cache (`cache_dir`): the pieces by content hash (`_load`, `_save`), and a refused
decomposition's reason with the limits it ran under (`_refused_before`).
"""

from __future__ import annotations

import io
import json
import math
import os
import subprocess
import sys
import tempfile
import time
import zipfile
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from factory.cache import cache_root, keep
from factory.errors import LDrawLimitError
from factory.parts import Part
from factory.physics.faithful import _faithful_pieces, _refined
from factory.physics.hull import INSET_LDU, inset_hull


@dataclass(frozen=True)
class DecompositionConfig:
    """coacd settings for part bodies; part of the cache key."""

    threshold: float = 0.05
    """coacd concavity threshold, for parts whose hull is not faithful (brackets, holders, seats):
    they are concave where other parts sit, so the split must be fine."""
    max_convex_hull: int = 32
    """Upper bound on body pieces per part (contacts cost grows with pieces)."""
    preprocess_resolution: int = 50
    """coacd's voxel resolution for its manifold preprocessing."""
    mcts_iterations: int = 60
    mcts_nodes: int = 12
    mcts_max_depth: int = 2
    seed: int = 0
    inset_ldu: float = INSET_LDU
    snap_ldu: float = 1.0
    """A coacd piece is rebuilt from the part's vertices within this distance of it."""
    faithful_pitch_ldu: float = 1.5
    """Spacing of the points sampled inside a hull to test whether it is faithful."""
    min_cut_ldu: float = 1.5
    """Thinnest half of a cell halved through its middle: a thinner cell may hold no sample point
    (at `faithful_pitch_ldu`) and would pass the test whatever it fills."""
    split_cells: int = 256
    """How many cells the split along the part's faces may examine before giving the body to coacd
    (a split into n faithful pieces examines 2n - 1)."""
    stud_bores_roofed: bool = True
    """Whether the faithfulness test counts a hollow stud's bore as roofed (the stud's collision
    prism is solid, so filling the bore under it changes nothing)."""
    refine_cells: int = 256
    """How many cells the split of one unfaithful piece (`faithful._refined`) may examine (the
    mudguard 35789 needs 128 since the refinement samples to the inset). Not part of the
    decomposition's cache key: refined pieces are cached under their own (`geometry.collision_shape`)."""


def cache_dir() -> Path:
    """Where decompositions are cached: `coacd/` in the factory's cache folder (`factory.cache`)."""
    return cache_root() / "coacd"


COACD_SECONDS = 300
"""CPU time one part's coacd decomposition may take, unless `COACD_SECONDS_ENV` says otherwise.
Most real parts take 0.1-15 s here, but 11208.dat (a 2,288-triangle part of 40448) took more than
300 s on this project's 2-core machine; a soup of 12,000 random triangles ran past 200 s at
2.4 GB, and one of 1.2 million was killed for memory at 24 GB after 96 s. coacd is native code
that cannot be stopped from Python, so it runs in a child process under this limit and
`COACD_MEMORY_BYTES`. CPU time, not wall time: measured as wall time, the same part was refused on
a busy machine and accepted on an idle one (LDraw's 6032 and 49309 at coarse settings: 271 s and
175 s on a free core, past 300 s of wall time beside other work)."""
WALL_FACTOR = 4
"""A child that has not ended after this many times the limit in wall time is stopped whatever CPU
time it used (a machine so busy that it hardly runs)."""
COACD_SECONDS_ENV = "BRICK_FACTORY_COACD_SECONDS"
"""Environment variable: seconds one decomposition may take (a slow machine meeting a slow part)."""
COACD_MEMORY_BYTES = 8 << 30
"""Address space of that child process (the 1.2-million-triangle soup reached 24 GB)."""


COARSE = {"preprocess_resolution": 30, "max_convex_hull": 16, "mcts_iterations": 20, "mcts_nodes": 8,
          "threshold": 0.1}
"""coacd settings of the second try, for a part whose decomposition ran past its time limit at
`DecompositionConfig`'s: the voxel resolution of coacd's preprocessing sets most of its time.
Measured on this project's 2-core machine, parts of LDraw's library that took more than 300 s:
6061 39 s coarse (1,232 triangles, 16 pieces), 48169 37 s, 4746 9 s. Which settings a part near
the limit gets can depend on the machine; the cache (and `pipelines.parts --pack`) keeps it."""


class DecompositionRefused(LDrawLimitError):
    """coacd ran past its time limit (at both settings) or its memory on a part, now or before
    (`_refused_before`): the part gets its hull's pieces instead (`hull_pieces`)."""


class DecompositionTooSlow(DecompositionRefused):
    """coacd ran past `coacd_seconds()` on a part."""


HULL_CELLS = 4096
"""How many cells the faithful split of a refused part's convex hull (`hull_pieces`) may examine:
LDraw's dome 24947 needs 107 pieces and the wheel 18976 137 (4 s and 2.3 s here; at the
decomposition's own 256 cells both stayed whole hulls). The wheels 56145 and 56904 need more
and keep their hull (10-11 s to find that here)."""


def hull_pieces(part: Part, verts: np.ndarray, cfg: DecompositionConfig) -> list[np.ndarray]:
    """The collision pieces of a part coacd refused: its convex hull split into faithful pieces of
    its own faces (`faithful._refined`, up to `HULL_CELLS` cells), else the hull itself. A whole
    hull fills the part's holes and hollows: a pin or an axle in a wheel's hub, a tyre on its rim
    or a stud in a socket still goes in (joint zones and connected studs are left out of the
    overlap), but a part beside it finds no room in a hollow."""
    try:
        hull = verts[ConvexHull(verts).vertices]
    except (QhullError, ValueError):
        return []
    piece = inset_hull(hull, cfg.inset_ldu)
    if piece is None:
        return []
    return _refined(part, [piece], replace(cfg, refine_cells=max(cfg.refine_cells, HULL_CELLS)))


def coacd_seconds() -> float:
    """The decomposition's time limit: `COACD_SECONDS_ENV` when set, else `COACD_SECONDS`."""
    raw = os.environ.get(COACD_SECONDS_ENV, "").strip()
    if not raw:
        return COACD_SECONDS
    try:
        seconds = float(raw)
    except ValueError:
        seconds = math.nan
    if not (math.isfinite(seconds) and seconds > 0):
        raise ValueError(f"{COACD_SECONDS_ENV} must be a number of seconds > 0, got {raw!r}")
    return seconds


_COACD_CHILD = """
import sys
try:  # set before numpy and coacd load (a preexec_fn is unsafe in threaded workers); POSIX only
    import resource
    resource.setrlimit(resource.RLIMIT_AS, (int(sys.argv[3]), int(sys.argv[3])))
    # The parent stops it at the CPU limit; this ends it if the parent died first (a killed run).
    resource.setrlimit(resource.RLIMIT_CPU, (int(sys.argv[4]), int(sys.argv[4])))
except ImportError:
    pass
import numpy as np
import coacd
data = np.load(sys.argv[1])
coacd.set_log_level("error")
args = {k: v.item() for k, v in data.items() if k not in ("vertices", "faces", "preprocess_mode")}
pieces = coacd.run_coacd(coacd.Mesh(data["vertices"], data["faces"]), preprocess_mode="auto", **args)
np.savez(sys.argv[2], *[np.asarray(v, dtype=np.float64) for v, _ in pieces])
"""


def _cpu_seconds(pid: int) -> float | None:
    """CPU time (user and system, every thread) a running process has used; None where the system
    does not say (no /proc)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return None


def _run_limited(argv: list[str], err, limit: float) -> int | None:
    """Run `argv` (stderr to the file `err`) until it ends: its return code, or None once it has used
    more than `limit` seconds of CPU time (wall time where the CPU time is not known), or run
    `WALL_FACTOR` times that in wall time; then it is killed."""
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=err)
    t0 = time.monotonic()
    try:
        while True:
            try:
                return proc.wait(timeout=min(0.05, limit / 4))
            except subprocess.TimeoutExpired:
                pass
            wall = time.monotonic() - t0
            used = _cpu_seconds(proc.pid)
            if (wall if used is None else used) > limit or wall > WALL_FACTOR * limit:
                return None
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def _decompose(vertices: np.ndarray, faces: np.ndarray, cfg: DecompositionConfig, name: str = "") -> list[np.ndarray]:
    """coacd's convex pieces of the mesh, computed in a child process bounded by `coacd_seconds()`
    and `COACD_MEMORY_BYTES`; past either, an `LDrawLimitError` naming the part."""
    with tempfile.TemporaryDirectory(prefix="bf-coacd-") as tmp:
        src, out = os.path.join(tmp, "mesh.npz"), os.path.join(tmp, "pieces.npz")
        np.savez(src, vertices=np.asarray(vertices, np.float64), faces=np.asarray(faces, np.int64),
                 threshold=cfg.threshold, max_convex_hull=cfg.max_convex_hull,
                 preprocess_resolution=cfg.preprocess_resolution, mcts_iterations=cfg.mcts_iterations,
                 mcts_nodes=cfg.mcts_nodes, mcts_max_depth=cfg.mcts_max_depth, seed=cfg.seed)
        what = f"decomposing {name or 'a part'} ({len(faces):,} triangles) into convex pieces"
        limit = coacd_seconds()
        with open(os.path.join(tmp, "stderr.txt"), "w+") as err:
            code = _run_limited([sys.executable, "-c", _COACD_CHILD, src, out, str(int(COACD_MEMORY_BYTES)),
                                 str(int(2 * limit) + 10)], err, limit)
            err.seek(0)
            stderr = err.read()
        if code is None:
            raise DecompositionTooSlow(f"{what} took more than {limit:g} s of CPU time; refusing the part (on a slow "
                                       f"machine, {COACD_SECONDS_ENV}=SECONDS allows longer)", name or None)
        if code != 0 or not os.path.exists(out):
            tail = (stderr.strip().splitlines() or ["no message"])[-1]
            raise DecompositionRefused(f"{what} failed within {COACD_MEMORY_BYTES >> 20:,} MB of memory ({tail}); "
                                       "refusing the part", name or None)
        with np.load(out) as pieces:
            return [pieces[f"arr_{i}"] for i in range(len(pieces.files))]


def _snap(piece: np.ndarray, verts: np.ndarray, snap: float) -> np.ndarray | None:
    """The part's vertices that lie in (or within `snap` of) a convex piece, or None if too few."""
    try:
        eq = ConvexHull(piece).equations
    except (QhullError, ValueError):
        return None
    inside = np.all(verts @ eq[:, :3].T + eq[:, 3] <= snap, axis=1)
    pts = verts[inside]
    if len(pts) < 4 or np.linalg.matrix_rank(pts - pts.mean(0), tol=1e-6) < 3:
        return None
    return pts


def _body_mesh(part: Part) -> tuple[np.ndarray, np.ndarray]:
    tris = part.flat.triangles[~part.flat.in_stud]
    verts, faces = np.unique(np.round(tris.reshape(-1, 3), 4), axis=0, return_inverse=True)
    faces = faces.reshape(-1, 3)
    keep = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
    return verts, faces[keep]


def _load(path: Path) -> tuple[list[np.ndarray], float] | None:
    """A cached entry's pieces and inset, None if missing or damaged (then recomputed): empty
    (EOFError), truncated (BadZipFile), foreign or unreadable."""
    try:
        with np.load(path) as data:
            return [data[f"p{i}"] for i in range(int(data["n"]))], float(data["inset"])
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):  # OSError: missing too
        return None


def _save(path: Path, body: list[np.ndarray], inset: float) -> None:
    """Keep an entry (`factory.cache.keep`: atomic; a cache that cannot be written is worked
    without, said once on stderr)."""
    buf = io.BytesIO()
    np.savez(buf, n=len(body), inset=inset, **{f"p{i}": p for i, p in enumerate(body)})
    keep(path, buf.getvalue())


def _decomposed(part: Part, verts: np.ndarray, faces: np.ndarray, cfg: DecompositionConfig,
                raw_key: str | None = None) -> list[np.ndarray]:
    """The body's inset pieces (faithful hull, faces-cut pieces, else snapped coacd pieces). With
    `raw_key`, a first try that ran past its time limit is kept (`_remember_slow`), so a run cut
    during the coarser second try resumes at that try, not at the first."""
    faithful = _faithful_pieces(part, cfg) if len(faces) else []
    if faithful is not None:
        return [p for p in (inset_hull(r, cfg.inset_ldu) for r in faithful) if p is not None]
    # coacd remeshes its input on a voxel grid, so its pieces bulge up to ~1 LDU out of the part.
    # Rebuild each piece as the hull of the part's own vertices it holds (within a snap
    # distance): pieces then follow the real surface.
    name = getattr(part, "file", None) or part.name
    slow = _slow_before(raw_key) if raw_key else None
    raw = None
    if slow is None:
        try:
            raw = _decompose(verts, faces, cfg, name)
        except DecompositionTooSlow as exc:
            slow = exc.message
            if raw_key:
                _remember_slow(raw_key, exc)
    if raw is None:
        try:
            raw = _decompose(verts, faces, replace(cfg, **COARSE), name)
        except LDrawLimitError as again:
            raise DecompositionRefused(f"{slow}; again at coarser settings: {again.message}", name) from None
    pieces = (_snap(r, verts, cfg.snap_ldu) for r in raw)
    return [p for p in (inset_hull(r, cfg.inset_ldu) for r in pieces if r is not None) if p is not None]


def decomposed_or_refused(part: Part, verts: np.ndarray, faces: np.ndarray, cfg: DecompositionConfig,
                          raw_key: str) -> tuple[list[np.ndarray], float] | None:
    """(the body's inset pieces, their inset) from `_decomposed`, cached under `raw_key`; None where
    coacd refuses the part, now (the refusal is kept) or before (`_refused_before`)."""
    try:
        _refused_before(raw_key, getattr(part, "file", None))
    except DecompositionRefused:
        return None
    try:
        raw = (_decomposed(part, verts, faces, cfg, raw_key), cfg.inset_ldu)
    except DecompositionRefused as exc:
        _remember_refusal(raw_key, exc)
        return None
    _save(cache_dir() / f"{raw_key}.npz", *raw)
    return raw


def _refusal_path(raw_key: str) -> Path:
    return cache_dir() / f"{raw_key}.json"


def _remember_refusal(raw_key: str, exc: LDrawLimitError) -> None:
    """Keep a refused decomposition's reason with the limits it ran under: the next process gives
    up at once instead of spending them again (a part that took more than 300 s, every run)."""
    keep(_refusal_path(raw_key), json.dumps({"seconds": coacd_seconds(), "clock": "cpu", "memory": COACD_MEMORY_BYTES,
                                             "coarse": COARSE, "message": exc.message}).encode())


def _as_wide(kept_: dict) -> bool:
    """Whether a kept record ran under limits at least as wide as today's: CPU seconds and memory
    (a refusal kept under the older wall-time limit is tried again). Raises KeyError, ValueError or
    TypeError on a record that is not one."""
    return float(kept_["seconds"]) >= coacd_seconds() and int(kept_["memory"]) >= COACD_MEMORY_BYTES \
        and kept_.get("clock") == "cpu"


def _slow_path(raw_key: str) -> Path:
    return cache_dir() / f"{raw_key}.slow.json"


def _remember_slow(raw_key: str, exc: LDrawLimitError) -> None:
    """Keep that a decomposition's first try ran past its time limit, with the limits it ran
    under: preparing a library is cut at any moment (a lent machine's time runs out), and a part
    whose two tries together take longer than a run would otherwise start again from the first."""
    keep(_slow_path(raw_key), json.dumps({"seconds": coacd_seconds(), "clock": "cpu", "memory": COACD_MEMORY_BYTES,
                                          "message": exc.message}).encode())


def _slow_before(raw_key: str) -> str | None:
    """The kept message of a first try that ran past limits at least as wide as today's (as
    `_refused_before`), else None: a larger `BRICK_FACTORY_COACD_SECONDS` tries it again."""
    try:
        kept_ = json.loads(_slow_path(raw_key).read_bytes())
        if _as_wide(kept_):
            return str(kept_["message"])
    except (OSError, ValueError, KeyError, TypeError):
        pass
    return None


def _refused_before(raw_key: str, file) -> None:
    """Raise the kept refusal of this decomposition, if it ran under limits at least as wide as
    today's and tried today's coarser settings too (a larger `BRICK_FACTORY_COACD_SECONDS`, or a
    refusal kept before the second try existed, tries again). The message is kept without the
    file, which may be another machine's path (a packed cache)."""
    try:
        kept_ = json.loads(_refusal_path(raw_key).read_bytes())
        wide = _as_wide(kept_) and kept_.get("coarse") == COARSE
        message = str(kept_["message"])
    except (OSError, ValueError, KeyError, TypeError):
        return
    if wide:
        raise DecompositionRefused(f"{message} (refused before; kept in the cache)", file)
