"""The filters of many runs stepped together (systems/estimators/marker_ekf/stack.py, by
`batch_runs`) give each run's `batch_run` (each filter's own `step`) to 1e-9, gated and reset
measurements included."""

import numpy as np
import pytest

from diagrams import marker_batch
from diagrams.marker_batch import batch_run, batch_runs
from diagrams.runner import load_scenario

SEEDS = [0, 1, 7, 12]


def _with_outliers(stream):
    """`_stream` with outliers: seed 1 has marker 2 5 m off at steps 20-24 (gated alone), seed 7 every
    marker 5 m off at steps 30-44 (fully gated steps: a reset after reset_after_rejected_steps)."""
    def outliers(config, t, truth, seed):
        p_CM, q_CM = stream(config, t, truth, seed)
        p_CM = p_CM.copy()
        if seed == 1:
            p_CM[20:25, 2] += 5.0
        if seed == 7:
            p_CM[30:45] += 5.0
        return p_CM, q_CM
    return outliers


@pytest.mark.parametrize("speed, latency", [(12, 1), (3, 0), (6, 2)])
def test_stacked_runs_give_each_runs_batch_run(monkeypatch, speed, latency):
    monkeypatch.setattr(marker_batch, "_stream", _with_outliers(marker_batch._stream))
    _, s = load_scenario("gv-marker-ekf", overrides=[f"vehicle.speed={speed}", f"estimation.latency_periods={latency}"])
    stacked = batch_runs(s, SEEDS, 3.0)
    for seed, run in zip(SEEDS, stacked):
        single = batch_run(s.__class__(**{**s.__dict__, "seed": seed}), 3.0)
        np.testing.assert_array_equal(run.measurements, single.measurements)
        assert set(run.estimates) == set(single.estimates) == {"paper_ekf", "ct_ekf"}
        for name in single.estimates:
            np.testing.assert_allclose(run.estimates[name], single.estimates[name], rtol=0, atol=1e-9)
            np.testing.assert_allclose(run.p_WM[name], single.p_WM[name], rtol=0, atol=1e-9)
            assert run.stats[name] == single.stats[name]
            if seed == 1:
                assert 0 < single.stats[name]["gated"] and single.stats[name]["resets"] == 0
            if seed == 7:
                assert single.stats[name]["resets"] >= 1
