"""metrics.json's landing timings against the supervisor's own record: its mode is discrete state, so a
logger at its rate shows at t_i the mode it decided at t_(i-1) (diagrams/landing_metrics.entered)."""

import numpy as np
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource, LogVectorOutput, TrajectorySource
from pydrake.trajectories import PiecewisePolynomial

from diagrams.landing_metrics import pad_landing
from diagrams.simulate import COMPLETED
from systems.control.landing import LandingConfig, LandingSupervisor, Mode
from systems.perception.seam import HEIGHT, RELATIVE_STATE_SIZE
from systems.vehicles.quadrotor import STATE_SIZE


def test_mode_entry_times_are_when_the_supervisor_decided_them():
    config = LandingConfig()
    builder = DiagramBuilder()
    supervisor = builder.AddSystem(LandingSupervisor(config))
    climb_at = 0.1  # the altitude steps above the take-off height here: TAKEOFF -> CLIMB
    altitude = builder.AddSystem(TrajectorySource(PiecewisePolynomial.ZeroOrderHold(
        [0.0, climb_at, 10.0], np.array([[0.0, 2.0, 2.0]]))))
    builder.Connect(altitude.get_output_port(), supervisor.GetInputPort("altitude"))
    for name, size, value in (("height_above_target", 1, 5.0), ("target_valid", 1, 0.0), ("target_offset", 2, 0.0),
                              ("target_velocity", 2, 0.0), ("tracking_velocity", 2, 0.0),
                              ("tracking_acceleration", 2, 0.0)):
        source = builder.AddSystem(ConstantVectorSource(np.full(size, value)))
        builder.Connect(source.get_output_port(), supervisor.GetInputPort(name))
    logger = LogVectorOutput(supervisor.GetOutputPort("mode"), builder, 1.0 / config.rate_hz)
    diagram = builder.Build()
    simulator = Simulator(diagram)
    simulator.AdvanceTo(0.3)
    context = simulator.get_context()
    since = supervisor.GetMyContextFromRoot(context).get_discrete_state(0).get_value()[0]  # mode_since_s
    log = logger.FindLog(context)
    t, mode = log.sample_times(), log.data()[0]
    assert Mode(int(mode[-1])) == Mode.CLIMB and since == climb_at

    relative = np.zeros((len(t), RELATIVE_STATE_SIZE))
    relative[:, HEIGHT] = 5.0
    quadrotor = np.zeros((len(t), STATE_SIZE))
    quadrotor[:, 0] = 1.0
    landing, _ = pad_landing({"t": t, "mode": mode, "true_relative_state": relative, "quadrotor_state": quadrotor},
                             COMPLETED, np.zeros(len(t)), 1.0, 0.02, 0.1, 9.81)
    assert landing["mode_entry_times_s"] == {"takeoff": 0.0, "climb": climb_at}
