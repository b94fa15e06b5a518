"""The landing flight stack every landing diagram shares: the seam cut into ports, seed 003's tracking
PID and landing supervisor, the flight controller on the quadrotor, and the referee that ends the run.

    stack = add_flight_stack(builder, config, quadrotor, nav_state, relative_state, carrier_state,
                             true_relative_state, carrier)

`config` is a `diagrams.gv_landing_config.FlightConfig` (the gv and deck-landing configs both are).
`nav_state` is what the UAV believes of itself (its navigation's state, or the truth); the seam is what
steers; the carrier (the vehicle, or the deck) and the true relative state are the referee's.
"""

from dataclasses import dataclass

from pydrake.systems.framework import DiagramBuilder, OutputPort
from pydrake.systems.primitives import Demultiplexer

from diagrams.gv_landing_config import FlightConfig
from systems.control.flight_controller import FlightController, SymbolicFlightController, make_flight_controller
from systems.control.landing import LandingSupervisor
from systems.control.monitor import LandingMonitor
from systems.control.pid import TrackingPid
from systems.control.velocity_integral import VelocityIntegral
from systems.perception.rendezvous import SeamSelect
from systems.perception.seam import SeamSplit
from systems.vehicles.ground_vehicle_geometry import PlatformConfig
from systems.vehicles.quadrotor import STATE_SIZE, Quadrotor


@dataclass
class FlightStack:
    seam: SeamSplit
    pid: TrackingPid
    supervisor: LandingSupervisor
    controller: SymbolicFlightController | FlightController
    monitor: LandingMonitor


def add_flight_stack(builder: DiagramBuilder, config: FlightConfig, quad: Quadrotor, nav_state: OutputPort,
                     relative_state: OutputPort, carrier_state: OutputPort, true_relative_state: OutputPort,
                     carrier: PlatformConfig, rendezvous: OutputPort | None = None) -> FlightStack:
    """Adds the stack, steering `quad` on the seam `relative_state`; returns its systems. `rendezvous`: a
    coarse seam (systems/perception/rendezvous.py) that the PID tracks where the vision one is invalid,
    which the supervisor never descends on."""
    seam = builder.AddNamedSystem("seam", SeamSplit())
    vision_valid = None
    if rendezvous is not None:
        select = builder.AddNamedSystem("seam_select", SeamSelect())
        builder.Connect(relative_state, select.GetInputPort("vision"))
        builder.Connect(rendezvous, select.GetInputPort("rendezvous"))
        relative_state, vision_valid = select.GetOutputPort("relative_state"), select.GetOutputPort("vision_valid")
    builder.Connect(relative_state, seam.get_input_port())
    pid = builder.AddNamedSystem("tracking_pid", TrackingPid(config.pid))
    supervisor = builder.AddNamedSystem("landing_supervisor", LandingSupervisor(config.landing))
    # Not held with the discretised quadrotor: it samples and holds the law at the period itself.
    controller = builder.AddNamedSystem("flight_controller", make_flight_controller(
        config.quadrotor, config.controller, config.controller_implementation, held=not config.integration.discrete))
    monitor = builder.AddNamedSystem("monitor", LandingMonitor(
        config.termination, carrier, config.landing.touchdown_height_m,
        ends_on_landed=config.landing.motors_stop_at_landed))
    altitude = builder.AddNamedSystem("altitude", Demultiplexer([2, 1, STATE_SIZE - 3]))
    builder.Connect(nav_state, altitude.get_input_port())
    for name in ("target_offset", "target_velocity", "target_valid"):
        builder.Connect(seam.GetOutputPort(name), pid.GetInputPort(name))
    for name in ("target_offset", "target_velocity"):
        builder.Connect(seam.GetOutputPort(name), supervisor.GetInputPort(name))
    if vision_valid is None:
        vision_valid = seam.GetOutputPort("target_valid")
    else:
        builder.Connect(select.GetOutputPort("rendezvous_valid"), supervisor.GetInputPort("rendezvous_valid"))
        builder.Connect(vision_valid, pid.GetInputPort("source"))  # a handover restarts the PID
    builder.Connect(vision_valid, supervisor.GetInputPort("target_valid"))
    builder.Connect(seam.GetOutputPort("target_acceleration"), pid.GetInputPort("target_acceleration"))
    builder.Connect(seam.GetOutputPort("height_above_target"), pid.GetInputPort("height"))
    builder.Connect(seam.GetOutputPort("height_above_target"), supervisor.GetInputPort("height_above_target"))
    builder.Connect(altitude.get_output_port(1), supervisor.GetInputPort("altitude"))
    builder.Connect(pid.GetOutputPort("velocity_command"), supervisor.GetInputPort("tracking_velocity"))
    builder.Connect(pid.GetOutputPort("acceleration_command"), supervisor.GetInputPort("tracking_acceleration"))
    if config.controller.velocity_integral_gain_xy > 0:  # the supervisor's command with integral action
        integral = builder.AddNamedSystem("velocity_integral", VelocityIntegral(config.controller))
        builder.Connect(supervisor.GetOutputPort("command"), integral.GetInputPort("command"))
        builder.Connect(nav_state, integral.GetInputPort("state"))
        builder.Connect(integral.GetOutputPort("command"), controller.GetInputPort("command"))
    else:
        builder.Connect(supervisor.GetOutputPort("command"), controller.GetInputPort("command"))
    builder.Connect(nav_state, controller.GetInputPort("state"))
    builder.Connect(controller.GetOutputPort("rotor_speed_commands"), quad.GetInputPort("rotor_speed_commands"))
    builder.Connect(quad.GetOutputPort("state"), monitor.GetInputPort("quadrotor_state"))
    builder.Connect(carrier_state, monitor.GetInputPort("vehicle_state"))
    builder.Connect(true_relative_state, monitor.GetInputPort("true_relative_state"))
    builder.Connect(vision_valid, monitor.GetInputPort("target_valid"))
    builder.Connect(supervisor.GetOutputPort("mode"), monitor.GetInputPort("mode"))
    return FlightStack(seam, pid, supervisor, controller, monitor)
