"""The benchmarks' counting and summarising on synthetic inputs: no flight, no render, nothing timed.
Each feeds a benchmark's own function figures it could have been given and checks what it counts,
prints and passes."""

import benchmarks.vision_landing as vision_landing


def _landing_figures(runs: int, landed: int) -> dict:
    error = {"median": 0.01, "p95": 0.01, "max": 0.01}
    return {"runs": runs, "landed": landed, "meets_targets": landed, "failures": [], "touchdown_error_m": error,
            "touchdown_rel_speed_mps": {"median": 0.3, "p95": 0.3, "max": 0.3}, "steering_rms_position_m": 0.01,
            "coast_before_touchdown_s": None, "time_to_land_s": None}


def test_vision_landing_counts_a_run_that_raised_as_not_landed(monkeypatch, tmp_path, capsys):
    # 10 asked per source; one ct_ekf run raised: the campaign's aggregate holds the 9 that finished.
    summary = {"filters": {"landing": {"ct_ekf": _landing_figures(9, 9), "paper_ekf": _landing_figures(10, 10),
                                       "truth": _landing_figures(10, 10)}},
               "cases": {"ct_ekf": {"requested": 10, "done": 9, "failed": 1},
                         "paper_ekf": {"requested": 10, "done": 10, "failed": 0},
                         "truth": {"requested": 10, "done": 10, "failed": 0}}}
    monkeypatch.setattr(vision_landing, "campaign_definition", lambda name: None)
    monkeypatch.setattr(vision_landing, "campaign_settings", lambda *args: None)
    monkeypatch.setattr(vision_landing, "run_campaign", lambda *args, **kwargs: summary)
    result = vision_landing.closed_loop(10, 0, tmp_path)
    checks = {label: (ok, detail) for label, ok, detail in result["checks"]}
    ok, detail = checks["ct_ekf: every run lands on the pad"]
    assert not ok and detail.startswith("9/10")
    out = capsys.readouterr().out
    assert "| ct_ekf | 9/10 (1 raised) | 9/10 |" in out and "| truth | 10/10 | 10/10 |" in out
    assert result["figures"]["ct_ekf"]["runs"] == 10 and result["figures"]["ct_ekf"]["failed"] == 1
