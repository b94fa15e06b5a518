"""Landing campaigns over any fields of a gv scenario (`--case KEY=V1,V2`): the grid of cases, its
checks (a field no scenario has, a value of the wrong type, a scenario that does not land), a small
campaign in this process with its per-case landing figures, resumed, and the command line."""

import json

import pytest

from diagrams.cli import main
from diagrams.montecarlo import run_campaign
from diagrams.montecarlo.grid import grid_cases, grid_settings, parse_case_option
from systems.config import ConfigError

pytestmark = pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")


def test_the_grid_is_the_product_of_the_fields_values_in_order():
    assert grid_cases(["vehicle.speed=3,6,12", "wind.mean_m_s=0,5"]) == (
        "vehicle.speed=3,wind.mean_m_s=0", "vehicle.speed=3,wind.mean_m_s=5", "vehicle.speed=6,wind.mean_m_s=0",
        "vehicle.speed=6,wind.mean_m_s=5", "vehicle.speed=12,wind.mean_m_s=0", "vehicle.speed=12,wind.mean_m_s=5")
    assert parse_case_option("seed = 1, 2") == ("seed", ["1", "2"])


@pytest.mark.parametrize("options, message", [
    (["vehicle.speed"], "--case expects KEY=VALUE"), (["vehicle.speed=3,,6"], "--case expects KEY=VALUE"),
    (["vehicle.speed=3,3"], "given twice"), (["vehicle.speed=3", "vehicle.speed=6"], "a field is given twice"),
])
def test_malformed_case_options_are_config_errors(options, message):
    with pytest.raises(ConfigError, match=message):
        grid_cases(options)


@pytest.mark.parametrize("scenario, options, overrides, message", [
    ("gv-landing", ["vehicle.sped=3,6"], [], r"unknown key 'vehicle\.sped'"),
    ("gv-landing", ["vehicle.speed=3,fast"], [], r"vehicle\.speed must be a number"),
    ("gv-landing", ["vehicle.speed=3,6"], ["vehicle.speed=1"], r"--set vehicle\.speed: a --case sets it"),
    ("stewart-dynamic", ["seed=1,2"], [], "not a landing scenario"),
])
def test_bad_grids_name_the_field_before_anything_runs(scenario, options, overrides, message):
    with pytest.raises(ConfigError, match=message):
        grid_settings(scenario, options, 1, 0, overrides)


def test_a_grid_campaign_lands_every_case_and_summarises_each(tmp_path):
    definition, settings = grid_settings("gv-landing", ["vehicle.speed=0.5,1.0"], 1, 0, ["vehicle.path=straight"])
    summary = run_campaign(definition, settings, tmp_path, workers=0, progress=False)
    assert set(summary["cases"]) == {"vehicle.speed=0.5", "vehicle.speed=1.0"}
    for case in summary["cases"].values():
        assert case["done"] == 1 and case["success_rate"] == 1.0 and case["aborts"] == 0
        assert case["touchdown_error_m"]["max"] < 0.01 and case["touchdown_rel_speed_mps"]["max"] < 0.5
        assert case["failure_reasons"] == {}
    record = json.loads((tmp_path / "runs" / "vehicle.speed=1.0" / "00000.json").read_text())
    assert record["case"] == "vehicle.speed=1.0"
    assert (tmp_path / "touchdowns.png").stat().st_size > 0
    again = run_campaign(definition, settings, tmp_path, workers=0, progress=False)  # resumed: nothing to do
    assert again["runs"]["computed_now"] == 0 and again["cases"] == summary["cases"]


def test_case_and_cases_do_not_mix_on_the_command_line(capfd, tmp_path):
    code = main(["montecarlo", "gv-landing", "--case", "vehicle.speed=1,2", "--cases", "3", "--out", str(tmp_path / "x")])
    assert code == 2
    err = capfd.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--case and --cases" in err and not (tmp_path / "x").exists()
