"""The landing plots name what carries the pad: the UGV and its path, or the pad alone on the ground; they mark
the touchdown where the metrics put it."""

import matplotlib.pyplot as plt
import numpy as np
import pytest
from matplotlib.colors import to_hex

from diagrams import landing_plots
from diagrams.landing_metrics import gv_touchdown, landing_metrics
from diagrams.runner import load_scenario
from systems.control.landing import Mode
from systems.control.monitor import GV_HEADING
from systems.perception.seam import HEIGHT, P_BP_W, RELATIVE_STATE_SIZE, V_WP, VALID
from systems.vehicles.quadrotor import V_WB


def a_short_log(n: int = 5) -> dict:
    """A hover of n samples over the pad, the estimate valid, the last sample landed."""
    state, relative = np.zeros((n, 17)), np.zeros((n, RELATIVE_STATE_SIZE))
    state[:, 2] = np.linspace(3.0, 0.1, n)
    relative[:, VALID] = 1.0
    mode = np.full(n, int(Mode.LAND))
    mode[-1] = int(Mode.LANDED)
    return {"t": np.linspace(0.0, 1.0, n), "quadrotor_state": state, "true_relative_state": relative,
            "relative_state": relative, "mode": mode, "command": np.zeros((n, 7))}


SCHEDULE = ["vehicle.speed_schedule_times_s=[0, 10, 12]", "vehicle.speed_schedule_m_s=[0, 0, 2]"]


@pytest.mark.parametrize("scenario, overrides, carrier, says", [
    ("gv-landing", [], "UGV", "straight, 0.5 m/s"),
    ("gv-landing", SCHEDULE, "UGV", "straight, 0-2 m/s scheduled"),  # not vehicle.speed's 0.5 m/s
    ("open-landing", [], "pad", "the pad on the ground")])
def test_the_titles_and_legends_name_the_pads_carrier(scenario, overrides, carrier, says, tmp_path, monkeypatch):
    _, config = load_scenario(scenario, overrides=overrides)
    figures = []
    monkeypatch.setattr(landing_plots, "save_figure", lambda fig, path: figures.append(fig))
    landing_plots.plot_flight(a_short_log(), config, tmp_path, 4)
    titles = [ax.get_title() for fig in figures for ax in fig.axes if ax.get_title()]
    labels = [line.get_label() for fig in figures for ax in fig.axes for line in ax.get_lines()]
    assert titles and all(says in title for title in titles)
    assert any(f"UAV and {carrier} " in title for title in titles)
    assert any("UGV" in text for text in titles + labels) == (carrier == "UGV")


def a_contact_log(n: int = 6, contact: int = 2) -> dict:
    """A descent onto the pad whose gear touches (true height 0.05 m, under landing.touchdown_height_m) at sample
    `contact`, the supervisor's LANDED only at the last sample."""
    log = a_short_log(n)
    relative = log["true_relative_state"].copy()
    relative[:, HEIGHT] = np.where(np.arange(n) < contact, 0.5, 0.05)
    log["quadrotor_state"][:, 0] = np.arange(n)  # the UAV's x tells the samples apart
    log.update(true_relative_state=relative, vehicle_state=np.zeros((n, 4)))
    return log


def test_a_touchdown_by_contact_before_landed_is_marked_where_the_metrics_put_it(tmp_path, monkeypatch):
    _, config = load_scenario("gv-landing")
    log = a_contact_log()
    found = gv_touchdown(log, "completed", config)
    assert found == (2, "contact")
    assert landing_metrics(log | {"vehicle_speed": np.zeros(6)}, "completed", config)["time_to_land_s"] == log["t"][2]
    figures = {}
    monkeypatch.setattr(landing_plots, "save_figure", lambda fig, path: figures.update({path.name: fig}))
    landing_plots.plot_flight(log, config, tmp_path, found[0])
    top = next(line for line in figures["trajectories_top.png"].axes[0].get_lines() if line.get_label() == "touchdown")
    np.testing.assert_array_equal(top.get_xydata(), [[2.0, 0.0]])  # the UAV at the contact, not at LANDED
    red = [line.get_xdata()[0] for line in figures["altitude.png"].axes[0].get_lines() if line.get_color() == "tab:red"]
    assert red == [log["t"][2]]


def labelled(ax, label):
    """The line of `ax` labelled `label`."""
    return next(line for line in ax.get_lines() if line.get_label() == label)


def a_tracked_log(n: int = 6) -> dict:
    """A flight whose every channel differs from the others: the pad away from the UAV (P_BP_W per axis), the
    estimate off the truth (and its height), the pad's velocity different on each axis, samples 1 and 4 without
    a valid estimate."""
    log = a_short_log(n)
    k = np.arange(n, dtype=float)
    log["quadrotor_state"][:, :3] = np.column_stack([k, 2.0 * k, np.linspace(3.0, 1.0, n)])
    truth = np.zeros((n, RELATIVE_STATE_SIZE))
    truth[:, P_BP_W] = np.column_stack([0.5 + 0.1 * k, -0.3 + 0.2 * k, -2.0 + 0.3 * k])
    truth[:, V_WP] = np.column_stack([1.0 + k, -2.0 - k, 0.1 * k])
    truth[:, HEIGHT], truth[:, VALID] = np.linspace(2.0, 0.2, n), 1.0
    estimate = truth.copy()
    estimate[:, P_BP_W] += [0.05, -0.07, 0.11]
    estimate[:, HEIGHT] += 0.4
    estimate[[1, 4], VALID] = 0.0
    log.update(true_relative_state=truth, relative_state=estimate)
    return log


def test_each_flight_plot_draws_the_channel_it_names(tmp_path, monkeypatch):
    """plot_flight's lines against the log they come from: the pad at UAV + P_BP_W, the true height above the pad
    (not the estimate's), LH drawn above the pad's height, each velocity panel its own axis of V_WP, the samples
    without a valid estimate at their own times, the 3-D touchdown at the touchdown's sample (not the last)."""
    _, config = load_scenario("gv-landing")
    log, touchdown = a_tracked_log(), 3
    figures = {}
    monkeypatch.setattr(landing_plots, "save_figure", lambda fig, path: figures.update({path.name: fig}))
    landing_plots.plot_flight(log, config, tmp_path, touchdown)
    p_uav, truth = log["quadrotor_state"][:, :3], log["true_relative_state"]

    top = figures["trajectories_top.png"].axes[0]
    np.testing.assert_allclose(labelled(top, "UGV (pad centre)").get_xydata(), p_uav[:, :2] + truth[:, :2])
    scene = figures["trajectories_3d.png"].axes[0]
    np.testing.assert_allclose(np.array(labelled(scene, "UGV (pad centre)").get_data_3d()).T, p_uav + truth[:, P_BP_W])
    mark = next(c for c in scene.collections if c.get_label() == "touchdown")
    np.testing.assert_allclose(np.ravel(mark._offsets3d), p_uav[touchdown])
    altitude = figures["altitude.png"].axes[0]
    np.testing.assert_allclose(labelled(altitude, "UAV above the pad").get_ydata(), truth[:, HEIGHT])
    assert labelled(altitude, "LH above the pad").get_ydata()[0] == pytest.approx(
        config.platform.height_m + config.landing.landing_height_m)
    for i, ax in enumerate(figures["velocity.png"].axes):
        np.testing.assert_allclose(labelled(ax, "UGV (pad centre)").get_ydata(), truth[:, V_WP][:, i])
    unseen = log["relative_state"][:, VALID] < 0.5
    for i, ax in enumerate(figures["tracking_error.png"].axes):
        ticks = labelled(ax, "no valid estimate")
        np.testing.assert_array_equal(ticks.get_xdata(), log["t"][unseen])
        np.testing.assert_allclose(ticks.get_ydata(), truth[unseen, i])


def test_the_perception_plot_draws_the_estimate_only_where_it_is_valid(tmp_path, monkeypatch):
    """perception.png's estimate lines: UAV + the seam's P_BP_W where the estimate is valid, a gap (NaN) where it
    is not, and the truth at UAV + the true P_BP_W."""
    log = a_tracked_log()
    figures = []
    monkeypatch.setattr(landing_plots, "save_figure", lambda fig, path: figures.append(fig))
    landing_plots.plot_perception(log, "hybrid", tmp_path, heading=False)
    p_uav, valid = log["quadrotor_state"][:, :3], log["relative_state"][:, VALID] > 0.5
    expected = np.where(valid[:, None], p_uav + log["relative_state"][:, P_BP_W], np.nan)
    for i, ax in enumerate(figures[0].axes[:3]):
        lines = {line.get_label(): line.get_ydata() for line in ax.get_lines()}
        np.testing.assert_allclose(lines["hybrid (valid)"], expected[:, i])  # NaN where NaN
        np.testing.assert_allclose(lines["true"], p_uav[:, i] + log["true_relative_state"][:, i])


def test_the_flight_plots_draw_the_uav_the_path_near_it_and_the_mode_changes(tmp_path, monkeypatch):
    """On a_tracked_log with the UAV's velocity, its command and the modes set: the path drawn only where it is
    near the flight (on both axes), the UAV's start (3-D and top view), its altitude (z), the pad's height, the
    dotted lines where APPROACH and LAND were decided (one sample before the first logged) and at the touchdown,
    and each velocity panel's UAV and desired velocity on its own axis."""
    _, config = load_scenario("gv-landing")
    assert config.platform.height_m != config.landing.landing_height_m
    log, touchdown, k = a_tracked_log(), 3, np.arange(6.0)
    log["quadrotor_state"][:, V_WB] = np.column_stack([0.3 * k, -0.2 * k, np.full(6, 0.1)])
    log["command"][:, :3] = np.column_stack([k, -k, 0.5 * k])
    log["mode"] = np.array([int(m) for m in (Mode.FOLLOW, Mode.FOLLOW, Mode.APPROACH, Mode.APPROACH, Mode.LAND,
                                              Mode.LANDED)])
    path_xy = np.array([[0.0, 0.0], [100.0, 0.0], [0.0, 100.0], [100.0, 100.0]])
    figures = {}
    monkeypatch.setattr(landing_plots, "save_figure", lambda fig, path: figures.update({path.name: fig}))
    landing_plots.plot_flight(log, config, tmp_path, touchdown, path_xy)
    # The UAV spans x 0..5, y 0..10 m and the pad x 0.5..6, y -0.3..11: 11.3 m, + 20 m; the pad's mean (3.25, 5.2).
    # Of the path only the origin is within 31.3 m of it on both axes ((100, 0) and (0, 100) on one only).
    top = figures["trajectories_top.png"].axes[0]
    np.testing.assert_array_equal(labelled(top, "path").get_xydata(), [[0.0, 0.0]])
    np.testing.assert_array_equal(labelled(top, "UAV start").get_xydata(), [[0.0, 0.0]])  # not the last (5, 10)
    start = next(c for c in figures["trajectories_3d.png"].axes[0].collections if c.get_label() != "touchdown")
    np.testing.assert_allclose(np.ravel(start._offsets3d), [0.0, 0.0, 3.0])
    altitude = figures["altitude.png"].axes[0]
    np.testing.assert_allclose(labelled(altitude, "UAV altitude").get_ydata(), np.linspace(3.0, 1.0, 6))
    np.testing.assert_allclose(labelled(altitude, "pad").get_ydata(), config.platform.height_m)
    for ax in [altitude, *figures["velocity.png"].axes]:
        dotted = [(line.get_xdata()[0], line.get_color()) for line in ax.get_lines() if line.get_linestyle() == ":"
                  and line.get_label().startswith("_")]
        assert [x for x, _ in dotted] == pytest.approx([0.2, 0.6, 0.6])  # APPROACH at t[1], LAND at t[3], touchdown
        assert [colour for _, colour in dotted] == ["tab:green", "tab:orange", "tab:red"]
    for i, ax in enumerate(figures["velocity.png"].axes):
        np.testing.assert_allclose(labelled(ax, "UAV").get_ydata(), [0.3 * k, -0.2 * k, np.full(6, 0.1)][i])
        np.testing.assert_allclose(labelled(ax, "UAV desired").get_ydata(), [k, -k, 0.5 * k][i])


def test_the_modes_are_shaded_from_each_change_to_the_next_in_their_own_colours():
    fig, ax = plt.subplots()
    mode = np.array([int(Mode.FOLLOW)] * 3 + [int(Mode.LAND)] * 3)
    landing_plots.shade_modes(ax, {"t": np.arange(6.0), "mode": mode})  # LAND from t[3] to the last sample
    assert [(patch.get_x(), patch.get_x() + patch.get_width()) for patch in ax.patches] == [(0.0, 3.0), (3.0, 5.0)]
    assert [to_hex(patch.get_facecolor()) for patch in ax.patches] == [
        to_hex(landing_plots.MODE_COLOURS[Mode.FOLLOW]), to_hex(landing_plots.MODE_COLOURS[Mode.LAND])]
    plt.close(fig)


@pytest.mark.parametrize("heading", [True, False], ids=["heading", "position-alone"])
def test_the_perception_plot_draws_the_position_error_from_its_floor_and_the_heading_error(heading, tmp_path,
                                                                                         monkeypatch):
    """a_tracked_log's estimate exact at sample 0 (drawn at the floor of the log scale), off by (0.05, -0.07, 0.11) m
    elsewhere, samples 1 and 4 invalid (gaps); the vehicle heading 90 deg and the steering estimate yawed 30 deg: a
    heading error of -60 deg. The invalid samples are ticked at 0 deg, or at the floor where no heading is drawn."""
    log = a_tracked_log()
    log["relative_state"][0, P_BP_W] = log["true_relative_state"][0, P_BP_W]
    log["vehicle_state"] = np.zeros((6, 4))
    log["vehicle_state"][:, GV_HEADING] = np.radians(90.0)
    half = np.radians(30.0) / 2  # [valid, x, y, z, qw, qx, qy, qz], a yaw about z
    log["steering_estimate"] = np.tile([1.0, 0.2, 0.3, 0.4, np.cos(half), 0.0, 0.0, np.sin(half)], (6, 1))
    figures = []
    monkeypatch.setattr(landing_plots, "save_figure", lambda fig, path: figures.append(fig))
    landing_plots.plot_perception(log, "ct_ekf", tmp_path, heading)
    axes, floor = figures[0].axes, landing_plots.ERROR_FLOOR_M
    off = np.sqrt(0.05**2 + 0.07**2 + 0.11**2)
    np.testing.assert_allclose(axes[3].get_lines()[0].get_ydata(), [floor, np.nan, off, off, np.nan, off])
    assert len(axes) == (5 if heading else 4)
    if heading:
        np.testing.assert_allclose(axes[4].get_lines()[0].get_ydata(), -60.0)
    ticks = labelled(axes[-1], "no valid estimate")
    np.testing.assert_array_equal(ticks.get_xdata(), log["t"][[1, 4]])
    np.testing.assert_array_equal(ticks.get_ydata(), [0.0, 0.0] if heading else [floor, floor])
