"""The closed loop through the perception seam: landings steered by a marker filter (on the paper's
synthetic stream, and on the rendered camera), a source of one's own wired in without changing the
package (examples/own_estimator.py), and an estimate that goes invalid below LH: the supervisor
holds, never descends on it, and climbs out."""

import runpy
from pathlib import Path

import numpy as np
import pytest
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.systems.framework import LeafSystem

from diagrams.gv_landing import build_gv_landing
from diagrams.gv_landing_run import fly
from diagrams.perception_sources import SOURCES, PerceptionSource, add_estimate_to_seam
from diagrams.runner import load_scenario
from systems.control.landing import Mode
from systems.estimators.estimate import PoseEstimate
from systems.perception.seam import P_BP_W, RELATIVE_STATE_SIZE, V_WP, VALID
from systems.vehicles.quadrotor import P_WB

EXAMPLE = Path(__file__).resolve().parent.parent / "examples" / "own_estimator.py"


def test_gv_landing_flies_on_the_constant_turn_filter_and_the_synthetic_stream():
    _, s = load_scenario("gv-landing", overrides=["perception.source=ct_ekf", "estimation.source=synthetic"])
    metrics, flight = fly(s, s.duration_s)
    landing, perception = metrics["landing"], metrics["perception"]
    assert landing["success"] and landing["touchdown_error_m"] < 0.10 and landing["touchdown_rel_speed_mps"] < 0.5
    assert perception["source"] == "ct_ekf" and 0 < perception["rms_position_m"] < 0.1
    assert perception["coast_before_touchdown_s"] < 0.1  # the synthetic stream never goes blind
    assert set(metrics["estimators"]) == {"ct_ekf"} and metrics["estimators"]["ct_ekf"]["rms_position_m"] < 0.1
    # What steered is the estimate, not the truth: the seam and the truth's differ.
    seam, truth = flight.log["relative_state"], flight.log["true_relative_state"]
    assert np.abs(seam[:, P_BP_W] - truth[:, P_BP_W]).max() > 0.01


class BlindAfter(LeafSystem):
    """A test source: the pad's true position and velocity as an estimate until `blind_s` [s],
    invalid after."""

    def __init__(self, blind_s: float):
        super().__init__()
        X_WB = self.DeclareAbstractInputPort("X_WB", AbstractValue.Make(RigidTransform()))
        relative = self.DeclareVectorInputPort("true_relative_state", RELATIVE_STATE_SIZE)
        self.DeclareAbstractOutputPort(
            "X_WP_estimate", lambda: AbstractValue.Make(PoseEstimate()), lambda c, o: o.set_value(
                PoseEstimate(c.get_time(), RigidTransform(X_WB.Eval(c).translation() + relative.Eval(c)[P_BP_W]),
                             c.get_time() < blind_s, reference="W", target="P")))
        self.DeclareVectorOutputPort("v_WP_estimate", 3, lambda c, o: o.SetFromVector(relative.Eval(c)[V_WP]))


def test_an_invalid_estimate_below_lh_holds_never_descends_and_climbs_out(monkeypatch):
    blind_s = 20.0  # gv-landing is in its final landing (LAND, below LH) from 18.1 s, touching down at 22.6 s

    def add_blind(builder, inputs):
        source = builder.AddSystem(BlindAfter(blind_s))
        builder.Connect(inputs.X_WB, source.GetInputPort("X_WB"))
        builder.Connect(inputs.true_relative_state, source.GetInputPort("true_relative_state"))
        return add_estimate_to_seam(builder, inputs, source.GetOutputPort("X_WP_estimate"),
                                    source.GetOutputPort("v_WP_estimate"))

    monkeypatch.setitem(SOURCES, "blind_after", PerceptionSource(add_blind))
    _, s = load_scenario("gv-landing", overrides=["perception.source=blind_after", "termination.lost_timeout_s=6"])
    metrics, flight = fly(s, s.duration_s)
    log = flight.log
    t, mode, altitude = log["t"], log["mode"], log["quadrotor_state"][:, P_WB][:, 2]
    blind = t >= blind_s
    assert mode[np.argmax(blind) - 1] == Mode.LAND and not log["relative_state"][blind, VALID].any()
    assert metrics["landing"]["failure_reason"] == "target_lost" and metrics["landing"]["touchdown_error_m"] is None
    # Aborted (climbing out), then searched; never LAND again and never commanding a descent on the
    # invalid estimate: the descent at the landing speed (0.3 m/s) stops within the velocity loop's
    # response (~7 cm).
    after = t > blind_s + 1e-6  # the samples logged after the supervisor's update at blind_s
    assert mode[after][0] == Mode.ABORT and Mode.SEARCH in mode[after] and Mode.LAND not in mode[after]
    assert np.all(log["command"][after, 2] >= 0.0)
    assert altitude[blind].min() > altitude[np.argmax(blind)] - 0.1
    aborting = blind & (mode == Mode.ABORT)
    assert altitude[aborting][-1] > altitude[np.argmax(blind)] + 0.5  # climbing out at 1 m/s for lost_hold_s
    climbing = blind & (mode == Mode.SEARCH)
    assert altitude[climbing][-1] > altitude[np.argmax(blind)] + 2.0
    assert metrics["perception"]["longest_invalid_s"] >= 6.0 - 0.1
    assert metrics["landing"]["aborts"] == 1 and metrics["landing"]["retries"] == 0


@pytest.mark.slow
def test_marker_landing_lands_by_vision_on_the_rendered_camera():
    # The shipped scenario, started lower for a short test: 4 m over the pad's start, IH 3.5 m.
    _, s = load_scenario("marker-landing", overrides=["start.height_m=4", "start.xy_m=[1.2, 1.2]",
                                                      "landing.initial_height_m=3.5"])
    metrics, _ = fly(s, s.duration_s)
    landing, perception = metrics["landing"], metrics["perception"]
    assert landing["success"] and landing["touchdown_error_m"] < 0.10 and landing["touchdown_rel_speed_mps"] < 0.5
    assert perception["source"] == "ct_ekf" and perception["valid_fraction"] > 0.9
    # The camera is too close to see a marker for the last ~0.3 m: the filter's prediction flies it.
    assert 0.3 < perception["coast_before_touchdown_s"] < 2.0
    assert metrics["measurements"]["source"] == "detector" and set(metrics["estimators"]) == {"paper_ekf", "ct_ekf"}


@pytest.mark.parametrize("name, source", [("marker-landing", "detector"), ("gv-marker-ekf", "synthetic")])
def test_the_measurements_section_gives_the_noise_of_the_stream_s_source(name, source):
    """The detector's noise is the camera's pixel noise; the synthetic stream's, its sigma_p_m and sigma_deg."""
    _, s = load_scenario(name)
    metrics, _ = fly(s, 0.2)
    measurements, est = metrics["measurements"], s.estimation
    assert measurements["source"] == source == est.source
    expected = ({"pixel_noise_std": est.camera.pixel_noise_std} if source == "detector"
                else {"sigma_p_m": est.sigma_p_m, "sigma_deg": est.sigma_deg})
    assert {key: measurements.get(key) for key in ("pixel_noise_std", "sigma_p_m", "sigma_deg")} == {
        "pixel_noise_std": None, "sigma_p_m": None, "sigma_deg": None, **expected}


@pytest.fixture
def registry_restored():
    """The example registers its source in the process-wide SOURCES: put the registry back as it was after the
    test, so that tests run later (test_perception_seam's list of sources) do not see it."""
    saved = dict(SOURCES)
    yield
    SOURCES.clear()
    SOURCES.update(saved)


def test_the_example_flies_an_estimator_of_ones_own(capsys, registry_restored):
    metrics = runpy.run_path(str(EXAMPLE), run_name="example")["main"](["--set", "estimation.source=synthetic"])
    out = capsys.readouterr().out
    assert metrics["perception"]["source"] == "averaged_markers" and metrics["landing"]["success"]
    assert "landed" in out and "averaged_markers steering: RMS position" in out
    assert "averaged_markers" not in SOURCES or SOURCES["averaged_markers"].needs_markers


def test_the_example_gives_bad_settings_one_line_and_exit_2(capsys, registry_restored):
    with pytest.raises(SystemExit) as exit_:
        runpy.run_path(str(EXAMPLE), run_name="example")["main"](["--set", "estimation.source=bogus"])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and len(err.strip().splitlines()) == 1
    assert "error: estimation.source 'bogus' is not one of" in err and "Traceback" not in err


def test_the_marker_detector_is_given_the_estimators_lens_model():
    # marker-landing's camera with barrel distortion: the detector told the lens measures as through a
    # pinhole; told none (calibration_error.k1 cancelling it), it measures otherwise.
    def measured(overrides):
        _, scenario = load_scenario("marker-landing", overrides=[
            "estimation.camera.pixel_noise_std=0.0", "start.height_m=4.5", *overrides])
        scenario.start.xy_m = [float(scenario.platform.p_VP[0]) + 0.6, float(scenario.platform.p_VP[1]) + 0.4]
        diagram, handles = build_gv_landing(scenario)
        context = diagram.CreateDefaultContext()
        handles.initialize(context)
        detector = handles.measurements.detector
        return {m.marker_id: m.p_CM for m in detector.get_output_port().Eval(detector.GetMyContextFromRoot(context))}

    lens = "estimation.camera.distortion=[-0.2, 0.0, 0.0, 0.0, 0.0]"
    pinhole, exact = measured([]), measured([lens])
    unmodelled = measured([lens, "estimation.camera.calibration_error.k1=0.2"])
    shared = set(pinhole) & set(exact) & set(unmodelled)
    assert len(shared) >= 3
    assert max(np.linalg.norm(exact[i] - pinhole[i]) for i in shared) < 0.03  # m, from 4.5 m
    assert min(np.linalg.norm(unmodelled[i] - exact[i]) for i in shared) > 0.05


def test_the_cameras_exposure_smears_the_pad_moving_under_it():
    # marker-landing at t = 0: the UAV still, the pad moving at the vehicle's speed under it. The blur's
    # axis flow is the pad's speed over its depth, and the 20 ms frame differs from the instant one.
    def frame(exposure_s):
        _, scenario = load_scenario("marker-landing", overrides=[
            f"estimation.camera.exposure_s={exposure_s}", "estimation.camera.pixel_noise_std=0.0",
            "start.height_m=4.5"])
        diagram, handles = build_gv_landing(scenario)
        context = diagram.CreateDefaultContext()
        handles.initialize(context)
        port = handles.measurements.color_image  # the noisy camera's
        image = port.Eval(port.get_system().GetMyContextFromRoot(context)).data.copy()
        return diagram, context, handles, image

    _, _, _, instant = frame(0.0)
    diagram, context, handles, smeared = frame(0.02)
    flow = diagram.GetSubsystemByName("axis_flow")
    truth = handles.truth.get_output_port().Eval(handles.truth.GetMyContextFromRoot(context))
    depth = -truth[P_BP_W][2] - 0.04  # the camera sits 0.04 m under the body, looking down
    speed = np.linalg.norm(truth[V_WP])
    assert speed > 1.0
    rate = np.linalg.norm(flow.get_output_port().Eval(flow.GetMyContextFromRoot(context)))
    assert rate == pytest.approx(speed / depth, rel=0.05)  # rad/s
    assert np.abs(smeared.astype(int) - instant.astype(int)).max() > 20
