"""The open-loop campaign's batch path (diagrams/marker_batch.py) gives the Diagram's estimates, and
only where it applies."""

import numpy as np
import pytest

from diagrams.gv_landing import build_gv_landing
from diagrams.gv_landing_run import fly_diagram
from diagrams.marker_batch import batch_applies, batch_run
from diagrams.marker_metrics import marker_metrics
from diagrams.runner import load_scenario
from systems.config import ConfigError
from systems.estimators.marker_ekf.engine import EST_Q_WP


@pytest.mark.parametrize("speed, seed, latency", [(6, 3, 1), (12, 11, 0), (3, 0, 2)])
def test_the_batch_path_gives_the_diagrams_estimates(speed, seed, latency):
    _, s = load_scenario("gv-marker-ekf", overrides=[f"vehicle.speed={speed}", f"estimation.latency_periods={latency}"],
                         seed=seed)
    diagram, handles = build_gv_landing(s)
    in_diagram = fly_diagram(diagram, handles, 4.0).sampled
    batch = batch_run(s, 4.0)
    np.testing.assert_array_equal(batch.t, in_diagram.t)
    np.testing.assert_allclose(batch.quadrotor_state, in_diagram.quadrotor_state, rtol=0, atol=1e-9)
    np.testing.assert_allclose(batch.measurements[..., :3], in_diagram.measurements[..., :3], rtol=0, atol=1e-9)
    q, q_diagram = batch.measurements[..., 3:], in_diagram.measurements[..., 3:]  # q and -q: the same attitude
    np.testing.assert_allclose(q * np.sign(np.sum(q * q_diagram, axis=-1, keepdims=True)), q_diagram, rtol=0,
                               atol=1e-9)
    assert set(batch.estimates) == set(in_diagram.estimates) == {"paper_ekf", "ct_ekf"}
    for name in batch.estimates:
        started = ~np.isnan(in_diagram.estimates[name][:, 1])
        assert started.mean() > 0.9
        # every figure but the filter's own compute time
        np.testing.assert_allclose(batch.estimates[name], in_diagram.estimates[name], rtol=0, atol=1e-9)
        np.testing.assert_allclose(batch.p_WM[name], in_diagram.p_WM[name], rtol=0, atol=1e-9)
        assert batch.stats[name] == in_diagram.stats[name] and batch.stats[name]["accepted"] > 0
        assert np.all(np.isfinite(in_diagram.estimates[name][started, EST_Q_WP]))
    # and so the same figures, the paper filter's roll and pitch included
    est = s.estimation
    metrics = [marker_metrics(run, s.platform, est.X_BC, est.settle_s)[1] for run in (batch, in_diagram)]
    for name in batch.estimates:
        figures, expected = ({k: v for k, v in m[name].items() if k != "per_frame_ms"} for m in metrics)
        assert figures.keys() == expected.keys() and "mae_rpy_deg" in expected
        for key, value in expected.items():
            if key in ("measurements", "attitude_axes"):
                assert figures[key] == value
            else:  # None (an axis the filter does not estimate) as NaN, and NaN equals NaN
                np.testing.assert_allclose(np.array(figures[key], dtype=float), np.array(value, dtype=float),
                                           rtol=0, atol=1e-9, err_msg=key)
    # a different seed is a different stream
    assert not np.allclose(batch_run(s.__class__(**{**s.__dict__, "seed": seed + 1}), 4.0).measurements,
                           batch.measurements, equal_nan=True)


DRAG = "quadrotor.rotor_drag_coefficient=8.06428e-5"  # RotorS's: the wind acts through it


@pytest.mark.parametrize("overrides", [
    ["perception.source=ct_ekf"], ["estimation.source=detector"], ["faults.drop_probability=0.5"],
    ["navigation.source=gnss_ins"], ["wind.turbulence=light", DRAG], ["rendezvous.source=broadcast"],
])
def test_the_batch_path_only_replays_a_flight_no_seed_alters(overrides):
    _, s = load_scenario("gv-marker-ekf", overrides=overrides)
    assert not batch_applies(s)
    with pytest.raises(ConfigError, match="the batch path replays one flight"):
        batch_run(s, 1.0)


def test_no_seed_alters_the_flight_the_batch_path_replays():
    # A mean wind, a gust and other vehicles (drawn from the seed, never rendered here) are let
    # through: the Diagram flies the same flight for two seeds, and the batch path, its flight flown
    # for the first, gives the second's Diagram estimates.
    overrides = ["vehicle.speed=6", "wind.mean_m_s=4", DRAG, "distractors.count=2",
                 "wind.gusts=[{start_s: 0.5, duration_s: 1.0, magnitude_m_s: 3.0, direction_deg: 90}]"]
    first, second = (load_scenario("gv-marker-ekf", overrides=overrides, seed=seed)[1] for seed in (1, 2))
    assert batch_applies(first) and batch_applies(second)
    flights = [fly_diagram(*build_gv_landing(s), 2.0).sampled for s in (first, second)]
    np.testing.assert_array_equal(flights[0].quadrotor_state, flights[1].quadrotor_state)
    np.testing.assert_array_equal(flights[0].vehicle_state, flights[1].vehicle_state)
    calm = fly_diagram(*build_gv_landing(load_scenario("gv-marker-ekf", overrides=overrides[:1], seed=1)[1]), 2.0)
    assert not np.allclose(calm.sampled.quadrotor_state, flights[0].quadrotor_state)  # the wind alters it
    batch_run(first, 2.0)
    batch = batch_run(second, 2.0)
    np.testing.assert_allclose(batch.quadrotor_state, flights[1].quadrotor_state, rtol=0, atol=1e-9)
    for name in batch.estimates:
        np.testing.assert_allclose(batch.estimates[name], flights[1].estimates[name], rtol=0, atol=1e-9)


def test_each_run_of_a_group_reports_its_share_of_the_filters_time(monkeypatch):
    """batch_runs steps the filters of 4 runs together: with a clock that moves 4 s while they step (and only
    then), each run's compute_s is 1 s per filter, its share, not the group's 4 s."""
    from types import SimpleNamespace

    import diagrams.marker_batch as marker_batch

    clock = SimpleNamespace(now=100.0)
    stepped = marker_batch.run_stack

    def run_stack(*args, **kwargs):
        clock.now += 4.0
        return stepped(*args, **kwargs)

    monkeypatch.setattr(marker_batch, "run_stack", run_stack)
    monkeypatch.setattr(marker_batch, "time", SimpleNamespace(perf_counter=lambda: clock.now))
    _, s = load_scenario("gv-marker-ekf", overrides=["vehicle.speed=6"])
    runs = marker_batch.batch_runs(s, [0, 1, 2, 3], 1.0)
    assert len(s.filter_names) == 2
    assert [run.compute_s for run in runs] == [{name: 1.0 for name in s.filter_names}] * 4
