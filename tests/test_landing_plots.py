"""The landing plots name what carries the pad: the UGV and its path, or the pad alone on the ground; they mark
the touchdown where the metrics put it."""

import numpy as np
import pytest

from diagrams import landing_plots
from diagrams.landing_metrics import gv_touchdown, landing_metrics
from diagrams.runner import load_scenario
from systems.control.landing import Mode
from systems.perception.seam import HEIGHT, P_BP_W, RELATIVE_STATE_SIZE, V_WP, VALID


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

    def line(ax, label):
        return next(line for line in ax.get_lines() if line.get_label() == label)

    top = figures["trajectories_top.png"].axes[0]
    np.testing.assert_allclose(line(top, "UGV (pad centre)").get_xydata(), p_uav[:, :2] + truth[:, :2])
    scene = figures["trajectories_3d.png"].axes[0]
    np.testing.assert_allclose(np.array(line(scene, "UGV (pad centre)").get_data_3d()).T, p_uav + truth[:, P_BP_W])
    mark = next(c for c in scene.collections if c.get_label() == "touchdown")
    np.testing.assert_allclose(np.ravel(mark._offsets3d), p_uav[touchdown])
    altitude = figures["altitude.png"].axes[0]
    np.testing.assert_allclose(line(altitude, "UAV above the pad").get_ydata(), truth[:, HEIGHT])
    assert line(altitude, "LH above the pad").get_ydata()[0] == pytest.approx(
        config.platform.height_m + config.landing.landing_height_m)
    for i, ax in enumerate(figures["velocity.png"].axes):
        np.testing.assert_allclose(line(ax, "UGV (pad centre)").get_ydata(), truth[:, V_WP][:, i])
    unseen = log["relative_state"][:, VALID] < 0.5
    for i, ax in enumerate(figures["tracking_error.png"].axes):
        ticks = line(ax, "no valid estimate")
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
