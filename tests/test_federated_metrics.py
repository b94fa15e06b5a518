"""Seed 001 Sec. 5.3's comparison where two nodes overlap (`overlap_metrics`) on a constructed log whose
errors are known: the frames where both nodes measured and the fused estimate is valid, and the height
RMSE of every local filter and of the fused estimate on exactly those frames; Overlap 1's
frames shaded in federated.png and its figures in what a run prints."""

from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pytest
from pydrake.math import RigidTransform, RollPitchYaw
from scipy.spatial.transform import Rotation

from diagrams import federated_plots
from diagrams.federated_metrics import (
    FederatedLog,
    federated_metrics,
    filter_metrics,
    node_metrics,
    overlap_metrics,
    true_p_CP,
    true_X_PB,
)
from diagrams.federated_plots import plot_federated, shade_frames
from diagrams.gv_landing_run import summary_lines
from systems.estimators.federated.system import (
    FED_BETAS,
    FED_LOCAL_P,
    FED_LOCAL_THETA,
    FED_LOCAL_TRACES,
    FED_P_PB,
    FED_Q_PB,
    FED_STARTED,
    FED_VALID,
    FEDERATED_VECTOR_SIZE,
)
from systems.perception.rqrlp.measurements import NODE_VECTOR_SIZE
from systems.sensors.camera import CameraConfig
from systems.sensors.ground_truth import pose_vector
from systems.vehicles.ground_vehicle_geometry import PlatformConfig
from systems.vehicles.quadrotor import P_WB, Q_WB, STATE_SIZE


def _log() -> tuple[FederatedLog, np.ndarray]:
    n = 10
    heights = np.linspace(5.0, 0.5, n)
    X_PB = np.zeros((n, 7))
    X_PB[:, 2], X_PB[:, 3] = heights, 1.0
    federated = np.zeros((n, FEDERATED_VECTOR_SIZE))
    federated[:, FED_VALID] = 1.0
    federated[7, FED_VALID] = 0.0  # the fused estimate invalid on one frame where all three nodes measure
    federated[:, FED_P_PB.start + 2] = heights + 0.01
    for i, offset in enumerate((0.02, -0.03, 0.04)):  # each local filter's z error, in NODES' order
        federated[:, FED_LOCAL_P.start + 3 * i + 2] = heights + offset
    federated[2, FED_LOCAL_P.start + 2] = heights[2] + 0.05  # the approaching filter off by more on one frame
    present = {"approach": range(0, 6), "adjustment": range(2, 9), "touchdown": range(5, 10)}
    nodes = {}
    for name, frames in present.items():
        nodes[name] = np.zeros((n, NODE_VECTOR_SIZE))
        nodes[name][list(frames), 0] = 1.0
    return FederatedLog(np.arange(n) * 0.02, federated, nodes, X_PB), heights


def test_overlaps_score_every_local_filter_and_the_fused_estimate_on_the_two_nodes_shared_frames():
    log, heights = _log()
    window = np.ones(len(heights), bool)
    window[3] = False  # frames past touchdown are not scored
    out = overlap_metrics(log, window)
    one, two = out["overlap_1"], out["overlap_2"]
    assert one["nodes"] == ["approach", "adjustment"] and two["nodes"] == ["adjustment", "touchdown"]
    assert one["frames"] == 3  # 2, 4, 5: both measure from 2 to 5, frame 3 outside the window
    assert one["altitude_band_m"] == [heights[5], heights[2]]
    np.testing.assert_allclose(one["rmse_height_m"]["local_approach"], np.sqrt((0.05**2 + 2 * 0.02**2) / 3))
    np.testing.assert_allclose(one["rmse_height_m"]["local_adjustment"], 0.03)
    np.testing.assert_allclose(one["rmse_height_m"]["federated"], 0.01)
    np.testing.assert_allclose(one["rmse_height_m"]["local_touchdown"], 0.04)  # measuring there too in ours
    assert two["frames"] == 3  # 5, 6, 8: frame 7's fused estimate is invalid
    np.testing.assert_allclose(two["rmse_height_m"]["local_touchdown"], 0.04)
    np.testing.assert_allclose(two["rmse_height_m"]["local_approach"], 0.02)


def test_docs_scenarios_names_every_height_an_overlap_scores():
    """docs/scenarios.md's `federated.overlaps` passage names each key of an overlap's `rmse_height_m` (it had
    said the two local filters and the fused estimate, where every local filter is scored)."""
    log, heights = _log()
    scored = overlap_metrics(log, np.ones(len(heights), bool))["overlap_1"]["rmse_height_m"]
    doc = (Path(__file__).parent.parent / "docs" / "scenarios.md").read_text()
    start = doc.index("`federated.overlaps` holds")
    passage = doc[start:doc.index(";", doc.index("`rmse_height_m`", start))]
    assert len(scored) == 4 and all(f"`{key}`" in passage for key in scored), passage


def test_an_overlap_without_shared_frames_has_no_figures():
    log, heights = _log()
    log.nodes["adjustment"][:, 0] = 0.0
    out = overlap_metrics(log, np.ones(len(heights), bool))
    assert out["overlap_1"]["frames"] == 0 and out["overlap_1"]["altitude_band_m"] is None
    assert "rmse_height_m" not in out["overlap_1"]


def test_overlap_1_is_shaded_where_both_nodes_measure():
    fig, ax = plt.subplots()
    t = np.arange(10) * 0.02
    frames = np.array([0, 1, 1, 0, 0, 1, 1, 1, 0, 1], bool)
    shade_frames(ax, t, frames, "Overlap 1")
    spans = [patch.get_x() for patch in ax.patches], [patch.get_x() + patch.get_width() for patch in ax.patches]
    np.testing.assert_allclose(spans[0], [t[1], t[5], t[9]])
    np.testing.assert_allclose(spans[1], [t[2], t[7], t[9]])
    assert [patch.get_label() for patch in ax.patches][0] == "Overlap 1"
    assert ax.get_legend_handles_labels()[1] == ["Overlap 1"]  # once, for three bands
    plt.close(fig)


def test_the_federated_figure_is_written(tmp_path):
    log, _ = _log()
    log.federated[:, FED_LOCAL_TRACES] = 1e-4
    plot_federated(log, CameraConfig().X_BC, tmp_path)
    assert (tmp_path / "federated.png").stat().st_size > 10_000


def test_a_run_prints_overlap_1s_figures_beside_the_papers():
    overlap = {"frames": 148, "altitude_band_m": [1.07, 3.75],
               "rmse_height_m": {"local_approach": 0.0017, "local_adjustment": 0.0018, "local_touchdown": 0.0019,
                                 "federated": 0.0016}}
    metrics = {"perception": {"source": "federated"}, "estimators": {"federated": {"overlaps": {"overlap_1": overlap}}}}
    assert ("open-landing: federated in Overlap 1 (1.07-3.75 m, 148 frames): height RMSE 0.0016 m, local filters "
            "0.0017 / 0.0018 / 0.0019 m (paper 0.037; 0.065 / 0.0835)") in summary_lines("open-landing", metrics)
    overlap["frames"], overlap["altitude_band_m"] = 0, None
    del overlap["rmse_height_m"]
    assert not any("Overlap" in line for line in summary_lines("open-landing", metrics))


def test_a_run_prints_the_local_filters_and_the_fused_estimate_but_not_the_nodes():
    """The nodes' own measurements (approach, adjustment, touchdown) are not printed; the local filters
    (local_<node>) and the fused estimate are."""
    figures = {"rmse_position_m": 0.01, "rmse_orientation_rad": 0.02, "rmse_height_m": 0.03, "valid_fraction": 0.5}
    names = ("approach", "adjustment", "touchdown", "local_approach", "local_adjustment", "local_touchdown",
             "federated")
    metrics = {"perception": {"source": "federated"}, "estimators": {name: dict(figures) for name in names}}
    assert summary_lines("open-landing", metrics) == [
        f"open-landing: {name}: RMSE position 0.0100 m, orientation 0.0200 rad, height 0.0300 m, valid 50.0%"
        for name in ("local_approach", "local_adjustment", "local_touchdown", "federated")]


def test_the_local_filters_are_scored_on_the_fused_estimates_valid_frames():
    # Frame 7's fused estimate is invalid: it counts against neither it nor the local filters.
    log, heights = _log()
    log.federated[:, FED_STARTED] = 1.0
    log.federated[:, FED_Q_PB] = [1.0, 0.0, 0.0, 0.0]  # the attitudes exact (FED_LOCAL_THETA zero)
    out = filter_metrics(log, np.ones(len(heights), bool))
    for name in ("local_approach", "local_adjustment", "local_touchdown", "federated"):
        assert out[name]["frames_scored"] == 9
    np.testing.assert_allclose(out["local_adjustment"]["rmse_height_m"], 0.03)
    np.testing.assert_allclose(out["federated"]["rmse_height_m"], 0.01)


def test_with_a_touchdown_every_valid_fraction_and_altitude_band_is_over_the_frames_up_to_it():
    # Touchdown at frame 5: frames 0-5 are scored, 6-9 (after it) count for no figure, nor for an altitude band.
    n = 10
    t = np.arange(n) * 0.02
    X_PB = np.tile([0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0], (n, 1))
    X_PB[6:, 2] = 0.2  # the UAV lower after touchdown
    federated = np.full((n, FEDERATED_VECTOR_SIZE), np.nan)
    federated[:, FED_STARTED] = np.arange(n) >= 2  # the local filters from frame 2: 4 of 6 frames, 8 of 10
    federated[:, FED_VALID] = np.arange(n) >= 3  # the fused estimate from frame 3: 3 of 6, 7 of 10
    federated[:, FED_P_PB], federated[:, FED_Q_PB] = [0.0, 0.0, 1.0], [1.0, 0.0, 0.0, 0.0]
    federated[2:, FED_LOCAL_P], federated[2:, FED_LOCAL_THETA] = np.tile([0.0, 0.0, 1.0], 3), 0.0
    nodes = {name: np.zeros((n, NODE_VECTOR_SIZE)) for name in ("approach", "adjustment", "touchdown")}
    # The adjustment node measures in 3 of the 6 frames (3 of 10), the touchdown node in 2 of 6 (6 of 10).
    for name, frames in (("adjustment", slice(0, 3)), ("touchdown", slice(4, 10))):
        nodes[name][frames, :8] = [1.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0]  # present, the true X_PB
    out = federated_metrics(FederatedLog(t, federated, nodes, X_PB), RigidTransform(), end_s=t[5])
    assert out["adjustment"]["valid_fraction"] == out["adjustment"]["present_fraction"] == 0.5
    np.testing.assert_allclose([out["touchdown"]["valid_fraction"], out["touchdown"]["present_fraction"]], 1 / 3)
    for name in ("local_approach", "local_adjustment", "local_touchdown"):
        np.testing.assert_allclose(out[name]["valid_fraction"], 4 / 6)
    assert out["federated"]["valid_fraction"] == 0.5
    assert out["adjustment"]["altitude_band_m"] == out["touchdown"]["altitude_band_m"] == [1.0, 1.0]


def test_the_truth_is_drakes_X_PB_and_p_CP():
    """true_X_PB of a tilted UAV over a yawed pad is X_WP^-1 X_WB (Drake, the platform's own X_WP), and
    true_p_CP the pad centre in a rotated, offset camera: X_CB X_BP's translation."""
    platform = PlatformConfig()
    X_WB = RigidTransform(RollPitchYaw(0.1, -0.2, 0.7), [1.0, 2.0, 4.0])
    vehicle = np.array([[0.5, -1.0, 0.6, 0.0]])
    quadrotor = np.zeros((1, STATE_SIZE))
    quadrotor[0, P_WB], quadrotor[0, Q_WB] = X_WB.translation(), X_WB.rotation().ToQuaternion().wxyz()
    X_PB = platform.X_WP(vehicle[0]).inverse().multiply(X_WB)
    got = true_X_PB(quadrotor, vehicle, platform)[0]
    np.testing.assert_allclose(got[:3], X_PB.translation(), atol=1e-12)
    assert abs(np.dot(got[3:], X_PB.rotation().ToQuaternion().wxyz())) == pytest.approx(1.0, abs=1e-12)
    X_BC = RigidTransform(RollPitchYaw(np.pi, 0.0, np.pi / 2), [0.05, 0.0, -0.1])
    log = FederatedLog(np.zeros(1), np.zeros((1, FEDERATED_VECTOR_SIZE)), {}, got[None, :])
    np.testing.assert_allclose(true_p_CP(log, X_BC)[0], X_BC.inverse().multiply(X_PB.inverse()).translation(),
                               atol=1e-12)


def test_true_p_CP_is_drakes_through_a_mount_whose_rotation_is_not_symmetric():
    """A camera tilted off the vertical, mounted at RPY (pi - 0.3, 0.2, pi/2) (a rotation matrix that is not its
    own transpose), offset from the body: true_p_CP of seeded random X_PB is Drake's X_BC^-1 X_PB^-1's translation."""
    X_BC = RigidTransform(RollPitchYaw(np.pi - 0.3, 0.2, np.pi / 2), [0.05, -0.02, -0.1])
    R_BC = X_BC.rotation().matrix()
    assert np.abs(R_BC - R_BC.T).max() > 0.4
    rng = np.random.default_rng(25)
    X_PB = [RigidTransform(RollPitchYaw(*rng.uniform(-0.5, 0.5, 3)), rng.uniform(-2.0, 2.0, 3) + [0.0, 0.0, 3.0])
            for _ in range(5)]
    log = FederatedLog(np.zeros(5), np.zeros((5, FEDERATED_VECTOR_SIZE)), {}, np.array([pose_vector(X) for X in X_PB]))
    np.testing.assert_allclose(true_p_CP(log, X_BC), [X_BC.inverse().multiply(X.inverse()).translation() for X in X_PB],
                               atol=1e-12)


def test_the_approaching_nodes_p_CP_is_scored_in_C_within_the_window():
    """The approaching node's p_CP off the truth (Drake's X_CB X_BP) by (0.02, -0.01, 0) and (-0.04, 0, 0.03) m on
    alternate frames up to the window's end, and by 5 m after it: MAE per axis the mean |error| (0.03, 0.005, 0.015),
    RMSE per axis and in 3-D the root mean squares of those two, the frames after the window left out."""
    log, _ = _log()
    X_BC = RigidTransform(RollPitchYaw(np.pi, 0.0, np.pi / 2), [0.05, 0.0, -0.1])
    assert np.all(log.X_PB[:, 3:] == [1.0, 0.0, 0.0, 0.0])  # X_PB a translation alone: X_BP = -p_PB
    p_CP = np.array([X_BC.inverse().multiply(RigidTransform(-row[:3])).translation() for row in log.X_PB])
    offsets = np.array([[0.02, -0.01, 0.0], [-0.04, 0.0, 0.03]] * 2 + [[5.0, 5.0, 5.0]] * 2)
    log.nodes["approach"][:6, 1:4] = p_CP[:6] + offsets  # present on frames 0-5
    for name in ("adjustment", "touchdown"):
        log.nodes[name][:, 1:8] = log.X_PB  # the pose nodes exact, not scored here
    window = np.arange(len(log.t)) <= 3
    approach = node_metrics(log, X_BC, window)["approach"]
    assert approach["frame"] == "C"
    np.testing.assert_allclose(approach["mae_xyz_m"], [0.03, 0.005, 0.015], atol=1e-12)
    np.testing.assert_allclose(approach["rmse_xyz_m"], np.sqrt([(0.02**2 + 0.04**2) / 2, 0.01**2 / 2, 0.03**2 / 2]),
                               atol=1e-12)
    assert approach["rmse_position_m"] == pytest.approx(np.sqrt((0.02**2 + 0.01**2 + 0.04**2 + 0.03**2) / 2))


def test_the_pose_nodes_are_scored_on_their_own_X_PB():
    """The adjustment node's X_PB off the truth by (0.01, -0.02, 0.03) m on every frame it measures, the touchdown
    node's exact: MAE and RMSE per axis the offset's magnitude (0 for the touchdown node), its 3-D RMSE |offset|."""
    log, _ = _log()
    offset = np.array([0.01, -0.02, 0.03])
    for name, error in (("adjustment", offset), ("touchdown", np.zeros(3))):
        present = log.nodes[name][:, 0] > 0.5
        log.nodes[name][present, 1:8] = log.X_PB[present] + np.r_[error, np.zeros(4)]
    out = node_metrics(log, RigidTransform(), np.ones(len(log.t), bool))
    np.testing.assert_allclose(out["adjustment"]["mae_xyz_m"], np.abs(offset), atol=1e-12)
    np.testing.assert_allclose(out["adjustment"]["rmse_xyz_m"], np.abs(offset), atol=1e-12)
    assert out["adjustment"]["rmse_position_m"] == pytest.approx(np.linalg.norm(offset))
    assert out["adjustment"]["frames_scored"] == 7
    np.testing.assert_allclose(out["touchdown"]["mae_xyz_m"], 0.0, atol=1e-12)
    np.testing.assert_allclose(out["touchdown"]["rmse_xyz_m"], 0.0, atol=1e-12)
    assert out["touchdown"]["rmse_position_m"] == pytest.approx(0.0, abs=1e-12)


def test_the_local_filters_and_the_fused_estimate_are_scored_in_3d_and_as_rms():
    """Truth yawed 0.3 rad; each local filter's rotation vector exactly it (no attitude error) and its position
    off by (0.03, 0.04, 0.12) m (RMSE 0.13 m in 3-D); the fused estimate exact in position, its attitude off
    about z by 0.1 rad on one frame and 0.3 rad on the other: an orientation RMSE of sqrt((0.1^2 + 0.3^2) / 2)."""
    n, yaw = 2, 0.3
    q = Rotation.from_rotvec([0.0, 0.0, yaw]).as_quat()  # x y z w
    X_PB = np.tile([1.0, 2.0, 3.0, q[3], *q[:3]], (n, 1))
    federated = np.zeros((n, FEDERATED_VECTOR_SIZE))
    federated[:, FED_STARTED] = federated[:, FED_VALID] = 1.0
    federated[:, FED_LOCAL_P] = np.tile([1.03, 2.04, 3.12], 3)
    federated[:, FED_LOCAL_THETA] = np.tile([0.0, 0.0, yaw], 3)
    federated[:, FED_P_PB] = [1.0, 2.0, 3.0]
    for i, extra in enumerate((0.1, -0.3)):
        xyzw = Rotation.from_rotvec([0.0, 0.0, yaw + extra]).as_quat()
        federated[i, FED_Q_PB] = [xyzw[3], *xyzw[:3]]
    out = filter_metrics(FederatedLog(np.arange(n) * 0.02, federated, {}, X_PB), np.ones(n, bool))
    for name in ("local_approach", "local_adjustment", "local_touchdown"):
        assert out[name]["rmse_position_m"] == pytest.approx(0.13)
        assert out[name]["rmse_orientation_rad"] == pytest.approx(0.0, abs=1e-9)
        np.testing.assert_allclose(out[name]["mae_xyz_m"], [0.03, 0.04, 0.12], atol=1e-12)
    assert out["federated"]["rmse_position_m"] == pytest.approx(0.0, abs=1e-12)
    assert out["federated"]["rmse_orientation_rad"] == pytest.approx(np.sqrt((0.1**2 + 0.3**2) / 2))


def test_each_federated_panel_draws_the_channel_it_names(tmp_path, monkeypatch):
    """federated.png against its log: (a) each node's height is its z (column 3), NaN where it is absent; (b) the
    approaching node's error is against the true depth along the camera's axis (Drake's X_CB X_BP), the others' and
    the fused one's against the true height; (e) each local filter's line is its own p_PB z, and the fused line is
    NaN where the fused estimate is invalid."""
    log, heights = _log()
    X_BC = RigidTransform(RollPitchYaw(np.pi, 0.0, np.pi / 2), [0.05, 0.0, -0.3])  # 0.3 m under the body
    depth = np.array([X_BC.inverse().multiply(RigidTransform(-np.array([0.0, 0.0, h]))).translation()[2]
                      for h in heights])
    assert np.all(np.abs(depth - heights) > 0.1)
    for i, name in enumerate(("approach", "adjustment", "touchdown")):
        present = log.nodes[name][:, 0] > 0.5
        truth = depth if name == "approach" else heights
        log.nodes[name][present, 1:4] = np.column_stack([np.full(present.sum(), 0.7), np.full(present.sum(), -0.4),
                                                         truth[present] + 0.01 * (i + 1)])
    figures = []
    monkeypatch.setattr(federated_plots, "save_figure", lambda fig, path: figures.append(fig))
    plot_federated(log, X_BC, tmp_path)
    axes = figures[0].axes
    lines = [{line.get_label(): line.get_ydata() for line in ax.get_lines()} for ax in axes]
    fused = np.where(log.federated[:, FED_VALID] > 0.5, log.federated[:, FED_P_PB.start + 2], np.nan)
    assert np.isnan(fused[7])
    for i, name in enumerate(("approach", "adjustment", "touchdown")):
        present = log.nodes[name][:, 0] > 0.5
        truth = depth if name == "approach" else heights
        np.testing.assert_allclose(lines[0][name], np.where(present, truth + 0.01 * (i + 1), np.nan))
        np.testing.assert_allclose(lines[1][name], np.where(present, 0.01 * (i + 1), np.nan), atol=1e-12)
        np.testing.assert_allclose(lines[4][f"LF {name}"], log.federated[:, FED_LOCAL_P.start + 3 * i + 2])
    np.testing.assert_allclose(lines[1]["federated"], np.abs(fused - heights), atol=1e-12)  # 0.01, NaN on frame 7
    np.testing.assert_allclose(lines[4]["federated (valid)"], fused)
    np.testing.assert_allclose(lines[4]["true"], heights)


def test_the_federated_figure_draws_each_nodes_trace_and_beta_the_error_floor_and_overlap_1(tmp_path, monkeypatch):
    """Each local filter's trace (c) and beta (d) are its own node's (distinct per node); an error of zero is drawn at
    the floor of the log scale (1e-4 m); Overlap 1 (approach and adjustment both measure: _log's frames 2-5, not
    overlap 2's 5-8) is shaded in (b) and (e)."""
    log, heights = _log()
    traces, betas = np.array([1e-3, 2e-3, 3e-3]), np.array([0.2, 0.3, 0.5])
    log.federated[:, FED_LOCAL_TRACES], log.federated[:, FED_BETAS] = traces, betas
    adjustment = log.nodes["adjustment"][:, 0] > 0.5
    log.nodes["adjustment"][:, 3] = heights  # exactly on the true height where it measures
    figures = []
    monkeypatch.setattr(federated_plots, "save_figure", lambda fig, path: figures.append(fig))
    plot_federated(log, CameraConfig().X_BC, tmp_path)
    axes = figures[0].axes
    lines = [{line.get_label(): line.get_ydata() for line in ax.get_lines()} for ax in axes]
    for i, name in enumerate(("approach", "adjustment", "touchdown")):
        np.testing.assert_allclose(lines[2][f"LF {name}"], np.full(10, traces[i]))
        np.testing.assert_allclose(lines[3][f"beta {name}"], np.full(10, betas[i]))
    np.testing.assert_allclose(lines[1]["adjustment"], np.where(adjustment, 1e-4, np.nan))
    t = log.t
    for ax in (axes[1], axes[4]):
        spans = [(patch.get_x(), patch.get_x() + patch.get_width()) for patch in ax.patches]
        np.testing.assert_allclose(spans, [(t[2], t[5])])
