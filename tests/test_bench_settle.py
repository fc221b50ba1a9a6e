"""`pipelines.bench_settle --throughput`: the same predictions settled over one or two worker
processes give the reference's outcomes, and MuJoCo C's time is split into its stepping and the
rest."""

from __future__ import annotations

import pytest

from factory.physics.settle import settle_all
from pipelines.bench_settle import cases, throughput

pytestmark = pytest.mark.usefixtures("isolated_cache")


def test_cpu_throughput_over_workers_gives_the_reference_outcomes_and_the_step_share():
    cs = cases(16, 8, seed=2)
    want = [r.outcome for r in settle_all([(c["structure"], c["part"], c["pose"], c["floor_y"]) for c in cs])]
    one, two = throughput(cs, "cpu", 1), throughput(cs, "cpu", 2)
    assert one["per_case"] == two["per_case"] == want
    assert one["outcomes_sha256"] == two["outcomes_sha256"]
    for got in (one, two):
        assert got["predictions"] == 16 and got["simulated"] == one["simulated"] > 0
        assert 0.0 < got["cpu"]["step_s"] < got["cpu"]["total_s"]
        assert 0.0 < got["cpu"]["step_share"] < 1.0
