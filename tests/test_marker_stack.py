"""The filters of many runs stepped together (systems/estimators/marker_ekf/stack.py, by
`batch_runs`) give each run's `batch_run` (each filter's own `step`) to 1e-9, gated and reset
measurements included."""

import numpy as np
import pytest

from diagrams import marker_batch
from diagrams.marker_batch import batch_run, batch_runs
from diagrams.runner import load_scenario
from systems.config import ConfigError
from systems.estimators.marker_ekf import ConstantTurnEkf
from systems.estimators.marker_ekf.engine import FilterStats
from systems.estimators.marker_ekf.stack import run_stack
from systems.perception.markers import MarkerMeasurement
from systems.quaternion import drake_to_paper
from tests.test_marker_ekf import LAYOUT, TS, circle, make, measure, straight, uav_over

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


def _one_run(steps: int, off_steps=(), truth=straight(6.0)):
    """A constant-turn filter and one run's stream on `truth` (test_marker_ekf's; default a straight drive) at TS:
    the steps' times, UAV poses, cameras, and every marker's p_CM (1, N, 5, 3), q_CM (1, N, 5, 4), every marker
    5 m off at `off_steps`."""
    marker_filter, rng = make(ConstantTurnEkf), np.random.default_rng(0)
    t = np.arange(steps) * TS
    X_WB = [uav_over(truth(tk), tk) for tk in t]
    frames = [measure(truth, tk, rng) for tk in t]
    p_CM = np.array([[m.p_CM for m in frame] for frame in frames])[None]
    q_CM = np.array([[m.q_CM for m in frame] for frame in frames])[None]
    p_CM[0, list(off_steps)] += 5.0
    cameras = marker_filter.camera(np.array([X.translation() for X in X_WB]),
                                   np.array([drake_to_paper(X.rotation()) for X in X_WB]))
    return marker_filter, t, X_WB, cameras, p_CM, q_CM


def _stepped_records(t, X_WB, p_CM, q_CM):
    """A constant-turn filter stepped on one run's stream (`_one_run`'s, on time): its record() at every step,
    and the filter."""
    stepped = make(ConstantTurnEkf)
    records = []
    for k, tk in enumerate(t):
        frame = [MarkerMeasurement(tk, i, p, q) for i, p, q in zip(LAYOUT.ids, p_CM[0, k], q_CM[0, k])]
        stepped.step(tk, X_WB[k], frame)
        records.append(stepped.record())
    return records, stepped


def test_gated_steps_that_alternate_with_fused_ones_never_reset_the_stack():
    """Every marker 5 m off at every other step from 20 to 58: 20 fully gated steps, never two in a row, so no
    run of reset_after_rejected_steps (10) and no restart; the stack gives each filter step's stats and
    records, as MarkerFilter.step does."""
    off = range(20, 60, 2)
    marker_filter, t, X_WB, cameras, p_CM, q_CM = _one_run(80, off)
    stack = run_stack(marker_filter, t, cameras, p_CM, q_CM, 0)
    records, stepped = _stepped_records(t, X_WB, p_CM, q_CM)
    for k, (x, variance, last) in enumerate(records):
        np.testing.assert_allclose(stack.x[0, k], x, rtol=0, atol=1e-9)
        assert stack.position_variance[0, k] == pytest.approx(variance, abs=1e-12)
        assert stack.last_measurement_s[0, k] == last
    assert stack.stats[0] == stepped.stats == FilterStats(accepted=5 * (80 - len(off)), gated=5 * len(off))


def test_a_fully_gated_step_keeps_its_prior_yaw_unwrapped_as_the_filter_does():
    """On a 20 m circle at 6 m/s (0.3 rad/s) the pad's heading passes pi between steps 299 and 300 (pi / 0.3 =
    10.47 s, 299.2 steps); every marker 5 m off at steps 295-303 (9 steps, one short of a reset): the filter's
    prior, predicted through them, has its yaw past pi, which only an update wraps. The stack keeps that prior
    as it is at every fully gated step, as MarkerFilter.step does."""
    off = range(295, 304)
    marker_filter, t, X_WB, cameras, p_CM, q_CM = _one_run(310, off, circle(6.0, 20.0))
    assert 299 * TS < np.pi / 0.3 < 300 * TS
    stack = run_stack(marker_filter, t, cameras, p_CM, q_CM, 0)
    records, stepped = _stepped_records(t, X_WB, p_CM, q_CM)
    for k, (x, _, _) in enumerate(records):
        np.testing.assert_allclose(stack.x[0, k], x, rtol=0, atol=1e-9, err_msg=f"step {k}")
    psi = np.array([x[ConstantTurnEkf.PSI] for x, _, _ in records])
    assert psi[list(off)].max() > np.pi and psi.max() == psi[list(off)].max()
    assert stack.stats[0] == stepped.stats == FilterStats(accepted=5 * (310 - len(off)), gated=5 * len(off))


def test_a_stack_whose_stream_arrives_after_the_history_is_refused():
    """At latency L a measurement of t_0 arrives at t_L: 15 steps of 35 ms (0.525 s) is past the filter's
    0.5 s history, which MarkerFilter.step could not re-run; 14 steps (0.49 s) is within it."""
    marker_filter, t, _, cameras, p_CM, q_CM = _one_run(40)
    assert marker_filter.config.history_s == 0.5
    with pytest.raises(ConfigError, match="within the filter's history"):
        run_stack(marker_filter, t, cameras, p_CM, q_CM, 15)
    assert run_stack(marker_filter, t, cameras, p_CM, q_CM, 14).started[14:].all()


def test_a_stack_whose_latency_is_its_length_is_refused():
    """At latency L the measurements of t_0 arrive at step L: ten steps at latency 10 have no step for them to
    arrive in, refused as the history check's ConfigError (not an IndexError); latency 9, the last step, is run."""
    marker_filter, t, _, cameras, p_CM, q_CM = _one_run(10)
    with pytest.raises(ConfigError, match="within the filter's history"):
        run_stack(marker_filter, t, cameras, p_CM, q_CM, 10)
    assert run_stack(marker_filter, t, cameras, p_CM, q_CM, 9).started.tolist() == [False] * 9 + [True]


@pytest.mark.parametrize("field", ["p_CM", "q_CM"])
def test_a_stack_with_a_nan_in_its_stream_is_refused(field):
    """MarkerFilter.step screens a NaN measurement out; the stack, which fuses every marker of every step, refuses
    a stream holding one (marker 1's at step 3) rather than carry the NaN into the run."""
    marker_filter, t, _, cameras, p_CM, q_CM = _one_run(10)
    (p_CM if field == "p_CM" else q_CM)[0, 3, 1, 0] = np.nan
    with pytest.raises(ConfigError, match="only usable measurements"):
        run_stack(marker_filter, t, cameras, p_CM, q_CM, 0)
