"""Wind: MIL-F-8785C's low-altitude scales, the exact discretisation of the Dryden filters against their
analytic autocorrelations, a long seeded run's statistics, 1-cosine gusts, the WindSystem in a Drake
diagram (replayed against the pure functions, its statistics, seeds, calm air, no feedthrough) and every
validation error."""

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource, LogVectorOutput, MatrixGain
from scipy.linalg import solve_discrete_lyapunov

from systems.config import ConfigError
from systems.environment.wind import (
    W20_M_S,
    GustConfig,
    WindConfig,
    dryden_low_altitude,
    gust_velocity_W,
    mean_wind_W,
    stationary_turbulence_state,
    turbulence_airspeed,
    turbulence_discrete,
    turbulence_output,
    turbulence_scales,
    turbulence_step,
    wind_axes_R_W,
)
from systems.environment.wind_system import WindSystem
from systems.noise import sample_rng
from systems.vehicles.quadrotor import STATE_SIZE

FT = 0.3048  # m
KT = 0.514444  # m/s
MODERATE_W20 = 30 * KT


def analytic_R(sigma, length_m, xi_m):
    """MIL-F-8785C's Dryden autocorrelations (3, ...) at distance xi (m): u exponential, v and w
    (1 - xi / 2L) e^(-xi / L)."""
    sigma, length_m = np.asarray(sigma)[:, None], np.asarray(length_m)[:, None]
    r = np.abs(np.atleast_1d(xi_m))[None, :] / length_m
    shape = np.vstack([np.exp(-r[:1]), (1 - r[1:] / 2) * np.exp(-r[1:])])
    return sigma**2 * shape


def output_matrix(sigma):
    """The linear map (3x5) from turbulence state to output, read off `turbulence_output`."""
    return np.column_stack([turbulence_output(e, sigma) for e in np.eye(5)])


def autocovariance_std(R_of_lag, lag: int, n: int) -> float:
    """Std of the sample autocovariance (1/m) sum y_i y_(i+lag), m = n - lag, of a zero-mean Gaussian
    sequence with autocovariance R_of_lag(j) (Isserlis): Var = (1/m) sum_|j|<m (1 - |j|/m) (R(j)^2 + R(j+lag) R(j-lag))."""
    m = n - lag
    j = np.arange(-m + 1, m)
    terms = (1 - np.abs(j) / m) * (R_of_lag(j) ** 2 + R_of_lag(j + lag) * R_of_lag(j - lag))
    return float(np.sqrt(terms.sum() / m))


def mean_std(R_of_lag, n: int) -> float:
    """Std of the sample mean of n samples of a zero-mean sequence with autocovariance R_of_lag(j)."""
    j = np.arange(-n + 1, n)
    return float(np.sqrt(((1 - np.abs(j) / n) * R_of_lag(j)).sum() / n))


# --- MIL-F-8785C low-altitude intensities and scales ---

@pytest.mark.parametrize("level, knots", [("light", 15), ("moderate", 30), ("severe", 45)])
def test_w20_and_vertical_intensity_is_a_tenth_of_it(level, knots):
    assert W20_M_S[level] == pytest.approx(knots * KT, rel=1e-12)
    for altitude in (5.0, 50.0, 250.0):
        sigma, _ = dryden_low_altitude(altitude, W20_M_S[level])
        assert sigma[2] == pytest.approx(0.1 * knots * KT, rel=1e-12)


@pytest.mark.parametrize("h_ft, sigma_uv, L_uv_ft", [
    (50.0, 1.543332 * 1.8386451185, 310.7876435306),  # (0.177 + 0.000823 * 50) = 0.21815
    (500.0, 1.543332 * 1.2362360761, 944.6572102019),  # (0.177 + 0.000823 * 500) = 0.5885
])
def test_low_altitude_scales_against_mil_f_8785c(h_ft, sigma_uv, L_uv_ft):
    """sigma_u = sigma_v = sigma_w / (0.177 + 0.000823 h)^0.4, L_u = L_v = h / (0.177 + 0.000823 h)^1.2,
    L_w = h (ft), moderate: sigma_w = 0.1 * 30 kt = 1.543332 m/s."""
    factor = 0.177 + 0.000823 * h_ft
    assert sigma_uv == pytest.approx(1.543332 / factor**0.4, rel=1e-9)
    assert L_uv_ft == pytest.approx(h_ft / factor**1.2, rel=1e-9)
    sigma, length = dryden_low_altitude(h_ft * FT, MODERATE_W20)
    np.testing.assert_allclose(sigma, [sigma_uv, sigma_uv, 1.543332], rtol=1e-9)
    np.testing.assert_allclose(length, [L_uv_ft * FT, L_uv_ft * FT, h_ft * FT], rtol=1e-9)


def test_scales_below_the_minimum_altitude_are_held_and_custom_ones_are_fixed():
    config = WindConfig(turbulence="severe")
    held = turbulence_scales(config, config.min_altitude_m)
    for altitude in (2.0, 0.0, -1.0):
        np.testing.assert_array_equal(turbulence_scales(config, altitude), held)
    assert held[1][2] == pytest.approx(10 * FT)
    custom = WindConfig(turbulence="custom", sigma_m_s=[1.0, 2.0, 3.0], length_scale_m=[40.0, 30.0, 5.0])
    for altitude in (1.0, 100.0):
        np.testing.assert_array_equal(turbulence_scales(custom, altitude), ([1, 2, 3], [40, 30, 5]))


# --- the Dryden filters: exact discretisation and a long run ---

@pytest.mark.parametrize("length_m, airspeed, dt", [
    ([67.366, 67.366, 10.0], 5.0, 0.01),  # moderate at 10 m, 5 m/s past it, 100 Hz
    ([20.0, 35.0, 4.0], 12.0, 0.05),
    ([300.0, 300.0, 150.0], 1.0, 0.01),  # slow: V dt / L = 3e-5
    ([5.0, 5.0, 3.0], 30.0, 0.5),  # coarse: V dt / L = 3-5
])
def test_discrete_model_has_the_analytic_variance_and_autocorrelation(length_m, airspeed, dt):
    sigma = np.array([2.9, 2.1, 1.5])
    phi, g = turbulence_discrete(length_m, airspeed, dt)
    P = solve_discrete_lyapunov(phi, g @ g.T)
    C = output_matrix(sigma)
    np.testing.assert_allclose(C @ P @ C.T, np.diag(sigma**2), rtol=1e-9, atol=1e-12)
    for k in (1, 7, 50, 300):
        lagged = C @ np.linalg.matrix_power(phi, k) @ P @ C.T
        expected = analytic_R(sigma, length_m, airspeed * k * dt)[:, 0]
        np.testing.assert_allclose(lagged, np.diag(expected), rtol=1e-9, atol=1e-9 * sigma.max() ** 2)
    # The initial draw is the stationary distribution of the discrete model.
    S = np.column_stack([stationary_turbulence_state(e) for e in np.eye(5)])
    np.testing.assert_allclose(S @ S.T, P, rtol=1e-9, atol=1e-12)


def test_step_is_the_discrete_model():
    length, x, noise = [30.0, 30.0, 8.0], np.arange(5.0) - 2, np.array([0.3, -1.2, 0.8, 2.0, -0.4])
    phi, g = turbulence_discrete(length, 7.0, 0.02)
    np.testing.assert_allclose(turbulence_step(x, length, 7.0, 0.02, noise), phi @ x + g @ noise, rtol=1e-15)


def test_long_seeded_run_has_the_analytic_statistics():
    """200 000 samples, V dt / L = 0.1 (u, v) and 0.25 (w): the sample variance and the autocovariance
    at a few lags within 4.5 standard deviations of the estimator, those computed from the analytic R
    (a few per cent for the variance)."""
    sigma, length, airspeed, dt, n = np.array([1.5, 1.2, 0.8]), np.array([20.0, 20.0, 8.0]), 10.0, 0.2, 200_000
    phi, g = turbulence_discrete(length, airspeed, dt)
    noise = np.random.default_rng(7).standard_normal((n, 5)) @ g.T
    x = stationary_turbulence_state(np.random.default_rng(8).standard_normal(5))
    states = np.empty((n, 5))
    for i in range(n):
        states[i] = x
        x = phi @ x + noise[i]
    y = states @ output_matrix(sigma).T
    for axis in range(3):
        def R(j, axis=axis):
            return analytic_R(sigma, length, airspeed * dt * j)[axis]
        for lag in (0, 5, 10, 20):
            estimate = np.mean(y[: n - lag, axis] * y[lag:, axis])
            tolerance = 4.5 * autocovariance_std(R, lag, n)
            assert abs(estimate - R(lag)[0]) < tolerance, (axis, lag, estimate, R(lag)[0], tolerance)
        assert 4.5 * autocovariance_std(R, 0, n) < 0.05 * sigma[axis] ** 2


# --- frames, mean wind and gusts ---

def test_wind_axes_and_mean_wind():
    R = wind_axes_R_W(90.0)
    np.testing.assert_allclose(R, [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-15)  # u = +y, v = -x, w = +z
    R = wind_axes_R_W(-120.0)
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-15)
    assert np.linalg.det(R) == pytest.approx(1.0)
    np.testing.assert_allclose(R[:, 0], [-0.5, -np.sqrt(3) / 2, 0], atol=1e-15)
    np.testing.assert_allclose(mean_wind_W(WindConfig(mean_m_s=5.0, direction_deg=90.0)), [0, 5, 0], atol=1e-15)
    np.testing.assert_allclose(mean_wind_W(WindConfig(mean_m_s=2.0, direction_deg=225.0)),
                               [-np.sqrt(2), -np.sqrt(2), 0], atol=1e-15)


def test_turbulence_airspeed_is_against_the_mean_wind_and_floored():
    config = WindConfig(mean_m_s=5.0, direction_deg=90.0)
    assert turbulence_airspeed([3.0, 0.0, 0.0], config) == pytest.approx(np.sqrt(34.0))
    assert turbulence_airspeed([0.0, 5.3, 0.0], config) == pytest.approx(1.0)  # 0.3 m/s, floored
    assert turbulence_airspeed([0.0, 0.0, 0.0], WindConfig(min_airspeed_m_s=2.5)) == 2.5


def test_one_cosine_gust():
    gust = GustConfig(start_s=2.0, duration_s=4.0, magnitude_m_s=6.0, direction_deg=90.0, elevation_deg=30.0)
    for t in (0.0, 1.999, 6.001, 50.0):
        np.testing.assert_array_equal(gust_velocity_W([gust], t), np.zeros(3))
    np.testing.assert_allclose(gust_velocity_W([gust], 4.0), 6.0 * np.array([0, np.sqrt(3) / 2, 0.5]), atol=1e-14)
    np.testing.assert_allclose(gust_velocity_W([gust], 3.0), 3.0 * np.array([0, np.sqrt(3) / 2, 0.5]), atol=1e-14)
    np.testing.assert_allclose(gust_velocity_W([gust], 2.0), np.zeros(3), atol=1e-14)
    np.testing.assert_allclose(gust_velocity_W([gust], 6.0), np.zeros(3), atol=1e-14)


def test_overlapping_gusts_add():
    a = GustConfig(start_s=0.0, duration_s=2.0, magnitude_m_s=4.0, direction_deg=0.0)
    b = GustConfig(start_s=0.5, duration_s=1.0, magnitude_m_s=2.0, direction_deg=180.0, elevation_deg=-90.0)
    # at t = 1: a at its peak toward +x, b at its peak straight down.
    np.testing.assert_allclose(gust_velocity_W([a, b], 1.0), [4.0, 0.0, -2.0], atol=1e-14)
    t = 0.8
    np.testing.assert_allclose(gust_velocity_W([a, b], t), gust_velocity_W([a], t) + gust_velocity_W([b], t))
    assert gust_velocity_W([a, b], t)[0] == pytest.approx(2.0 * (1 - np.cos(np.pi * 0.8)))


# --- the WindSystem in a diagram ---

def quadrotor_state(z_m=10.0, v_WB=(0.0, 0.0, 0.0)) -> np.ndarray:
    state = np.zeros(STATE_SIZE)
    state[2], state[3], state[7:10] = z_m, 1.0, v_WB
    return state


def simulate(config: WindConfig, seed: int | None, duration_s: float, state=None):
    """The logged wind_velocity_W (3 x n) at every turbulence sample time from 0 to duration_s (seed None: the
    WindSystem's default)."""
    builder = DiagramBuilder()
    source = builder.AddSystem(ConstantVectorSource(quadrotor_state() if state is None else state))
    wind = builder.AddSystem(WindSystem(config) if seed is None else WindSystem(config, seed))
    builder.Connect(source.get_output_port(), wind.get_input_port())
    logger = LogVectorOutput(wind.get_output_port(), builder, publish_period=config.period_s)
    simulator = Simulator(builder.Build())
    simulator.AdvanceTo(duration_s)
    log = logger.FindLog(simulator.get_context())
    return log.sample_times(), log.data()


def test_system_replays_the_pure_functions():
    """A vehicle at 20 m moving at [3, 2, -1] m/s in a 5 m/s wind toward +y, with a gust: the log at t_(k+1)
    holds the sample of t_k (a publish at t_(k+1) comes before that time's update). The turbulence passes at the
    airspeed |v_WB - v_mean| = |(3, -3, -1)|; the velocity has a part along the wind, so -v_WB (|(-3, -7, 1)|)
    would step it otherwise."""
    gust = GustConfig(start_s=0.3, duration_s=0.5, magnitude_m_s=3.0, direction_deg=10.0)
    config = WindConfig(mean_m_s=5.0, direction_deg=90.0, turbulence="moderate", gusts=[gust])
    times, data = simulate(config, 11, 1.0, quadrotor_state(20.0, (3.0, 2.0, -1.0)))
    sigma, length = dryden_low_altitude(20.0, MODERATE_W20)
    airspeed = np.linalg.norm([3.0, -3.0, -1.0])
    R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    x = stationary_turbulence_state(sample_rng(11, "wind", 0).standard_normal(5))
    assert len(times) == 101
    np.testing.assert_allclose(data[:, 0], data[:, 1])  # the initialization event holds the sample of t = 0
    for k in range(100):
        expected = [0.0, 5.0, 0.0] + R @ turbulence_output(x, sigma) + gust_velocity_W([gust], times[k + 1])
        np.testing.assert_allclose(data[:, k + 1], expected, rtol=1e-12, atol=1e-12)
        x = turbulence_step(x, length, airspeed, 0.01, sample_rng(11, "wind", k + 1).standard_normal(5))


def test_system_statistics_in_the_wind_axes():
    """Hovering at 10 m in a 5 m/s wind toward +y, moderate: L_u = L_v = 67 m pass at 5 m/s in 13 s, so the
    run is 14 000 s sampled at 0.5 Hz (the discretisation is exact at any rate). Mean, variance and lag-1
    autocovariance per wind axis within 4.5 standard deviations of their estimators from the analytic R."""
    config = WindConfig(mean_m_s=5.0, direction_deg=90.0, turbulence="moderate", rate_hz=0.5)
    _, data = simulate(config, 5, 14_000.0)
    y = wind_axes_R_W(90.0).T @ (data[:, 1:] - [[0.0], [5.0], [0.0]])  # the samples of t_0 .. t_(n-1)
    n = y.shape[1]
    sigma, length = dryden_low_altitude(10.0, MODERATE_W20)
    for axis in range(3):
        def R(j, axis=axis):
            return analytic_R(sigma, length, 5.0 * 2.0 * j)[axis]
        assert abs(y[axis].mean()) < 4.5 * mean_std(R, n), axis
        for lag in (0, 1):
            estimate = np.mean(y[axis, : n - lag] * y[axis, lag:])
            assert abs(estimate - R(lag)[0]) < 4.5 * autocovariance_std(R, lag, n), (axis, lag, estimate, R(lag)[0])
    assert 4.5 * mean_std(lambda j: analytic_R(sigma, length, 10.0 * j)[0], n) < 0.6  # m/s: a meaningful bound


def test_same_seed_same_series_other_seed_differs():
    config = WindConfig(mean_m_s=5.0, direction_deg=90.0, turbulence="moderate")
    _, first = simulate(config, 3, 2.0)
    _, again = simulate(config, 3, 2.0)
    _, other = simulate(config, 4, 2.0)
    np.testing.assert_array_equal(first, again)
    assert np.abs(first - other).max() > 0.1


def test_the_default_seed_is_zero():
    config = WindConfig(mean_m_s=5.0, direction_deg=90.0, turbulence="moderate")
    _, default = simulate(config, None, 0.2)
    _, zero = simulate(config, 0, 0.2)
    _, one = simulate(config, 1, 0.2)
    np.testing.assert_array_equal(default, zero)
    assert np.abs(default - one).max() > 0.1  # the seed shows in the output


def test_a_gust_alone_follows_the_context_time():
    """Without turbulence there are no discrete updates: the output still depends on the time (a 1-cosine gust
    of 4 m/s toward +x over [0, 1] s: 2 (1 - cos(2 pi t)), 0 at t = 0 and 4 at t = 0.5), not cached on the
    discrete state alone."""
    gust = GustConfig(start_s=0.0, duration_s=1.0, magnitude_m_s=4.0, direction_deg=0.0)
    wind = WindSystem(WindConfig(gusts=[gust]))
    context = wind.CreateDefaultContext()
    wind.get_input_port().FixValue(context, quadrotor_state())
    np.testing.assert_allclose(wind.get_output_port().Eval(context), [0.0, 0.0, 0.0], atol=1e-14)
    context.SetTime(0.5)
    np.testing.assert_allclose(wind.get_output_port().Eval(context), [4.0, 0.0, 0.0], atol=1e-14)
    context.SetTime(0.25)
    np.testing.assert_allclose(wind.get_output_port().Eval(context), [2.0, 0.0, 0.0], atol=1e-14)


def test_calm_air_is_exactly_zero():
    config = WindConfig()
    assert config.is_calm
    _, data = simulate(config, 0, 1.0)
    assert data.shape == (3, 101) and np.all(data == 0.0)


def test_is_calm():
    assert WindConfig(gusts=[GustConfig(magnitude_m_s=0.0)]).is_calm
    assert not WindConfig(mean_m_s=0.1).is_calm
    assert not WindConfig(turbulence="light").is_calm
    assert not WindConfig(gusts=[GustConfig(magnitude_m_s=1.0)]).is_calm


def test_no_direct_feedthrough_and_no_algebraic_loop():
    for config in (WindConfig(), WindConfig(mean_m_s=3.0, turbulence="severe")):
        assert not WindSystem(config).HasDirectFeedthrough(0, 0)
    # The wind fed back into the vehicle state's velocity: builds (no algebraic loop) and runs.
    builder = DiagramBuilder()
    wind = builder.AddSystem(WindSystem(WindConfig(mean_m_s=3.0, turbulence="light")))
    into_velocity = np.zeros((STATE_SIZE, 3))
    into_velocity[7:10] = np.eye(3)
    gain = builder.AddSystem(MatrixGain(into_velocity))
    builder.Connect(wind.get_output_port(), gain.get_input_port())
    builder.Connect(gain.get_output_port(), wind.get_input_port())
    simulator = Simulator(builder.Build())
    simulator.AdvanceTo(0.5)
    assert np.all(np.isfinite(wind.get_output_port().Eval(wind.GetMyContextFromRoot(simulator.get_context()))))


# --- validation ---

@pytest.mark.parametrize("elevation_deg", [90.0, -90.0])
def test_a_gust_straight_up_or_down_is_valid(elevation_deg):
    """The elevation bounds are inclusive: a gust at exactly +-90 deg validates and blows straight up or down."""
    config = WindConfig(gusts=[GustConfig(duration_s=2.0, magnitude_m_s=3.0, elevation_deg=elevation_deg)])
    config.validate()
    WindSystem(config)
    np.testing.assert_allclose(gust_velocity_W(config.gusts, 1.0), [0.0, 0.0, np.sign(elevation_deg) * 3.0],
                               atol=1e-15)


@pytest.mark.parametrize("changes, message", [
    ({"mean_m_s": -1.0}, "wind.mean_m_s must not be negative, got -1.0"),
    ({"turbulence": "strong"}, "wind.turbulence 'strong' is not one of none, light, moderate, severe, custom"),
    ({"turbulence": "custom", "length_scale_m": [1.0, 1.0, 1.0]}, "wind.sigma_m_s must be 3 positive values"),
    ({"turbulence": "custom", "sigma_m_s": [1.0, 0.0, 1.0], "length_scale_m": [1.0, 1.0, 1.0]},
     "wind.sigma_m_s must be 3 positive values"),
    ({"turbulence": "custom", "sigma_m_s": [1.0, 1.0, 1.0, 1.0], "length_scale_m": [1.0, 1.0, 1.0]},
     "wind.sigma_m_s must be 3 positive values"),  # one too many
    ({"turbulence": "custom", "sigma_m_s": [1.0, 1.0, 1.0], "length_scale_m": [1.0, 1.0]},
     "wind.length_scale_m must be 3 positive values"),
    ({"turbulence": "moderate", "sigma_m_s": [1.0, 1.0, 1.0]},
     "wind.sigma_m_s is used only with turbulence 'custom', not 'moderate'"),
    ({"length_scale_m": [1.0, 1.0, 1.0]}, "wind.length_scale_m is used only with turbulence 'custom', not 'none'"),
    ({"min_altitude_m": 0.0}, "wind.min_altitude_m must be positive, got 0.0"),
    ({"min_airspeed_m_s": -1.0}, "wind.min_airspeed_m_s must be positive, got -1.0"),
    ({"rate_hz": 0.0}, "wind.rate_hz must be positive, got 0.0"),
    ({"gusts": [GustConfig(), GustConfig(duration_s=0.0)]}, "wind.gusts[1].duration_s must be positive, got 0.0"),
    ({"gusts": [GustConfig(start_s=-1.0)]}, "wind.gusts[0].start_s must not be negative, got -1.0"),
    ({"gusts": [GustConfig(magnitude_m_s=-2.0)]}, "wind.gusts[0].magnitude_m_s must not be negative, got -2.0"),
    # 180 deg up from the horizontal blew the gust against its direction_deg
    ({"gusts": [GustConfig(), GustConfig(elevation_deg=180.0)]}, "wind.gusts[1].elevation_deg must be in [-90, 90]"),
    ({"gusts": [GustConfig(elevation_deg=-90.5)]}, "wind.gusts[0].elevation_deg must be in [-90, 90]"),
    ({"direction_deg": float("nan")}, "wind.direction_deg must be finite, got nan"),  # the wind would be NaN
    ({"gusts": [GustConfig(direction_deg=float("inf"))]}, "wind.gusts[0].direction_deg must be finite, got inf"),
])
def test_validation_errors_name_the_field(changes, message):
    config = WindConfig(**changes)
    with pytest.raises(ConfigError) as error:
        config.validate()
    assert str(error.value).startswith(message) and "\n" not in str(error.value)
    with pytest.raises(ConfigError):
        WindSystem(config)
