"""The landing plots name what carries the pad: the UGV and its path, or the pad alone on the ground."""

import numpy as np
import pytest

from diagrams import landing_plots
from diagrams.runner import load_scenario
from systems.control.landing import Mode
from systems.perception.seam import RELATIVE_STATE_SIZE, VALID


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
    landing_plots.plot_flight(a_short_log(), config, tmp_path)
    titles = [ax.get_title() for fig in figures for ax in fig.axes if ax.get_title()]
    labels = [line.get_label() for fig in figures for ax in fig.axes for line in ax.get_lines()]
    assert titles and all(says in title for title in titles)
    assert any(f"UAV and {carrier} " in title for title in titles)
    assert any("UGV" in text for text in titles + labels) == (carrier == "UGV")
