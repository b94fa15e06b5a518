"""Running rqrlp-maneuvers (seed 001 Sec. 5.1): fly the manoeuvres, then write metrics.json
(`estimators`: each vision node, each local filter and the federated estimate against the truth,
diagrams/federated_metrics.py), log.npz and federated.png.

    landing-sim run rqrlp-maneuvers [--meshcat] [--video]
"""

from dataclasses import dataclass

import numpy as np

from diagrams.federated_metrics import federated_log, federated_metrics
from diagrams.federated_plots import plot_federated
from diagrams.outputs import write_npz
from diagrams.rqrlp_maneuvers import ManeuversConfig, ManeuversHandles, build_rqrlp_maneuvers
from diagrams.scenario import RunSettings
from diagrams.simulate import Simulation, simulate
from systems.config import require


@dataclass
class Scenario(RunSettings, ManeuversConfig):
    """An rqrlp-maneuvers scenario file. duration_s 0 (the default): the manoeuvres' length."""

    diagram: str = "rqrlp_maneuvers"
    duration_s: float = 0.0

    def validate(self) -> None:
        require(self.duration_s >= 0, "duration_s must not be negative (0: the manoeuvres' length)")
        ManeuversConfig.validate(self)

    @property
    def run_length_s(self) -> float:
        return self.duration_s if self.duration_s > 0 else self.manoeuvres_s


def collect_logs(handles: ManeuversHandles, context) -> dict[str, np.ndarray]:
    """The camera-rate logs as arrays (times `t`): the federated perception's and the truth's."""
    loggers = {**handles.perception.logs, **handles.truth_logs}
    logs = {name: logger.FindLog(context) for name, logger in loggers.items()}
    arrays = {name: log.data().T.copy() for name, log in logs.items()}
    arrays["t"] = logs["federated"].sample_times().copy()
    return arrays


def maneuvers_metrics(simulation: Simulation, log: dict, config: ManeuversConfig, name: str) -> dict:
    """metrics.json: the run and `estimators` over the whole flight."""
    return {"scenario": name, "seed": config.seed, "sim_time_s": simulation.sim_time_s,
            "wall_time_s": simulation.wall_time_s, "realtime_factor": simulation.realtime_factor,
            "end": simulation.status,
            "estimators": federated_metrics(federated_log(log, config.platform), config.federated.camera.X_BC)}


def simulate_maneuvers(diagram, handles, config: ManeuversConfig, duration_s: float, **options) -> Simulation:
    """Simulates a built diagram (diagrams/simulate.py's options) with the scenario's integration: the
    discretised quadrotor's own steps, or the Simulator's integrator as `integration` sets it."""
    return simulate(diagram, duration_s, initialize=handles.initialize,
                    simulator_config=config.integration.diagram_integrator(), **options)


def fly(config: ManeuversConfig, duration_s: float, **options) -> tuple[dict, dict]:
    """Builds and flies without files: (metrics, logs)."""
    diagram, handles = build_rqrlp_maneuvers(config)
    simulation = simulate_maneuvers(diagram, handles, config, duration_s, **options)
    log = collect_logs(handles, simulation.context)
    return maneuvers_metrics(simulation, log, config, "rqrlp-maneuvers"), log


def run(scenario: Scenario, ctx) -> dict:
    from diagrams.runner import finish_run

    video_path = ctx.out_dir / "camera.mp4" if ctx.options.video else None
    diagram, handles = build_rqrlp_maneuvers(scenario, ctx.meshcat, video_path)
    simulation = simulate_maneuvers(diagram, handles, scenario, scenario.run_length_s, realtime=ctx.options.meshcat,
                                    progress=ctx.options.progress, visualizer=handles.meshcat_visualizer,
                                    record=ctx.options.record, video=handles.video)
    log = collect_logs(handles, simulation.context)
    metrics = maneuvers_metrics(simulation, log, scenario, ctx.name)
    write_npz(ctx.out_dir / "log.npz", **log)
    plot_federated(federated_log(log, scenario.platform), scenario.federated.camera.X_BC, ctx.out_dir)
    fused = metrics["estimators"]["federated"]
    if "rmse_position_m" in fused:
        print(f"{ctx.name}: federated RMSE position {fused['rmse_position_m']:.4f} m (paper 0.0239), orientation "
              f"{fused['rmse_orientation_rad']:.4f} rad (paper 0.0818), valid {fused['valid_fraction']:.1%}")
    return finish_run(ctx, metrics)
