"""benchmarks/landing_campaign.py's `--set`: the overrides reach every group's runs (the exit code 0 or 1 as its
targets' checks); a bad one is one line, exit 2, nothing written."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow  # spawns the benchmark

BENCHMARK = Path(__file__).resolve().parents[1] / "benchmarks" / "landing_campaign.py"
NO_RUNS = ["--rendered-runs", "0", "--throughput-runs", "0", "--scaling-runs", "0", "--workers", "0"]


def run(*args, out: Path):
    return subprocess.run([sys.executable, str(BENCHMARK), *args, *NO_RUNS, "--out", str(out)],
                          capture_output=True, text=True, timeout=600, check=False)


def test_set_overrides_reach_the_campaign(tmp_path):
    result = run("--only", "still", "--runs", "1", "--set", "landing.land_acceptance_radius_m=0.15",
                 "--json", str(tmp_path / "figures.json"), out=tmp_path / "c")
    written = json.loads((tmp_path / "figures.json").read_text())
    assert result.returncode == (0 if all(met for _, met, _ in written["checks"]) else 1), result.stderr[-2000:]
    campaign = json.loads((tmp_path / "c" / "still-synthetic" / "campaign.json").read_text())
    assert campaign["overrides"][-1] == "landing.land_acceptance_radius_m=0.15"
    figures = written["figures"]["still-synthetic"]
    assert figures["cases"]["vehicle.speed=3"]["done"] == 1


def test_a_bad_override_is_one_line_and_exit_2(tmp_path):
    for value, message in (("landing.nope=1", "unknown key 'landing.nope'"),
                           ("landing.land_acceptance_radius_m=-1", "must not be negative")):
        result = run("--set", value, out=tmp_path / "c")
        assert result.returncode == 2 and message in result.stderr
        assert len(result.stderr.strip().splitlines()) == 1
        assert not (tmp_path / "c").exists()
