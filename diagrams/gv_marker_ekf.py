"""gv-marker-ekf: seed 002 section 4, the pose of the landing pad on a ground vehicle estimated from
five ArUco markers by the paper's EKF and by our constant-turn EKF, side by side, in the Diagram.

    landing-sim run gv-marker-ekf --set vehicle.speed=6 [--meshcat] [--record]
    landing-sim run gv-marker-ekf --set estimation.source=detector [--video]   # the rendered camera
    landing-sim montecarlo gv-marker-ekf --runs 100 --speeds 3 6 12            # diagrams/gv_marker_ekf_mc.py

The gv diagram (diagrams/gv_landing.py) open loop: the truth steers, the filters watch. The vehicle
drives Eq. (13)'s sine path at `vehicle.speed` (C1 = 3, C2 = 6, C3 = 12 m/s); the UAV starts
hovering at (0, 0, 10) m (seed 002's r_0) and its supervisor, with IH 2.0 m (0.4 m above the pad)
and `landing.centred_radius_m` 1e-6, tracks the pad while it descends to IH and then holds there
(APPROACH never comes). Every T_s = 35 ms the measurement source (`estimation.source`: the paper's
synthetic one, or the rendered camera's detections) gives the filters the identical list of
measurements, one period late. `duration_s: 0` (the default) means 500 m of driving along the path: Eq. (13)'s x reaches
about 441 m (its long wave's period, 500 m of x, is 560 m of path).

metrics.json has no landing section; `flight` says how the hold went, and `measurements` and
`estimators` score the stream and the filters (diagrams/marker_metrics.py).
"""

from dataclasses import dataclass, field

from diagrams.gv_landing_config import GvLandingConfig, MarkerEstimationConfig, StartConfig
from diagrams.gv_landing_run import run_flight
from diagrams.scenario import RunSettings
from systems.config import require, require_positive

LONG_WAVE_M = 500.0  # seed 002 Eq. (13): the long wave's period in x [m]; a run drives this far along the path


def _paper_estimation() -> MarkerEstimationConfig:
    return MarkerEstimationConfig(source="synthetic", filters=["paper_ekf", "ct_ekf"])


@dataclass
class Scenario(RunSettings, GvLandingConfig):
    """A gv-marker-ekf scenario file: the gv flight, held, with the filters watching.
    duration_s 0: 500 m of driving (LONG_WAVE_M / vehicle.speed)."""

    diagram: str = "gv_marker_ekf"
    start: StartConfig = field(default_factory=lambda: StartConfig(xy_m=[0.0, 0.0], height_m=10.0))  # seed 002 r_0
    duration_s: float = 0.0
    estimation: MarkerEstimationConfig = field(default_factory=_paper_estimation)

    def validate(self) -> None:
        require(self.duration_s >= 0, "duration_s must not be negative (0: 500 m of driving)")
        require_positive(self.vehicle.speed, "vehicle.speed")
        require(not self.vehicle.speed_schedule_times_s, "vehicle.speed_schedule_* is not used by gv-marker-ekf")
        GvLandingConfig.validate(self)
        require(self.estimation.source != "none" and self.estimation.filters,
                "gv-marker-ekf needs a measurement stream (estimation.source) and filters (estimation.filters)")
        require(self.platform.height_m < self.start.height_m and self.landing.initial_height_m < self.start.height_m,
                f"platform.height_m and landing.initial_height_m must be below start.height_m "
                f"({self.start.height_m} m)")
        require(self.estimation.settle_s < self.run_length_s,
                f"estimation.settle_s ({self.estimation.settle_s:g} s) must be below the run's length "
                f"({self.run_length_s:g} s: duration_s, or 500 m of driving at vehicle.speed when it is 0): "
                "nothing would be scored")
        self.faults.check_within(self.run_length_s)

    @property
    def run_length_s(self) -> float:
        return self.duration_s if self.duration_s > 0 else LONG_WAVE_M / self.vehicle.speed


def run(scenario: Scenario, ctx) -> dict:
    return run_flight(scenario, ctx, scenario.run_length_s, landing=False)
