"""Seed 003's hybrid camera array in a gv diagram (`perception.source: hybrid`): the fisheye and the
stereo pair on the UAV, the UGV detector, the tracker, the stereo altimeter and its filter, the hybrid
pad estimate (systems/perception/hybrid_pad.py) with its velocity observer, into the seam.

    fisheye --color_image--> UGV detector (learned | classical) --> box tracker --target_box-->
    stereo pair --> StereoAltimeter (Eq. 11-12) --> AltitudeFilterSystem (Eq. 13-14) --altitude-->
        HybridPadEstimator (ray -> World -> pad plane) --X_WP_estimate--> seam
                           (its velocity observer on the measurements, world, Eq. 15-19) --v_WP--> seam
    stereo left eye --> StereoPadFinder (the pad's markers, in the last metres) --pad_fix--> HybridPadEstimator

The source brings its own sensors (PerceptionInputs.scene_graph, .body_frame_id) and a textured ground
(diagrams/stereo_hover.py's, the detector's training ground) a millimetre above the gv scene's plain one:
stereo matching needs texture. Its logs at the fisheye's rate feed `hybrid_metrics`.
"""

from dataclasses import dataclass, field

from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput

from diagrams.stereo_hover import GroundConfig, add_stereo_altimeter, add_textured_ground
from systems.config import require
from systems.estimators.altitude_kf import AltitudeFilterSystem, AltitudeKfConfig
from systems.estimators.velocity_observer import VelocityObserverConfig
from systems.perception.box_tracker import BoxTrackerConfig
from systems.perception.box_tracker_system import BoxTrackerSystem
from systems.perception.hybrid_pad import (
    DetectionsToTracker,
    HybridPadConfig,
    HybridPadEstimator,
    LockedTrackVector,
)
from systems.perception.markers import MarkerLayout
from systems.perception.stereo_depth import StereoAltimeter, StereoDepthConfig
from systems.perception.stereo_pad import StereoPadConfig, StereoPadFinder
from systems.perception.ugv_box_refiner import BoxRefinementConfig, ColourRefinedDetector
from systems.perception.ugv_cnn_detector import CnnDetector
from systems.perception.ugv_detector import ColourPadConfig, ColourPadDetector, UgvDetectorSystem
from systems.sensors.camera import RENDERER_NAME, add_renderer
from systems.sensors.fisheye import FisheyeConfig, add_fisheye_camera
from systems.sensors.stereo import StereoConfig, add_stereo_pair
from systems.viewers import TrackOverlay, VideoRecorder

DETECTORS = ("learned", "classical")
GROUND_LIFT_M = 0.001  # the textured ground over the plain one (no z-fighting)


def hybrid_stereo() -> StereoConfig:
    """The MYNT EYE pair (systems/sensors/stereo.py) at the fisheye's 10 Hz: the paper's pipeline runs at
    about 9 Hz (Table 7), and two 752 x 480 renders at 60 Hz would triple the run's cost."""
    return StereoConfig(rate_hz=10.0, pixel_noise_std=2.0)


@dataclass
class HybridPerceptionConfig:
    """Seed 003's camera array and what runs on it (rates in Hz in each part's section)."""

    detector: str = "learned"  # "learned" (a small CNN, ONNX through cv2.dnn) or "classical" (colour + pad white)
    model_path: str = ""  # the learned detector's model; empty: models/ugv_detector.onnx
    classical: ColourPadConfig = field(default_factory=ColourPadConfig)
    # The learned detector's boxes re-centred on the pad by the classical one's colour segmentation around them
    # (systems/perception/ugv_box_refiner.py, method "colour", the default); "none": the network's boxes as they come.
    refinement: BoxRefinementConfig = field(default_factory=BoxRefinementConfig)
    fisheye: FisheyeConfig = field(default_factory=FisheyeConfig)  # 10 Hz
    stereo: StereoConfig = field(default_factory=hybrid_stereo)
    depth: StereoDepthConfig = field(default_factory=StereoDepthConfig)
    altitude_kf: AltitudeKfConfig = field(default_factory=AltitudeKfConfig)
    tracker: BoxTrackerConfig = field(default_factory=BoxTrackerConfig)
    # The linear fit on the stereo eye's fixes only (systems/estimators/velocity_observer.py; "mean" is Eq. 18-19's).
    velocity_observer: VelocityObserverConfig = field(default_factory=lambda: VelocityObserverConfig(fit="linear"))
    estimator: HybridPadConfig = field(default_factory=HybridPadConfig)
    stereo_pad: StereoPadConfig = field(default_factory=StereoPadConfig)  # the last metres (ours)
    ground: GroundConfig = field(default_factory=lambda: GroundConfig(size_m=100.0, texture_seed=0))

    def validate(self, prefix: str = "hybrid") -> None:
        require(self.detector in DETECTORS, f"{prefix}.detector '{self.detector}' is not one of: {', '.join(DETECTORS)}")
        self.classical.validate(f"{prefix}.classical")
        self.refinement.validate(f"{prefix}.refinement")
        self.fisheye.validate(f"{prefix}.fisheye")
        require(self.detector != "learned" or (self.fisheye.width, self.fisheye.height) == (512, 512),
                f"{prefix}.fisheye.width and height must be 512 for the learned detector (its network's input), "
                f"got {self.fisheye.width} x {self.fisheye.height}")
        self.stereo.validate(f"{prefix}.stereo")
        self.depth.validate(f"{prefix}.depth", self.stereo)
        self.altitude_kf.validate(f"{prefix}.altitude_kf")
        self.tracker.validate(f"{prefix}.tracker", self.fisheye.width, self.fisheye.height)
        self.velocity_observer.validate(f"{prefix}.velocity_observer")
        self.estimator.validate(f"{prefix}.estimator")
        self.stereo_pad.validate(f"{prefix}.stereo_pad")
        self.ground.validate(f"{prefix}.ground")
        require(self.velocity_observer.source == "world",
                f"{prefix}.velocity_observer.source must be world: the observer reads the hybrid p_WP")
        for name, rate in (("tracker", self.tracker.rate_hz), ("velocity_observer", self.velocity_observer.rate_hz)):
            require(abs(rate - self.fisheye.rate_hz) < 1e-9,
                    f"{prefix}.{name}.rate_hz ({rate:g}) must be {prefix}.fisheye.rate_hz ({self.fisheye.rate_hz:g}): "
                    f"one step per frame")

    def make_detector(self):
        """The `detector` named: the learned one with its boxes re-centred by the colour where
        `refinement.method` is colour; the classical one's boxes are its own."""
        if self.detector == "classical":
            return ColourPadDetector(self.classical)
        learned = CnnDetector(self.model_path) if self.model_path else CnnDetector()
        if self.refinement.method == "none":
            return learned
        return ColourRefinedDetector(learned, ColourPadDetector(self.classical), self.refinement)


@dataclass
class HybridPorts:
    detector: UgvDetectorSystem
    tracker: BoxTrackerSystem
    altimeter: StereoAltimeter
    altitude_filter: AltitudeFilterSystem
    estimator: HybridPadEstimator
    v_WP: object  # the estimator's observer's velocity, else the coasting estimate's, else zero
    logs: dict
    video: VideoRecorder | None = None  # the fisheye stream with the boxes drawn (video_path given)


def add_hybrid_perception(builder: DiagramBuilder, config: HybridPerceptionConfig, scene_graph, body_frame_id,
                          z_pad: float, seed: int, X_WB, markers: MarkerLayout | None = None,
                          video_path=None, ground_xy: tuple | None = None) -> HybridPorts:
    """The array on `body_frame_id`, its perception, the estimate on X_WB (the UAV's navigation); with the
    pad's `markers` (and hybrid.stereo_pad.enabled) the left eye's pad fix for the last metres; with
    `video_path` a video of the fisheye stream with the detections and the target's box drawn. The textured
    ground covers `ground_xy` ((lower, upper) World x, y [m]; None: hybrid.ground's one square)."""
    add_textured_ground(scene_graph, config.ground, GROUND_LIFT_M, ground_xy)
    if not scene_graph.HasRenderer(RENDERER_NAME):
        add_renderer(scene_graph)
    rig = add_fisheye_camera(builder, scene_graph, body_frame_id, config.fisheye)
    pair = add_stereo_pair(builder, scene_graph, body_frame_id, config.stereo, seed)
    fe = config.fisheye
    detector = builder.AddNamedSystem("ugv_detector", UgvDetectorSystem(config.make_detector(), fe.width, fe.height))
    builder.Connect(rig.color_image, detector.get_input_port())
    to_tracker = builder.AddNamedSystem("ugv_detections", DetectionsToTracker())
    builder.Connect(detector.get_output_port(), to_tracker.get_input_port())
    tracker = builder.AddNamedSystem("box_tracker", BoxTrackerSystem(config.tracker, fe.width, fe.height))
    builder.Connect(to_tracker.GetOutputPort("detections"), tracker.GetInputPort("detections"))
    builder.Connect(rig.color_image, tracker.GetInputPort("color_image"))
    altimeter, altitude = add_stereo_altimeter(builder, pair, config.stereo, config.depth, config.altitude_kf)
    estimator = builder.AddNamedSystem("hybrid_pad", HybridPadEstimator(fe, config.stereo.X_BL, z_pad, config.estimator,
                                                                        config.velocity_observer))
    builder.Connect(tracker.GetOutputPort("target_box"), estimator.GetInputPort("target_box"))
    builder.Connect(tracker.GetOutputPort("target_valid"), estimator.GetInputPort("target_valid"))
    builder.Connect(altitude.GetOutputPort("altitude"), estimator.GetInputPort("altitude"))
    builder.Connect(altitude.GetOutputPort("valid"), estimator.GetInputPort("altitude_valid"))
    builder.Connect(X_WB, estimator.GetInputPort("X_WB"))
    if markers is not None and config.stereo_pad.enabled:
        finder = builder.AddNamedSystem("stereo_pad", StereoPadFinder(config.stereo, markers, z_pad, config.stereo_pad))
        builder.Connect(pair.left_image, finder.GetInputPort("left_image"))
        builder.Connect(X_WB, finder.GetInputPort("X_WB"))
        builder.Connect(finder.get_output_port(), estimator.GetInputPort("pad_fix"))
    lock = builder.AddNamedSystem("locked_track", LockedTrackVector())
    builder.Connect(tracker.GetOutputPort("tracks"), lock.GetInputPort("tracks"))
    builder.Connect(tracker.GetOutputPort("target_box"), lock.GetInputPort("target_box"))
    builder.Connect(lock.get_output_port(), estimator.GetInputPort("target_lock"))
    period = fe.period_s
    logs = {"hybrid": LogVectorOutput(estimator.GetOutputPort("hybrid_vector"), builder, period),
            "v_WP": LogVectorOutput(estimator.GetOutputPort("v_WP_observed"), builder, period),
            "v_valid": LogVectorOutput(estimator.GetOutputPort("v_valid"), builder, period),
            "target_box": LogVectorOutput(tracker.GetOutputPort("target_box"), builder, period),
            "target_valid": LogVectorOutput(tracker.GetOutputPort("target_valid"), builder, period),
            "lock": LogVectorOutput(lock.get_output_port(), builder, period),
            "detections": LogVectorOutput(to_tracker.GetOutputPort("detection_vector"), builder, period),
            "stereo_altitude": LogVectorOutput(altimeter.GetOutputPort("altitude"), builder, period),
            "stereo_valid": LogVectorOutput(altimeter.GetOutputPort("altitude_valid"), builder, period),
            "altitude": LogVectorOutput(altitude.GetOutputPort("altitude"), builder, period),
            "altitude_valid": LogVectorOutput(altitude.GetOutputPort("valid"), builder, period)}
    video = None
    if video_path is not None:
        overlay = builder.AddNamedSystem("track_overlay", TrackOverlay(fe.width, fe.height))
        builder.Connect(rig.color_image, overlay.GetInputPort("color_image"))
        builder.Connect(detector.get_output_port(), overlay.GetInputPort("detections"))
        builder.Connect(tracker.GetOutputPort("target_box"), overlay.GetInputPort("target_box"))
        builder.Connect(tracker.GetOutputPort("target_valid"), overlay.GetInputPort("target_valid"))
        builder.Connect(lock.get_output_port(), overlay.GetInputPort("lock"))
        video = builder.AddNamedSystem("video", VideoRecorder(video_path, period, fe.width, fe.height))
        builder.Connect(overlay.GetOutputPort("image"), video.get_input_port())
    return HybridPorts(detector, tracker, altimeter, altitude, estimator, estimator.GetOutputPort("v_WP"), logs,
                       video)

