"""`settle` batched in MuJoCo XLA (MJX on JAX): many predicted placements released at once.

`settle_many(cases)` gives, per case (structure, part, pose, floor_y), what `settle.settle` gives,
with the simulation run by `mujoco.mjx` instead of `mujoco.mj_step`; everything else is the
reference's own code (`settle.Release`): the overlap check and snapping before simulating, then
after every `snap_every` steps, on the host, snapping (the checks judge each candidate once per
scene: the judge is shared) and the at-rest window, and at the end the outcome from the end pose
and the contacts MuJoCo C finds there (`mj_forward` on the scene's `MjModel` at the MJX end state).

Batching and compiles. Cases are grouped by scene: the same `Structure` and `Part` objects (by
identity) and floor. A scene's `MjModel` (`settle_model`) is put on the device once
(`mjx.put_model`) and its undecided cases run together: a batch of `mjx.Data` whose qpos holds the
predicted poses, `jax.vmap` over the batch of a `jax.lax.fori_loop` of `snap_every` `mjx.step`s,
one jitted call per chunk, the model passed as an argument. A case that stops (snapped, at rest)
keeps its end state and rides along idle until the batch's last case stops. The batch is padded to
a power of two (`BATCH_SIZES`), so a scene compiles at most once per batch size it meets; JAX's
jit cache is keyed by the model's static part, and MJX makes a scene's collision functions static
per distinct pair of meshes (`collision_driver._geom_groups`: one convex-convex function per
(part mesh, structure mesh) pair), so two scenes share a compile only when they have the same geoms
and meshes (the same structure and part up to placement). Bucketing across scenes would need every
convex piece padded to a few fixed vertex counts with its vertices as data rather than as the
model's static mesh, and the structure's geoms padded to a fixed count: not done. With
`jax_cache.enable()` the compiles persist across processes (a scene met again loads its kernel).

On JAX's CPU backend a compile is slow (about 1-4 minutes for a 3-brick scene: the convex
collision functions unrolled per mesh pair); `settle_many` is for GPUs, and for the parity
measurement (`pipelines.bench_settle`) on the CPU.

MJX support: the scene is mesh geoms (convex hulls of the collision pieces, `margin` 0) on fixed
bodies, a plane and one free body, elliptic cones, condim 3, the Newton solver: all supported by
MJX (JAX implementation) of MuJoCo 3.3+. A scene `mjx.put_model` refuses (`NotImplementedError`)
falls back to MuJoCo C (`settle.settle`), counted in `MjxStats.fallbacks`. MJX computes in float32
(MuJoCo C in float64) and its convex collision (GJK/EPA, up to 4 contacts per mesh pair) is not
MuJoCo C's (libccd / MuJoCo's own convex collider), so trajectories differ slightly; how often the outcomes agree is what `pipelines.bench_settle`
measures (run so far on 2 simulated cases only: both agreed).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from functools import cache

import mujoco
import numpy as np

from factory.physics.settle import (Release, SettleConfig, Settled, _Judge, _pose_of, _touched, default_floor_y,
                                    settle, settle_model)
from factory.pose import Pose

BATCH_SIZES = tuple(2 ** k for k in range(13))
"""Batch sizes a scene's cases are padded to (the least that holds them; larger batches split)."""


@dataclass
class MjxStats:
    """What `settle_many` did (filled in when passed)."""

    scenes: int = 0
    """Scenes simulated with MJX."""
    simulated: int = 0
    """Cases simulated with MJX (the others were decided before simulating or fell back)."""
    fallbacks: int = 0
    """Cases run on MuJoCo C because MJX refused their scene."""
    compiles: int = 0
    """Chunk functions compiled (new entries in the jit cache)."""
    compile_s: float = 0.0
    """Seconds of the first call of each new (scene, batch size): compiling, mostly."""
    run_s: float = 0.0
    """Seconds of the other chunk calls."""
    refused: list[str] = field(default_factory=list)
    """Why MJX refused each scene it refused."""


def _bucket(n: int) -> int:
    return next(b for b in BATCH_SIZES if b >= n)


@cache
def _chunk_fn(steps: int):
    """The jitted chunk: `steps` `mjx.step`s of every member of a batch of `mjx.Data`."""
    import jax
    from mujoco import mjx  # lazy: mujoco.mjx imports JAX, an optional extra

    def chunk(m, d):
        return jax.vmap(lambda one: jax.lax.fori_loop(0, steps, lambda _, x: mjx.step(m, x), one))(d)

    return jax.jit(chunk)


def _device(backend: str | None):
    import jax

    return jax.devices(backend)[0] if backend else jax.devices()[0]


def settle_many(cases, config: SettleConfig = SettleConfig(), backend: str | None = None,
                stats: MjxStats | None = None) -> list[Settled]:
    """`settle` of every case (structure, part, pose, floor_y; floor_y None for the structure's
    lowest point), the simulations batched in MJX per scene on JAX's `backend` (its default when
    None). Results in the cases' order."""
    stats = stats if stats is not None else MjxStats()
    out: list[Settled | None] = [None] * len(cases)
    groups: dict[tuple, list[int]] = {}
    floors = []
    for i, (structure, part, pose, floor_y) in enumerate(cases):
        floor = default_floor_y(structure, part, pose) if floor_y is None else float(floor_y)
        floors.append(floor)
        groups.setdefault((id(structure), id(part), floor), []).append(i)
    for (_, _, floor), idx in groups.items():
        structure, part = cases[idx[0]][0], cases[idx[0]][1]
        judge = _Judge(structure, part, floor, config)
        releases = {i: Release(structure, part, cases[i][2], floor, config, judge) for i in idx}
        pending = []
        for i, r in releases.items():
            if r.result is not None:
                out[i] = r.result
            else:
                pending.append(i)
        if not pending:
            continue
        scene = settle_model(structure, part, floor, config)
        try:
            from mujoco import mjx  # lazy: mujoco.mjx imports JAX, an optional extra

            model = mjx.put_model(scene.model, device=_device(backend))
        except NotImplementedError as e:
            stats.refused.append(str(e))
            stats.fallbacks += len(pending)
            for i in pending:
                out[i] = settle(structure, part, cases[i][2], floor, config)
            continue
        stats.scenes += 1
        big = BATCH_SIZES[-1]
        for start in range(0, len(pending), big):
            part_idx = pending[start:start + big]
            ends = _simulate(model, scene, [releases[i] for i in part_idx], config, backend, stats)
            for i, settled in zip(part_idx, ends):
                out[i] = settled
    return out  # type: ignore[return-value]


def _simulate(model, scene, releases: list[Release], config: SettleConfig, backend: str | None,
              stats: MjxStats) -> list[Settled]:
    """One scene's batch of undecided releases, simulated in MJX with the host's rules per chunk."""
    import jax
    import jax.numpy as jnp
    from mujoco import mjx  # lazy: mujoco.mjx imports JAX, an optional extra

    n = len(releases)
    size = _bucket(n)
    qpos = np.zeros((size, 7))
    for k in range(size):
        pos, quat = releases[min(k, n - 1)].pose.to_mujoco_quat()
        qpos[k, :3], qpos[k, 3:7] = pos, quat
    one = mjx.make_data(model, device=_device(backend))
    data = jax.vmap(lambda q: one.replace(qpos=q))(jnp.asarray(qpos, one.qpos.dtype))
    # Strong types throughout, as the chunk's output has them: else the second call compiles again.
    data = jax.tree_util.tree_map(lambda x: jnp.array(x, dtype=x.dtype) if hasattr(x, "dtype") else x, data)
    stats.simulated += n
    steps = int(round(config.seconds / config.timestep))
    body = scene.part_body
    active = list(range(n))
    end_qpos = np.zeros((n, 7))
    stopped = np.zeros(n, np.int64)
    done = 0
    while done < steps and active:
        k = min(config.snap_every, steps - done)
        fn = _chunk_fn(k)
        before = fn._cache_size()
        t0 = time.perf_counter()
        data = fn(model, data)
        xpos, xmat, q = (np.asarray(a, np.float64) for a in (data.xpos[:, body], data.xmat[:, body], data.qpos))
        dt = time.perf_counter() - t0
        if fn._cache_size() > before:
            stats.compiles += 1
            stats.compile_s += dt
        else:
            stats.run_s += dt
        done += k
        still = []
        for i in active:
            end_qpos[i], stopped[i] = q[i], done
            now = Pose.from_mujoco(xpos[i], xmat[i].reshape(3, 3))
            if not releases[i].after_chunk(now, done):
                still.append(i)
        active = still
    out = []
    host = mujoco.MjData(scene.model)
    for i, r in enumerate(releases):
        if r.result is not None:
            out.append(r.result)
            continue
        host.qpos[:] = end_qpos[i]
        host.qvel[:] = 0.0
        mujoco.mj_forward(scene.model, host)
        out.append(r.finish(_pose_of(host, body), _touched(host, scene), int(stopped[i])))
    return out


__all__ = ["BATCH_SIZES", "MjxStats", "settle_many"]
