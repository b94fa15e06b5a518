"""metrics.json's `perception` section (diagrams/perception_metrics.py) on constructed logs whose errors
are known: a source that estimates a position alone (the hybrid one) is scored on positions only."""

import numpy as np
import pytest
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix

from diagrams.perception_metrics import longest_span_s, perception_metrics
from systems.estimators.estimate import PoseEstimate, estimate_vector
from systems.estimators.marker_ekf.engine import EST_LAST_MEASUREMENT, ESTIMATE_VECTOR_SIZE
from systems.perception.seam import HEIGHT, P_BP_W, RELATIVE_STATE_SIZE, VALID
from systems.vehicles.quadrotor import P_WB, Q_WB, STATE_SIZE

N = 50


def _log(estimated_yaw: float | None) -> dict:
    """The pad moving along x under a hovering UAV, its vehicle heading 90 deg; the seam exact, the
    steering estimate's rotation the identity (a position alone) or yaw `estimated_yaw`."""
    t = np.arange(N) * 0.02
    p_WB = np.tile([0.0, 0.0, 3.0], (N, 1))
    p_WP = np.column_stack([np.linspace(0.0, 1.0, N), np.zeros(N), np.full(N, 0.5)])
    quadrotor = np.zeros((N, STATE_SIZE))
    quadrotor[:, P_WB], quadrotor[:, Q_WB] = p_WB, [1.0, 0.0, 0.0, 0.0]
    vehicle = np.zeros((N, 4))
    vehicle[:, 2] = np.radians(90.0)
    truth = np.zeros((N, RELATIVE_STATE_SIZE))
    truth[:, P_BP_W], truth[:, HEIGHT], truth[:, VALID] = p_WP - p_WB, 2.5, 1.0
    R = RotationMatrix() if estimated_yaw is None else RotationMatrix(RollPitchYaw(0.0, 0.0, estimated_yaw))
    steering = np.array([estimate_vector(PoseEstimate(ti, RigidTransform(R, p), True, None, "W", "P"))
                         for ti, p in zip(t, p_WP)])
    return {"t": t, "relative_state": truth.copy(), "true_relative_state": truth, "quadrotor_state": quadrotor,
            "vehicle_state": vehicle, "steering_estimate": steering}


def test_a_position_alone_has_no_heading_figures():
    out = perception_metrics(_log(None), "hybrid", heading=False)
    assert out["rms_position_m"] == 0.0 and out["frames_scored"] == N
    assert not {"rms_heading_deg", "mae_rpy_deg", "rmse_rpy_deg", "flips"} & set(out)
    np.testing.assert_allclose(out["mae_xyz_m"], 0.0)


def test_without_a_steering_estimate_there_is_no_heading_to_score():
    """The truth steers with no estimate logged: its positions are scored (exact here), its heading is not (no
    0 deg that no estimate made), as perception.png leaves out the heading panel."""
    log = _log(None)
    del log["steering_estimate"]
    out = perception_metrics(log, "truth")
    assert out["rms_position_m"] == 0.0 and out["frames_scored"] == N
    assert not {"rms_heading_deg", "mae_rpy_deg", "rmse_rpy_deg", "flips"} & set(out)


def test_an_estimated_heading_is_scored_against_the_vehicles():
    out = perception_metrics(_log(np.radians(88.0)), "ct_ekf")
    assert out["rms_heading_deg"] == pytest.approx(2.0)
    # Roll and pitch are not scored (the seam carries a position and a heading): null, not a zero that no
    # estimate could change.
    assert out["mae_rpy_deg"][:2] == out["rmse_rpy_deg"][:2] == [None, None]
    assert out["mae_rpy_deg"][2] == pytest.approx(2.0)
    assert out["flips"] == 0


@pytest.mark.parametrize("heading, steering", [(True, True), (False, True), (True, False)])
def test_the_heading_error_is_drawn_only_for_a_source_that_estimates_it(heading, steering, tmp_path, monkeypatch):
    from diagrams import landing_plots

    figures = []
    monkeypatch.setattr(landing_plots, "save_figure", lambda fig, path: figures.append(fig))
    log = _log(None)
    log["mode"] = np.zeros(N)
    log["relative_state"][:5, VALID] = 0.0  # the first samples without a valid estimate
    if not steering:  # the truth steered: no estimate, no heading
        del log["steering_estimate"]
    landing_plots.plot_perception(log, "hybrid", tmp_path, heading)
    labels = [ax.get_ylabel() for ax in figures[0].axes if ax.get_ylabel()]
    drawn = heading and steering
    assert ("heading error (deg)" in labels) == drawn  # no panel holding only the invalid samples' ticks
    assert labels[-1] == ("heading error (deg)" if drawn else "position error (m)")
    last = figures[0].axes[len(labels) - 1]
    ticks = next(line for line in last.get_lines() if line.get_label() == "no valid estimate")
    np.testing.assert_array_equal(ticks.get_xdata(), log["t"][:5])
    if drawn:  # the identity rotation against the vehicle's 90 deg
        error = next(line for line in last.get_lines() if len(line.get_xdata()) == N)
        np.testing.assert_allclose(error.get_ydata(), -90.0)


@pytest.mark.parametrize("invalid, expected_s", [
    (np.ones(N, bool), (N - 1) * 0.02),  # invalid throughout: the run's length, not one sample more
    (np.arange(N) >= 40, 9 * 0.02),  # to the end: from its first sample to the last
    ((np.arange(N) >= 10) & (np.arange(N) < 15), 5 * 0.02),  # inside: to the first valid sample after it
    (np.zeros(N, bool), 0.0),
])
def test_the_longest_time_without_a_valid_estimate_is_within_the_run(invalid, expected_s):
    log = _log(None)
    log["relative_state"][invalid, VALID] = 0.0
    out = perception_metrics(log, "ct_ekf")
    assert out["longest_invalid_s"] == pytest.approx(expected_s, abs=1e-12)
    assert out["longest_invalid_s"] <= log["t"][-1] - log["t"][0]


def test_the_longest_span_follows_uneven_sample_times():
    t = np.array([0.0, 0.1, 0.3, 0.35, 1.0])
    assert longest_span_s(t, np.array([False, True, True, False, False])) == pytest.approx(0.25)
    assert longest_span_s(t, np.array([True, False, False, True, True])) == pytest.approx(0.65)


def test_the_heading_error_wraps_across_180_deg():
    """An estimate at 179 deg of a vehicle at -179 deg is 2 deg off, not 358."""
    log = _log(np.radians(179.0))
    log["vehicle_state"][:, 2] = np.radians(-179.0)
    assert perception_metrics(log, "ct_ekf")["rms_heading_deg"] == pytest.approx(2.0)


def test_an_uneven_heading_error_is_scored_as_its_rms():
    """Estimated headings 1 deg under and 3 deg over the vehicle's on alternate samples: an RMS heading error of
    sqrt(5) deg (not the mean |error|, 2 deg), as the yaw's RMSE; its MAE 2 deg."""
    log, over = _log(np.radians(89.0)), _log(np.radians(93.0))
    log["steering_estimate"][1::2] = over["steering_estimate"][1::2]
    out = perception_metrics(log, "ct_ekf")
    assert out["rms_heading_deg"] == pytest.approx(np.sqrt(5.0))
    assert out["rmse_rpy_deg"][2] == pytest.approx(np.sqrt(5.0)) and out["mae_rpy_deg"][2] == pytest.approx(2.0)


def test_an_uneven_position_error_is_scored_as_the_rms_of_its_3d_norm():
    """A seam off by (0.03, 0, 0) m and (0.03, 0.04, 0.12) m (0.13 m) on alternate samples: the RMS of the 3-D
    error, sqrt((0.03^2 + 0.13^2) / 2) m, not the mean of its norm (0.08 m)."""
    log = _log(np.radians(90.0))
    log["relative_state"][0::2, P_BP_W] += [0.03, 0.0, 0.0]
    log["relative_state"][1::2, P_BP_W] += [0.03, 0.04, 0.12]
    out = perception_metrics(log, "ct_ekf")
    assert out["rms_position_m"] == pytest.approx(np.sqrt((0.03**2 + 0.13**2) / 2))


def test_the_position_error_is_the_rms_of_the_3d_error_over_the_valid_samples():
    """A seam off by (0.02, 0.04, 0.04) m (0.06 m) where valid; its first 5 samples invalid and far off, left
    out; the first valid time is the sixth sample's."""
    log = _log(np.radians(90.0))
    log["relative_state"][:, P_BP_W] += [0.02, 0.04, 0.04]
    log["relative_state"][:5, VALID] = 0.0
    log["relative_state"][:5, P_BP_W] += 10.0
    out = perception_metrics(log, "ct_ekf")
    assert out["rms_position_m"] == pytest.approx(0.06)
    assert out["first_valid_s"] == pytest.approx(log["t"][5])


def test_the_coast_before_touchdown_is_from_the_last_fusion_before_it():
    """Fusions until 0.3 s, touchdown at 0.5 s: 0.2 s of coasting; a fusion after touchdown does not count."""
    t = np.arange(N) * 0.02
    estimate = np.zeros((N, ESTIMATE_VECTOR_SIZE))
    estimate[:, EST_LAST_MEASUREMENT] = np.minimum(t, 0.3)
    estimate[t > 0.6, EST_LAST_MEASUREMENT] = 0.8
    out = perception_metrics(_log(np.radians(90.0)), "ct_ekf", touchdown_s=0.5, filter_t=t, filter_estimate=estimate)
    assert out["coast_before_touchdown_s"] == pytest.approx(0.2)


def test_a_fusion_at_the_touchdown_sample_leaves_no_coast():
    """The filter fused at every sample, the touchdown exactly at one of them: no coasting before touchdown (0 s),
    the later fusions not counted."""
    t = np.arange(N) * 0.02
    estimate = np.zeros((N, ESTIMATE_VECTOR_SIZE))
    estimate[:, EST_LAST_MEASUREMENT] = t
    out = perception_metrics(_log(np.radians(90.0)), "ct_ekf", touchdown_s=t[25], filter_t=t, filter_estimate=estimate)
    assert out["coast_before_touchdown_s"] == 0.0


@pytest.mark.parametrize("last_fusion_s, touchdown_s", [
    (np.nan, 0.5),  # the filter never fused
    (0.0, -0.1),  # touchdown before the filter's first sample: none to read
])
def test_without_a_fusion_before_touchdown_there_is_no_coast_figure(last_fusion_s, touchdown_s):
    """No last fusion to count the coast from: no figure (None), not NaN."""
    t = np.arange(N) * 0.02
    estimate = np.zeros((N, ESTIMATE_VECTOR_SIZE))
    estimate[:, EST_LAST_MEASUREMENT] = last_fusion_s
    out = perception_metrics(_log(np.radians(90.0)), "ct_ekf", touchdown_s=touchdown_s, filter_t=t,
                             filter_estimate=estimate)
    assert out["coast_before_touchdown_s"] is None
