"""Load programs started from a smaller solved one (`solve_from`, `Solved`, `ProgramKeys`,
`start_basis`).

A candidate's program is the structure's program plus its own columns and rows, and the
structure's program is that of its last part when it was a candidate. Started from that
program's final basis (its columns and rows found again by what they are: the parts, stud bases
and support points), HiGHS's primal simplex takes a few iterations where a start from nothing
takes hundreds: on the 135 structures of objects 0 and 1 of the default config (seed 0), each
started from the one before, 1,494 against 20,495 iterations and 1.31 s against 3.66 s
(`solve_from`, its keys and start included, against a solve from nothing), objectives within
6.3e-15 (this repository's 2-core CPU, shared with another job).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from factory.physics.check_state import current
from factory.physics.load_model import LoadConfig, LoadModel
from factory.physics.load_program import PER_CONNECTION, PER_LINK, PER_SUPPORT, capacity_rows, to_lp
from factory.physics.lp import BASIS_STATUS, Basis, LPResult, solve_highs_from

WARM_START = True
"""Whether the reference starts a candidate's program from the structure's solved one (`check_loads.py`);
off, every program starts from nothing (as tests compare)."""

# Programs solved by `solve_from` (started from a basis, from nothing, their simplex iterations)
# are counted in the current checker's `CheckState.warm_counts`, read with `Checker.counters()`.

_ROUND = 1e4  # keys of stud bases and support points, to 1e-4 LDU


def _point_keys(parts: np.ndarray, *rest) -> list[tuple]:
    """One key per row: the part numbers as they are, the points rounded to `1 / _ROUND` LDU."""
    if not len(parts):
        return []
    cols = [np.asarray(parts, np.int64)[:, None]]
    for r in rest:
        r = np.asarray(r)
        cols.append(np.asarray(r, np.int64).reshape(len(parts), -1) if r.dtype.kind in "iu"
                    else np.round(r.reshape(len(parts), -1) * _ROUND).astype(np.int64))
    return [tuple(row) for row in np.concatenate(cols, axis=1).tolist()]


@dataclass(frozen=True, eq=False)
class ProgramKeys:
    """What names the columns and rows of a model's program (`to_lp`), by the caller's part
    numbers: each connection (its two parts and stud base), support point (its part and position)
    and link (its two parts and point), and each body's part."""

    conn: list
    ground: list
    link: list
    parts: list

    @classmethod
    def of(cls, model: LoadModel) -> "ProgramKeys":
        p = model.parts
        return cls(_point_keys(p[model.conn_a], p[model.conn_b], model.conn_pos),
                   _point_keys(p[model.ground_body], model.ground_pos),
                   _point_keys(p[model.link_a], p[model.link_b], model.link_pos), p.tolist())

    @cached_property
    def distinct(self) -> bool:
        """Whether no two connections, support points or links share a key (else no start maps)."""
        return all(len(set(k)) == len(k) for k in (self.conn, self.ground, self.link))

    @cached_property
    def index(self) -> tuple[dict, dict, dict, dict]:
        """Each connection's, support point's, link's and body's position by its key."""
        return tuple({k: i for i, k in enumerate(ks)} for ks in (self.conn, self.ground, self.link, self.parts))


@dataclass(frozen=True, eq=False)
class Solved:
    """A load program's final basis, with what names its columns and rows, so that a larger
    program can start from it (`start_basis`)."""

    basis: Basis
    keys: ProgramKeys

    @classmethod
    def of(cls, model: LoadModel, basis: Basis) -> "Solved":
        return cls(basis, ProgramKeys.of(model))


def start_basis(solved: Solved, model: LoadModel, cfg: LoadConfig = LoadConfig(),
                keys: ProgramKeys | None = None) -> Basis | None:
    """A basis of `model`'s program (`to_lp`; `keys` its `ProgramKeys` when known) from a solved
    smaller one whose every body, connection, support point and link `model` holds too: those
    keep their statuses, a new force is nonbasic (free ones at zero, the ground's at its bound 0)
    and a new row's slack basic, so the basic columns and slacks stay as many as the rows. None
    where `model` lacks one of `solved`'s things or two things of either share a key."""
    keys = keys or ProgramKeys.of(model)
    if BASIS_STATUS is None or not solved.keys.distinct or not keys.distinct:
        return None
    if np.isfinite(model.link_cap).any() or len(solved.basis.rows) != (
            len(capacity_rows(cfg)) * len(solved.keys.conn) + 6 * len(solved.keys.parts)):
        return None  # a joint's capacity rows (`load_program.link_rows`) are not mapped: started cold
    basic, zero, lower = BASIS_STATUS.kBasic, BASIS_STATUS.kZero, BASIS_STATUS.kLower
    conn, ground, link, body = solved.keys.index
    old_cols, old_rows = solved.basis.cols, solved.basis.rows
    conn_src = [conn.get(k) for k in keys.conn]
    ground_src = [ground.get(k) for k in keys.ground]
    link_src = [link.get(k) for k in keys.link]
    body_src = [body.get(k) for k in keys.parts]
    found = sum(o is not None for src in (conn_src, ground_src, link_src, body_src) for o in src)
    if found != len(conn) + len(ground) + len(link) + len(body):
        return None

    def columns(src, first: int, width: int, new) -> list:
        out = []
        for o in src:
            out += [new] * width if o is None else old_cols[first + width * o:first + width * (o + 1)]
        return out

    g0 = 1 + PER_CONNECTION * len(conn)
    cols = [old_cols[0], *columns(conn_src, 1, PER_CONNECTION, zero), *columns(ground_src, g0, PER_SUPPORT, lower),
            *columns(link_src, g0 + PER_SUPPORT * len(ground), PER_LINK, zero)]
    kinds = len(capacity_rows(cfg))
    rows = [basic if o is None else old_rows[j * len(conn) + o] for j in range(kinds) for o in conn_src]
    e0 = kinds * len(conn)
    for o in body_src:
        rows += [basic] * 6 if o is None else old_rows[e0 + 6 * o:e0 + 6 * (o + 1)]
    return Basis(cols, rows)


def solve_from(model: LoadModel, cfg: LoadConfig = LoadConfig(),
               start: Solved | None = None) -> tuple[LPResult, Solved | None]:
    """The model's load program with HiGHS, started from `start` (`start_basis`) where one maps,
    with its own final basis for the programs after it. The objective is HiGHS's optimum either
    way; a started solve may end at another optimal vertex of a degenerate program."""
    keys = ProgramKeys.of(model)
    basis = start_basis(start, model, cfg, keys) if start is not None and WARM_START else None
    result, final, iterations = solve_highs_from(to_lp(model, cfg), basis)
    counts = current().warm_counts
    counts["started" if basis is not None else "cold"] += 1
    counts["iterations"] += max(iterations, 0)
    return result, None if final is None else Solved(final, keys)
