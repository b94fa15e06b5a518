"""The wind at a vehicle as a Drake system: mean wind + Dryden turbulence + gusts (systems/environment/wind.py)."""

import numpy as np
from pydrake.systems.framework import LeafSystem

from systems.environment.wind import (
    TURBULENCE_STATES,
    WindConfig,
    gust_velocity_W,
    mean_wind_W,
    stationary_turbulence_state,
    turbulence_airspeed,
    turbulence_output,
    turbulence_scales,
    turbulence_step,
    wind_axes_R_W,
)
from systems.noise import sample_index, sample_rng
from systems.vehicles.quadrotor import P_WB, STATE_SIZE, V_WB


class WindSystem(LeafSystem):
    """Outputs `wind_velocity_W` (3, m/s, in W) = mean wind + turbulence (wind axes to W) + gusts(t).

    Input `quadrotor_state` (17): its altitude z of p_WB (m) sets the turbulence scales, its v_WB (in W, m/s)
    the speed at which the frozen turbulence passes it (`turbulence_airspeed`).
    Discrete state: the 5 turbulence states, drawn from the stationary distribution with
    sample_rng(seed, "wind", 0) so the turbulence is stationary from t = 0, and the held turbulence
    velocity (3, m/s, in W). The update every 1/rate_hz from t = 0 holds the sample of t_k,
    sigma(z_k) C x_k, and steps the state to x_{k+1} with the L and V of t_k and the noise
    sample_rng(seed, "wind", k + 1); an initialization event holds the sample of t = 0 (before it, in a
    bare context, the output is the mean wind and gusts only). The output reads the time and the discrete
    state only: no direct feedthrough, so quadrotor state -> wind -> quadrotor input is not an algebraic loop.
    """

    def __init__(self, config: WindConfig, seed: int = 0):
        super().__init__()
        config.validate()
        self._config, self._seed = config, seed
        self._mean_W = mean_wind_W(config)
        self._R_W = wind_axes_R_W(config.direction_deg)
        self.DeclareVectorInputPort("quadrotor_state", STATE_SIZE)
        turbulent = config.turbulence != "none"
        x0 = np.zeros(TURBULENCE_STATES)
        if turbulent:
            x0 = stationary_turbulence_state(sample_rng(seed, "wind", 0).standard_normal(TURBULENCE_STATES))
        self._turbulence_state = self.DeclareDiscreteState(x0)
        self._held_velocity = self.DeclareDiscreteState(3)
        if turbulent:
            self.DeclareInitializationDiscreteUpdateEvent(self._hold_sample)
            self.DeclarePeriodicDiscreteUpdateEvent(config.period_s, 0.0, self._sample_and_step)
        self.DeclareVectorOutputPort("wind_velocity_W", 3, self._calc_wind, {self.time_ticket(), self.xd_ticket()})

    def _scales(self, context):
        """(sigma (3,) m/s, length (3,) m, airspeed m/s) of the turbulence at the vehicle's current state."""
        state = self.get_input_port().Eval(context)
        sigma, length = turbulence_scales(self._config, state[P_WB][2])
        return sigma, length, turbulence_airspeed(state[V_WB], self._config)

    def _hold_sample(self, context, discrete_state):
        sigma, _, _ = self._scales(context)
        x = context.get_discrete_state(self._turbulence_state).CopyToVector()
        discrete_state.set_value(self._held_velocity, self._R_W @ turbulence_output(x, sigma))

    def _sample_and_step(self, context, discrete_state):
        self._hold_sample(context, discrete_state)
        _, length, airspeed = self._scales(context)
        period = self._config.period_s
        k = sample_index(context.get_time(), period)
        noise = sample_rng(self._seed, "wind", k + 1).standard_normal(TURBULENCE_STATES)
        x = context.get_discrete_state(self._turbulence_state).CopyToVector()
        discrete_state.set_value(self._turbulence_state, turbulence_step(x, length, airspeed, period, noise))

    def _calc_wind(self, context, output):
        held = context.get_discrete_state(self._held_velocity).CopyToVector()
        output.SetFromVector(self._mean_W + held + gust_velocity_W(self._config.gusts, context.get_time()))
