"""The registry behind `perception.source`, in the gv scenarios and deck-landing alike: the name of what
steers the UAV -> the function that adds that perception source to a builder.

A source's function gets the builder and `PerceptionInputs` (what the scene offers it: the UAV's
own pose and kinematics, the truth, the marker measurement stream, the marker filters already in
the diagram, the camera's stream, and on the deck its tag estimators) and returns `SeamPorts`: the
seam (systems/perception/seam.py), where it has one the pose estimate that metrics score, and its
own logs. Nothing in the controller or the supervisor changes with the source. A source that brings
its own camera (`PerceptionSource.camera`) gets the scene to render it. `PerceptionSource.scenes`
names the diagrams that offer what it needs (gv_landing.py's, deck_landing.py's).

    register_source("mine", PerceptionSource(add_mine, needs_markers=True))   # your own estimator

`add_estimate_to_seam` is the adapter's wiring, for any estimator that outputs a PoseEstimate of the
pad in W (and, where it has them, the pad's velocity and acceleration).
"""

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from pydrake.geometry import SceneGraph
from pydrake.math import RigidTransform
from pydrake.systems.framework import DiagramBuilder, OutputPort
from pydrake.systems.primitives import LogVectorOutput

from diagrams.federated_metrics import federated_log, federated_metrics
from diagrams.federated_perception import add_federated_perception
from diagrams.federated_plots import plot_federated
from diagrams.hybrid_metrics import hybrid_metrics, plot_hybrid
from diagrams.hybrid_perception import add_hybrid_perception
from diagrams.stewart_scene import delayed
from systems.config import ConfigError
from systems.estimators.deck_tracker import DeckTracker
from systems.estimators.marker_ekf import FILTERS, MarkerFilterSystem
from systems.perception.seam import EstimateToSeam
from systems.viewers import VideoRecorder

SCENES = {"gv": "the gv scenarios", "deck": "deck-landing"}  # the diagrams that add perception sources


@dataclass
class PerceptionInputs:
    """What a scenario's diagram offers a perception source (deck-landing: no marker stream nor filters)."""

    config: object  # the scenario (diagrams.gv_landing_config.GvLandingConfig, deck_landing_config.DeckLandingConfig)
    X_WB: OutputPort  # the UAV's own pose (RigidTransform): its navigation's (`navigation.source`)
    V_WB: OutputPort  # its true spatial velocity (6: [w; v] in W) and acceleration (A_WB), for an IMU
    A_WB: OutputPort
    quadrotor_state: OutputPort  # the truth, for a source's own logs: the UAV's state (17) and the carrier's (4)
    vehicle_state: OutputPort
    true_relative_state: OutputPort  # the truth's seam
    marker_measurements: OutputPort | None  # list of MarkerMeasurement, after the latency; None: no stream
    color_image: OutputPort | None  # the downward camera's images (ImageRgba8U, with noise); None: no camera
    filters: dict[str, MarkerFilterSystem] = field(default_factory=dict)  # marker filters by name
    # For a source that brings its own sensors (`hybrid`): the scene (its renderers, geometry) and the
    # UAV's body frame in it, on which cameras mount. None where the scene offers none.
    scene_graph: SceneGraph | None = None
    body_frame_id: object = None
    video_path: Path | None = None  # --video: where a source that records its own stream writes it
    ground_xy: tuple | None = None  # the plain ground's (lower, upper) World x, y [m]; None: the origin's alone
    # deck-landing: its tag estimators' X_CT_estimate outputs by name ("atda", "crhf": PoseEstimate of the tag T
    # in the camera C, estimate_latency_frames late) and the deck frame P in the tag's frame T.
    tag_estimates: dict[str, OutputPort] = field(default_factory=dict)
    X_TP: RigidTransform | None = None
    true_deck_motion: OutputPort | None = None  # deck-landing: the deck's true motion (the truth source's)


@dataclass
class SeamPorts:
    """What a perception source gives the controller (`relative_state`) and the metrics
    (`X_WP_estimate`, a PoseEstimate of the pad in W; None for the truth)."""

    relative_state: OutputPort
    X_WP_estimate: OutputPort | None = None
    filter_name: str | None = None  # the marker filter behind it, if any
    logs: dict = field(default_factory=dict)  # the source's own loggers (name -> VectorLogSink), for its metrics
    video: VideoRecorder | None = None  # its own stream's recorder (--video), where it records one
    # deck-landing: the deck's motion as the source estimates it (systems/estimators/deck_tracker.py's layout), for
    # the landing window; a deck source must give it (the truth source gives the truth's).
    deck_motion: OutputPort | None = None


@dataclass(frozen=True)
class PerceptionSource:
    """How to add a source, and what it needs from the scenario (checked when it is loaded)."""

    add: Callable[[DiagramBuilder, PerceptionInputs], SeamPorts]
    needs_markers: bool = False  # a marker measurement stream (estimation.source synthetic or detector)
    needs_camera: bool = False  # the rendered camera: estimation.source detector's, or its own
    camera: Callable | None = None  # config -> its own CameraConfig, which the scene adds (None: none of its own)
    records_video: bool = False  # --video records its own stream (PerceptionInputs.video_path)
    # Its own figures: (arrays of its `logs` by name with their times "t", config, touchdown time or None)
    # -> metrics.json's `estimators` entries; and its plots: (the same arrays, config, out_dir).
    metrics: Callable | None = None
    plot: Callable | None = None
    estimates_heading: bool = True  # its estimate carries the pad's heading (false: a position alone)
    # The diagrams that offer what it needs (SCENES); deck-landing collects no `logs`, `metrics`, `plot` or video.
    scenes: tuple[str, ...] = ("gv",)


def add_estimate_to_seam(builder: DiagramBuilder, inputs: PerceptionInputs, X_WP_estimate: OutputPort,
                         v_WP_estimate: OutputPort | None = None, a_WP_estimate: OutputPort | None = None) -> SeamPorts:
    """Wires `EstimateToSeam` (validity from scenario.perception) to an estimator's outputs."""
    adapter = builder.AddNamedSystem("estimate_to_seam", EstimateToSeam(inputs.config.perception))
    builder.Connect(inputs.X_WB, adapter.GetInputPort("X_WB"))
    builder.Connect(X_WP_estimate, adapter.GetInputPort("X_WP_estimate"))
    for port, name in ((v_WP_estimate, "v_WP_estimate"), (a_WP_estimate, "a_WP_estimate")):
        if port is not None:
            builder.Connect(port, adapter.GetInputPort(name))
    return SeamPorts(adapter.GetOutputPort("relative_state"), X_WP_estimate)


def _truth(builder: DiagramBuilder, inputs: PerceptionInputs) -> SeamPorts:
    return SeamPorts(inputs.true_relative_state, deck_motion=inputs.true_deck_motion)


def _marker_filter(name: str) -> Callable[[DiagramBuilder, PerceptionInputs], SeamPorts]:
    def add(builder: DiagramBuilder, inputs: PerceptionInputs) -> SeamPorts:
        marker_filter = inputs.filters[name]  # the builder adds every filter the scenario names
        ports = add_estimate_to_seam(builder, inputs, marker_filter.GetOutputPort("X_WP_estimate"),
                                     marker_filter.GetOutputPort("v_WP_estimate"),
                                     marker_filter.GetOutputPort("a_WP_estimate"))
        ports.filter_name = name
        return ports
    return add


def _deck_estimator(name: str) -> Callable[[DiagramBuilder, PerceptionInputs], SeamPorts]:
    """deck-landing: the tag estimator `name` (ATDA or CRHF, on the camera stream) through the deck tracker
    (systems/estimators/deck_tracker.py: X_WP through the UAV's pose at the frame's exposure, predicted to now)."""
    def add(builder: DiagramBuilder, inputs: PerceptionInputs) -> SeamPorts:
        config = inputs.config
        period, frames = config.camera.period_s, config.estimate_latency_frames
        tracker = builder.AddNamedSystem("deck_tracker", DeckTracker(config.tracker, config.X_BC, inputs.X_TP, period,
                                                                     frames * period))
        builder.Connect(inputs.tag_estimates[name], tracker.GetInputPort("X_CT_estimate"))
        X_WB_exposure = delayed(builder, inputs.X_WB, period, frames, RigidTransform()) if frames else inputs.X_WB
        builder.Connect(X_WB_exposure, tracker.GetInputPort("X_WB"))
        ports = add_estimate_to_seam(builder, inputs, tracker.GetOutputPort("X_WP_estimate"),
                                     tracker.GetOutputPort("v_WP_estimate"))
        ports.deck_motion = tracker.GetOutputPort("deck_motion")
        return ports
    return add


def _federated(builder: DiagramBuilder, inputs: PerceptionInputs) -> SeamPorts:
    """Seed 001: the RQRLP's three vision nodes and the federated EKF (diagrams/federated_perception.py)."""
    config = inputs.config
    federated = add_federated_perception(builder, config.federated, config.platform.rqrlp, config.seed,
                                         inputs.color_image, inputs.X_WB, inputs.V_WB, inputs.A_WB)
    ports = add_estimate_to_seam(builder, inputs, federated.filter.GetOutputPort("X_WP_estimate"),
                                 federated.filter.GetOutputPort("v_WP_estimate"))
    period = config.federated.camera.period_s
    ports.logs = {**federated.logs, "quadrotor_state": LogVectorOutput(inputs.quadrotor_state, builder, period),
                  "vehicle_state": LogVectorOutput(inputs.vehicle_state, builder, period)}
    return ports


def _federated_metrics(log: dict, config, end_s: float | None) -> dict:
    return federated_metrics(federated_log(log, config.platform), config.federated.camera.X_BC, end_s)


def _federated_plot(log: dict, config, out_dir) -> None:
    plot_federated(federated_log(log, config.platform), config.federated.camera.X_BC, out_dir)


def _hybrid(builder: DiagramBuilder, inputs: PerceptionInputs) -> SeamPorts:
    """Seed 003: the fisheye + stereo array, the UGV detector and tracker, the stereo altitude, the hybrid pad
    estimate and the velocity observer (diagrams/hybrid_perception.py), on the scene's own geometry."""
    config = inputs.config
    hybrid = add_hybrid_perception(builder, config.hybrid, inputs.scene_graph, inputs.body_frame_id,
                                   float(config.platform.p_VP[2]), config.seed, inputs.X_WB,
                                   config.platform.markers if config.platform.pattern == "markers" else None,
                                   inputs.video_path, inputs.ground_xy)
    ports = add_estimate_to_seam(builder, inputs, hybrid.estimator.GetOutputPort("X_WP_estimate"), hybrid.v_WP)
    ports.video = hybrid.video
    period = config.hybrid.fisheye.period_s
    ports.logs = {**hybrid.logs, "quadrotor_state": LogVectorOutput(inputs.quadrotor_state, builder, period),
                  "vehicle_state": LogVectorOutput(inputs.vehicle_state, builder, period),
                  "true_relative_state": LogVectorOutput(inputs.true_relative_state, builder, period)}
    return ports


SOURCES: dict[str, PerceptionSource] = {
    "truth": PerceptionSource(_truth, scenes=("gv", "deck")),
    **{name: PerceptionSource(_marker_filter(name), needs_markers=True) for name in FILTERS},
    "federated": PerceptionSource(_federated, needs_camera=True, camera=lambda config: config.federated.camera,
                                  metrics=_federated_metrics, plot=_federated_plot),
    "hybrid": PerceptionSource(_hybrid, metrics=hybrid_metrics, plot=plot_hybrid, records_video=True,
                               estimates_heading=False),
    **{name: PerceptionSource(_deck_estimator(name), scenes=("deck",)) for name in ("crhf", "atda")},
}


def register_source(name: str, source: PerceptionSource) -> None:
    """Adds a perception source (e.g. your own estimator) under `name`, for `perception.source`."""
    SOURCES[name] = source


def perception_source(name: str, prefix: str = "perception.source", scene: str = "gv") -> PerceptionSource:
    """The registered source that `scene` (a key of SCENES) can add; ConfigError naming the ones it can otherwise."""
    known = ", ".join(n for n, source in SOURCES.items() if scene in source.scenes)
    if name not in SOURCES:
        raise ConfigError(f"{prefix} '{name}' is not a perception source (known: {known})")
    if scene not in SOURCES[name].scenes:
        raise ConfigError(f"{prefix} '{name}' does not run in {SCENES[scene]} (its sources: {known})")
    return SOURCES[name]


def require_offered(name: str, prefix: str, markers_missing: str | None, camera_missing: str | None) -> None:
    """ConfigError when the source `name` needs what its scene lacks: `markers_missing` (`camera_missing`) None where
    the scene offers the marker stream (the camera's), else why it does not and what to set, a clause."""
    source = SOURCES[name]
    if source.needs_markers and markers_missing is not None:
        raise ConfigError(f"{prefix} '{name}' needs marker measurements, and {markers_missing}")
    if source.needs_camera and camera_missing is not None:
        raise ConfigError(f"{prefix} '{name}' needs the camera, and {camera_missing}")
