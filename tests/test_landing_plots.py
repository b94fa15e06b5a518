"""The landing plots name what carries the pad: the UGV and its path, or the pad alone on the ground; they mark
the touchdown where the metrics put it."""

import numpy as np
import pytest

from diagrams import landing_plots
from diagrams.landing_metrics import gv_touchdown, landing_metrics
from diagrams.runner import load_scenario
from systems.control.landing import Mode
from systems.perception.seam import HEIGHT, RELATIVE_STATE_SIZE, VALID


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
