"""The separating-axis kernels of piece pairs on the JAX device (backend 'jax').

For each pair (a unit piece of a candidate, a structure piece: `piece_sets`), kind 'sweep' gives
the open interval of s along the candidate's approach d where the overlap of the unit piece moved
back by s d exceeds the pair's threshold (`sweep_jax`, whose docstring gives the method), and kind
'still' the pair's depths at the candidate's pose (`collide_jax`). Pairs are grouped by the size
buckets of both pieces, and each group runs in one jitted vmap over pairs, its counts padded to
powers of two, at most `MAX_WORK` projections per launch: so a run compiles once per shape met
(`COMPILES`), never per call. On a GPU the padded sizes start at those a worker reaches, and the
kernels of boxes and studs are readied before its first round (`warm_up`). A round's launches send
only the piece rows their pairs name, the tables and poses in one transfer, and their results come
back in one copy (`intervals_many`).
"""

from __future__ import annotations

import math
import os
from functools import cache, partial
from typing import Sequence

import numpy as np

from factory import gpus
from factory.physics import jax_export
from factory.physics.jax_cache import enable as enable_compile_cache
from factory.physics.piece_sets import LEVELS, PieceSet, convex_piece, pow2

COMPILES: list[tuple] = []
"""(kernel kind, edge axes or not, pairs, unit table rows, structure table rows, candidates, and
vertices, normals, edges of both pieces) of every launch shape compiled in this process."""
MIN_ROWS = 256
"""Smallest padded count of pairs, candidates and table rows per launch: fewer shapes to compile."""
GPU_MIN_PAIRS = 1024
"""Smallest padded count of a launch's pairs on a GPU (at most the launch's `MAX_WORK` chunk)."""
GPU_MIN_STRUCTURE_ROWS = 1024
"""Smallest padded row count of a round's structure-side piece tables on a GPU.

Both are the sizes a default build's worker reaches within its first shard anyway (a padded size
only grows, `_grown`): starting there, a process meets each kernel at its working size at once
instead of compiling it at two or three sizes on the way. Measured on a lent H100 machine, one
process growing four shards of four objects (the default config) from an empty cache: 35 kernel
shapes, 30.5 s of the first shard's 97.5 s in the first launches of 32 of them (2.2 s with the
cache warm). On a lent H200 machine a 16-worker `N=700` build from an empty cache finished its first
shards about 30 s after the reference's, every worker waiting for each shape's one compile
(`jax_export`). A GPU runs a launch of a few pairs in about the time of one of thousands, so the
padding costs little there; on the CPU it would cost compute, so the CPU keeps `MIN_ROWS`."""
MAX_WORK = 1 << 25
"""Vertex-axis projections per launch (memory: a few times this many floats)."""


@cache
def _on_gpu() -> bool:
    """Whether JAX's default device is a GPU (asked at the first launch, not at import)."""
    import jax  # optional: the [jax] extra; the 'cpu' backend needs none

    enable_compile_cache()
    return jax.default_backend() == "gpu"


_HIGH: dict[tuple, int] = {}
"""The largest padded size met so far in this process per kind of array (`_grown`)."""


def _grown(key: tuple, n: int, minimum: int = MIN_ROWS) -> int:
    """`pow2(n)`, or the largest size met before for `key` if larger: a padded size only grows
    during a run, so objects finishing (fewer tables stacked, fewer candidates) meet no new shape."""
    size = max(pow2(n, minimum), _HIGH.get(key, 0))
    _HIGH[key] = size
    return size


def _table_rows(key: tuple, n: int) -> int:
    """The padded rows of a round's piece table for `key` = (side 'u' or 's', piece bucket) holding
    `n` rows (`_grown`; on a GPU the structure side from `GPU_MIN_STRUCTURE_ROWS`)."""
    floor = GPU_MIN_STRUCTURE_ROWS if key[0] == "s" and _on_gpu() else MIN_ROWS
    return _grown(("rows", *key), n, floor)


_KERNEL = None


def _kernel():
    """The jitted batches of pairs by kind: 'sweep' (intervals of s) and 'still' (depths at the
    candidate's pose, `collide_jax`). JAX is imported here: the 'cpu' backend needs none."""
    global _KERNEL
    if _KERNEL is None:
        import jax  # optional: the [jax] extra
        import jax.numpy as jnp

        enable_compile_cache()

        def interval(av, bv, axes, valid, d, thr):
            """Open interval of s where every axis's two overlaps of (A - s d) and B exceed thr."""
            pa, pb = av @ axes.T, bv @ axes.T
            dn = axes @ d
            c = jnp.concatenate([pa.max(0) - pb.min(0), pb.max(0) - pa.min(0)])
            m = jnp.concatenate([-dn, dn])
            ok = jnp.concatenate([valid, valid])
            r = (thr - c) / jnp.where(m == 0, 1.0, m)  # c + m s > thr  <=>  s > r (m > 0), s < r (m < 0)
            lo = jnp.max(jnp.where(ok & (m > 0), r, -jnp.inf))
            hi = jnp.min(jnp.where(ok & (m < 0), r, jnp.inf))
            flat_fails = jnp.any(ok & (m == 0) & (c <= thr))
            return lo, jnp.where(flat_fails, -jnp.inf, hi)

        def pair(crosses, ut, st, R, t, d, u, s, k, thr, thr_c):
            uv, un, ue, uc = (x[u] for x in ut)
            sv, sn, se, sc = (x[s] for x in st)
            Rk, tk, dk = R[k], t[k], d[k]
            av, an, ae, ac = uv @ Rk.T + tk, un @ Rk.T, ue @ Rk.T, uc @ Rk.T + tk
            axes, valid = jnp.concatenate([an, sn]), jnp.ones(len(an) + len(sn), bool)
            if crosses:
                cross = jnp.cross(ae[:, None, :], se[None, :, :]).reshape(-1, 3)
                size = jnp.linalg.norm(cross, axis=1)
                ok = size > 1e-9  # parallel edges give no axis
                axes = jnp.concatenate([axes, cross / jnp.where(ok, size, 1.0)[:, None]])
                valid = jnp.concatenate([valid, ok])
            lo, hi = interval(av, sv, axes, valid, dk, thr)
            ones_s, ones_u = jnp.ones(len(sn), bool), jnp.ones(len(an), bool)
            lo_a, hi_a = interval(ac[None], sv, sn, ones_s, dk, thr_c)  # the unit piece's centre in s
            lo_b, hi_b = interval(av, sc[None], an, ones_u, dk, thr_c)  # the structure piece's in u
            return jnp.stack([lo, hi, lo_a, hi_a, lo_b, hi_b])

        def depth(a, b, axes, valid):
            """Separating-axis depth of point sets a into b: > 0 overlap (exact), <= 0 apart."""
            pa, pb = a @ axes.T, b @ axes.T
            c = jnp.minimum(pa.max(0) - pb.min(0), pb.max(0) - pa.min(0))
            return jnp.min(jnp.where(valid, c, jnp.inf))

        def still(crosses, ut, st, R, t, d, u, s, k, thr, thr_c):
            """At the candidate's pose (s = 0): the pieces' depth, then each centre's inside the other."""
            uv, un, ue, uc = (x[u] for x in ut)
            sv, sn, se, sc = (x[s] for x in st)
            Rk, tk = R[k], t[k]
            av, an, ae, ac = uv @ Rk.T + tk, un @ Rk.T, ue @ Rk.T, uc @ Rk.T + tk
            axes, valid = jnp.concatenate([an, sn]), jnp.ones(len(an) + len(sn), bool)
            if crosses:
                cross = jnp.cross(ae[:, None, :], se[None, :, :]).reshape(-1, 3)
                size = jnp.linalg.norm(cross, axis=1)
                ok = size > 1e-9
                axes = jnp.concatenate([axes, cross / jnp.where(ok, size, 1.0)[:, None]])
                valid = jnp.concatenate([valid, ok])
            ones_s, ones_u = jnp.ones(len(sn), bool), jnp.ones(len(an), bool)
            return jnp.stack([depth(av, sv, axes, valid), depth(ac[None], sv, sn, ones_s),
                              depth(av, sc[None], an, ones_u)])

        def split(table, v, n, e):
            """A packed table's (vertices, normals, edges, centres) (`_gathered`)."""
            return table[:, :v], table[:, v:v + n], table[:, v + n:v + n + e], table[:, v + n + e]

        def run(fn, crosses, sizes, ut, st, poses, pairs):
            # Packed arguments (`_launch`): the tables and the candidates' poses, already on the
            # device, and one host array of the pairs (their indices exact in float64).
            ut, st = split(ut, *sizes[:3]), split(st, *sizes[3:])
            R, t, d = poses[:, :9].reshape(-1, 3, 3), poses[:, 9:12], poses[:, 12:15]
            u, s, k = (pairs[:, i].astype(jnp.int64) for i in range(3))
            thr, thr_c = pairs[:, 3], pairs[:, 4]
            return jax.vmap(partial(fn, crosses), in_axes=(None, None, None, None, None, 0, 0, 0, 0, 0))(
                ut, st, R, t, d, u, s, k, thr, thr_c)

        _KERNEL = {"sweep": jax.jit(partial(run, pair), static_argnums=(0, 1)),
                   "still": jax.jit(partial(run, still), static_argnums=(0, 1))}
    return _KERNEL


WIDTH = {"sweep": 6, "still": 3}
"""Values per pair of each kernel kind."""


def _chunk(crosses: bool, us: tuple, ss: tuple) -> int:
    """Pairs per launch of the kernel of buckets `us`, `ss` (a power of two, at least 1): as many
    as keep its vertex-axis projections within `MAX_WORK`; edge-edge axes only with `crosses`.
    No floor: at 256 pairs, pieces of the largest buckets (a round part's 128 vertices and
    128 x 128 edge axes) made one buffer of 256 x 128 x 16,512 doubles, 4 GiB, and every shard of
    a 16-worker build of 40 real parts on one H200 ran out of its worker's share of the GPU."""
    nv = us[0] + ss[0]
    axes = us[1] + ss[1] + crosses * us[2] * ss[2]
    return 1 << int(math.log2(max(1, MAX_WORK // (nv * axes))))


def _launch(crosses: bool, ut, us: tuple, st, ss: tuple, poses, u, s, k, thr, thr_c, kind: str = "sweep") -> list:
    """Starts the launches of pairs (u, s, k, thr, thr_c) and returns them, each (first pair,
    pairs, device result) (`_results`): (n, 6) intervals of the pairs (lo, hi of the overlap, then
    of the two centre tests), or for kind 'still' (n, 3) depths (of the pieces, of each centre in
    the other); edge-edge axes only with `crosses`. `ut`, `st`: `_gathered` tables of buckets
    `us`, `ss`; `poses`: the candidates' packed poses on the device (`_on_device`). A caller
    starts all its launches before it waits for any: the device runs them back to back, and the
    host waits once."""
    import jax  # optional: the [jax] extra

    n = len(u)
    chunk = _chunk(crosses, us, ss)
    pairs = np.stack([u, s, k, thr, thr_c], axis=1).astype(np.float64)  # indices < 2**53: exact
    sizes = (*us, *ss)
    dims = (kind, crosses, *sizes)
    started = []
    with jax.enable_x64(True):
        for a in range(0, n, chunk):
            m = min(chunk, n - a)
            # On a GPU a launch of a few pairs costs about what one of thousands does: pairs are
            # padded to the most met (at least `GPU_MIN_PAIRS`), so a run compiles few pair counts.
            rows = min(chunk, _grown(("pairs", *dims), m, GPU_MIN_PAIRS) if _on_gpu() else pow2(m, MIN_ROWS))
            shape = (kind, int(crosses), rows, ut.shape[0], st.shape[0], poses.shape[0], *sizes)
            if shape not in COMPILES:
                COMPILES.append(shape)
            # Through its export: a shape this process has not met is not traced again (`jax_export`).
            # The bucket sizes name it: they split the packed tables.
            res = jax_export.call(f"{kind}-{int(crosses)}-{'.'.join(map(str, sizes))}",
                                  partial(_kernel()[kind], crosses, sizes), ut, st, poses,
                                  np.concatenate([pairs[a:a + m], np.repeat(pairs[a:a + 1], rows - m, 0)]),
                                  source=__file__)
            started.append((a, m, res))
    return started


def _results(launches: list, kind: str) -> list[np.ndarray]:
    """The (pairs, `WIDTH[kind]`) results of `_launch`es, copied to the host together (one wait,
    not one per launch)."""
    import jax  # optional: the [jax] extra

    host = iter(jax.device_get([res for started in launches for _, _, res in started]))
    out = []
    for started in launches:
        got = np.empty((sum(m for _, m, _ in started), WIDTH[kind]))
        for a, m, _ in started:
            got[a:a + m] = np.asarray(next(host))[:m]
        out.append(got)
    return out


def _on_device(arrays: list[np.ndarray]) -> list:
    """Host arrays on the device, float64 as on the host, in one call."""
    import jax  # optional: the [jax] extra

    with jax.enable_x64(True):
        return jax.device_put(arrays)


WARM_LEVELS = LEVELS[:2]
"""Piece sizes whose kernels a GPU process has ready before its first round (`warm_up`): boxes and
studs, which nearly every part has."""
_WARMED = False


def warm_shapes() -> list[tuple]:
    """(kind, crosses, unit piece size, structure piece size) of every kernel `warm_up` readies."""
    return [(kind, crosses, us, ss) for kind in ("still", "sweep") for crosses in (False, True)
            for us in WARM_LEVELS for ss in WARM_LEVELS]


def warm_up() -> int:
    """Once per process on a GPU, before its first round: every kernel of `warm_shapes` at the sizes
    a first round uses (`MIN_ROWS` unit rows and candidates, `GPU_MIN_STRUCTURE_ROWS`,
    `GPU_MIN_PAIRS`), compiled or loaded (`jax_export`), starting at this worker's number
    (`gpus.slot`; else at its pid) and going round. The workers of a fresh machine then compile
    different shapes at once, each under its shape's lock, and load the others' from the cache;
    meeting each shape in a round, together, they waited in turn for its one compile (about 1 s a
    shape on a lent H100).
    Returns the kernels readied here (0 when not on a GPU, or done before)."""
    global _WARMED
    if _WARMED or not _on_gpu():
        return 0
    _WARMED = True
    import jax  # optional: the [jax] extra

    shapes = warm_shapes()
    # A build's workers are numbered; other processes (Ray tasks, say) start by their pid instead.
    slot = gpus.slot()
    start = (os.getpid() if slot is None else slot) % len(shapes)
    one = np.zeros(1, np.int64)
    launches = []
    for kind, crosses, us, ss in shapes[start:] + shapes[:start]:
        ut, st, poses = _on_device([np.zeros((_table_rows(("u", us), 1), sum(us) + 1, 3)),
                                    np.zeros((_table_rows(("s", ss), 1), sum(ss) + 1, 3)),
                                    np.zeros((_grown(("candidates",), 1), 15))])
        launches.append(_launch(crosses, ut, us, st, ss, poses, one, one, one, np.zeros(1), np.zeros(1), kind))
    jax.block_until_ready([res for started in launches for _, _, res in started])
    return len(shapes)


def _gathered(tables: list[tuple], rows: np.ndarray, size: int) -> np.ndarray:
    """The rows `rows` (ascending) of `tables` (one bucket's (vertices, normals, edges, centres) of
    several sets, counted one after the other) packed in one (size, vertices + normals + edges + 1,
    3) array, padded to `size` by repeating its first row. A launch takes only the pieces its
    pairs name: a round's whole tables were 14.5 MB a launch on average (docs/concepts/batched-checks.md), and
    every host array is copied again on its way to the device."""
    chunks, start = [], 0
    for table in tables:
        end = start + len(table[0])
        local = rows[np.searchsorted(rows, start):np.searchsorted(rows, end)] - start
        if len(local):
            chunks.append(np.concatenate([table[0][local], table[1][local], table[2][local],
                                          table[3][local][:, None]], axis=1))
        start = end
    packed = np.concatenate(chunks)
    return np.concatenate([packed, np.repeat(packed[:1], size - len(packed), 0)])


def intervals_many(jobs, kind: str = "sweep") -> list[np.ndarray]:
    """For each job (unit set, structure set, R, t, d, k, u, s, thr, thr_c): the (pairs, 6)
    intervals of unit piece u[i] of candidate k[i] (pose R, t; direction d) against structure piece
    s[i] (`_launch`; with kind 'still' their depths at the pose). One launch per group of pairs
    with the same piece buckets (and alignment) whatever job they come from: per side and bucket,
    the rows the pairs name, of every job's sets, in one table (`_gathered`); the tables and all
    candidates' poses go to the device in one call, every launch starts before the first result
    is waited for, and the results come back in one copy (`_results`)."""
    out = [np.empty((len(j[5]), WIDTH[kind])) for j in jobs]
    if not jobs:
        return out
    warm_up()
    # Bucket shapes (vertices, normals, edges) of every set, and where each set's table of a bucket
    # starts when the tables of that shape are counted one after the other.
    tables: dict[tuple, list] = {}
    offset: dict[tuple[int, tuple], int] = {}

    def place(the_set: PieceSet, side: str) -> None:
        for b, shape in enumerate(the_set.buckets):
            key = (id(the_set), side, shape)
            if key not in offset:
                rows = tables.setdefault((side, shape), [])
                offset[key] = sum(len(t[0]) for t in rows)
                rows.append(the_set.tables[b])

    for uset, sset, *_ in jobs:
        place(uset, "u")
        place(sset, "s")
    # Candidates of all jobs in one array; pairs labelled by their group.
    k_start = np.cumsum([0] + [len(j[2]) for j in jobs])
    kp = _grown(("candidates",), int(k_start[-1]))
    Rs, ts, ds = (np.concatenate([j[i] for j in jobs]) for i in (2, 3, 4))
    Rp, tp, dp = (np.concatenate([x, np.repeat(x[:1], kp - len(x), 0)]) for x in (Rs, ts, ds))
    shapes: dict[tuple, int] = {}
    per_job = []
    for n, (uset, sset, R, t, d, k, u, s, thr, thr_c) in enumerate(jobs):
        # Pairs of right prisms along one direction need no edge-edge axes (`piece_sets._prism_axes`).
        up = np.einsum("pij,pkj->pki", R[k], uset.prism[u])
        aligned = (np.abs(np.einsum("pai,pbi->pab", up, sset.prism[s])) > 1 - 1e-9).any(axis=(1, 2))
        ushape, sshape = uset.buckets, sset.buckets
        codes = np.array([shapes.setdefault((us, ss, al), len(shapes))
                          for us in ushape for ss in sshape for al in (False, True)], np.int64)
        group = codes[(uset.bucket_of[u] * len(sshape) + sset.bucket_of[s]) * 2 + aligned]
        uoff = np.array([offset[(id(uset), "u", sh)] for sh in ushape], np.int64)[uset.bucket_of[u]]
        soff = np.array([offset[(id(sset), "s", sh)] for sh in sshape], np.int64)[sset.bucket_of[s]]
        per_job.append((group, uset.local[u] + uoff, sset.local[s] + soff, k + k_start[n], thr, thr_c))
    groups = []
    for (us, ss, al), code in shapes.items():
        sel = [np.flatnonzero(g[0] == code) for g in per_job]
        if sum(len(x) for x in sel):
            groups.append((us, ss, al, sel, *(np.concatenate([pj[i][x] for pj, x in zip(per_job, sel)])
                                              for i in (1, 2, 3, 4, 5))))
    # Per side and bucket, the rows some pair names, in one table on the device.
    named: dict[tuple, list] = {}
    for us, ss, al, sel, gu, gs, *_ in groups:
        named.setdefault(("u", us), []).append(gu)
        named.setdefault(("s", ss), []).append(gs)
    rows = {key: np.unique(np.concatenate(x)) for key, x in named.items()}
    keys = list(rows)
    # The tables and the candidates' poses go to the device in one call.
    *tables_on, poses = _on_device([_gathered(tables[key], rows[key], _table_rows(key, len(rows[key])))
                                    for key in keys] + [np.concatenate([Rp.reshape(kp, 9), tp, dp], axis=1)])
    packed = dict(zip(keys, tables_on))
    launches = []
    for us, ss, al, sel, gu, gs, gk, gthr, gthc in groups:
        u_at, s_at = np.searchsorted(rows[("u", us)], gu), np.searchsorted(rows[("s", ss)], gs)
        launches.append(_launch(not al, packed[("u", us)], us, packed[("s", ss)], ss, poses, u_at, s_at, gk, gthr, gthc,
                                kind))
    # Every group is started before the first is waited for.
    for (_, _, _, sel, *_), res in zip(groups, _results(launches, kind)):
        at = 0
        for n, x in enumerate(sel):
            out[n][x] = res[at:at + len(x)]
            at += len(x)
    return out


def exact_intervals(a: Sequence[np.ndarray], b: Sequence[np.ndarray], d: np.ndarray, thr: np.ndarray) -> np.ndarray:
    """(n, 2): for convex point sets a[i], b[i] (world), the open interval of s where the depth of
    a[i] moved by -s d[i] into b[i] exceeds thr[i] >= 0 (empty: hi <= lo). For tests and checks."""
    n = len(a)
    ua = PieceSet.of_pieces([convex_piece(v, False, 0.0) for v in a], np.array([v.mean(0) for v in a]), np.arange(n), n)
    sb = PieceSet.of_pieces([convex_piece(v, False, 0.0) for v in b], np.array([v.mean(0) for v in b]), np.arange(n), n)
    idx = np.arange(n)
    R, t = np.repeat(np.eye(3)[None], n, 0), np.zeros((n, 3))
    (res,) = intervals_many([(ua, sb, R, t, np.asarray(d, float), idx, idx, idx, np.asarray(thr, float),
                              np.full(n, np.inf))])
    return res[:, :2]
