"""The pose plots (diagrams/pose_plots.py, seed 000's Figures 24-30) draw what their axes name: on a constructed
run whose poses are known (Drake's roll-pitch-yaw), translations in metres, angles in degrees, the estimate left
out where it is invalid, the trajectory's views on their own axis pairs and the angle errors in the angle panel."""

import numpy as np
from pydrake.math import RollPitchYaw

from diagrams import pose_plots

N = 5


def _rows(xyz: np.ndarray, rpy: np.ndarray) -> np.ndarray:
    """(N, 7) [x, y, z, qw, qx, qy, qz] rows from positions and Drake roll-pitch-yaw angles (rad)."""
    return np.array([[*p, *RollPitchYaw(a).ToQuaternion().wxyz()] for p, a in zip(xyz, rpy)])


def test_each_pose_plot_draws_the_channel_it_names(tmp_path, monkeypatch):
    """The truth moving on all three axes at once, yawing and tilting; the estimate off by (0.1, -0.2, 0.3) m and
    (2, -3, 5) deg, row 2 flagged invalid (its values finite)."""
    t = np.linspace(0.0, 0.4, N)
    xyz = np.column_stack([1.0 + t, -2.0 + 3.0 * t, 4.0 - 5.0 * t])
    rpy = np.column_stack([0.1 + t, -0.2 + 0.5 * t, 0.3 - 2.0 * t])
    rpy_error = np.radians([2.0, -3.0, 5.0])
    truth = _rows(xyz, rpy)
    estimate = np.column_stack([np.ones(N), _rows(xyz + [0.1, -0.2, 0.3], rpy + rpy_error)])
    estimate[2, 0] = 0.0
    valid = estimate[:, 0] > 0.5
    figures = {}
    monkeypatch.setattr(pose_plots, "save_figure", lambda fig, path: figures.update({path.name: fig}))
    pose_plots.plot_pose_estimates(t, truth, {"atda": estimate}, tmp_path)

    def lines(ax):
        return {line.get_label(): line for line in ax.get_lines()}

    for i, ax in enumerate(figures["pose_translation.png"].axes):
        drawn = lines(ax)
        np.testing.assert_allclose(drawn["truth"].get_ydata(), xyz[:, i])
        np.testing.assert_allclose(drawn["atda"].get_ydata(), np.where(valid, xyz[:, i] + [0.1, -0.2, 0.3][i], np.nan))
    for i, ax in enumerate(figures["pose_angles.png"].axes):  # degrees, roll included
        drawn = lines(ax)
        np.testing.assert_allclose(drawn["truth"].get_ydata(), np.degrees(rpy[:, i]))
        np.testing.assert_allclose(drawn["atda"].get_ydata(), np.where(valid, np.degrees(rpy[:, i] + rpy_error[i]),
                                                                        np.nan))
    views = figures["pose_trajectory.png"].axes[:3]
    for ax, (i, j) in zip(views, ((0, 2), (1, 2), (0, 1))):  # XZ, YZ, XY
        assert (ax.get_xlabel(), ax.get_ylabel()) == (f"{'xyz'[i]} (m)", f"{'xyz'[j]} (m)")
        np.testing.assert_allclose(lines(ax)["truth"].get_xydata(), xyz[:, [i, j]])
    scene = figures["pose_trajectory.png"].axes[3]  # the 3-D view: x, y, z on their own axes
    np.testing.assert_allclose(np.array(lines(scene)["truth"].get_data_3d()), xyz.T)
    position, angles = figures["errors_atda.png"].axes
    for k, label in enumerate("xyz"):
        np.testing.assert_allclose(lines(position)[label].get_ydata(), np.full(valid.sum(), [0.1, 0.2, 0.3][k]))
    for k, label in enumerate(("roll", "pitch", "yaw")):
        np.testing.assert_array_equal(lines(angles)[label].get_xdata(), t[valid])
        np.testing.assert_allclose(lines(angles)[label].get_ydata(), np.full(valid.sum(), [2.0, 3.0, 5.0][k]))
