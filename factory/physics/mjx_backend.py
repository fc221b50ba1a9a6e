"""Stability rollouts in MuJoCo XLA: a whole batch of candidates in one vmapped, jitted call.

The scene is the fixed-capacity stability model of `factory.physics.stability` (one rigid body on
`n_feet` support points); mass, inertia, support points and start pose vary per candidate as
batched model fields and state. Batches are padded to a few bucket sizes, so a run compiles at
most once per bucket, never per step or per structure.

Two implementations of MJX run the same scene: "jax" (everywhere) and "warp" (MuJoCo Warp, on a
CUDA GPU with `warp-lang` installed: the `gpu` extra). On an H100 Warp ran 3-5x more rollouts per
second at batches of 256-4,096 (docs/physics.md): MJX's JAX solver launches many small kernels per
step and a small batch cannot fill the GPU between them. Warp's finite results gave the same
verdicts as JAX; its few non-finite ones are redone with JAX (`rollout_mjx`).
"""

from __future__ import annotations

import os
from functools import lru_cache

import numpy as np

from factory.physics.stability import (
    RigidObject, StabilityConfig, invweight0, movements_ldu, stability_model, stability_xml,
)

BUCKETS = (64, 256, 1024, 4096, 16384, 65536)
"""Batch sizes the rollout is compiled for; larger batches run in chunks of the largest."""

IMPLS = ("jax", "warp")
IMPL_ENV = "BRICK_FACTORY_MJX_IMPL"
"""Environment variable that picks the implementation (default: warp where it can run, else jax)."""

COMPILES: list[tuple[int, int, str]] = []
"""(bucket, feet, implementation) of every compile in this process, for reports and tests."""


@lru_cache(maxsize=1)
def _warp_runs() -> bool:
    try:
        import jax
        import warp  # noqa: F401
    except (ImportError, RuntimeError):
        return False
    return jax.default_backend() == "gpu"


def default_impl() -> str:
    """The MJX implementation rollouts use: `$BRICK_FACTORY_MJX_IMPL`, else "warp" where MuJoCo
    Warp can run (warp-lang installed, JAX on a CUDA GPU), else "jax"."""
    impl = os.environ.get(IMPL_ENV)
    if impl is None:
        return "warp" if _warp_runs() else "jax"
    if impl not in IMPLS:
        raise ValueError(f"{IMPL_ENV}={impl!r}: expected one of {', '.join(IMPLS)}")
    if impl == "warp" and not _warp_runs():
        raise RuntimeError(f"{IMPL_ENV}=warp needs warp-lang (pip install '.[gpu]') and JAX on a CUDA GPU")
    return impl


@lru_cache(maxsize=None)
def _rollout_fn(cfg: StabilityConfig, bucket: int, impl: str = "jax"):
    import jax
    import mujoco
    from mujoco import mjx

    COMPILES.append((bucket, cfg.n_feet, impl))
    if impl == "warp":
        # MuJoCo Warp refuses the midphase flag; its broadphase bounds each foot at run time anyway.
        model = mujoco.MjModel.from_xml_string(stability_xml(cfg).replace('<flag midphase="disable"/>', ""))
        mx = mjx.put_model(model, impl="warp")
        # Solver and line-search limits are reached by design (StabilityConfig); do not print per step.
        mx = mx.replace(opt=mx.opt.replace(_impl=mx.opt._impl.replace(warn_overflow=0)))
    else:
        model = stability_model(cfg)
        mx = mjx.put_model(model)
    feet_slice = slice(1, 1 + cfg.n_feet)

    def one(mass, inertia, iquat, invweight, feet, com):
        m = mx.replace(
            body_mass=mx.body_mass.at[1].set(mass),
            body_inertia=mx.body_inertia.at[1].set(inertia),
            body_iquat=mx.body_iquat.at[1].set(iquat),
            body_ipos=mx.body_ipos.at[1].set(0.0),
            body_invweight0=mx.body_invweight0.at[1].set(invweight),
            geom_pos=mx.geom_pos.at[feet_slice].set(feet),
        )
        if impl == "warp":
            # Contact capacity is shared by the whole batch; each object has at most n_feet, each
            # a pyramid of 4 constraint rows.
            data = mjx.make_data(model, impl="warp", naconmax=cfg.n_feet * bucket, njmax=4 * cfg.n_feet)
        else:
            data = mjx.make_data(m)
        qpos = data.qpos.at[:3].set(com).at[3:7].set(jax.numpy.array([1.0, 0.0, 0.0, 0.0]))
        data = data.replace(qpos=qpos)
        data, _ = jax.lax.scan(lambda d, _: (mjx.step(m, d), None), data, None, length=cfg.steps)
        return data.qpos

    return jax.jit(jax.vmap(one))


def rollout_mjx(objs: list[RigidObject], cfg: StabilityConfig, impl: str | None = None) -> np.ndarray:
    """Movement (LDU) of each object after `cfg.duration_s`, batched on the default JAX device
    (`impl`: "jax" or "warp"; default `default_impl()`)."""
    impl = impl or default_impl()
    if impl not in IMPLS:
        raise ValueError(f"unknown MJX implementation {impl!r}; expected one of {', '.join(IMPLS)}")
    out = np.empty(len(objs))
    start = 0
    while start < len(objs):
        chunk = objs[start : start + BUCKETS[-1]]
        bucket = next(b for b in BUCKETS if b >= len(chunk))
        n = len(chunk)
        pad = np.r_[np.arange(n), np.full(bucket - n, n - 1)]  # repeat the last object into the bucket
        fields = {k: np.array([getattr(o, k) for o in chunk]) for k in ("mass", "inertia", "iquat", "feet", "com", "corners")}
        fields["invweight"] = invweight0(fields["mass"], fields["inertia"])
        args = tuple(fields[k][pad] for k in ("mass", "inertia", "iquat", "invweight", "feet", "com"))
        qpos = np.asarray(_rollout_fn(cfg, bucket, impl)(*args))[:n]
        out[start : start + n] = movements_ldu(fields["corners"], fields["com"], qpos)
        start += n
    if impl == "warp":
        # MuJoCo Warp returned NaN for a few light objects (8 of 222 rollouts of a sampler object at
        # 6-9 parts, 3 g, inertia below 1e-6 kg m^2) that JAX and MuJoCo's C engine keep standing;
        # so a non-finite Warp result is rolled out again with JAX (docs/physics.md).
        redo = np.flatnonzero(~np.isfinite(out))
        if len(redo):
            out[redo] = rollout_mjx([objs[i] for i in redo], cfg, "jax")
    return out
