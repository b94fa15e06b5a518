"""Stewart platform: inverse kinematics, the motion modes, the LeafSystem's outputs, and
configuration errors."""

import math
from dataclasses import replace

import numpy as np
import pytest
from pydrake.geometry import SceneGraph
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from pydrake.systems.framework import DiagramBuilder
from scipy.stats import norm

from systems.config import ConfigError
from systems.platforms.stewart import (
    TAG_ABOVE_DECK_M,
    StewartGeometry,
    StewartMotion,
    StewartPlatform,
    StewartPlatformConfig,
    leg_lengths,
    stroke_step_s,
    stroke_violation,
    within_stroke,
)
from tests.conftest import pose


def hand_leg(config: StewartPlatformConfig, i: int, dz: float = 0.0, yaw: float = 0.0) -> float:
    """Leg i by hand for the deck at its nominal pose lifted by dz and yawed by `yaw` (rad) about its
    centre: both joints from their circles with explicit cos/sin; the vertical distance between the
    joint planes is nominal_height_m + dz."""
    a = math.radians(config.base_joint_angles_deg[i])
    b = math.radians(config.platform_joint_angles_deg[i]) + yaw
    bx, by = config.base_radius_m * math.cos(a), config.base_radius_m * math.sin(a)
    qx, qy = config.platform_radius_m * math.cos(b), config.platform_radius_m * math.sin(b)
    return math.sqrt((qx - bx) ** 2 + (qy - by) ** 2 + (config.nominal_height_m + dz) ** 2)


def nominal_top_z(config: StewartPlatformConfig) -> float:
    return config.base_joint_height_m + config.nominal_height_m + config.deck_thickness_m


def asymmetric_config() -> StewartPlatformConfig:
    """Unequal joint angles, so the six legs differ at the nominal pose."""
    return StewartPlatformConfig(base_joint_angles_deg=[-20.0, 10.0, 100.0, 140.0, 220.0, 262.0],
                                 platform_joint_angles_deg=[-50.0, 40.0, 80.0, 170.0, 190.0, 280.0],
                                 base_radius_m=0.55, platform_radius_m=0.3, nominal_height_m=0.62)


@pytest.mark.parametrize("config", [StewartPlatformConfig(), asymmetric_config()], ids=["default", "asymmetric"])
def test_leg_lengths_at_nominal_pose_match_hand_computation(config):
    geometry = StewartGeometry.from_config(config)
    np.testing.assert_allclose(geometry.X_SP0.translation(), [0.0, 0.0, nominal_top_z(config)], atol=1e-15)
    np.testing.assert_allclose(leg_lengths(geometry.X_SP0, geometry), [hand_leg(config, i) for i in range(6)],
                               rtol=0, atol=1e-12)


def test_leg_zero_of_default_platform_by_hand():
    # Base joint at -15 deg on a 0.5 m circle, deck joint at -45 deg on a 0.35 m circle, joint planes 0.6 m apart.
    c15, s15, c45, s45 = math.cos(math.radians(15)), math.sin(math.radians(15)), math.sqrt(0.5), math.sqrt(0.5)
    expected = math.sqrt((0.35 * c45 - 0.5 * c15) ** 2 + (-0.35 * s45 + 0.5 * s15) ** 2 + 0.6**2)
    geometry = StewartGeometry.from_config(StewartPlatformConfig())
    assert leg_lengths(geometry.X_SP0, geometry)[0] == pytest.approx(expected, abs=1e-12)


@pytest.mark.parametrize("dz", [-0.08, 0.05, 0.12])
def test_vertical_lift_changes_every_leg_to_the_hypotenuse(dz):
    config = asymmetric_config()
    geometry = StewartGeometry.from_config(config)
    horizontal_sq = [hand_leg(config, i) ** 2 - config.nominal_height_m**2 for i in range(6)]
    X = RigidTransform([0.0, 0.0, nominal_top_z(config) + dz])
    expected = [math.sqrt(h2 + (config.nominal_height_m + dz) ** 2) for h2 in horizontal_sq]
    np.testing.assert_allclose(leg_lengths(X, geometry), expected, rtol=0, atol=1e-12)


def test_yaw_about_the_deck_centre_follows_the_law_of_cosines():
    config, yaw = asymmetric_config(), math.radians(7.0)
    geometry = StewartGeometry.from_config(config)
    X = RigidTransform(RotationMatrix.MakeZRotation(yaw), geometry.X_SP0.translation())
    expected = [math.sqrt(config.base_radius_m**2 + config.platform_radius_m**2 - 2 * config.base_radius_m
                          * config.platform_radius_m * math.cos(math.radians(config.platform_joint_angles_deg[i]
                                                                               - config.base_joint_angles_deg[i]) + yaw)
                          + config.nominal_height_m**2) for i in range(6)]
    np.testing.assert_allclose(leg_lengths(X, geometry), expected, rtol=0, atol=1e-12)
    np.testing.assert_allclose(expected, [hand_leg(config, i, yaw=yaw) for i in range(6)], atol=1e-12)


def test_within_stroke_checks_both_ends():
    geometry = StewartGeometry.from_config(StewartPlatformConfig(leg_min_m=0.5, leg_max_m=0.85))
    assert within_stroke(np.full(6, 0.5), geometry) and within_stroke(np.full(6, 0.85), geometry)
    assert not within_stroke(np.r_[np.full(5, 0.7), 0.86], geometry)
    assert not within_stroke(np.r_[0.49, np.full(5, 0.7)], geometry)


def make_platform(config: StewartPlatformConfig, seed: int = 0):
    platform = StewartPlatform(config, SceneGraph(), seed)
    return platform, platform.CreateDefaultContext()


def outputs_at(platform, context, t):
    context.SetTime(t)
    return (platform.GetOutputPort("X_WP").Eval(context), platform.GetOutputPort("leg_lengths").Eval(context),
            platform.GetOutputPort("stroke_exceeded").Eval(context)[0])


def test_stroke_exceeded_flags_a_big_vertical_excursion():
    # z = 0.3 sin(2 pi 0.25 t): 0 at t = 0 and 2 s, +0.3 m at t = 1 s, -0.3 m at t = 3 s.
    config = StewartPlatformConfig(motion="sinusoid", z_amplitude_m=[0.3], z_frequency_hz=[0.25])
    platform, context = make_platform(config)
    top = nominal_top_z(config)
    for t, dz, exceeded in ((0.0, 0.0, 0.0), (1.0, 0.3, 1.0), (2.0, 0.0, 0.0), (3.0, -0.3, 1.0)):
        X_WP, lengths, flag = outputs_at(platform, context, t)
        np.testing.assert_allclose(X_WP.translation(), [0.0, 0.0, top + dz], atol=1e-12)
        np.testing.assert_allclose(lengths, [hand_leg(config, i, dz=dz) for i in range(6)], atol=1e-12)
        expect_outside = lengths.max() > config.leg_max_m or lengths.min() < config.leg_min_m
        assert expect_outside == bool(exceeded)
        assert flag == exceeded, f"t = {t}: legs {lengths}"


def test_static_mode_holds_the_nominal_pose():
    config = StewartPlatformConfig()
    platform, context = make_platform(config)
    expected_legs = [hand_leg(config, i) for i in range(6)]
    for t in (0.0, 0.37, 12.5, 199.0):
        X_WP, lengths, flag = outputs_at(platform, context, t)
        np.testing.assert_allclose(X_WP.GetAsMatrix4(), RigidTransform([0, 0, nominal_top_z(config)]).GetAsMatrix4(),
                                   atol=1e-15)
        np.testing.assert_allclose(lengths, expected_legs, atol=1e-12)
        assert flag == 0.0


def test_sinusoid_mode_sums_the_configured_sinusoids():
    config = StewartPlatformConfig(motion="sinusoid", x_amplitude_m=[0.02, 0.01], x_frequency_hz=[0.1, 0.35],
                                   x_phase_deg=[0.0, 30.0], pitch_amplitude_deg=[5.0], pitch_frequency_hz=[0.2])
    motion = StewartMotion(config)
    for t in (0.0, 0.8, 3.3):
        x = 0.02 * math.sin(2 * math.pi * 0.1 * t) + 0.01 * math.sin(2 * math.pi * 0.35 * t + math.radians(30))
        pitch = math.radians(5.0) * math.sin(2 * math.pi * 0.2 * t)
        np.testing.assert_allclose(motion(t), [x, 0, 0, 0, pitch, 0], atol=1e-15)


def random_walk_config() -> StewartPlatformConfig:
    return StewartPlatformConfig(motion="random_walk", x_amplitude_m=[0.03, 0.02], x_frequency_hz=[0.1, 0.2],
                                 z_amplitude_m=[0.04], z_frequency_hz=[0.1],
                                 roll_amplitude_deg=[6.0], roll_frequency_hz=[0.1],
                                 yaw_amplitude_deg=[-10.0], yaw_frequency_hz=[0.1])


# The walk is drawn in chunks of 256 knots 0.25 s apart (64 s): sample across chunk boundaries.
TIMES = np.arange(0.0, 150.0, 0.05)


def test_random_walk_is_deterministic_for_a_seed():
    walk = StewartMotion(random_walk_config(), seed=5)
    same = StewartMotion(random_walk_config(), seed=5)
    other = StewartMotion(random_walk_config(), seed=6)
    A = np.array([walk(t) for t in TIMES])
    B = np.array([same(t) for t in TIMES])
    C = np.array([other(t) for t in TIMES])
    np.testing.assert_array_equal(A, B)
    assert np.max(np.abs(A - C)) > 0.01


def test_random_walk_does_not_depend_on_the_order_of_evaluation():
    forward = StewartMotion(random_walk_config(), seed=2)
    A = np.array([forward(t) for t in TIMES])
    shuffled = StewartMotion(random_walk_config(), seed=2)
    order = np.random.default_rng(0).permutation(len(TIMES))[:200]
    for i in order:
        np.testing.assert_array_equal(shuffled(TIMES[i]), A[i])


def test_random_walk_stays_inside_its_bound_and_uses_it():
    config = random_walk_config()
    bound = np.array([0.05, 0.0, 0.04, math.radians(6.0), 0.0, math.radians(10.0)])
    for seed in range(3):
        walk = StewartMotion(config, seed)
        A = np.array([walk(t) for t in TIMES])
        assert np.all(np.abs(A) <= bound), f"seed {seed}"
        moving = bound > 0
        # It wanders over a good part of its envelope (and so is not stuck at zero).
        assert np.all(np.max(np.abs(A[:, moving]), axis=0) > 0.3 * bound[moving])
        assert np.all(A[:, ~moving] == 0.0)


def walk_at_knots(seeds=range(4), knots=2048) -> tuple[np.ndarray, np.ndarray]:
    """A random walk with every axis moving (bounds 0.5 m, 10 deg) sampled at its knots t = k h, past a burn-in
    of 64 knots (16 s, four time constants: the walk starts at zero): (offsets [seed, knot, axis], bounds)."""
    config = StewartPlatformConfig(motion="random_walk", x_amplitude_m=[0.5], y_amplitude_m=[0.5],
                                   z_amplitude_m=[0.5], roll_amplitude_deg=[10.0], pitch_amplitude_deg=[10.0],
                                   yaw_amplitude_deg=[10.0])
    h = config.random_walk_knot_interval_s
    walks = [StewartMotion(config, seed) for seed in seeds]
    offsets = np.array([[walk(h * k) for k in range(64, 64 + knots)] for walk in walks])
    return offsets, np.array([0.5, 0.5, 0.5, *np.radians([10.0] * 3)])


def test_random_walk_knots_are_an_ornstein_uhlenbeck_walk_of_unit_variance():
    """At its knots the deck is bound tanh(x / 2) of an Ornstein-Uhlenbeck walk x of unit stationary variance
    and correlation time tau: x's lag-1 autocorrelation is exp(-h / tau) (0.939 for h 0.25 s, tau 4 s)."""
    offsets, bound = walk_at_knots()
    x = 2.0 * np.arctanh(offsets / bound)
    # 4 seeds x 2048 knots x 6 axes, correlated over 16 knots: about 1500 independent samples, so the variance is
    # within 0.027 and the autocorrelation within 0.002 (one standard deviation, as seen over 15 groups of seeds):
    # the tolerances are five of them.
    assert np.mean(x**2) == pytest.approx(1.0, abs=0.15)
    lag_1 = np.sum(x[:, 1:] * x[:, :-1]) / np.sum(x[:, :-1] ** 2)
    assert lag_1 == pytest.approx(math.exp(-0.25 / 4.0), abs=0.01)


def test_random_walk_spreads_over_its_bound_as_a_squashed_unit_normal():
    """At its knots the deck's offset over its bound is tanh(x / 2), x standard normal: the quantile p of
    |offset| / bound is tanh(Phi^-1((1 + p) / 2) / 2) (a median of 0.33: a third of the bound)."""
    offsets, bound = walk_at_knots()
    share = np.abs(offsets / bound).ravel()
    for p in (0.25, 0.5, 0.75, 0.9):
        # about 1500 independent samples (see above): each quantile within 0.007 (one standard deviation, over 15
        # groups of seeds); the tolerance is four of them
        assert np.quantile(share, p) == pytest.approx(math.tanh(norm.ppf((1 + p) / 2) / 2), abs=0.03), p


def test_random_walk_is_continuous():
    walk = StewartMotion(random_walk_config(), seed=1)
    bound = np.array([0.05, 1.0, 0.04, math.radians(6.0), 1.0, math.radians(10.0)])
    for start in (0.0, 63.5, 127.5):  # includes the chunk boundaries at 64 s and 128 s
        t = np.arange(start, start + 1.0, 1e-4)
        A = np.array([walk(ti) for ti in t]) / bound
        steps = np.abs(np.diff(A, axis=0))
        # A jump would show as one step far above the rest; a smooth walk moves a tiny fraction of its
        # bound in 0.1 ms.
        assert steps.max() < 1e-3, f"largest step {steps.max()} near t = {t[np.argmax(steps.max(axis=1))]}"


@pytest.mark.parametrize("changes, field", [
    ({"tag_size_m": 0.9}, "platform.tag_size_m"),  # 0.9 m black square is 1.125 m with its border: > 1 m deck
    ({"leg_max_m": 0.5, "leg_min_m": 0.5}, "platform.leg_max_m"),
    ({"leg_max_m": 0.4}, "platform.leg_max_m"),
    ({"motion": "wobble"}, "platform.motion"),
    ({"base_radius_m": 0.0}, "platform.base_radius_m"),
    ({"base_joint_angles_deg": [0.0] * 5}, "platform.base_joint_angles_deg"),
    ({"motion": "sinusoid", "roll_amplitude_deg": [5.0]}, "platform.roll_amplitude_deg"),
    ({"motion": "sinusoid", "y_amplitude_m": [0.1], "y_frequency_hz": [-1.0]}, "platform.y_frequency_hz"),
    # one phase for two sinusoids: neither empty nor one a sinusoid
    ({"motion": "sinusoid", "z_amplitude_m": [0.01, 0.02], "z_frequency_hz": [0.1, 0.2], "z_phase_deg": [30.0]},
     "platform.z_phase_deg must be empty or have one entry per sinusoid"),
    ({"tag_id": 587}, "platform.tag_id"),
    ({"tag_id": -1}, "platform.tag_id"),  # unchecked: cv2.error from the tag's mesh
    # unchecked: a random walk at t = -1 s raised TypeError
    ({"motion": "random_walk", "z_amplitude_m": [0.02], "time_offset_s": -1.0}, "platform.time_offset_s"),
    # 1e-8 s knots: the stroke check sampled 3e9 times over 30 s (MemoryError)
    ({"motion": "random_walk", "random_walk_knot_interval_s": 1e-8},
     "platform.random_walk_knot_interval_s must be at least 0.001 s"),
    # deck joints 2 m out under a 1 m deck; the joints at 75 and 165 deg reach its edge (0.5 m) at 0.518 m
    ({"platform_radius_m": 2.0}, r"platform.platform_radius_m \(2 m\) puts deck joints off the 1 m deck"),
    ({"platform_radius_m": 0.52}, r"platform.platform_radius_m \(0.52 m\) puts deck joints off the 1 m deck"),
    # a static deck (the default) stands still: a motion set for it was run as a still deck, silently
    ({"roll_amplitude_deg": [8.0], "roll_frequency_hz": [0.05]},
     r"platform.roll_amplitude_deg is \[8.0\] but platform.motion is 'static'"),
    ({"z_amplitude_m": [0.0, -0.1]}, r"platform.z_amplitude_m is \[0.0, -0.1\] but platform.motion is 'static'"),
    ({"x_frequency_hz": [0.2]}, r"platform.x_frequency_hz is \[0.2\] but platform.motion is 'static'"),
    ({"yaw_phase_deg": [30.0]}, r"platform.yaw_phase_deg is \[30.0\] but platform.motion is 'static'"),
])
def test_invalid_configuration_raises_config_error_naming_the_field(changes, field):
    config = StewartPlatformConfig(**changes)
    with pytest.raises(ConfigError, match=field.replace(".", r"\.")):
        config.validate()
    with pytest.raises(ConfigError, match=field.replace(".", r"\.")):
        StewartPlatform(config, SceneGraph())


def test_tag_that_just_fits_is_accepted():
    StewartPlatformConfig(tag_size_m=0.8, deck_size_m=1.0).validate()  # 0.8 m with border is exactly 1.0 m
    StewartPlatformConfig(motion="random_walk").validate()
    StewartPlatformConfig(platform_radius_m=0.515).validate()  # the joints at 75 and 165 deg 0.497 m out: under it
    StewartPlatformConfig(motion="static", pitch_amplitude_deg=[0.0]).validate()  # a zero amplitude: still


def test_the_shortest_random_walk_knot_interval_accepted_is_checked_against_the_stroke():
    config = StewartPlatformConfig(motion="random_walk", z_amplitude_m=[0.02], random_walk_knot_interval_s=1e-3)
    config.validate()
    assert stroke_violation(config, 0.5) is None
    # half a metre of heave, decorrelated in 10 ms: within 0.5 s it goes further than the legs' 0.35 m stroke
    config.z_amplitude_m, config.random_walk_time_constant_s = [0.5], 0.01
    assert stroke_violation(config, 0.5) is not None


def test_a_walk_at_the_shortest_knot_interval_gives_its_rates_at_t_0_first():
    """The rates' central difference first reads the walk at t = -RATE_STEP_S: at a knot interval of exactly that
    step no knot was drawn for it (TypeError from the missing interpolant). The rates at t = 0 are the same whether
    asked first or after a later time built the walk."""
    config = StewartPlatformConfig(motion="random_walk", z_amplitude_m=[0.02], random_walk_knot_interval_s=1e-3)
    first = StewartMotion(config, seed=3).translation_rates(0.0)
    later = StewartMotion(config, seed=3)
    later(1.0)
    for a, b in zip(first, later.translation_rates(0.0)):
        np.testing.assert_array_equal(a, b)
    assert np.all(np.isfinite(first)) and np.any(first[0] != 0.0)


def test_a_motion_too_long_or_fast_to_check_against_the_stroke_is_refused():
    """The check samples the motion 40 times a period of its fastest sinusoid over the whole run: at 1 GHz or over
    1e9 s that was a MemoryError (87 TiB); now one line."""
    fast = StewartPlatformConfig(motion="sinusoid", z_amplitude_m=[0.01], z_frequency_hz=[1.0e9])
    for config, duration_s in ((fast, 1.0), (StewartPlatformConfig(), 1.0e9)):
        with pytest.raises(ConfigError, match=r"^platform: the deck's motion cannot be checked against the legs' "
                                              r"stroke over .* s: at .* s a sample .* over 1e\+06 samples"):
            stroke_violation(config, duration_s)


@pytest.mark.parametrize("knot_interval_s, step_s", [
    (0.25, 0.025),  # the default knots: a tenth of one, under the 0.05 s cap
    (0.1, 0.01),
    (1.0, 0.05),  # a tenth of a knot is 0.1 s: the cap
])
def test_the_stroke_check_samples_a_random_walk_ten_times_a_knot(knot_interval_s, step_s):
    config = StewartPlatformConfig(motion="random_walk", z_amplitude_m=[0.02],
                                   random_walk_knot_interval_s=knot_interval_s)
    assert stroke_step_s(config) == pytest.approx(step_s, rel=1e-12)


def moving_platform(**motion):
    config = StewartPlatformConfig(motion="sinusoid", **motion)
    platform = StewartPlatform(config, SceneGraph())
    return platform, platform.CreateDefaultContext()


def test_pad_motion_is_the_sinusoids_and_their_derivatives():
    a, f, phase = 0.06, 0.041, 0.3
    platform, context = moving_platform(z_amplitude_m=[a], z_frequency_hz=[f], z_phase_deg=[math.degrees(phase)],
                                        x_amplitude_m=[0.05], x_frequency_hz=[0.031])
    w, t = 2 * math.pi * f, 3.7
    context.SetTime(t)
    motion = platform.GetOutputPort("pad_motion").Eval(context)
    top = platform.geometry.X_SP0.translation()[2]
    np.testing.assert_allclose(motion[2], top + a * math.sin(w * t + phase), atol=1e-12)
    np.testing.assert_allclose(motion[5], a * w * math.cos(w * t + phase), rtol=1e-6)  # central differences
    np.testing.assert_allclose(motion[8], -a * w * w * math.sin(w * t + phase), rtol=1e-4, atol=1e-9)
    wx = 2 * math.pi * 0.031
    np.testing.assert_allclose(motion[3], 0.05 * wx * math.cos(wx * t), rtol=1e-6)
    # the true deck_motion's heave is the same deck top's z (X_WP), and its rate the same derivative
    deck = platform.GetOutputPort("deck_motion").Eval(context)
    np.testing.assert_allclose(deck[4], top + a * math.sin(w * t + phase), atol=1e-12)
    np.testing.assert_allclose(deck[5], a * w * math.cos(w * t + phase), rtol=1e-6)


def test_the_deck_s_spatial_velocity_is_drake_s_from_the_angles_rates():
    a, f = np.deg2rad([6.0, 4.0, 9.0]), [0.05, 0.07, 0.027]
    platform, context = moving_platform(roll_amplitude_deg=[6.0], roll_frequency_hz=[f[0]],
                                        pitch_amplitude_deg=[4.0], pitch_frequency_hz=[f[1]],
                                        yaw_amplitude_deg=[9.0], yaw_frequency_hz=[f[2]],
                                        x_amplitude_m=[0.05], x_frequency_hz=[0.031])
    t = 3.1
    context.SetTime(t)
    w = 2 * np.pi * np.array(f)
    rpy, rpy_dt = a * np.sin(w * t), a * w * np.cos(w * t)
    w_WP = RollPitchYaw(rpy).CalcAngularVelocityInParentFromRpyDt(rpy_dt)
    V_WP = platform.GetOutputPort("V_WP").Eval(context)
    np.testing.assert_allclose(V_WP[:3], w_WP, rtol=1e-5, atol=1e-9)  # central differences
    assert np.linalg.norm(w_WP - rpy_dt) > 1e-3  # the angles' rates alone are not the angular velocity here
    np.testing.assert_allclose(V_WP[3:], platform.GetOutputPort("pad_motion").Eval(context)[3:6], atol=1e-15)


def test_deck_motion_and_carrier_state_describe_the_tilted_yawed_deck():
    platform, context = moving_platform(roll_amplitude_deg=[8.0], roll_frequency_hz=[0.05],
                                        yaw_amplitude_deg=[10.0], yaw_frequency_hz=[0.027])
    t = 2.0
    context.SetTime(t)
    roll, yaw = math.radians(8.0) * math.sin(2 * math.pi * 0.05 * t), math.radians(10.0) * math.sin(
        2 * math.pi * 0.027 * t)
    R = RotationMatrix(RollPitchYaw(roll, 0.0, yaw))
    motion = platform.GetOutputPort("deck_motion").Eval(context)
    np.testing.assert_allclose(motion[:2], R.col(2)[:2], atol=1e-12)
    h = 1e-5
    rate = (RotationMatrix(RollPitchYaw(math.radians(8.0) * math.sin(2 * math.pi * 0.05 * (t + h)), 0.0,
                                        math.radians(10.0) * math.sin(2 * math.pi * 0.027 * (t + h)))).col(2)
            - RotationMatrix(RollPitchYaw(math.radians(8.0) * math.sin(2 * math.pi * 0.05 * (t - h)), 0.0,
                                          math.radians(10.0) * math.sin(2 * math.pi * 0.027 * (t - h)))).col(2)) / (2 * h)
    np.testing.assert_allclose(motion[2:4], rate[:2], rtol=1e-5)
    assert motion[6] == 1.0
    np.testing.assert_allclose(platform.GetOutputPort("carrier_state").Eval(context), [0.0, 0.0, yaw, 0.0],
                               atol=1e-12)


@pytest.mark.parametrize("yaw_deg", [150.0, -120.0])
def test_the_carrier_heading_is_the_deck_s_yaw_beyond_a_quarter_turn(yaw_deg):
    """A constant yaw (0 Hz, phase 90 deg: amplitude x sin(90 deg)) with the deck's x axis pointing backwards
    (cos(yaw) < 0): the heading is the yaw itself, not its mirror across W's y axis."""
    platform, context = moving_platform(yaw_amplitude_deg=[yaw_deg], yaw_frequency_hz=[0.0], yaw_phase_deg=[90.0])
    context.SetTime(1.0)
    np.testing.assert_allclose(platform.GetOutputPort("carrier_state").Eval(context),
                               [0.0, 0.0, math.radians(yaw_deg), 0.0], atol=1e-12)


def test_a_level_downward_camera_over_the_level_deck_sees_the_tag_frame_unturned():
    """X_PT is the tag frame of its docstring: a camera h above the level deck looking straight down (x_C along
    x_W, z_C down: a half turn about x) sees the tag at X_CT = [I, (0, 0, h)], less the plate's 0.5 mm lift."""
    config, h = StewartPlatformConfig(), 2.0
    platform, _ = make_platform(config)
    X_WC = pose([0.0, 0.0, nominal_top_z(config) + h], [180.0, 0.0, 0.0])
    X_CT = X_WC.InvertAndCompose(platform.X_WP(0.0).multiply(platform.X_PT))
    np.testing.assert_allclose(X_CT.GetAsMatrix4(), RigidTransform([0.0, 0.0, h - TAG_ABOVE_DECK_M]).GetAsMatrix4(),
                               atol=1e-12)


def test_time_offset_starts_the_motion_later():
    config = StewartPlatformConfig(motion="sinusoid", z_amplitude_m=[0.05], z_frequency_hz=[0.1])
    shifted = StewartMotion(StewartPlatformConfig(**{**config.__dict__, "time_offset_s": 1.5}))
    np.testing.assert_allclose(shifted(2.0), StewartMotion(config)(3.5), atol=1e-15)


def test_stroke_violation_names_when_and_which_leg():
    within = StewartPlatformConfig(motion="sinusoid", z_amplitude_m=[0.06], z_frequency_hz=[0.041])
    assert stroke_violation(within, 30.0) is None
    beyond = StewartPlatformConfig(motion="sinusoid", z_amplitude_m=[0.3], z_frequency_hz=[0.1])
    message = stroke_violation(beyond, 30.0)
    # z + 0.3 sin(0.2 pi t): the legs (0.6 m joint planes apart, max 0.85) pass their stroke before t = 2.5 s.
    assert message is not None and message.startswith("t = ") and "leg" in message
    assert float(message.split()[2]) < 2.5


@pytest.mark.parametrize("frequency_hz, amplitude_m, phase_deg, leg_m", [
    (10.0, 0.25, 0.0, None),  # every 0.05 s sample on a zero crossing: the legs reach 0.44-0.89 m between them
    (2.5, 0.1774, 22.5, 0.498),  # the shortest leg 2 mm under the stroke, at 0.275 s, between 0.25 and 0.30 s
    (2.5, 0.17525, 22.5, 0.4998),  # 0.2 mm under it, between two of the finer samples: found by the refinement
    # the same across one 0.01 s sample step (9 deg of phase): the legs at their shortest, each joint pair 0.263 m
    # apart horizontally, sqrt(0.263^2 + (0.6 - 0.17525)^2) = 0.4998 m, wherever that falls between two samples
    # (the refinement searches both intervals beside a sampled minimum)
    (2.5, 0.17525, 18.0, 0.4998),
    (2.5, 0.17525, 19.8, 0.4998),
    (2.5, 0.17525, 21.6, 0.4998),
    (2.5, 0.17525, 24.3, 0.4998),
    (2.5, 0.17525, 26.1, 0.4998),
])
def test_a_stroke_left_between_samples_is_found(frequency_hz, amplitude_m, phase_deg, leg_m):
    config = StewartPlatformConfig(motion="sinusoid", z_amplitude_m=[amplitude_m], z_frequency_hz=[frequency_hz],
                                   z_phase_deg=[phase_deg])
    message = stroke_violation(config, 20.0)
    assert message is not None
    if leg_m is not None:
        assert float(message.split()[-2]) == pytest.approx(leg_m, abs=1e-3)


def test_the_stroke_is_checked_over_the_run_and_no_further():
    """z 0.3 m at 0.7 Hz takes a leg past 0.85 m at 0.1744 s: a 0.17 s run stays within the stroke (before:
    sampled up to half a step past its end, and refused), a 0.2 s one does not."""
    config = StewartPlatformConfig(motion="sinusoid", z_amplitude_m=[0.3], z_frequency_hz=[0.7])
    assert stroke_violation(config, 0.17) is None
    assert stroke_violation(config, 0.2) == "t = 0.18 s, leg 3 0.854 m"


def test_a_stroke_left_in_the_first_sampling_interval_is_found():
    """A 0.7 Hz heave whose legs peak at 0.3 of the first step (0.0357 s), 0.2 mm past 0.85 m, both samples
    around it within the stroke (before: only interior samples were peaks, and this one was missed)."""
    config = StewartPlatformConfig(motion="sinusoid", z_amplitude_m=[0.2083515300209276], z_frequency_hz=[0.7],
                                   z_phase_deg=[87.3], leg_min_m=0.4)
    assert stroke_violation(config, 1.0) == "t = 0.01 s, leg 3 0.850 m"


def test_a_random_walk_deck_takes_its_bounds_alone():
    """A random walk bounds each axis by its amplitudes' sum; it has no frequencies (before: refused, one
    frequency asked per amplitude)."""
    config = StewartPlatformConfig(motion="random_walk", z_amplitude_m=[0.02, 0.01], z_frequency_hz=[])
    config.validate()


def leg_parts_in_scene(platform: StewartPlatform, scene_graph: SceneGraph):
    """The six legs' (cylinder, rod) as (X_WG, length) from SceneGraph, with the platform at its pose at t = 0."""
    builder = DiagramBuilder()
    builder.AddSystem(scene_graph)
    builder.AddSystem(platform)
    builder.Connect(platform.GetOutputPort("geometry_pose"), scene_graph.get_source_pose_port(platform.source_id))
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    query = scene_graph.get_query_output_port().Eval(scene_graph.GetMyContextFromRoot(context))
    inspector = query.inspector()
    parts = {inspector.GetName(g): (query.GetPoseInWorld(g), inspector.GetShape(g).length())
             for g in inspector.GetAllGeometryIds() if inspector.GetName(g).startswith("leg")}
    return [(parts[f"leg{i}_cylinder"], parts[f"leg{i}_rod"]) for i in range(6)]


@pytest.mark.parametrize("leg_m", [0.401, 0.949], ids=["shortest", "longest"])
def test_leg_cylinders_stay_under_the_deck_and_the_rods_reach_them(leg_m):
    # A 0.40-0.95 m stroke (the livelier deck's): a cylinder of 0.6 of the longest leg (0.57 m) stood up through
    # the deck at the shortest legs, over the deck joints at +-45 deg, which lie under the tag's corners.
    shape = StewartPlatformConfig(leg_min_m=0.4, leg_max_m=0.95)
    horizontal = hand_leg(replace(shape, nominal_height_m=0.0), 0)  # every leg's joints 30 deg apart
    config = replace(shape, nominal_height_m=math.sqrt(leg_m**2 - horizontal**2))
    scene_graph = SceneGraph()
    platform = StewartPlatform(config, scene_graph)
    X_WP = platform.X_WP(0.0)
    np.testing.assert_allclose(leg_lengths(X_WP, platform.geometry), leg_m, atol=1e-12)
    q_W = X_WP.multiply(platform.geometry.q_P.T).T
    for (cylinder, rod), b_W, q in zip(leg_parts_in_scene(platform, scene_graph), platform.geometry.b_S, q_W):
        cylinder_end = cylinder[0].multiply([0.0, 0.0, cylinder[1] / 2])
        rod_end = rod[0].multiply([0.0, 0.0, rod[1] / 2])
        np.testing.assert_allclose(cylinder[0].multiply([0.0, 0.0, -cylinder[1] / 2]), b_W, atol=1e-12)
        np.testing.assert_allclose(rod[0].multiply([0.0, 0.0, -rod[1] / 2]), q, atol=1e-12)
        assert np.linalg.norm(cylinder_end - b_W) <= leg_m + 1e-12  # at or below the deck joint
        assert np.linalg.norm(rod_end - q) >= np.linalg.norm(cylinder_end - q) - 1e-12  # into the cylinder
