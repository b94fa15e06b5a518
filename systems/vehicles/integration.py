"""Discretised vehicle dynamics: what Quadrotor and GroundVehicle share when given a `time_period`.

A vehicle with `time_period` T integrates its continuous equations over each period T in C++
(Drake's DiscreteTimeApproximation), holding its input over the period. A diagram with no
continuous state never evaluates whole-diagram derivatives, each of which would call into every
Python LeafSystem in it (several evaluations per integrator step).
"""

from pydrake.systems.analysis import DiscreteTimeApproximation, SimulatorConfig

from systems.config import require_positive


def discrete_integration(time_period: float) -> SimulatorConfig:
    """The default integration of a discretised vehicle: Drake's RK5 (Dormand-Prince), one fixed
    step per period. Over a 5 ms period its error matches seed 002's RK4 at 1 ms (~1e-13 m;
    benchmarks/landing_sweep.py)."""
    return SimulatorConfig(integration_scheme="runge_kutta5", max_step_size=time_period,
                           use_error_control=False)


def discretise(system, time_period: float, integration: SimulatorConfig | None, name: str):
    """`system` (continuous) integrated per `time_period` with `integration` (default
    `discrete_integration`): a discrete system with the same ports."""
    require_positive(time_period, f"{name} time_period")
    return DiscreteTimeApproximation(system, time_period, integration or discrete_integration(time_period))


def set_vehicle_state(system, root_context, x) -> None:
    """Sets the state of a vehicle diagram (Quadrotor, GroundVehicle) inside a root context: the
    continuous state of its subsystem `dynamics`, or its discrete state when discretised."""
    context = system.dynamics.GetMyMutableContextFromRoot(root_context)
    if context.num_continuous_states():
        context.SetContinuousState(x)
    else:
        context.SetDiscreteState(x)
