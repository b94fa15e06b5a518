"""Seed 003's altitude Kalman filter (section 2.2.2, Eq. 13-14) on the stereo altimeter's raw altitude.

The paper's model, per camera frame k:
    x_k = A x_{k-1} + w_k      (Eq. 13)   x = [d, Delta d]: the depth and its change per frame, A = [1, 1; 0, 1]
    z_k = H x_k + v_k          (Eq. 14)   z = [Z, Delta Z]: the measured altitude and its change, H = [1, 0; 0, 1]
with w, v white Gaussian noise N(0, xi). Here the change is carried as a rate (m/s): x = [d, d_dot] with
A = [1, T; 0, 1] and z = [Z_k, (Z_k - Z_{k-1}) / T], the same filter with Delta d = d_dot T, so the
period T may be any camera rate and a coasted gap of several frames is one prediction.

The paper gives no value for xi. Q is the discrete white-noise-acceleration model of `accel_std_mps2`
(a vertical acceleration the airframe does not report); R follows stereo's error growth,
sigma_Z = measurement_std_m + measurement_std_per_m2 * Z^2 (sigma_Z = Z^2 sigma_d / (f T_x)), and the
measured change's noise follows from it: var(Delta Z / T) = 2 sigma_Z^2 / T^2, cov(Z, Delta Z / T) = sigma_Z^2 / T.
Without the previous frame's measurement, only Z is used (H = [1, 0]).

Invalid input: the filter predicts (coasts); it turns invalid when `max_coast_s` has passed since the
last measurement it used, and the next valid measurement starts it afresh. Before its first
measurement, and when invalid, its outputs are NaN with valid 0.

The altimeter's nearest range (`nearest_m`, f T_x / (numDisparities - 1): 0.667 m for the MYNT pair), ours where
the paper is silent: nearer, the true disparity lies beyond SGBM's search and what it matches is wrong, yet
may pass its checks (over the UGV's roof it read 1.2-1.6 m at 0.6 m, flagged valid: ugv-hybrid, measured).
So while the filter predicts a depth within `near_band_m` over the nearest range (or under it), only readings
within that band are used, and the filter coasts through the others; once it has let go there (its prediction
under the band's top), it starts again only on two readings in a row, the first within the band, where a climb
back into range is first read (the takeoff's first reading: 0.667 m), and the next within `near_band_m` of it (a
climb of up to near_band_m a frame: 3 m/s at 10 Hz); one alone can be a wrong match (0.678 m read at 0.09 m,
measured). A let-go in the band over the nearest range is one too: the UGV's roof sliding under a UAV 0.8 m up
(0.3 m true) reads 1.2-1.6 m, which would otherwise start it again, valid. But not when the readings it coasted
through climb out of the band: each over it and within `near_band_m` of the one before, the first of the
prediction (hovering in the band, then climbing; a frame without a reading breaks no climb); then the next reading
starts it, as anywhere over the band.
A jump out of the band (the roof leaving the window at 0.8 m) is not told from a wrong match: it waits for the
band's readings, as a let-go under the nearest range does.
"""

import math
from dataclasses import dataclass, field

import numpy as np
from pydrake.systems.framework import LeafSystem

from systems.config import require, require_non_negative, require_positive
from systems.flags import is_set
from systems.stepped import SteppedValue


@dataclass
class AltitudeKfConfig:
    """Noise (m, m/s^2) and coasting (s). The paper gives Eq. 13-14's form, not its noise (xi)."""

    accel_std_mps2: float = 1.0  # process noise: white vertical acceleration
    measurement_std_m: float = 0.01  # sigma_Z = measurement_std_m + measurement_std_per_m2 * Z^2
    measurement_std_per_m2: float = 0.004  # the raw altitude's rms error over 0.7-8 m: 0.0035 Z^2 (benchmarks/stereo.py)
    initial_speed_std_mps: float = 1.0  # the speed is unknown at the first measurement
    use_rate_measurement: bool = True  # Eq. 14's H = I: the measured change Delta Z is a measurement too
    max_coast_s: float = 0.5  # invalid after this long without a measurement
    near_band_m: float = 0.3  # predicted within this over the nearest range: only readings within it are used

    def validate(self, prefix: str = "altitude_kf") -> None:
        require_positive(self.accel_std_mps2, f"{prefix}.accel_std_mps2")
        require_non_negative(self.measurement_std_per_m2, f"{prefix}.measurement_std_per_m2")
        require_non_negative(self.measurement_std_m, f"{prefix}.measurement_std_m")
        require(self.measurement_std_m > 0 or self.measurement_std_per_m2 > 0,
                f"{prefix}: measurement_std_m and measurement_std_per_m2 cannot both be zero")
        require_positive(self.initial_speed_std_mps, f"{prefix}.initial_speed_std_mps")
        require_non_negative(self.max_coast_s, f"{prefix}.max_coast_s")
        require_positive(self.near_band_m, f"{prefix}.near_band_m")

    def measurement_std(self, altitude_m: float) -> float:
        return self.measurement_std_m + self.measurement_std_per_m2 * altitude_m**2


@dataclass
class AltitudeKfState:
    """x = [altitude d (m), its rate d_dot (m/s)], covariance P; `time` of the last step (None before
    the first); `last_measurement` the previous step's altitude measurement (None when that step had
    none; while lost near, the last step's reading in the band); `measured_s` the time of the last measurement
    used (None when not valid; `coast_s` the time since it); `valid`; `lost_near` whether it let go in the near
    band or under it (and has not started again); `climb_m` while it coasts in the near band, the last reading of
    a climb out of it (module docstring), else None."""

    x: np.ndarray = field(default_factory=lambda: np.full(2, np.nan))
    P: np.ndarray = field(default_factory=lambda: np.full((2, 2), np.nan))
    time: float | None = None
    last_measurement: float | None = None
    measured_s: float | None = None
    valid: bool = False
    lost_near: bool = False
    climb_m: float | None = None

    @property
    def coast_s(self) -> float:
        return math.inf if self.measured_s is None else self.time - self.measured_s


def transition(T: float) -> np.ndarray:
    """Eq. 13's A for a step of T seconds, the depth's change carried as a rate: [1, T; 0, 1]."""
    return np.array([[1.0, T], [0.0, 1.0]])


def process_noise(T: float, accel_std: float) -> np.ndarray:
    """Eq. 13's w covariance: a white acceleration of std `accel_std` held over the step."""
    return accel_std**2 * np.array([[T**4 / 4, T**3 / 2], [T**3 / 2, T**2]])


def predict(x: np.ndarray, P: np.ndarray, T: float, config: AltitudeKfConfig) -> tuple[np.ndarray, np.ndarray]:
    A = transition(T)
    return A @ x, A @ P @ A.T + process_noise(T, config.accel_std_mps2)


def measurement(z: float, previous: float | None, T: float,
                config: AltitudeKfConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eq. 14's (z, H, R): [Z, Delta Z / T] with H = I when the previous step measured, else [Z], H = [1, 0]."""
    var = config.measurement_std(z) ** 2
    if config.use_rate_measurement and previous is not None and T > 0:
        return (np.array([z, (z - previous) / T]), np.eye(2),
                np.array([[var, var / T], [var / T, 2 * var / T**2]]))
    return np.array([z]), np.array([[1.0, 0.0]]), np.array([[var]])


def altitude_kf_step(state: AltitudeKfState, z: float, z_valid: bool, t: float,
                     config: AltitudeKfConfig, nearest_m: float = 0.0) -> AltitudeKfState:
    """The filter after the frame at time t (s) with raw altitude z (m) and its flag; `state` unchanged.
    `nearest_m`: the altimeter's nearest range (m; 0: none).

    A valid finite z updates the prediction (or starts the filter when it is not valid); otherwise, and for
    a z beyond the near band while the prediction lies in it, the filter coasts on its prediction and turns
    invalid once `config.max_coast_s` has passed."""
    has_z = bool(z_valid) and math.isfinite(z)
    T = 0.0 if state.time is None else t - state.time
    top = nearest_m + config.near_band_m
    in_band = has_z and nearest_m <= z <= top
    if not state.valid:
        pending = state.last_measurement  # while lost near: the last step's reading in the band
        if state.lost_near and not (has_z and pending is not None and abs(z - pending) <= config.near_band_m):
            return AltitudeKfState(time=t, last_measurement=z if in_band else None, lost_near=True)
        if not has_z:
            return AltitudeKfState(time=t)
        P0 = np.diag([config.measurement_std(z) ** 2, config.initial_speed_std_mps**2])
        return AltitudeKfState(np.array([z, 0.0]), P0, t, z, t, True)
    x, P = predict(state.x, state.P, T, config)
    climb = None
    if nearest_m > 0 and x[0] < top and not in_band:
        last = x[0] if state.climb_m is None else state.climb_m
        if not has_z:  # a frame without a reading leaves a climb out of the band as it was
            climb = state.climb_m
        elif z > top and abs(z - last) <= config.near_band_m:  # ... and one within near_band_m of it goes on
            climb = z
        has_z = False
    if not has_z:
        if t - state.measured_s > config.max_coast_s + 1e-9:  # the time since, not a sum of frame intervals
            return AltitudeKfState(time=t, lost_near=bool(nearest_m > 0 and x[0] < top and climb is None))
        return AltitudeKfState(x, P, t, None, state.measured_s, True, climb_m=climb)
    zv, H, R = measurement(z, state.last_measurement, T, config)
    S = H @ P @ H.T + R
    K = np.linalg.solve(S, H @ P).T
    x = x + K @ (zv - H @ x)
    I_KH = np.eye(2) - K @ H
    P = I_KH @ P @ I_KH.T + K @ R @ K.T  # Joseph form: stays symmetric positive definite
    return AltitudeKfState(x, P, t, z, t, True)


class AltitudeFilterSystem(LeafSystem):
    """The altitude filter stepped at the camera rate (period_s).

    Inputs `altitude` (1, m) and `altitude_valid` (1: > 0.5 is valid), read at the steps (the
    StereoAltimeter's outputs, so the images render at the camera rate); `nearest_m` its nearest range
    (m; `StereoAltitudeEstimator.nearest_m`, 0: none). Outputs `altitude` (1, m) and
    `vertical_speed` (1, m/s, the altitude's rate: negative descending), predicted from the last step
    to the context's time, and `valid` (1: 1.0 or 0.0); NaN altitude and speed when not valid. At a
    step time the outputs include that step (`SteppedValue`)."""

    def __init__(self, config: AltitudeKfConfig | None = None, period_s: float = 1.0 / 60.0, nearest_m: float = 0.0):
        super().__init__()
        self.config = config or AltitudeKfConfig()
        self.config.validate()
        require_positive(period_s, "altitude filter period_s")
        require_non_negative(nearest_m, "altitude filter nearest_m")
        self.nearest_m = nearest_m
        self._altitude = self.DeclareVectorInputPort("altitude", 1)
        self._valid = self.DeclareVectorInputPort("altitude_valid", 1)
        self._stepped = SteppedValue(self, "altitude_kf", AltitudeKfState(), period_s, self._step, lambda s: s.time)
        tickets = {self._stepped.now.ticket()}
        self.DeclareVectorOutputPort("altitude", 1, lambda c, o: o.SetAtIndex(0, self._predicted(c)[0]), tickets)
        self.DeclareVectorOutputPort("vertical_speed", 1, lambda c, o: o.SetAtIndex(0, self._predicted(c)[1]),
                                     tickets)
        self.DeclareVectorOutputPort("valid", 1, lambda c, o: o.SetAtIndex(0, float(self.state(c).valid)), tickets)

    def state(self, context) -> AltitudeKfState:
        """The filter after its last step at or before the context's time."""
        return self._stepped.now.Eval(context)

    def _step(self, context, state: AltitudeKfState) -> AltitudeKfState:
        z = float(self._altitude.Eval(context)[0])
        return altitude_kf_step(state, z, is_set(self._valid.Eval(context)[0]), context.get_time(), self.config,
                                self.nearest_m)

    def _predicted(self, context) -> np.ndarray:
        s = self.state(context)
        if not s.valid:
            return np.full(2, np.nan)
        return transition(context.get_time() - s.time) @ s.x
