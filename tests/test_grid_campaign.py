"""Landing campaigns over any fields of a gv scenario (`--case KEY=V1,V2`): the grid of cases, its
checks (a field no scenario has, a value of the wrong type, a scenario that does not land), a small
campaign in this process with its per-case landing figures, resumed, its touchdown plot, and the command line."""

import json
from types import SimpleNamespace

import numpy as np
import pytest

from diagrams import landing_campaign
from diagrams.cli import main
from diagrams.landing_campaign import CAMPAIGN, landing_case_summary, run_task
from diagrams.montecarlo import campaign_definition, campaign_settings, grid, run_campaign
from diagrams.montecarlo.grid import grid_cases, grid_settings, parse_case_option
from diagrams.montecarlo.settings import GRID, RunTask
from systems.config import ConfigError

pytestmark = pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")


def test_the_grid_is_the_product_of_the_fields_values_in_order():
    assert grid_cases(["vehicle.speed=3,6,12", "wind.mean_m_s=0,5"]) == (
        "vehicle.speed=3,wind.mean_m_s=0", "vehicle.speed=3,wind.mean_m_s=5", "vehicle.speed=6,wind.mean_m_s=0",
        "vehicle.speed=6,wind.mean_m_s=5", "vehicle.speed=12,wind.mean_m_s=0", "vehicle.speed=12,wind.mean_m_s=5")
    assert parse_case_option("vehicle.speed = 1, 2") == ("vehicle.speed", ["1", "2"])
    assert parse_case_option("x=1,true") == ("x", ["1", "true"])  # a bool is no number: not the value 1 twice


def test_a_grid_runs_scenario_applies_each_of_its_cases_assignments_and_its_seed():
    task = RunTask("gv-landing", "vehicle.speed=3,start.height_m=2", 0, 7, (), GRID)
    name, scenario = task.load_scenario()
    assert name == "gv-landing" and scenario.seed == 7
    assert (scenario.vehicle.speed, scenario.start.height_m) == (3.0, 2.0)


@pytest.mark.parametrize("options, message", [
    (["vehicle.speed"], "--case expects KEY=VALUE"), (["vehicle.speed=3,,6"], "--case expects KEY=VALUE"),
    (["vehicle.speed=3,3"], "given twice"), (["vehicle.speed=3", "vehicle.speed=6"], "a field is given twice"),
    (["vehicle.speed=3,3.0,3e0"], "given twice"),  # one value: one case flown three times on the same seeds
    (["vehicle.speed=3,3.0"], "given twice"),  # an int and a float of one value
    ([" =1,2"], "--case expects KEY=VALUE"),  # a key of spaces is no key
    (["seed=1,2"], "the campaign seeds each run"),  # the run's seed would replace it: two cases, one scenario
    (["seed = 1, 2"], "the campaign seeds each run"),  # spaces around the key are no other key
])
def test_malformed_case_options_are_config_errors(options, message):
    with pytest.raises(ConfigError, match=message):
        grid_cases(options)


@pytest.mark.parametrize("scenario, options, overrides, message", [
    ("gv-landing", ["vehicle.sped=3,6"], [], r"unknown key 'vehicle\.sped'"),
    ("gv-landing", ["vehicle.speed=3,fast"], [], r"vehicle\.speed must be a number"),
    ("gv-landing", ["vehicle.speed=3,6"], ["vehicle.speed=1"], r"--set vehicle\.speed: a --case sets it"),
    ("gv-landing", ["vehicle.speed = 3,6"], ["vehicle.speed=1"], r"--set vehicle\.speed: a --case sets it"),
    ("stewart-dynamic", ["seed=1,2"], [], "not a landing scenario"),
    ("gv-marker-ekf", ["vehicle.speed=3,6"], [], "not a landing scenario"),  # a gv scenario that flies no landing
    ("rqrlp-maneuvers", ["seed=1,2"], [], "not a landing scenario"),  # it flies, and lands nowhere
    ("gv-landing", ["vehicle.speed=3,6"], ["seed=5"], "the campaign seeds each run"),
    ("gv-landing", [f"vehicle.speed={'1' * 310}"], [], "too long to name a directory"),  # beyond a float
    ("gv-landing", ["vehicle.path=[a"], [], "cannot name a directory"),  # no YAML, and no file name
])
def test_bad_grids_name_the_field_before_anything_runs(scenario, options, overrides, message):
    with pytest.raises(ConfigError, match=message):
        grid_settings(scenario, options, 1, 0, overrides)


def test_a_setting_only_some_seeds_refuse_is_an_error_before_anything_runs(capfd, tmp_path):
    # A 17 deg roll leaves the legs' stroke in the motion of some seeds only: runs 0 to 3 load, run 4 not.
    overrides = ["platform.roll_amplitude_deg=[17.0]", "duration_s=60"]
    with pytest.raises(ConfigError, match=r"run 4 \(seed 877150602\): platform: the motion leaves the legs' stroke"):
        grid_settings("deck-landing", ["perception.source=truth"], 6, 1, overrides)
    assert main(["montecarlo", "deck-landing", "--case", "perception.source=truth", "--runs", "6", "--seed", "1",
                 "--set", overrides[0], "--set", overrides[1], "--out", str(tmp_path / "x")]) == 2
    err = capfd.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "run 4" in err and not (tmp_path / "x").exists()


def test_a_setting_only_the_build_refuses_is_an_error_before_anything_is_written(capfd, tmp_path):
    # CRHF reads its pad calibration when the deck's diagram is built, not when the scenario loads.
    missing = tmp_path / "missing.npz"
    assert main(["montecarlo", "deck-landing", "--case", "perception.source=truth,atda", "--runs", "2", "--set",
                 f"crhf.calibration_file={missing}", "--set", "duration_s=1", "--workers", "0",
                 "--out", str(tmp_path / "x"), "--quiet"]) == 2
    err = capfd.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "case perception.source=truth, run 0" in err, err
    assert f"pad calibration file {missing} does not exist" in err and not (tmp_path / "x").exists()
    # A source's campaign builds each source's diagram too: the hybrid source loads its detector's model there.
    with pytest.raises(ConfigError, match=r"source hybrid, run 0 .*missing\.onnx does not exist"):
        campaign_settings(CAMPAIGN, "marker-landing", ["truth", "hybrid"], 1, 0,
                          [f"hybrid.model_path={tmp_path / 'missing.onnx'}"])


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


def test_a_landing_run_keeps_its_seed_and_the_landing_sections_of_what_it_flew(monkeypatch):
    flown = []

    def fly(scenario, duration_s):
        flown.append(scenario)
        return {"landing": {"x": 1}, "junk": 2}, None

    monkeypatch.setattr(landing_campaign, "_run_module", lambda diagram: SimpleNamespace(fly=fly))
    assert run_task(RunTask("gv-landing", "vehicle.speed=3", 2, 7, (), GRID)) == {"seed": 7, "landing": {"x": 1}}
    assert [(scenario.seed, scenario.vehicle.speed) for scenario in flown] == [(7, 3.0)]


def test_a_sources_campaign_flies_run_i_of_every_source_on_one_seed():
    """As the command builds it (`--cases truth ct_ekf --runs 2`): the sources are compared on the same noise."""
    settings = campaign_settings(campaign_definition("marker-landing"), "marker-landing", ["truth", "ct_ekf"], 2, 0)
    seeds = {}
    for task in settings.tasks():
        seeds.setdefault(task.case, []).append(task.seed)
    assert seeds["truth"] == seeds["ct_ekf"] and len(set(seeds["truth"])) == 2


def a_landing(error_m: float | None, speed_mps: float | None, xy_m=None) -> SimpleNamespace:
    """A run record's metrics as a landing campaign writes them; None: no touchdown."""
    landed = error_m is not None
    return SimpleNamespace(metrics={"landing": {
        "success": landed, "touchdown_error_m": error_m, "touchdown_rel_speed_mps": speed_mps,
        "touchdown_offset_pad_xy_m": xy_m, "failure_reason": None if landed else "timeout", "aborts": 0,
        "meets_targets": landed and error_m < 0.10 and speed_mps < 0.5}})


def test_a_run_that_raised_counts_against_the_success_rate():
    summary = landing_case_summary([a_landing(0.01, 0.3), a_landing(0.02, 0.3), a_landing(None, None)], failed=1)
    assert summary["success_rate"] == 0.5 and (summary["landed"], summary["ended"]) == (2, 4)
    assert summary["failure_reasons"] == {"timeout": 1, "run_failed": 1}
    assert summary["touchdown_error_m"]["max"] == 0.02


def test_a_case_with_no_run_ended_has_no_success_rate():
    summary = landing_case_summary([])
    assert summary["success_rate"] is None and (summary["landed"], summary["ended"]) == (0, 0)


def test_a_cases_touchdowns_aborts_targets_and_waits_are_each_over_the_runs_they_name():
    """On a deck: the touchdown figures are over every run that touched down, a failed (hard) touchdown included;
    aborts and the targets met are counted over every run (the aborts of a run that never touched down too; a
    success that misses the targets not counted); the tilt over the touchdowns, the waits over every run."""
    def deck(success, error_m, speed_mps, reason, aborts, meets, wait_s, tilt_deg=None):
        landing = {"success": success, "touchdown_error_m": error_m, "touchdown_rel_speed_mps": speed_mps,
                   "failure_reason": reason, "aborts": aborts, "meets_targets": meets, "wait_s": wait_s}
        if tilt_deg is not None:  # only a run that touched down has a tilt at touchdown
            landing["deck_tilt_at_touchdown_deg"] = tilt_deg
        return SimpleNamespace(metrics={"landing": landing})

    records = [deck(True, 0.02, 0.3, None, 0, True, 1.0, 2.0),
               deck(False, 0.3, 1.2, "hard", 0, False, 4.0, 5.0),  # touched down, too hard
               deck(False, None, None, "timeout", 2, False, 10.0),  # aborted twice, never touched down
               deck(True, 0.12, 0.6, None, 0, False, 2.0, 3.0)]  # landed, off the targets

    def percentiles(values):
        return {"p50": np.median(values), "p95": np.percentile(values, 95), "max": np.max(values)}

    summary = landing_case_summary(records)
    assert (summary["landed"], summary["aborts"], summary["meets_targets"]) == (2, 2, 1)
    assert summary["failure_reasons"] == {"hard": 1, "timeout": 1}
    for key, values in (("touchdown_error_m", [0.02, 0.3, 0.12]), ("touchdown_rel_speed_mps", [0.3, 1.2, 0.6]),
                        ("deck_tilt_at_touchdown_deg", [2.0, 5.0, 3.0]), ("wait_s", [1.0, 4.0, 10.0, 2.0])):
        assert summary[key] == pytest.approx(percentiles(values)), key


def test_a_sources_figures_are_a_cases_with_the_steering_figures_added():
    """`--cases` (per source) and `--case` (per case) summarise landings in one summary, summary.json's "cases"."""
    records = [a_landing(0.01, 0.3), a_landing(0.02, 0.3), a_landing(None, None)]
    for record, steering_m, coast_s, land_s in zip(records, (0.03, 0.04, None), (0.5, None, None), (20.0, 30.0, None),
                                                   strict=True):
        record.metrics["perception"] = {"rms_position_m": steering_m, "coast_before_touchdown_s": coast_s}
        record.metrics["landing"]["time_to_land_s"] = land_s
    summary = CAMPAIGN.case_summary(records, 1)  # one run raised
    case = landing_case_summary(records, 1)
    assert {key: summary[key] for key in case} == case
    assert summary["success_rate"] == 0.5 and summary["failure_reasons"] == {"timeout": 1, "run_failed": 1}
    assert summary["touchdown_error_m"] == {"p50": 0.015, "p95": pytest.approx(0.0195), "max": 0.02}
    assert summary["steering_rms_position_m"] == pytest.approx(0.5 ** 0.5 * 0.05)  # RMS of 0.03 and 0.04 m
    assert summary["coast_before_touchdown_s"] == {"p50": 0.5, "p95": 0.5, "max": 0.5}
    assert summary["time_to_land_s"]["p50"] == 25.0
    assert CAMPAIGN.aggregate({"truth": records}) == {}  # nothing in "filters" beside it


def test_the_touchdown_plot_zooms_on_clustered_points_and_counts_each_cases_landings(tmp_path, monkeypatch):
    figures = []
    monkeypatch.setattr(grid, "save_figure", lambda fig, path: figures.append(fig))
    a, b = "platform.pad_size_m=1.0", "platform.pad_size_m=1.6"  # a case may set the pad's size
    done = {a: [a_landing(0.004, 0.3, [0.003, -0.0027]), a_landing(0.002, 0.6, [-0.002, 0.0])],
            b: [a_landing(0.001, 0.4, [0.001, 0.0]), a_landing(None, None)]}
    grid.plot_grid(SimpleNamespace(scenario="gv-landing", overrides=[], runs=3), done, tmp_path)  # one run raised
    pad, zoom, errors, speeds = figures[0].axes
    assert 0.8 < pad.get_xlim()[1] < 0.9  # the larger pad whole
    outlines = sorted(max(line.get_xdata()) for line in pad.get_lines())
    assert outlines == pytest.approx([0.5, 0.8])  # each size's outline [m]
    assert 3.0 < zoom.get_xlim()[1] < 12.0 and 3.0 < zoom.get_ylim()[1] < 12.0  # mm: the farthest coordinate 3 mm
    ticks = [label.get_text() for label in errors.get_yticklabels()]
    assert ticks == [f"{a}\nlanded 2/3, within every target 1/3", f"{b}\nlanded 1/3, within every target 1/3"]
    assert [list(line.get_xdata()) for line in errors.get_lines()[:2]] == [[0.004, 0.002], [0.001]]
    assert [list(line.get_xdata()) for line in speeds.get_lines()[:2]] == [[0.3, 0.6], [0.4]]


def test_case_and_cases_do_not_mix_on_the_command_line(capfd, tmp_path):
    code = main(["montecarlo", "gv-landing", "--case", "vehicle.speed=1,2", "--cases", "3", "--out", str(tmp_path / "x")])
    assert code == 2
    err = capfd.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--case and --cases" in err and not (tmp_path / "x").exists()
