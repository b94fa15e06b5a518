"""A strapdown IMU: accelerometer (specific force) and gyroscope of a body, sampled at a fixed rate.

Defaults are the Xsens MTi-G-700 of seed 001 Table 1: 100-400 Hz, gyroscope full range 450 deg/s and
noise density 0.01 deg/s/sqrt(Hz), accelerometer full range 50 m/s^2 and noise density
80 ug/sqrt(Hz). Table 1 gives no biases; the bias defaults are the in-run bias stability of Xsens'
MTi 100-series datasheet (gyroscope 10 deg/h, accelerometer 40 ug), drawn once per run from the seed
as a constant turn-on bias per axis.
"""

from dataclasses import dataclass

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.systems.framework import BasicVector, LeafSystem

from systems.config import require, require_positive
from systems.noise import sample_index, sample_rng

STANDARD_GRAVITY = 9.80665  # m/s^2, the g of datasheet units (ug)


@dataclass
class ImuConfig:
    rate_hz: float = 200.0  # seed 001 Table 1: 100~400 Hz
    gyro_noise_density_deg_s_rthz: float = 0.01  # seed 001 Table 1
    accel_noise_density_ug_rthz: float = 80.0  # seed 001 Table 1
    gyro_range_deg_s: float = 450.0  # seed 001 Table 1
    accel_range_m_s2: float = 50.0  # seed 001 Table 1
    gyro_bias_std_deg_h: float = 10.0  # Xsens MTi 100-series datasheet, in-run bias stability
    accel_bias_std_ug: float = 40.0  # Xsens MTi 100-series datasheet, in-run bias stability
    gravity_m_s2: float = 9.81  # the world's g: QuadrotorParams.gravity_m_s2, so a flown IMU reads its gravity

    def validate(self, prefix: str = "imu") -> None:
        for name in ("rate_hz", "gyro_range_deg_s", "accel_range_m_s2", "gravity_m_s2"):
            require_positive(getattr(self, name), f"{prefix}.{name}")
        require(self.accel_range_m_s2 > self.gravity_m_s2,
                f"{prefix}.accel_range_m_s2 must exceed {prefix}.gravity_m_s2 ({self.gravity_m_s2:g} m/s^2) or the "
                f"accelerometer clips what it reads at rest or in hover, got {self.accel_range_m_s2:g}")
        for name in ("gyro_noise_density_deg_s_rthz", "accel_noise_density_ug_rthz", "gyro_bias_std_deg_h",
                     "accel_bias_std_ug"):
            require(getattr(self, name) >= 0, f"{prefix}.{name} must not be negative")

    @property
    def period_s(self) -> float:
        return 1.0 / self.rate_hz

    @property
    def gyro_sample_std_rad_s(self) -> float:
        """Per-sample white-noise std: density * sqrt(sample rate)."""
        return np.deg2rad(self.gyro_noise_density_deg_s_rthz) * np.sqrt(self.rate_hz)

    @property
    def accel_sample_std_m_s2(self) -> float:
        return self.accel_noise_density_ug_rthz * 1e-6 * STANDARD_GRAVITY * np.sqrt(self.rate_hz)


def ideal_imu(R_WB, w_WB_W: np.ndarray, a_WB_W: np.ndarray, gravity_m_s2: float):
    """Noise-free (specific force f_B in m/s^2, angular velocity w_B in rad/s), both in body axes.

    f_B = R_BW (a_WB - g_W), g_W = [0, 0, -gravity_m_s2]: at rest on a z-up world it reads
    +gravity_m_s2 along the body's up axis."""
    R_BW = R_WB.inverse().matrix()
    return R_BW @ (np.asarray(a_WB_W) + [0.0, 0.0, gravity_m_s2]), R_BW @ np.asarray(w_WB_W)


class Imu(LeafSystem):
    """Samples the body's kinematics at `rate_hz` and outputs `imu` = [f_B (m/s^2), w_B (rad/s)].

    Inputs: X_WB (RigidTransform), V_WB ([w; v] in W), A_WB ([alpha; a] in W).
    The output holds the last sample (a zero-order hold): a sample taken at t is seen after t."""

    def __init__(self, config: ImuConfig, seed: int = 0):
        super().__init__()
        config.validate()
        self._config, self._seed = config, seed
        bias_rng = sample_rng(seed, "imu_bias", 0)
        self.accel_bias = bias_rng.standard_normal(3) * config.accel_bias_std_ug * 1e-6 * STANDARD_GRAVITY
        self.gyro_bias = bias_rng.standard_normal(3) * np.deg2rad(config.gyro_bias_std_deg_h / 3600.0)
        self._X_WB = self.DeclareAbstractInputPort("X_WB", AbstractValue.Make(RigidTransform()))
        self._V_WB = self.DeclareVectorInputPort("V_WB", 6)
        self._A_WB = self.DeclareVectorInputPort("A_WB", 6)
        # [f_B; w_B] of a sample = clip(ideal + bias + standard normal x std, -limit, limit), per component.
        self._bias = np.concatenate([self.accel_bias, self.gyro_bias])
        self._std = np.repeat([config.accel_sample_std_m_s2, config.gyro_sample_std_rad_s], 3)
        self._limit = np.repeat([config.accel_range_m_s2, np.deg2rad(config.gyro_range_deg_s)], 3)
        state = self.DeclareDiscreteState(BasicVector([0.0, 0.0, config.gravity_m_s2, 0.0, 0.0, 0.0]))
        self.DeclarePeriodicDiscreteUpdateEvent(config.period_s, 0.0, self._sample)
        self.DeclareStateOutputPort("imu", state)

    def _sample(self, context, discrete_state):
        c = self._config
        f_B, w_B = ideal_imu(self._X_WB.Eval(context).rotation(), self._V_WB.Eval(context)[:3],
                             self._A_WB.Eval(context)[3:], c.gravity_m_s2)
        noise = sample_rng(self._seed, "imu", sample_index(context.get_time(), c.period_s)).standard_normal(6)
        reading = np.clip(np.concatenate([f_B, w_B]) + self._bias + noise * self._std, -self._limit, self._limit)
        discrete_state.get_mutable_vector().SetFromVector(reading)
