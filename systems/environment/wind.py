"""Wind: a mean wind, Dryden turbulence (MIL-F-8785C) and 1-cosine gust pulses, as configuration and pure maths.

Frames and units: World W is z up (x, y horizontal, the ground at z = 0); speeds in m/s, lengths in m,
times in s, angles in deg. A direction is where the air moves TOWARD, measured from W +x toward +y
(direction 90 is air moving toward +y); this is not the meteorological "from" convention. Turbulence is
expressed in the wind axes (`wind_axes_R_W`): u along the mean wind's horizontal direction, v horizontal
to its left, w up.

Turbulence, MIL-F-8785C's Dryden form: with V the speed at which the frozen turbulence field passes the
vehicle and tau_i = L_i / V,
    H_u(s) = sigma_u sqrt(2 L_u / (pi V)) / (1 + tau_u s),
    H_v(s) = sigma_v sqrt(L_v / (pi V)) (1 + sqrt(3) tau_v s) / (1 + tau_v s)^2,  H_w likewise,
whose autocorrelations in the distance xi = V t are
    R_u(xi) = sigma_u^2 exp(-xi / L_u),  R_v(xi) = sigma_v^2 (1 - xi / (2 L_v)) exp(-xi / L_v).
Each component is realised here in its normalised time r = t / tau_i, driven by unit white noise n
(E[n(r) n(r')] = delta(r - r')):
    u:    dx/dr = -x + sqrt(2) n,                          u = sigma_u x,
    v, w: dx/dr = [[-1, 1], [0, -1]] x + [0, 1] n,         v = sigma_v ((1 - sqrt(3)) x_1 + sqrt(3) x_2).
In physical time these are the H above times sqrt(pi) (the MIL forms' 1/sqrt(pi) belongs to their
one-sided spectrum), so each output's stationary variance is exactly sigma^2 and its autocorrelation is R.
The 5 states (u: 1, v: 2, w: 2) are dimensionless with a stationary covariance that does not depend on
sigma, L or V: when altitude or airspeed change them, the state stays stationary and the output rescales
at once. Each sample is discretised exactly over dt (Van Loan 1978) from the current L and V.
"""

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import block_diag

from systems.config import require, require_non_negative, require_positive
from systems.noise import stationary_factor, van_loan_discretisation

FT_M = 0.3048
KNOT_M_S = 0.514444
TURBULENCE_LEVELS = ("none", "light", "moderate", "severe", "custom")
# Wind speed at 20 ft that sets the low-altitude intensities (MIL-F-8785C, MIL-HDBK-1797): 15, 30, 45 kt.
W20_M_S = {"light": 15 * KNOT_M_S, "moderate": 30 * KNOT_M_S, "severe": 45 * KNOT_M_S}

TURBULENCE_STATES = 5
_SQRT3 = np.sqrt(3.0)
_SECOND_ORDER = np.array([[-1.0, 1.0], [0.0, -1.0]])
_A = block_diag([[-1.0]], _SECOND_ORDER, _SECOND_ORDER)  # in normalised time
_B = block_diag([[np.sqrt(2.0)]], [[0.0], [1.0]], [[0.0], [1.0]])  # 5x3: one unit white noise per component
_C = block_diag([[1.0]], [[1.0 - _SQRT3, _SQRT3]], [[1.0 - _SQRT3, _SQRT3]])  # 3x5, to unit-sigma u, v, w
_COMPONENT_OF_STATE = np.array([0, 1, 1, 2, 2])
# Cholesky factor of the states' stationary covariance P, A P + P A^T + B B^T = 0.
_STATIONARY_FACTOR = stationary_factor(_A, _B @ _B.T)


@dataclass
class GustConfig:
    """A discrete 1-cosine gust: starts at `start_s`, peaks at `magnitude_m_s` at mid-duration, ends after
    `duration_s`; it moves toward `direction_deg` (from W +x toward +y), `elevation_deg` above the horizontal."""

    start_s: float = 0.0
    duration_s: float = 1.0
    magnitude_m_s: float = 0.0
    direction_deg: float = 0.0
    elevation_deg: float = 0.0

    def validate(self, prefix: str = "gust") -> None:
        require_non_negative(self.start_s, f"{prefix}.start_s")
        require_positive(self.duration_s, f"{prefix}.duration_s")
        require_non_negative(self.magnitude_m_s, f"{prefix}.magnitude_m_s")
        require(math.isfinite(self.direction_deg), f"{prefix}.direction_deg must be finite, got {self.direction_deg}")
        # Past +-90 deg the gust would move against direction_deg: that is direction_deg + 180.
        require(-90 <= self.elevation_deg <= 90,
                f"{prefix}.elevation_deg must be in [-90, 90] (turn direction_deg instead), got {self.elevation_deg}")


@dataclass
class WindConfig:
    """Mean wind, turbulence and gusts.

    mean_m_s: horizontal mean wind speed (m/s), the same at every height (no wind shear).
    direction_deg: where the mean air moves toward, from W +x toward +y (not the "from" convention).
    turbulence: none | light | moderate | severe (MIL-F-8785C low altitude, `dryden_low_altitude`) |
      custom (`sigma_m_s` and `length_scale_m`, 3 each for u, v, w, held at every altitude).
    min_altitude_m: below it the low-altitude scales are those of this altitude (10 ft; the model's
      own range is 10-1000 ft, and its formulas are used as they are above 1000 ft).
    min_airspeed_m_s: floor of the speed at which the frozen turbulence passes the vehicle, taken as
      the air-relative speed against the mean wind |v_WB - v_mean_W|. Our choice: a hovering vehicle
      in calm mean air still sees the turbulence evolve.
    rate_hz: the turbulence's sample rate.
    """

    mean_m_s: float = 0.0
    direction_deg: float = 0.0
    turbulence: str = "none"
    sigma_m_s: list[float] = field(default_factory=list)
    length_scale_m: list[float] = field(default_factory=list)
    min_altitude_m: float = 10 * FT_M
    min_airspeed_m_s: float = 1.0
    rate_hz: float = 100.0
    gusts: list[GustConfig] = field(default_factory=list)

    def validate(self, prefix: str = "wind") -> None:
        require_non_negative(self.mean_m_s, f"{prefix}.mean_m_s")
        require(math.isfinite(self.direction_deg), f"{prefix}.direction_deg must be finite, got {self.direction_deg}")
        require(self.turbulence in TURBULENCE_LEVELS,
                f"{prefix}.turbulence '{self.turbulence}' is not one of {', '.join(TURBULENCE_LEVELS)}")
        for name in ("sigma_m_s", "length_scale_m"):
            values = getattr(self, name)
            if self.turbulence == "custom":
                require(len(values) == 3 and all(v > 0 for v in values),
                        f"{prefix}.{name} must be 3 positive values (u, v, w) with turbulence 'custom', got {values}")
            else:
                require(not values, f"{prefix}.{name} is used only with turbulence 'custom', not '{self.turbulence}'")
        for name in ("min_altitude_m", "min_airspeed_m_s", "rate_hz"):
            require_positive(getattr(self, name), f"{prefix}.{name}")
        for i, gust in enumerate(self.gusts):
            gust.validate(f"{prefix}.gusts[{i}]")

    @property
    def period_s(self) -> float:
        return 1.0 / self.rate_hz

    @property
    def is_calm(self) -> bool:
        """No mean wind, no turbulence and no gust of any magnitude: the wind is zero at all times."""
        return self.mean_m_s == 0 and self.turbulence == "none" and all(g.magnitude_m_s == 0 for g in self.gusts)


def dryden_low_altitude(altitude_m: float, w20_m_s: float) -> tuple[np.ndarray, np.ndarray]:
    """MIL-F-8785C low-altitude turbulence: (sigma (3,) in m/s, length scale (3,) in m) for u, v, w.

    With h the altitude in ft: sigma_w = 0.1 W20, sigma_u = sigma_v = sigma_w / (0.177 + 0.000823 h)^0.4,
    L_w = h, L_u = L_v = h / (0.177 + 0.000823 h)^1.2. (MIL-HDBK-1797 instead has L_w = h / 2 and
    L_u = 2 L_v; this is MIL-F-8785C's.) Valid for 10-1000 ft: the caller clamps the altitude."""
    h_ft = altitude_m / FT_M
    factor = 0.177 + 0.000823 * h_ft
    sigma_w = 0.1 * w20_m_s
    sigma_uv = sigma_w / factor**0.4
    length_uv_m = h_ft / factor**1.2 * FT_M
    return np.array([sigma_uv, sigma_uv, sigma_w]), np.array([length_uv_m, length_uv_m, altitude_m])


def turbulence_scales(config: WindConfig, altitude_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(sigma (3,) in m/s, length scale (3,) in m) of a config with turbulence (not 'none') at an altitude
    (m): the custom values, or the low-altitude model at the altitude clamped to `min_altitude_m`."""
    if config.turbulence == "custom":
        return np.array(config.sigma_m_s, dtype=float), np.array(config.length_scale_m, dtype=float)
    return dryden_low_altitude(max(altitude_m, config.min_altitude_m), W20_M_S[config.turbulence])


def turbulence_airspeed(v_WB_W: np.ndarray, config: WindConfig) -> float:
    """The speed (m/s) at which the frozen turbulence passes the vehicle: max(|v_WB - v_mean_W|, floor)."""
    return max(float(np.linalg.norm(np.asarray(v_WB_W) - mean_wind_W(config))), config.min_airspeed_m_s)


def turbulence_discrete(length_m: np.ndarray, airspeed_m_s: float, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """The exact discrete model over dt: (Phi (5x5), G (5x5)) with x_next = Phi x + G n, n ~ N(0, I).

    In normalised time each component steps h_i = V dt / L_i (systems.noise.van_loan_discretisation with each
    state's row of A and of B scaled by its h_i, sqrt(h_i)). Recomputed every sample
    (L and V change): one call costs about 35 us (a 10x10 expm and a 5x5 Cholesky, measured on one
    AMD EPYC core), a whole WindSystem sample in a simulation about 0.15 ms, 1.5 % of real time at 100 Hz."""
    h = (airspeed_m_s * dt_s / np.asarray(length_m, dtype=float))[_COMPONENT_OF_STATE]
    B_h = np.sqrt(h)[:, None] * _B
    return van_loan_discretisation(h[:, None] * _A, B_h @ B_h.T)


def turbulence_step(x: np.ndarray, length_m: np.ndarray, airspeed_m_s: float, dt_s: float,
                    noise: np.ndarray) -> np.ndarray:
    """The turbulence state (5,) dt later, from standard normal `noise` (5,)."""
    phi, g = turbulence_discrete(length_m, airspeed_m_s, dt_s)
    return phi @ x + g @ noise


def stationary_turbulence_state(noise: np.ndarray) -> np.ndarray:
    """A turbulence state (5,) drawn from the stationary distribution, from standard normal `noise` (5,)."""
    return _STATIONARY_FACTOR @ noise


def turbulence_output(x: np.ndarray, sigma_m_s: np.ndarray) -> np.ndarray:
    """The turbulence velocity [u, v, w] (3,) in the wind axes (m/s) of state x (5,)."""
    return np.asarray(sigma_m_s) * (_C @ x)


def wind_axes_R_W(direction_deg: float) -> np.ndarray:
    """The rotation (3x3) from the wind axes (u toward `direction_deg`, v to its left, w up) to W."""
    a = np.deg2rad(direction_deg)
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def mean_wind_W(config: WindConfig) -> np.ndarray:
    """The mean wind velocity (3,) in W (m/s), horizontal, toward `direction_deg`."""
    return config.mean_m_s * wind_axes_R_W(config.direction_deg)[:, 0]


def gust_velocity_W(gusts: list[GustConfig], t: float) -> np.ndarray:
    """The sum of the gusts' velocities (3,) in W (m/s) at time t (s).

    Each is a 1-cosine pulse in time rather than distance, the shape of CS-25.341's discrete gust (MIL-F-8785C's
    discrete gust ramps up the same way and then holds its peak; two of its ramps, up and down, make this pulse):
    v(t) = (V_m / 2) (1 - cos(2 pi (t - t0) / T)) for t0 <= t <= t0 + T, zero outside; it rises to V_m at
    mid-duration and falls back to zero."""
    total = np.zeros(3)
    for g in gusts:
        if g.start_s <= t <= g.start_s + g.duration_s:
            speed = g.magnitude_m_s / 2 * (1 - np.cos(2 * np.pi * (t - g.start_s) / g.duration_s))
            total += speed * _unit_vector_W(g.direction_deg, g.elevation_deg)
    return total


def _unit_vector_W(direction_deg: float, elevation_deg: float) -> np.ndarray:
    """The unit vector toward `direction_deg` (from W +x toward +y), `elevation_deg` above the horizontal."""
    azimuth, elevation = np.deg2rad(direction_deg), np.deg2rad(elevation_deg)
    return np.array([np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)])
