"""Stability rollouts in MuJoCo XLA: a whole batch of candidates in one vmapped, jitted call.

The scene is the fixed-capacity stability model of `factory.physics.stability` (one rigid body on
`n_feet` support points); mass, inertia, support points and start pose vary per candidate as
batched model fields and state. Batches are padded to a few bucket sizes, so a run compiles at
most once per bucket, never per step or per structure.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from factory.physics.stability import RigidObject, StabilityConfig, movements_ldu, stability_model

BUCKETS = (64, 256, 1024, 4096, 16384, 65536)
"""Batch sizes the rollout is compiled for; larger batches run in chunks of the largest."""

COMPILES: list[tuple[int, int]] = []
"""(bucket, feet) of every compile in this process, for reports and tests."""


@lru_cache(maxsize=None)
def _rollout_fn(cfg: StabilityConfig, bucket: int):
    import jax
    from mujoco import mjx

    COMPILES.append((bucket, cfg.n_feet))
    mx = mjx.put_model(stability_model(cfg))
    feet_slice = slice(1, 1 + cfg.n_feet)

    def one(mass, inertia, iquat, feet, com):
        model = mx.replace(
            body_mass=mx.body_mass.at[1].set(mass),
            body_inertia=mx.body_inertia.at[1].set(inertia),
            body_iquat=mx.body_iquat.at[1].set(iquat),
            body_ipos=mx.body_ipos.at[1].set(0.0),
            geom_pos=mx.geom_pos.at[feet_slice].set(feet),
        )
        data = mjx.make_data(model)
        qpos = data.qpos.at[:3].set(com).at[3:7].set(jax.numpy.array([1.0, 0.0, 0.0, 0.0]))
        data = data.replace(qpos=qpos)
        data = jax.lax.fori_loop(0, cfg.steps, lambda _, d: mjx.step(model, d), data)
        return data.qpos

    return jax.jit(jax.vmap(one))


def rollout_mjx(objs: list[RigidObject], cfg: StabilityConfig) -> np.ndarray:
    """Movement (LDU) of each object after `cfg.duration_s`, batched on the default JAX device."""
    out = np.empty(len(objs))
    start = 0
    while start < len(objs):
        chunk = objs[start : start + BUCKETS[-1]]
        bucket = next(b for b in BUCKETS if b >= len(chunk))
        n = len(chunk)
        pad = np.r_[np.arange(n), np.full(bucket - n, n - 1)]  # repeat the last object into the bucket
        fields = {k: np.array([getattr(o, k) for o in chunk]) for k in ("mass", "inertia", "iquat", "feet", "com", "corners")}
        args = tuple(fields[k][pad] for k in ("mass", "inertia", "iquat", "feet", "com"))
        qpos = np.asarray(_rollout_fn(cfg, bucket)(*args))[:n]
        out[start : start + n] = movements_ldu(fields["corners"], fields["com"], qpos)
        start += n
    return out
