"""Faults in the marker stream: covered camera (fixed intervals and seeded random bursts), dropped
frames and outliers, against their configured rates; their settings' checks; and in the loop, a
landing on a stream with outliers and bursts, the filter gating the outliers and the supervisor
aborting rather than descending blind."""

import math
from fractions import Fraction

import numpy as np
import pytest
from pydrake.common.value import AbstractValue
from scipy.spatial.transform import Rotation

from diagrams.cli import main
from diagrams.gv_landing_run import fly
from diagrams.runner import load_scenario
from systems.config import ConfigError
from systems.perception.marker_faults import FaultsConfig, MarkerFaults, apply_faults, occluded
from systems.perception.markers import MarkerMeasurement

pytestmark = pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")

T = 0.035
FRAME = [MarkerMeasurement(0.0, i, [0.1 * i, 0.0, 2.0], [0.0, 0.0, 0.0, 1.0]) for i in range(3)]


def covered_runs(covered) -> np.ndarray:
    """The lengths of the runs of covered samples (True) that start and end inside `covered`."""
    steps = np.diff(np.asarray(covered, dtype=int))
    starts, ends = np.flatnonzero(steps == 1) + 1, np.flatnonzero(steps == -1) + 1
    return ends[ends > starts[0]][:len(starts) - 1] - starts[:len(starts) - 1]


def test_a_fixed_occlusion_covers_its_interval_and_nothing_else():
    config = FaultsConfig(occlusions_s=[[1.0, 1.5]])
    covered = [k for k in range(100) if not apply_faults(FRAME, k, T, config, seed=0)]
    assert covered == [k for k in range(100) if 1.0 <= k * T <= 1.5]
    assert apply_faults(FRAME, 10, T, config, seed=0) == FRAME  # untouched outside


def test_an_occlusion_bound_on_a_sample_covers_that_sample():
    # [1.0, 3.5] s on the 35 ms grid: 1.0 / 0.035 is not whole, 3.5 s is sample 100 (100 * 0.035 is 3.5000000000000004
    # in floating point): samples 29 to 100, both ends included.
    config = FaultsConfig(occlusions_s=[[1.0, 3.5]])
    assert [k for k in range(200) if occluded(k, T, config, seed=0)] == list(range(29, 101))
    config = FaultsConfig(occlusions_s=[[0.35, 0.7]])  # samples 10 and 20 exactly
    assert [k for k in range(200) if occluded(k, T, config, seed=0)] == list(range(10, 21))


def test_random_bursts_cover_the_share_their_rate_and_length_give_and_are_seeded():
    config = FaultsConfig(occlusion_rate_hz=0.2, occlusion_duration_s=0.5)
    covered = np.array([occluded(k, T, config, seed=3) for k in range(20000)])
    n = math.ceil(0.5 / T)
    expected = 1 - (1 - 0.2 * T) ** n
    assert covered.mean() == pytest.approx(expected, abs=4 * math.sqrt(expected * n / covered.size))
    lengths = covered_runs(covered)
    # a lone burst covers exactly its n samples (most of them: another starts within one with 1 - (1 - rate T)^n,
    # 10 %), two or more overlapping ones longer
    assert lengths.min() == n and np.bincount(lengths).argmax() == n
    assert np.array_equal(covered, [occluded(k, T, config, seed=3) for k in range(20000)])
    assert not np.array_equal(covered, [occluded(k, T, config, seed=4) for k in range(20000)])


def test_a_burst_a_whole_number_of_periods_long_covers_that_many_samples():
    """A 0.14 s burst on a 20 ms stream covers 7 samples: 0.14 / 0.02 is 7 (7.000000000000001 in floating point,
    whose ceiling is 8), so a lone burst is 7 samples long."""
    n = Fraction("0.14") / Fraction("0.02")
    assert n == 7
    config = FaultsConfig(occlusion_rate_hz=1.0, occlusion_duration_s=0.14)
    lengths = covered_runs([occluded(k, 0.02, config, seed=2) for k in range(2000)])
    # about 40 bursts, each overlapped by another with 1 - (1 - rate T)^7, 13 %: most alone
    assert lengths.min() == n and np.bincount(lengths).argmax() == n


def test_drops_and_outliers_at_their_rates_with_their_errors():
    config = FaultsConfig(drop_probability=0.1, outlier_probability=0.2, outlier_position_m=0.5, outlier_deg=20.0)
    frames = [apply_faults(FRAME, k, T, config, seed=1) for k in range(5000)]
    dropped = np.array([not f for f in frames])
    assert dropped.mean() == pytest.approx(0.1, abs=0.015)
    moved, angles = [], []
    for frame in frames:
        for m, original in zip(frame, FRAME):
            moved.append(m.p_CM - original.p_CM)
            angles.append(np.degrees((Rotation.from_quat(m.q_CM) * Rotation.from_quat(original.q_CM).inv()).magnitude()))
    moved, angles = np.array(moved), np.array(angles)
    is_outlier = np.linalg.norm(moved, axis=1) > 0
    assert is_outlier.mean() == pytest.approx(0.2, abs=0.015)
    assert moved[is_outlier].std(axis=0) == pytest.approx([0.5] * 3, rel=0.08)
    # an outlier is moved by the error, not put at it: its displacement averages zero (~2700 outliers of 13500
    # measurements kept, standard error 0.5 / sqrt(2700) ~ 0.01 m per axis, so 0.05 m is ~5 sigma)
    assert is_outlier.sum() > 2400
    assert moved[is_outlier].mean(axis=0) == pytest.approx([0.0] * 3, abs=0.05)
    assert np.sqrt(np.mean(angles[is_outlier] ** 2)) == pytest.approx(20.0, rel=0.08)  # |N(0, 20 deg)|


@pytest.mark.parametrize("name, left", [("drop_probability", 0), ("outlier_probability", 3)])
def test_a_probability_of_one_is_allowed_and_hits_every_sample(name, left):
    """A drop or outlier probability of 1 is within [0, 1]: every frame dropped, or every measurement an outlier."""
    config = FaultsConfig(**{name: 1.0})
    config.validate()
    frames = [apply_faults(FRAME, k, T, config, seed=0) for k in range(50)]
    assert [len(frame) for frame in frames] == [left] * 50
    assert all(np.linalg.norm(m.p_CM - f.p_CM) > 0 for frame in frames for m, f in zip(frame, FRAME))


@pytest.mark.parametrize("q_CM", [[np.nan, 0.0, 0.0, 1.0], [0.0, 0.0, 0.0, 0.0]])
def test_an_outlier_leaves_a_measurement_without_a_rotation_as_it_is(q_CM):
    """Every measurement an outlier: the valid ones are moved, the one whose quaternion is NaN or zero (the
    filters' screening rejects it) comes through unchanged instead of raising in SciPy."""
    frame = [*FRAME, MarkerMeasurement(0.0, 3, [0.3, 0.0, 2.0], q_CM)]
    out = apply_faults(frame, 0, T, FaultsConfig(outlier_probability=1.0), seed=1)
    assert len(out) == 4 and out[3] is frame[3]
    assert all(np.linalg.norm(m.p_CM - f.p_CM) > 0 for m, f in zip(out[:3], FRAME))


@pytest.mark.parametrize("assignment, field", [
    ("faults.occlusions_s=[[2.0, 1.0]]", r"faults\.occlusions_s\[0\]"),
    ("faults.occlusions_s=[[1.0, 1.0]]", r"faults\.occlusions_s\[0\] must be \[start, end\] with 0 <= start < end"),
    ("faults.occlusions_s=[[1.0, 2.0, 3.0]]", r"faults\.occlusions_s\[0\] must be \[start, end\]"),
    ("faults.outlier_deg=-1", r"faults\.outlier_deg must be positive"),
    ("faults.drop_probability=1.5", r"faults\.drop_probability"),
    ("faults.occlusion_duration_s=0", r"faults\.occlusion_duration_s"),
    ("faults.occlusions_s=[[0.0, 500.0]]", "longer than the run"),
    ("faults.occlusion_rate_hz=30", r"faults\.occlusion_rate_hz \(30\) times the stream's period \(0\.035 s\) must be "
                                    "at most 1"),
])
def test_bad_fault_settings_name_the_field(assignment, field):
    with pytest.raises(ConfigError, match=field):
        load_scenario("marker-landing", overrides=["estimation.source=synthetic", assignment])


def test_a_burst_rate_above_one_per_sample_is_one_line_and_exit_2(capfd, tmp_path):
    """30 Hz of bursts on a 35 ms stream: a start probability of 1.05 per sample, refused before anything runs."""
    out = tmp_path / "run"
    code = main(["run", "marker-landing", "--set", "estimation.source=synthetic", "--set", "duration_s=1",
                 "--set", "faults.occlusion_rate_hz=30", "--out", str(out), "--quiet"])
    _, err = capfd.readouterr()
    assert code == 2 and "faults.occlusion_rate_hz (30)" in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_the_faults_system_refuses_a_burst_rate_above_one_per_sample():
    FaultsConfig(occlusion_rate_hz=20.0).check_period(0.05)  # exactly 1: every sample starts a burst
    with pytest.raises(ConfigError, match=r"faults\.occlusion_rate_hz \(100\) times the stream's period"):
        MarkerFaults(FaultsConfig(occlusion_rate_hz=100.0), T)


def test_the_faults_system_checks_its_settings():
    with pytest.raises(ConfigError, match=r"faults\.drop_probability must be within \[0, 1\], got 1\.5"):
        MarkerFaults(FaultsConfig(drop_probability=1.5), T)


def test_an_occlusion_may_last_the_whole_run():
    FaultsConfig(occlusions_s=[[0.0, 4.0]]).check_within(4.0)
    with pytest.raises(ConfigError, match=r"an occlusion of 4 s is longer than the run \(3\.5 s\)"):
        FaultsConfig(occlusions_s=[[0.0, 4.0]]).check_within(3.5)


def test_the_burst_length_limits_the_run_only_when_there_are_bursts():
    assert FaultsConfig().occlusion_duration_s == 0.5  # the default burst length, longer than the run below
    FaultsConfig().check_within(0.3)  # no bursts at rate 0
    with pytest.raises(ConfigError, match=r"faults: an occlusion of 0\.5 s is longer than the run \(0\.3 s\)"):
        FaultsConfig(occlusion_rate_hz=1.0).check_within(0.3)


def test_the_faults_system_applies_the_faults_of_the_sample_at_its_time():
    """MarkerFaults at t_k = k T gives sample k's faults, apply_faults(..., k, ...), also where k T / T is not k in
    floating point (k = 63, 119, 125, 126 at 35 ms: 118.99999999999999 for 119), where a cover of [4.15, 4.17] s
    takes sample 119 (4.165 s)."""
    config = FaultsConfig(occlusions_s=[[4.15, 4.17]], drop_probability=0.3, outlier_probability=0.3)
    system = MarkerFaults(config, T, seed=4)
    context = system.CreateDefaultContext()
    system.get_input_port().FixValue(context, AbstractValue.Make(FRAME))

    def numbers(frame):
        return [(m.marker_id, m.p_CM.tolist(), m.q_CM.tolist()) for m in frame]

    outputs = []
    for k in range(200):
        context.SetTime(k * T)
        outputs.append(system.get_output_port().Eval(context))
        assert numbers(outputs[k]) == numbers(apply_faults(FRAME, k, T, config, seed=4)), k
    assert outputs[119] == []  # covered


@pytest.mark.parametrize("fault", ["drop_probability", "outlier_probability"])
def test_faults_need_a_stream(fault):
    """Either fault alone makes the faults active (gv_landing leaves MarkerFaults out otherwise: outliers alone
    would silently never apply), and faults need a marker stream."""
    assert FaultsConfig(**{fault: 0.1}).active
    with pytest.raises(ConfigError, match="estimation.source"):
        load_scenario("gv-landing", overrides=[f"faults.{fault}=0.1"])


@pytest.mark.slow
def test_in_the_loop_outliers_are_gated_and_a_covered_final_descent_is_flown_on_the_prediction():
    # marker-landing on the synthetic stream, started low; 5 % outliers throughout, the camera covered
    # for 1.2 s during the final descent: the filter gates the outliers and predicts through the
    # cover, its estimate valid (its position std stays small), and the UAV lands on the pad.
    base = ["estimation.source=synthetic", "start.height_m=4", "start.xy_m=[1.2, 1.2]", "landing.initial_height_m=3.5"]
    _, clean = load_scenario("marker-landing", overrides=base)
    clean_metrics, _ = fly(clean, clean.duration_s)
    land_s = clean_metrics["landing"]["mode_entry_times_s"]["land"]
    cover = (land_s + 0.5, land_s + 1.7)
    _, s = load_scenario("marker-landing", overrides=[*base, "faults.outlier_probability=0.05",
                                                      f"faults.occlusions_s=[[{cover[0]}, {cover[1]}]]"])
    metrics, flight = fly(s, s.duration_s)
    gated = [m["estimators"]["ct_ekf"]["measurements"]["gated"] for m in (clean_metrics, metrics)]
    assert gated[1] > gated[0] + 10
    sampled = flight.sampled
    covered = (sampled.t >= cover[0]) & (sampled.t <= cover[1])
    assert covered.sum() > 30 and np.all(np.isnan(sampled.measurements[covered]))  # nothing got through
    assert not np.all(np.isnan(sampled.measurements[~covered]))
    landing = metrics["landing"]
    assert landing["success"] and landing["touchdown_error_m"] < 0.10 and landing["aborts"] == 0
    assert metrics["perception"]["valid_fraction"] == pytest.approx(clean_metrics["perception"]["valid_fraction"])
