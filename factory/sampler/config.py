"""The sampler's typed configuration, validated when built (and against the library by `Sampler`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping, Sequence, Union

from factory.config import ConfigError, config_from_dict, config_to_dict
from factory.prior.choose import embedded_choice
from factory.prior.prior import load_prior
from factory.physics.check import BACKENDS, CheckConfig, backend_arg, backend_name


MAX_STEPS = 1000
"""Most parts an object may be grown to: 11x the default's 90, so a mistyped length fails at once
instead of growing (and holding its structure's load programs) for hours."""


class SamplerConfigError(ConfigError):
    """A sampler setting is invalid; the message names the setting and the valid choices."""


WeightsLike = Union[Mapping, Sequence]
"""`{"3001": 2.0, ...}`, `[("3001", 2.0), ...]` or `["3001", ...]` (weight 1 each)."""

_DEFAULT_PRIOR = load_prior()
DEFAULT_PRIOR_LABEL = _DEFAULT_PRIOR.label()
"""The shipped usage prior (`factory.prior.DEFAULT_PRIOR`) as a record names it."""

DEFAULT_PARTS, DEFAULT_COLOURS = embedded_choice(_DEFAULT_PRIOR)
"""The parts and colours of the shipped usage prior that the embedded library holds, with the
prior's weights (`factory.prior.choose.embedded_choice`): what objects are grown from without a
library. With a library, `factory.prior.configure` draws from the parts of the library instead."""


def _weights(name: str, value: WeightsLike, key) -> tuple[tuple, ...]:
    items = list(value.items()) if isinstance(value, Mapping) else [
        tuple(v) if isinstance(v, (tuple, list)) else (v, 1.0) for v in value
    ]
    if not items:
        raise SamplerConfigError(f"{name}: the set is empty; give at least one entry with a positive weight")
    out, seen = [], set()
    for item in items:
        if len(item) != 2:
            raise SamplerConfigError(f"{name}: expected (name, weight) pairs, got {item!r}")
        k, w = item
        try:
            k = key(k)
        except (TypeError, ValueError):
            raise SamplerConfigError(f"{name}: invalid entry {item[0]!r}") from None
        try:
            w = float(w)
        except (TypeError, ValueError):
            raise SamplerConfigError(f"{name}: weight of {k!r} must be a number, got {item[1]!r}") from None
        if not (math.isfinite(w) and w > 0):
            raise SamplerConfigError(f"{name}: weight of {k!r} must be a finite number > 0, got {w}")
        if k in seen:
            raise SamplerConfigError(f"{name}: {k!r} is listed twice")
        seen.add(k)
        out.append((k, w))
    if not math.isfinite(sum(w for _, w in out)):  # draws divide by the sum
        raise SamplerConfigError(f"{name}: the weights sum to more than a float holds; give smaller weights "
                                 "(only their ratios matter)")
    return tuple(out)


def part_key(name) -> str:
    """A part name as the config keeps it: lower case, no `.dat`, '/' separators."""
    s = str(name).strip().replace("\\", "/").lower()
    if not s:
        raise ValueError("empty part name")
    return s[:-4] if s.endswith(".dat") else s


@dataclass(frozen=True)
class SamplerConfig:
    """How objects are grown. Object `i` is a function of this config, `i` and the library only."""

    parts: tuple[tuple[str, float], ...] = DEFAULT_PARTS
    """Part set with draw weights: `(name, weight)` pairs (a mapping or a list of names is
    accepted). Names as in the library (`3001` or `3001.dat`); checked against it by `Sampler`."""
    colours: tuple[tuple[int, float], ...] = DEFAULT_COLOURS
    """Colour set with draw weights: `(LDraw colour code, weight)` pairs; codes are checked against
    the library's `LDConfig.ldr` by `Sampler` (16 and 24 are not colours of their own)."""
    min_steps: int = 20
    """Fewest parts of an object: each object's target length is drawn uniformly in
    [min_steps, max_steps]. An object that gets stuck before `min_steps` is grown again from a
    stream of its own (`sampler.RESTARTS` times at most, the longest kept); one stuck later ends
    early (`end_reason` says why)."""
    max_steps: int = 90
    """Most parts of an object."""
    density_weight: float = 1.0
    """Weight of the density reward in the choice among surviving candidates (0: uniform choice,
    the reward off)."""
    temperature: float = 0.3
    """Softmax temperature. A surviving candidate's logit is
    `density_weight * n * ln(density after placing it) / temperature`, n = parts after placement:
    one part changes the density by about 1/n relatively, so the factor n keeps the logits' spread
    the same at every object size (the choice goes by density^(w n / T)). Against a candidate
    inside the current hull, one that grows the hull by h is exp(w h / (T H/n)) times less likely,
    H/n being the hull volume per part so far: at the defaults, growing it by one part's share
    makes a candidate e^(1/0.3) ~ 28x less likely."""
    candidates_per_step: int = field(default=64, metadata={"aliases": ("--candidates",)})
    """Feasible attachments checked per part draw: a random subset (drawn with the object's RNG)
    when there are more; all of them otherwise."""
    check_batch: int | None = None
    """Most candidates in one checker request: the next one in softmax-key order and, after it,
    the next unasked ones by their keys' bounds. Changes only the cost, never the object: the
    chosen placement, the rejection counts and `checked` stop at the first survivor (see
    `Sampler`). None (the default) takes `default_check_batch(backend, candidates_per_step)`: 1
    on the CPU, where every check past the first survivor is wasted (6 objects grew in 28.7 s at 1
    against 36.1 s at 8, the same files); `JAX_CHECK_BATCH` for the 'jax' backend."""
    judge_first: int | None = None
    """Of a checker request's candidates that pass connection, collision and clutch, how many (in
    decreasing order of their keys' bounds) are swept and load-judged in that request; the sweep
    and the loads are the dearest checks, and only the first survivor in key order is used. A later
    request judges the next ones when none of these is it. Changes only the cost, never the object
    (like `check_batch`). None (the default) takes `default_judge_first(check_batch)`: 4 when a
    request holds more candidates than that (the 'jax' backend), else all."""
    max_redraws: int = 8
    """Part draws after the first in one step when no candidate of the drawn part survives; then
    the object ends (`end_reason` 'stuck')."""
    backend: str = field(default="cpu", metadata={"choices": BACKENDS, "flag": "check-backend",
                                                         "type": backend_arg})
    """How the physics checks run: 'cpu' (MuJoCo's C collision and NumPy/SciPy on the CPU, one
    candidate at a time) or 'jax' (this project's batched JAX kernels, on a GPU where there is
    one). Both grow the same objects, so it is not part of a dataset's identity. The former names
    'mujoco' and 'mjx' are accepted with a FutureWarning."""
    seed: int = 0
    """Seed of the whole run: object i draws from `np.random.default_rng([seed, i])` only."""
    prior: str = field(default=DEFAULT_PRIOR_LABEL, metadata={"flag": False})
    """The usage prior `parts` and `colours` were drawn from, as `name sha256:...` ('' when the
    user gave both): a record for the data card; the commands set it with `--prior FILE`."""
    check: CheckConfig = field(default_factory=CheckConfig)
    """Thresholds of the physics checks (written by `to_dict` only when they differ from the
    defaults, so the hashes of datasets built before they were recorded stay the same)."""

    def __post_init__(self):
        try:
            # stacklevel 4: backend_name, here, the dataclass's __init__, the caller.
            object.__setattr__(self, "backend", backend_name(self.backend, stacklevel=3))
        except ValueError as e:
            raise SamplerConfigError(str(e)) from None
        object.__setattr__(self, "parts", _weights("parts", self.parts, part_key))
        if self.check_batch is None and isinstance(self.candidates_per_step, int):
            object.__setattr__(self, "check_batch", default_check_batch(self.backend, self.candidates_per_step))
        object.__setattr__(self, "colours", _weights("colours", self.colours, _colour_key))
        if self.judge_first is None and isinstance(self.check_batch, int):
            object.__setattr__(self, "judge_first", default_judge_first(self.check_batch))
        for name in ("min_steps", "max_steps", "candidates_per_step", "check_batch", "judge_first", "max_redraws",
                     "seed"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int):
                raise SamplerConfigError(f"{name} must be an integer, got {v!r}")
        if self.min_steps < 1:
            raise SamplerConfigError(f"min_steps must be >= 1, got {self.min_steps}")
        if self.max_steps < self.min_steps:
            raise SamplerConfigError(f"max_steps ({self.max_steps}) must be >= min_steps ({self.min_steps})")
        if self.candidates_per_step < 1:
            raise SamplerConfigError(f"candidates_per_step must be >= 1, got {self.candidates_per_step}")
        if self.check_batch < 1:
            raise SamplerConfigError(f"check_batch must be >= 1, got {self.check_batch}")
        if self.judge_first < 1:
            raise SamplerConfigError(f"judge_first must be >= 1, got {self.judge_first}")
        if self.max_redraws < 0:
            raise SamplerConfigError(f"max_redraws must be >= 0, got {self.max_redraws}")
        if not 0 <= self.seed < 2 ** 63:
            raise SamplerConfigError(f"seed must be in 0..2**63-1 (it is stored as int64), got {self.seed}")
        if self.max_steps > MAX_STEPS:
            raise SamplerConfigError(f"max_steps must be <= {MAX_STEPS}, got {self.max_steps}")
        if not (math.isfinite(self.density_weight) and self.density_weight >= 0):
            raise SamplerConfigError(f"density_weight must be a finite number >= 0, got {self.density_weight}")
        if not (math.isfinite(self.temperature) and self.temperature > 0):
            raise SamplerConfigError(f"temperature must be a finite number > 0, got {self.temperature}")

    def to_dict(self) -> dict:
        """The settings as JSON values (`factory.config`); parts and colours as ordered
        [name, weight] lists, since their order drives the draws."""
        out = config_to_dict(self)
        if self.check == CheckConfig():
            del out["check"]
        # A cost setting added later: left out at its default, so earlier datasets' hashes stay.
        if self.judge_first == default_judge_first(self.check_batch):
            del out["judge_first"]
        if not self.prior:  # parts and colours given by the user, as every config before priors
            del out["prior"]
        return out

    @classmethod
    def from_dict(cls, data: dict) -> "SamplerConfig":
        """The inverse of `to_dict`; unknown keys are refused, naming the valid ones. A record
        without `prior` has none (parts and colours given, as every record before priors)."""
        return config_from_dict(cls, {"prior": "", **data} if isinstance(data, dict) else data, SamplerConfigError)


RUN_SETTINGS = ("backend", "check_batch", "judge_first")
"""`SamplerConfig` fields that change how the physics checks run (where, and how many candidates
one request holds), never an object: not part of a dataset's identity (`DatasetConfig.to_json`
leaves them out from schema version 2)."""


JAX_CHECK_BATCH = 16
"""`check_batch` of the batched 'jax' checks. The walk reaches its first survivor after about 12
candidates (30-part objects), so asking all 64 of a draw at once checked 29,380 candidates where
16 at a time checked 11,958 (16 objects, one process): 20-22 % less host time on a 2-core CPU, and
on one H100 (16 processes, 256 objects) 182.6 steps/s against 174.7 at 64 (docs/results.md)."""


def default_check_batch(backend: str, candidates_per_step: int) -> int:
    """`check_batch` for a checker backend: 1 for 'cpu', one candidate at a time (no check past the first
    survivor), `JAX_CHECK_BATCH` (at most a draw's candidates) for the batched 'jax' checks."""
    return min(JAX_CHECK_BATCH, candidates_per_step) if backend_name(backend) == "jax" else 1


JUDGE_FIRST = 4
"""`judge_first` where a request holds more candidates: about half the candidates that pass the
clutch rule pass the sweep and the loads too (30-brick structures, docs/concepts/physics.md), so 4 of them
hold the first survivor in most requests. Growing 30-part objects in 16 processes on an H100, 4
was faster than 2 and 1 (docs/results.md): each further request is another round of launches."""


def default_judge_first(check_batch: int) -> int:
    """`judge_first` for a `check_batch`: `JUDGE_FIRST`, or the whole batch when it is no larger."""
    return min(JUDGE_FIRST, check_batch)


def _colour_key(code) -> int:
    if isinstance(code, bool):
        raise ValueError(code)
    if isinstance(code, str):
        return int(code.strip(), 0)
    if isinstance(code, float) and not code.is_integer():
        raise ValueError(code)
    return int(code)
