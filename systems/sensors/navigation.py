"""The UAV's own navigation (issue 10): what its autopilot believes of its pose and velocity, the
truth plus the errors of a GNSS/INS grade, for the flight controller, the supervisor and the
estimators that place the pad in World; the truth stays with the referee and the metrics.

Errors, seeded per sample (sample_rng(seed, "navigation", k), t_k = k T, T = 1 / rate_hz), each
exactly discretised and started from its stationary distribution:
- position: a second-order Gauss-Markov process per axis (an INS's error, smooth, held by GNSS):
  e'' = -e / tau^2 - 2 e' / tau + white noise, standard deviation `position_std_m`, autocorrelation
  sigma^2 (1 + |t| / tau) e^(-|t| / tau) with tau = `position_time_constant_s`; the velocity error is
  its rate e' (standard deviation sigma / tau), so the two agree as an INS's do;
- attitude: first-order Gauss-Markov per roll, pitch and yaw (`tilt_std_deg`, `yaw_std_deg`,
  `attitude_time_constant_s`; e_{k+1} = a e_k + sigma sqrt(1 - a^2) n, a = exp(-T / tau)), applied
  as R_WB_nav = R_WB R(roll, pitch, yaw errors).
Frames: World W (z up), body B; m, s, rad (deg in the settings' names).
"""

import math
from dataclasses import dataclass

import numpy as np
from pydrake.common.value import Value
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from pydrake.systems.framework import LeafSystem

from systems.config import require, require_non_negative, require_positive
from systems.noise import sample_index, sample_rng, stationary_factor, van_loan_discretisation
from systems.vehicles.quadrotor import P_WB, Q_WB, STATE_SIZE, V_WB, pose_from_state

SOURCES = ("truth", "gnss_ins")


@dataclass
class NavigationConfig:
    """`source`: truth, or gnss_ins (the errors of the module docstring). The defaults are a
    consumer grade: GPS with a nine-axis IMU and a barometer, about 2 m (seed 000's reference [21]);
    the rest are ours (a GNSS error wanders over about a minute, which makes the velocity error
    2 m / 60 s = 0.033 m/s; a consumer autopilot's attitude filter holds the tilt to about half a
    degree and the heading to a couple of degrees)."""

    source: str = "truth"
    rate_hz: float = 200.0  # the errors' sample rate (the flight controller's)
    position_std_m: float = 2.0
    position_time_constant_s: float = 60.0
    tilt_std_deg: float = 0.5
    yaw_std_deg: float = 2.0
    attitude_time_constant_s: float = 30.0

    def validate(self, prefix: str = "navigation") -> None:
        require(self.source in SOURCES, f"{prefix}.source '{self.source}' is not one of {', '.join(SOURCES)}")
        for name in ("rate_hz", "position_time_constant_s", "attitude_time_constant_s"):
            require_positive(getattr(self, name), f"{prefix}.{name}")
        for name in ("position_std_m", "tilt_std_deg", "yaw_std_deg"):
            require_non_negative(getattr(self, name), f"{prefix}.{name}")


def gauss_markov_step(error: np.ndarray, std: np.ndarray, time_constant_s: float, period_s: float,
                      noise: np.ndarray) -> np.ndarray:
    """A first-order Gauss-Markov error one period later (exact), from standard normal `noise`."""
    a = math.exp(-period_s / time_constant_s)
    return a * error + np.asarray(std) * math.sqrt(1.0 - a * a) * noise


def second_order_model(time_constant_s: float, period_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The unit-variance second-order Gauss-Markov process [e, e'] (module docstring) over one
    period: (Phi (2x2), G (2x2) with x_next = Phi x + G n, n ~ N(0, I), and the stationary covariance's
    Cholesky factor), exact (systems.noise.van_loan_discretisation)."""
    tau = time_constant_s
    A = np.array([[0.0, 1.0], [-1.0 / tau**2, -2.0 / tau]])
    B = np.array([[0.0], [2.0 / math.sqrt(tau**3)]])  # makes var(e) = 1: q = 4 / tau^3
    return (*van_loan_discretisation(A * period_s, B @ B.T * period_s), stationary_factor(A, B @ B.T))


class SecondOrderGaussMarkov:
    """Independent unit-variance second-order Gauss-Markov processes (module docstring), one per axis, each
    [e, e'] stepped exactly every period: values flat as (axes x 2), scaled by the caller."""

    def __init__(self, time_constant_s: float, period_s: float):
        self._phi, self._g, self._stationary = second_order_model(time_constant_s, period_s)

    def initial(self, noise: np.ndarray) -> np.ndarray:
        """A draw from the stationary distribution, from 2 x axes standard normal numbers."""
        return (self._stationary @ np.asarray(noise).reshape(2, -1)).T.ravel()

    def step(self, values: np.ndarray, noise: np.ndarray) -> np.ndarray:
        """The values one period later, from 2 x axes standard normal numbers."""
        return (np.asarray(values).reshape(-1, 2) @ self._phi.T + np.asarray(noise).reshape(-1, 2) @ self._g.T).ravel()


def navigation_state(true_state: np.ndarray, position_error: np.ndarray, attitude_error: np.ndarray,
                     velocity_error: np.ndarray) -> np.ndarray:
    """The 17-vector state as the navigation gives it: position and velocity (m, m/s, in W) plus
    their errors, the attitude turned by the [roll, pitch, yaw] error (rad) in B; the body rates
    and rotor speeds as they are."""
    out = np.array(true_state, dtype=float)
    out[P_WB] += position_error
    out[V_WB] += velocity_error
    R_WB = pose_from_state(true_state).rotation().multiply(RotationMatrix(RollPitchYaw(attitude_error)))
    out[Q_WB] = R_WB.ToQuaternion().wxyz()
    return out


class NavigationSystem(LeafSystem):
    """Input `quadrotor_state` (17, the truth); outputs `state` (17, navigation_state) and `X_WB`
    (abstract RigidTransform) of the navigation. Discrete state: the position errors and their rates
    (3 x 2, in units of position_std_m), the attitude errors (3, rad), stepped every 1 / rate_hz from
    t = 0."""

    def __init__(self, config: NavigationConfig, seed: int = 0):
        super().__init__()
        config.validate()
        self._config, self._seed, self._period = config, seed, 1.0 / config.rate_hz
        self._attitude_std = np.radians([config.tilt_std_deg, config.tilt_std_deg, config.yaw_std_deg])
        self._position = SecondOrderGaussMarkov(config.position_time_constant_s, self._period)
        initial = sample_rng(seed, "navigation", 0).standard_normal(9)
        position = self._position.initial(initial[:6])  # [e, e'] per axis, unit variance
        self._errors = self.DeclareDiscreteState(np.r_[position, self._attitude_std * initial[6:]])
        self._truth = self.DeclareVectorInputPort("quadrotor_state", STATE_SIZE)
        self.DeclarePeriodicDiscreteUpdateEvent(self._period, 0.0, self._step)
        state = self.DeclareVectorOutputPort("state", STATE_SIZE, self._calc_state)
        self.DeclareAbstractOutputPort("X_WB", lambda: Value(RigidTransform()),  # from the state's cached value
                                       lambda c, o: o.set_value(pose_from_state(state.Eval(c))))

    def _step(self, context, discrete_state):
        c = self._config
        errors = context.get_discrete_state_vector().CopyToVector()
        k = sample_index(context.get_time(), self._period)
        noise = sample_rng(self._seed, "navigation", k + 1).standard_normal(9)
        position = self._position.step(errors[0:6], noise[0:6])
        attitude = gauss_markov_step(errors[6:9], self._attitude_std, c.attitude_time_constant_s, self._period,
                                     noise[6:9])
        discrete_state.set_value(np.r_[position, attitude])

    def _calc_state(self, context, output):
        errors = context.get_discrete_state_vector().CopyToVector()
        position = errors[0:6].reshape(3, 2) * self._config.position_std_m  # [e, e'] per axis, in m and m/s
        output.SetFromVector(navigation_state(self._truth.Eval(context), position[:, 0], errors[6:9], position[:, 1]))
