"""The perception seam: the adapter's vector and its validity (the estimate's own flag, covariance and
age), and the registry behind `perception.source` with its one-line errors and its sources' wiring."""

import copy
import dataclasses
import pickle

import numpy as np
import pytest
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.systems.primitives import LogVectorOutput

from diagrams.cli import main
from diagrams.gv_landing import build_gv_landing
from diagrams.gv_landing_run import fly
from diagrams.perception_sources import SOURCES, PerceptionSource, perception_source
from diagrams.runner import load_scenario
from systems.config import ConfigError
from systems.estimators.estimate import PoseEstimate
from systems.perception.seam import (
    A_WP,
    HEIGHT,
    P_BP_B,
    P_BP_W,
    RELATIVE_STATE_SIZE,
    V_WP,
    VALID,
    EstimateToSeam,
    SeamConfig,
    SeamSplit,
    estimate_is_valid,
    seam_vector,
)
from tests.conftest import wiring

X_WB = RigidTransform(RollPitchYaw(0.1, -0.2, 1.3), [4.0, -2.0, 6.5])
X_WP = RigidTransform(RollPitchYaw(0.0, 0.0, 0.4), [5.0, -1.0, 1.6])


def covariance(position_std_m: float) -> np.ndarray:
    """[roll, pitch, yaw, x, y, z] covariance with the given position std (sqrt of the trace)."""
    return np.diag([0.01, 0.01, 0.01, *np.full(3, position_std_m**2 / 3)])


def test_the_seam_is_the_pad_relative_to_the_uav_in_world_and_body():
    values = seam_vector(X_WB, X_WP.translation(), [3.0, 0.5, 0.0], [0.2, -0.1, 0.0], True)
    p_BP_W = X_WP.translation() - X_WB.translation()
    np.testing.assert_allclose(values[P_BP_W], p_BP_W)
    np.testing.assert_allclose(values[P_BP_B], X_WB.rotation().matrix().T @ p_BP_W, atol=1e-12)
    np.testing.assert_allclose(values[V_WP], [3.0, 0.5, 0.0])
    np.testing.assert_allclose(values[A_WP], [0.2, -0.1, 0.0])
    assert values[HEIGHT] == pytest.approx(4.9) and values[VALID] == 1.0
    assert seam_vector(X_WB, X_WP.translation(), np.zeros(3), np.zeros(3), False)[VALID] == 0.0
    # Never NaN: a non-finite entry becomes zero and the seam invalid.
    broken = seam_vector(X_WB, [np.nan, 0.0, 1.6], np.zeros(3), [np.inf, 0.0, 0.0], True)
    assert np.all(np.isfinite(broken)) and broken[VALID] == 0.0


@pytest.mark.parametrize("estimate, time, valid", [
    (PoseEstimate(10.0, X_WP, True, covariance(0.3)), 10.0, True),
    (PoseEstimate(10.0, X_WP, True, None), 10.2, True),  # no covariance: the flag and the age decide
    (PoseEstimate(10.0, X_WP, False, covariance(0.3)), 10.0, False),  # the estimator says no
    (PoseEstimate(10.0, X_WP, True, covariance(1.5)), 10.0, False),  # too uncertain to steer on
    (PoseEstimate(10.0, X_WP, True, covariance(0.3)), 10.6, False),  # too old
    (PoseEstimate(10.0, X_WP, True, covariance(0.3)), 10.5, True),  # exactly max_age_s old: "no older than"
    (PoseEstimate(np.nan, X_WP, True, covariance(0.3)), 10.0, False),  # stamped NaN: it has no age to check
    (PoseEstimate(20.0, X_WP, True, covariance(0.3)), 10.0, False),  # stamped in the future
    (PoseEstimate(10.0 + 1e-6, X_WP, True, covariance(0.3)), 10.0, False),
    (PoseEstimate(10.0 + 1e-12, X_WP, True, covariance(0.3)), 10.0, True),  # the same time, to rounding
    (PoseEstimate(10.0, RigidTransform([np.nan, 0.0, 0.0]), True, None), 10.0, False),
    (PoseEstimate(10.0, X_WP, True, np.full((6, 6), np.nan)), 10.0, False),
    # A negative variance (a diverged filter's P) is no std: x and y 7 m, z -100 m^2 summed to a trace of 0.
    (PoseEstimate(10.0, X_WP, True, np.diag([0.0, 0.0, 0.0, 50.0, 50.0, -100.0])), 10.0, False),
    (PoseEstimate(10.0, X_WP, True, np.diag([0.0, 0.0, 0.0, 0.01, 0.01, -1e-15])), 10.0, True),  # round-off
])
def test_validity_is_the_estimates_own(estimate, time, valid):
    assert estimate_is_valid(estimate, time, SeamConfig(max_position_std_m=1.0, max_age_s=0.5)) == valid


@pytest.mark.parametrize("limit_m, position_std_m, valid", [
    (2.0, 1.8, True),  # variance 3.24 m^2 over the limit's number, its std within the limit
    (0.5, 0.6, False),  # std over the limit, variance 0.36 m^2 within its number
])
def test_the_position_limit_is_on_the_std_not_the_variance(limit_m, position_std_m, valid):
    """max_position_std_m bounds sqrt(trace) of the position covariance, in metres: away from a limit of 1 m, where
    a std and its square agree, the two give opposite answers."""
    estimate = PoseEstimate(10.0, X_WP, True, covariance(position_std_m))
    assert estimate_is_valid(estimate, 10.0, SeamConfig(max_position_std_m=limit_m)) == valid


@pytest.mark.parametrize("field", ["max_position_std_m", "max_age_s"])
def test_a_seam_limit_must_be_positive(field):
    with pytest.raises(ConfigError, match=rf"perception.{field} must be positive, got 0.0"):
        SeamConfig(**{field: 0.0}).validate()


def test_the_split_ports_are_the_seams_named_slots():
    """A seam of distinct numbers (each slot its own index): every port the controller reads is its slots."""
    seam = np.arange(RELATIVE_STATE_SIZE, dtype=float)
    split = SeamSplit()
    context = split.CreateDefaultContext()
    split.GetInputPort("relative_state").FixValue(context, seam)
    expected = {"target_offset": seam[P_BP_W][:2], "target_velocity": seam[V_WP][:2],
                "target_acceleration": seam[A_WP][:2], "height_above_target": [seam[HEIGHT]],
                "target_valid": [seam[VALID]], "p_BP_W": seam[P_BP_W], "p_BP_B": seam[P_BP_B]}
    assert {split.get_output_port(i).get_name() for i in range(split.num_output_ports())} == set(expected)
    for name, slots in expected.items():
        np.testing.assert_array_equal(split.GetOutputPort(name).Eval(context), slots, err_msg=name)


@pytest.mark.parametrize("rates", [True, False])
def test_the_adapter_system(rates):
    adapter = EstimateToSeam(SeamConfig())
    context = adapter.CreateDefaultContext()
    context.SetTime(3.0)
    adapter.GetInputPort("X_WB").FixValue(context, X_WB)
    adapter.GetInputPort("X_WP_estimate").FixValue(context, PoseEstimate(3.0, X_WP, True, covariance(0.2), "W", "P"))
    if rates:  # an estimator without rates leaves these unconnected: zero feed-forward
        adapter.GetInputPort("v_WP_estimate").FixValue(context, [3.0, 0.5, 0.0])
        adapter.GetInputPort("a_WP_estimate").FixValue(context, [0.2, -0.1, 0.0])
    values = adapter.get_output_port().Eval(context)
    assert len(values) == RELATIVE_STATE_SIZE and values[VALID] == 1.0
    expected = seam_vector(X_WB, X_WP.translation(), [3.0, 0.5, 0.0] if rates else np.zeros(3),
                           [0.2, -0.1, 0.0] if rates else np.zeros(3), True)
    np.testing.assert_allclose(values, expected, atol=1e-12)


@pytest.mark.parametrize("covariance", [np.eye(3) * 1e4, np.full(6, 1e4), np.zeros(36), np.zeros((4, 9))])
def test_an_estimates_covariance_is_6x6_or_none(covariance):
    # A 3x3 would have passed the seam as a zero position std; a 6-vector raised IndexError mid-flight. 36 entries
    # are not a 6x6 in any other shape.
    with pytest.raises(ConfigError, match=r"the X_WP estimate's covariance must be 6x6 .*got shape \(" +
                       str(len(covariance))):
        PoseEstimate(10.0, X_WP, True, covariance, "W", "P")
    assert PoseEstimate(10.0, X_WP, True, None, "W", "P").covariance is None


def test_estimates_name_their_frames_and_the_seam_takes_only_the_pad_in_the_world():
    estimate = PoseEstimate(1.0, X_WP, True, None, "C", "T")
    assert estimate.frames == "X_CT" and estimate.X_CT is estimate.X_RT
    with pytest.raises(AttributeError):
        estimate.X_WP
    assert copy.deepcopy(estimate).X_CT.IsExactlyEqualTo(X_WP) and pickle.loads(pickle.dumps(estimate)).frames == "X_CT"
    adapter = EstimateToSeam()
    context = adapter.CreateDefaultContext()
    adapter.GetInputPort("X_WB").FixValue(context, X_WB)
    adapter.GetInputPort("X_WP_estimate").FixValue(context, estimate)
    with pytest.raises(ConfigError, match="needs an estimate of the pad in the world, X_WP; it got X_CT"):
        adapter.get_output_port().Eval(context)


def test_an_invalid_estimate_names_its_frames_in_order_at_its_time():
    """PoseEstimate.invalid(time, reference, target): not valid, stamped `time`, its pose the identity, named
    X_<reference><target> (invalid(2.0, "W", "P") is the pad in the world, X_WP, not X_PW)."""
    estimate = PoseEstimate.invalid(2.0, "W", "P")
    assert (estimate.reference, estimate.target, estimate.frames) == ("W", "P", "X_WP")
    assert not estimate.valid and estimate.time == 2.0 and estimate.covariance is None
    assert estimate.X_WP.IsExactlyEqualTo(RigidTransform())


def test_the_registry_names_every_source_and_what_it_needs():
    assert {"truth", "ct_ekf", "paper_ekf"} <= set(SOURCES)
    assert not perception_source("truth").needs_markers and perception_source("ct_ekf").needs_markers
    with pytest.raises(ConfigError, match=r"perception.source 'kalman' is not a perception source \(known: truth"):
        perception_source("kalman")
    # deck-landing's tag estimators are in the one registry, and run only there.
    assert perception_source("crhf", scene="deck").scenes == ("deck",) and "atda" in SOURCES
    with pytest.raises(ConfigError, match=r"perception.source 'crhf' does not run in the gv scenarios \(its sources: "
                                          r"truth, paper_ekf, ct_ekf, federated, hybrid\)"):
        perception_source("crhf")


@pytest.mark.parametrize("overrides, message", [
    (["perception.source=kalman"], "perception.source 'kalman' is not a perception source (known: truth, "),
    (["perception.source=ct_ekf"], "perception.source 'ct_ekf' needs marker measurements, and estimation.source "
                                   "is none: set estimation.source to synthetic or detector"),
    (["estimation.filters=[ct_ekf]"], "estimation.filters need a measurement stream"),
])
def test_a_source_that_cannot_run_is_one_line_and_exit_2(capfd, tmp_path, overrides, message):
    out = tmp_path / "run"
    code = main(["run", "gv-landing", *[a for o in overrides for a in ("--set", o)], "--out", str(out), "--quiet"])
    _, err = capfd.readouterr()
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_a_source_that_needs_the_camera_says_so(monkeypatch):
    monkeypatch.setitem(SOURCES, "on_images", PerceptionSource(lambda builder, inputs: None, needs_camera=True))
    with pytest.raises(ConfigError, match="perception.source 'on_images' needs the camera, and estimation.source is "
                                          "synthetic: set estimation.source to detector"):
        load_scenario("gv-landing", overrides=["perception.source=on_images", "estimation.source=synthetic"])
    _, s = load_scenario("gv-landing", overrides=["perception.source=on_images", "estimation.source=detector"])
    assert s.perception.source == "on_images"


def _add_logged_truth(builder, inputs):
    """The truth's seam, its relative state logged by the source itself every 0.05 s."""
    ports = SOURCES["truth"].add(builder, inputs)
    return dataclasses.replace(ports, logs={"seam": LogVectorOutput(ports.relative_state, builder, 0.05)})


def test_a_sources_own_metrics_of_its_own_logs_are_in_the_estimators_section(monkeypatch):
    """A source with logs and a metrics callable: fly gives the callable the source's logs (with their times)
    and the scenario, and puts what it returns in metrics["estimators"]."""
    given = []

    def metrics_of(arrays, config, touchdown_s):
        given.append((arrays, config, touchdown_s))
        return {"logged": {"samples": len(arrays["t"])}}

    monkeypatch.setitem(SOURCES, "logged", PerceptionSource(_add_logged_truth, metrics=metrics_of))
    _, s = load_scenario("gv-landing", overrides=["perception.source=logged"])
    metrics, flight = fly(s, 0.2)
    [(arrays, config, touchdown_s)] = given
    assert arrays is flight.source_log and config is s and touchdown_s is None  # not landed in 0.2 s
    assert arrays["seam"].shape == (len(arrays["t"]), RELATIVE_STATE_SIZE) and len(arrays["t"]) >= 4
    assert metrics["estimators"]["logged"] == {"samples": len(arrays["t"])}


def test_any_gv_scenario_takes_a_perception_source():
    for name in ("gv-landing", "gv-marker-ekf", "marker-landing"):
        _, s = load_scenario(name, overrides=["perception.source=paper_ekf", "estimation.source=synthetic"])
        assert s.perception.source == "paper_ekf" and "paper_ekf" in s.filter_names


def test_the_hybrid_source_estimates_no_heading_and_a_marker_filter_does():
    """The hybrid pad estimator (systems/perception/hybrid_pad.py) places the pad from a box's ray and a height:
    a position alone, its rotation the identity whatever the pad's heading. So its source says it estimates no
    heading, and perception_metrics scores no heading, rotation or flip for it; a marker filter's estimate has the
    markers' heading, scored."""
    assert perception_source("hybrid").estimates_heading is False
    assert perception_source("ct_ekf").estimates_heading is True


SAME_NAMES = {"X_WP_estimate": "X_WP_estimate", "v_WP_estimate": "v_WP_estimate", "a_WP_estimate": "a_WP_estimate"}


@pytest.mark.parametrize("scenario, overrides, estimator, ports", [
    ("gv-landing", ["perception.source=ct_ekf", "estimation.source=synthetic"], "ct_ekf", SAME_NAMES),
    ("gv-landing", ["perception.source=paper_ekf", "estimation.source=synthetic"], "paper_ekf", SAME_NAMES),
    ("open-landing", ["perception.source=federated"], "federated_filter",
     {"X_WP_estimate": "X_WP_estimate", "v_WP_estimate": "v_WP_estimate"}),
    # the hybrid pad's v_WP: its observer's velocity, else its coast's, never NaN (not v_WP_observed)
    ("ugv-hybrid", [], "hybrid_pad", {"X_WP_estimate": "X_WP_estimate", "v_WP_estimate": "v_WP"}),
], ids=["ct_ekf", "paper_ekf", "federated", "hybrid"])
def test_a_source_wires_its_estimators_rates_into_the_seam(scenario, overrides, estimator, ports):
    """The built diagram's adapter (estimate_to_seam) takes the pose and every rate the source's estimator has
    from it (seam input -> the estimator's output): a marker filter's velocity and acceleration (the PID's
    feed-forward), the federated filter's and the hybrid pad's velocity (they have no acceleration); the UAV's pose
    besides."""
    _, config = load_scenario(scenario, overrides=overrides)
    diagram, _ = build_gv_landing(config)
    wired = {port: source for (system, port), source in wiring(diagram).items() if system == "estimate_to_seam"}
    assert wired.pop("X_WB") is not None
    assert wired == {name: (estimator, output) for name, output in ports.items()}
