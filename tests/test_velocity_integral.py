"""Integral action on the horizontal velocity error: the clamp, and a hovering quadrotor held still
in a steady wind, where the proportional loop alone drifts downwind at the speed the analysis gives."""

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource

from diagrams.gv_landing import build_gv_landing
from diagrams.runner import load_scenario
from systems.control.flight_controller import FlightController, FlightControllerConfig, flight_command
from systems.control.velocity_integral import VelocityIntegral, integral_step
from systems.vehicles.quadrotor import V_WB, Quadrotor, QuadrotorParams, hover_state
from tests.conftest import wiring

pytestmark = pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")

QUAD = QuadrotorParams(rotor_drag_coefficient=8.06428e-5)


def test_the_integral_accumulates_the_error_and_is_clamped():
    step = integral_step(np.array([0.1, 0.0]), [1.0, 0.5], [0.0, 0.0], 0.01, 1.0, 3.0)
    np.testing.assert_allclose(step, [0.11, 0.005])
    clamped = integral_step(np.array([2.9, 0.0]), [0.0, 50.0], [0.0, 0.0], 0.01, 2.0, 3.0)
    assert np.linalg.norm(clamped) * 2.0 == pytest.approx(3.0)  # K_i |I| at the limit, in the error's direction
    assert clamped[1] > 0


def test_the_system_steps_the_integral_at_its_rate_and_adds_it_to_the_horizontal_feed_forward():
    """Commanded v_des = (1, -0.5, 0) with a_ff = (0.1, 0.2, 0.3), flying v_WB = (0.2, 0.1, 0), K_i = 1 at 200 Hz:
    by t = 22.5 ms the steps of 0, 5, 10, 15 and 20 ms have each added T (v_des - v)_xy = 0.005 (0.8, -0.6), so
    I = (0.02, -0.015) and the output's a_ff is (0.1 + 0.02, 0.2 - 0.015, 0.3); the rest of the command passes."""
    system = VelocityIntegral(FlightControllerConfig(velocity_integral_gain_xy=1.0, rate_hz=200.0))
    simulator = Simulator(system)
    context = simulator.get_mutable_context()
    command = flight_command([1.0, -0.5, 0.0], 0.7, [0.1, 0.2, 0.3])
    system.GetInputPort("command").FixValue(context, command)
    state = hover_state(QUAD, [0.0, 0.0, 10.0])
    state[V_WB] = [0.2, 0.1, 0.0]
    system.GetInputPort("state").FixValue(context, state)
    simulator.AdvanceTo(0.0225)
    np.testing.assert_allclose(system.get_output_port().Eval(context),
                               [1.0, -0.5, 0.0, 0.7, 0.1 + 0.02, 0.2 - 0.015, 0.3], rtol=0, atol=1e-12)


@pytest.mark.parametrize("gain", [0.0, 1.0])
def test_a_quadrotor_told_to_hold_still_in_a_steady_wind(gain):
    config = FlightControllerConfig(velocity_integral_gain_xy=gain)
    builder = DiagramBuilder()
    quad = builder.AddSystem(Quadrotor(QUAD, wind=True))
    controller = builder.AddSystem(FlightController(QUAD, config))
    command = builder.AddSystem(ConstantVectorSource(flight_command([0.0, 0.0, 0.0])))
    wind = builder.AddSystem(ConstantVectorSource([4.0, 0.0, 0.0]))
    builder.Connect(wind.get_output_port(), quad.GetInputPort("wind_velocity_W"))
    builder.Connect(quad.GetOutputPort("state"), controller.GetInputPort("state"))
    builder.Connect(controller.get_output_port(), quad.GetInputPort("rotor_speed_commands"))
    if gain:
        integral = builder.AddSystem(VelocityIntegral(config))
        builder.Connect(command.get_output_port(), integral.GetInputPort("command"))
        builder.Connect(quad.GetOutputPort("state"), integral.GetInputPort("state"))
        builder.Connect(integral.get_output_port(), controller.GetInputPort("command"))
    else:
        builder.Connect(command.get_output_port(), controller.GetInputPort("command"))
    simulator = Simulator(builder.Build())
    quad.set_state(simulator.get_mutable_context(), hover_state(QUAD, [0.0, 0.0, 10.0]))
    simulator.AdvanceTo(15.0)
    v = quad.GetOutputPort("state").Eval(quad.GetMyContextFromRoot(simulator.get_context()))[V_WB]
    if gain:
        assert np.linalg.norm(v[:2]) < 1e-3  # horizontally (the vertical loop has no integral)
    else:  # K_v v = c (4 - v), c = k_rd 4 w_hover / m: the proportional loop's steady drift downwind
        c = QUAD.rotor_drag_coefficient * 4 * QUAD.hover_rotor_speed() / QUAD.mass_kg
        assert v[0] == pytest.approx(4.0 * c / (config.velocity_gain_xy + c), rel=0.02) and v[0] > 0.2


@pytest.mark.parametrize("gain", [0.0, 1.0])
def test_the_landing_stack_puts_the_integral_between_the_supervisor_and_the_controller_on_the_navigation(gain):
    """In the gv-landing diagram (diagrams/flight_stack.py) with a positive velocity_integral_gain_xy, the
    supervisor's command reaches the flight controller through the integral, which integrates the velocity
    the UAV's navigation (gnss_ins here) believes, as the controller does, not the true one; with gain 0 there is
    no integral and the supervisor commands the controller directly."""
    _, config = load_scenario("gv-landing", overrides=["navigation.source=gnss_ins",
                                                       f"controller.velocity_integral_gain_xy={gain}"])
    diagram, _ = build_gv_landing(config)
    wired = wiring(diagram)
    assert wired["flight_controller", "state"] == ("navigation", "state")
    if gain:
        assert wired["velocity_integral", "command"] == ("landing_supervisor", "command")
        assert wired["velocity_integral", "state"] == ("navigation", "state")
        assert wired["flight_controller", "command"] == ("velocity_integral", "command")
    else:
        assert not diagram.HasSubsystemNamed("velocity_integral")
        assert wired["flight_controller", "command"] == ("landing_supervisor", "command")
