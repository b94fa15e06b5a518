"""IMU: the Imu system alone, inputs fixed, its periodic sample evaluated directly or by a Simulator."""

import math

import numpy as np
import pytest
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from pydrake.systems.analysis import Simulator
from scipy.spatial.transform import Rotation

from systems.config import ConfigError
from systems.sensors.imu import Imu, ImuConfig, ideal_imu

G = ImuConfig().gravity_m_s2  # the world's g, m/s^2 (the quadrotor's)
STANDARD_G = 9.80665  # the g of the datasheet's ug


def ideal_config(**changes) -> ImuConfig:
    """No noise and no bias, so readings are exact."""
    return ImuConfig(gyro_noise_density_deg_s_rthz=0.0, accel_noise_density_ug_rthz=0.0,
                     gyro_bias_std_deg_h=0.0, accel_bias_std_ug=0.0, **changes)


def imu_with_inputs(config: ImuConfig, R_WB=RotationMatrix(), w_WB_W=(0, 0, 0), a_WB_W=(0, 0, 0), seed=0):
    imu = Imu(config, seed)
    context = imu.CreateDefaultContext()
    imu.GetInputPort("X_WB").FixValue(context, RigidTransform(R_WB, [1.0, -2.0, 3.0]))
    imu.GetInputPort("V_WB").FixValue(context, np.r_[w_WB_W, 0.3, -0.2, 0.1])
    imu.GetInputPort("A_WB").FixValue(context, np.r_[0.5, -0.4, 0.2, a_WB_W])
    return imu, context


def sample(imu, context, t=0.0) -> np.ndarray:
    """The reading the periodic update takes at time t."""
    context.SetTime(t)
    return imu.EvalUniquePeriodicDiscreteUpdate(context).get_vector().CopyToVector()


def test_level_at_rest_reads_plus_g_up_and_no_rotation():
    imu, context = imu_with_inputs(ideal_config())
    np.testing.assert_allclose(sample(imu, context, 0.4), [0, 0, G, 0, 0, 0], rtol=0, atol=1e-12)


def test_output_holds_the_last_sample():
    imu, context = imu_with_inputs(ideal_config(rate_hz=100.0), R_WB=RotationMatrix.MakeXRotation(math.pi / 2),
                                   w_WB_W=(0.0, 0.0, 0.5))
    simulator = Simulator(imu, context)
    simulator.AdvanceTo(0.123)
    # f_B: gravity's reaction along the body's y axis, now pointing up; w: world z is body y.
    np.testing.assert_allclose(imu.get_output_port().Eval(simulator.get_context()), [0, G, 0, 0, 0.5, 0],
                               atol=1e-12)


def test_the_first_sample_is_taken_at_t_zero_and_then_every_period():
    """At 100 Hz, rolled 90 deg about x (the body's y axis up) and turning at 0.5 rad/s about the world's z: the
    reading f_B = R_BW [0, 0, g] = [0, g, 0], w_B = R_BW [0, 0, 0.5] = [0, 0.5, 0]. By t = 0.004 s the output is
    the t = 0 sample (not the level placeholder [0, 0, g, 0, 0, 0]), and by 0.123 s 13 samples were taken
    (t = 0, 0.01, ..., 0.12)."""
    imu, context = imu_with_inputs(ideal_config(rate_hz=100.0), R_WB=RotationMatrix.MakeXRotation(math.pi / 2),
                                   w_WB_W=(0.0, 0.0, 0.5))
    simulator = Simulator(imu, context)
    simulator.AdvanceTo(0.004)
    np.testing.assert_allclose(imu.get_output_port().Eval(simulator.get_context()), [0, G, 0, 0, 0.5, 0],
                               rtol=0, atol=1e-12)
    assert simulator.get_num_discrete_updates() == 1
    simulator.AdvanceTo(0.123)
    assert simulator.get_num_discrete_updates() == 13


@pytest.mark.parametrize("gravity", [G, 3.71])
def test_before_its_first_sample_the_output_is_a_level_body_at_rest(gravity):
    """At t = 0 after Initialize (the t = 0 sample is seen only after t = 0) the output already reads a level body
    at rest: the specific force +g up (the configured world's g) and no rotation, not zeros."""
    imu, context = imu_with_inputs(ideal_config(gravity_m_s2=gravity))
    simulator = Simulator(imu, context)
    simulator.Initialize()
    np.testing.assert_allclose(imu.get_output_port().Eval(simulator.get_context()), [0, 0, gravity, 0, 0, 0],
                               rtol=0, atol=1e-12)


@pytest.mark.parametrize("rpy_deg, expected", [
    ((90.0, 0.0, 0.0), [0.0, G, 0.0]),  # rolled right: the body's y axis (left) points up
    ((-90.0, 0.0, 0.0), [0.0, -G, 0.0]),
    ((0.0, 90.0, 0.0), [-G, 0.0, 0.0]),  # nose down: the body's x axis points down
    ((180.0, 0.0, 0.0), [0.0, 0.0, -G]),  # upside down
    ((0.0, 0.0, 70.0), [0.0, 0.0, G]),  # heading does not matter
])
def test_gravity_moves_with_the_body_attitude(rpy_deg, expected):
    R_WB = RotationMatrix(RollPitchYaw(np.deg2rad(rpy_deg)))
    imu, context = imu_with_inputs(ideal_config(), R_WB=R_WB)
    np.testing.assert_allclose(sample(imu, context), [*expected, 0, 0, 0], rtol=0, atol=1e-12)


def test_angular_velocity_is_rotated_into_body_axes():
    # Yawed 90 deg: body x is world y, body y is world -x. A turn about world x is a turn about -y_B.
    imu, context = imu_with_inputs(ideal_config(), R_WB=RotationMatrix.MakeZRotation(math.pi / 2),
                                   w_WB_W=(1.0, 0.0, 0.0))
    np.testing.assert_allclose(sample(imu, context)[3:], [0.0, -1.0, 0.0], atol=1e-12)


def test_a_general_attitude_against_scipy():
    rotation = Rotation.from_euler("zyx", [40.0, -25.0, 65.0], degrees=True)
    w_W, a_W = np.array([0.3, -1.1, 0.7]), np.array([1.5, -0.5, 2.0])
    imu, context = imu_with_inputs(ideal_config(), R_WB=RotationMatrix(rotation.as_matrix()), w_WB_W=w_W, a_WB_W=a_W)
    reading = sample(imu, context)
    np.testing.assert_allclose(reading[:3], rotation.inv().apply(a_W + [0.0, 0.0, G]), atol=1e-12)
    np.testing.assert_allclose(reading[3:], rotation.inv().apply(w_W), atol=1e-12)
    f_B, w_B = ideal_imu(RotationMatrix(rotation.as_matrix()), w_W, a_W, G)
    np.testing.assert_allclose(np.r_[f_B, w_B], reading, atol=1e-12)


@pytest.mark.parametrize("a_z, f_z", [(-G, 0.0), (G, 2 * G)])  # free fall reads nothing; climbing at 1 g reads 2 g
def test_specific_force_adds_the_body_acceleration(a_z, f_z):
    imu, context = imu_with_inputs(ideal_config(), a_WB_W=(0.0, 0.0, a_z))
    np.testing.assert_allclose(sample(imu, context)[:3], [0.0, 0.0, f_z], atol=1e-12)


def test_readings_saturate_at_full_range():
    config = ideal_config(accel_range_m_s2=50.0, gyro_range_deg_s=450.0)
    imu, context = imu_with_inputs(config, w_WB_W=(math.radians(600.0), -math.radians(1000.0), math.radians(100.0)),
                                   a_WB_W=(100.0, -80.0, 20.0))
    reading = sample(imu, context)
    np.testing.assert_allclose(reading[:3], [50.0, -50.0, 20.0 + G], atol=1e-12)
    np.testing.assert_allclose(reading[3:], np.radians([450.0, -450.0, 100.0]), atol=1e-12)


def test_noise_per_sample_is_density_times_root_rate():
    config = ImuConfig()  # seed 001 Table 1: 0.01 deg/s/sqrt(Hz), 80 ug/sqrt(Hz), at 200 Hz
    accel_std = 80e-6 * STANDARD_G * math.sqrt(200.0)
    gyro_std = math.radians(0.01) * math.sqrt(200.0)
    assert config.accel_sample_std_m_s2 == pytest.approx(accel_std)
    assert config.gyro_sample_std_rad_s == pytest.approx(gyro_std)
    imu, context = imu_with_inputs(config, R_WB=RotationMatrix.MakeYRotation(0.3), w_WB_W=(0.1, 0.2, -0.3))
    f_ideal, w_ideal = ideal_imu(RotationMatrix.MakeYRotation(0.3), np.array([0.1, 0.2, -0.3]), np.zeros(3), G)
    readings = np.array([sample(imu, context, k * config.period_s) for k in range(3000)])
    errors = readings - np.r_[f_ideal, w_ideal]
    # The constant turn-on bias is the mean of the error; the rest is white noise of the per-sample std.
    np.testing.assert_allclose(errors.mean(axis=0), np.r_[imu.accel_bias, imu.gyro_bias],
                               atol=4 * max(accel_std, gyro_std) / math.sqrt(len(errors)))
    np.testing.assert_allclose(errors.std(axis=0), [accel_std] * 3 + [gyro_std] * 3, rtol=0.06)
    lag1 = [np.corrcoef(e[:-1], e[1:])[0, 1] for e in errors.T]
    assert np.max(np.abs(lag1)) < 0.08


def test_biases_have_the_configured_spread():
    config = ImuConfig(gyro_bias_std_deg_h=10.0, accel_bias_std_ug=40.0)
    biases = np.array([np.r_[imu.accel_bias, imu.gyro_bias] for imu in (Imu(config, seed) for seed in range(400))])
    np.testing.assert_allclose(biases[:, :3].std(), 40e-6 * STANDARD_G, rtol=0.1)
    np.testing.assert_allclose(biases[:, 3:].std(), math.radians(10.0 / 3600.0), rtol=0.1)
    # Constant through a run: the same system gives the same bias at any time.
    imu, context = imu_with_inputs(ImuConfig(gyro_noise_density_deg_s_rthz=0.0, accel_noise_density_ug_rthz=0.0))
    np.testing.assert_allclose(sample(imu, context, 0.0) - sample(imu, context, 9.0), 0.0, atol=1e-15)
    assert np.all(sample(imu, context, 0.0) != [0, 0, G, 0, 0, 0])


def test_the_noise_is_drawn_apart_from_the_bias():
    """The first sample's white noise is independent of the turn-on bias: across 300 seeds the standardised
    noise (reading - ideal - bias) / sample std is uncorrelated with the standardised bias (drawn from the
    bias's own numbers the two would be equal)."""
    config = ImuConfig()
    std = np.repeat([config.accel_sample_std_m_s2, config.gyro_sample_std_rad_s], 3)
    bias_std = np.repeat([config.accel_bias_std_ug * 1e-6 * STANDARD_G,
                          math.radians(config.gyro_bias_std_deg_h / 3600.0)], 3)
    f_ideal, w_ideal = ideal_imu(RotationMatrix(), np.zeros(3), np.zeros(3), G)
    noise, bias = [], []
    for seed in range(300):
        imu, context = imu_with_inputs(config, seed=seed)
        b = np.r_[imu.accel_bias, imu.gyro_bias]
        noise.append((sample(imu, context, 0.0) - np.r_[f_ideal, w_ideal] - b) / std)
        bias.append(b / bias_std)
    noise, bias = np.array(noise), np.array(bias)
    np.testing.assert_allclose(noise.std(axis=0), 1.0, rtol=0.2)
    for axis in range(6):
        assert abs(np.corrcoef(noise[:, axis], bias[:, axis])[0, 1]) < 0.3


def test_same_seed_same_readings_other_seed_other_readings():
    config = ImuConfig()
    a, ca = imu_with_inputs(config, seed=4)
    b, cb = imu_with_inputs(config, seed=4)
    c, cc = imu_with_inputs(config, seed=5)
    for t in (0.0, 0.005, 1.25):
        np.testing.assert_array_equal(sample(a, ca, t), sample(b, cb, t))
        assert np.all(sample(a, ca, t) != sample(c, cc, t))
    assert np.all(sample(a, ca, 0.005) != sample(a, ca, 0.010))


@pytest.mark.parametrize("changes, field", [
    ({"rate_hz": 0.0}, "imu.rate_hz"),
    ({"accel_range_m_s2": -1.0}, "imu.accel_range_m_s2"),
    # At or below the g a resting accelerometer reads, every reading clips (before: accepted).
    ({"accel_range_m_s2": 1.0}, "imu.accel_range_m_s2 must exceed imu.gravity_m_s2"),
    ({"accel_range_m_s2": 9.81}, "imu.accel_range_m_s2 must exceed imu.gravity_m_s2"),
    ({"gyro_noise_density_deg_s_rthz": -0.1}, "imu.gyro_noise_density_deg_s_rthz"),
    # Every noise density and bias std is checked, not the gyroscope's noise alone.
    ({"accel_noise_density_ug_rthz": -1.0}, "imu.accel_noise_density_ug_rthz must not be negative"),
    ({"gyro_bias_std_deg_h": -1.0}, "imu.gyro_bias_std_deg_h must not be negative"),
    ({"accel_bias_std_ug": -1.0}, "imu.accel_bias_std_ug must not be negative"),
    # g points down the world's z: a negative g would read -g up at rest (an upside-down world).
    ({"gravity_m_s2": -9.81}, "imu.gravity_m_s2 must be positive"),
])
def test_invalid_configuration_names_the_field(changes, field):
    with pytest.raises(ConfigError, match=field.replace(".", r"\.")):
        Imu(ImuConfig(**changes))


def test_the_imu_and_the_quadrotor_share_the_worlds_gravity():
    from systems.vehicles.quadrotor import QuadrotorParams

    assert ImuConfig().gravity_m_s2 == QuadrotorParams().gravity_m_s2
