"""The configuration of deck-landing: seed 002's quadrotor and our flight controller over seed 000's
Stewart deck, with seed 000's camera, ToF sensors and estimators; one dataclass per YAML section.

Sections beyond the systems' own: `perception` (what steers: `source`, a perception source that runs
in deck-landing, and when its estimate is valid), `tracker` (the deck in W from the estimator's
frames), `window` (when the final descent may start), `start`, `integration`, `termination`.
"""

from dataclasses import dataclass, field, replace

import numpy as np
from pydrake.math import RigidTransform

from diagrams.gv_landing_config import FlightConfig
from diagrams.perception_sources import perception_source, require_offered
from systems.config import require, require_positive
from systems.control.landing_window import LandingWindowConfig
from systems.estimators.crhf import CrhfConfig
from systems.estimators.deck_tracker import DeckTrackerConfig
from systems.noise import sample_rng
from systems.perception.seam import SeamConfig
from systems.platforms.stewart import StewartGeometry, StewartPlatformConfig, require_within_stroke
from systems.sensors.camera import CameraConfig
from systems.sensors.tof import TofConfig
from systems.vehicles.ground_vehicle_geometry import PlatformConfig

ESTIMATORS = ("atda", "crhf")


@dataclass
class DeckPerceptionConfig(SeamConfig):
    """What steers (`source`: a name in diagrams.perception_sources.SOURCES that runs in deck-landing: the truth,
    crhf or atda through the deck tracker, or one registered) and (SeamConfig) when its estimate is valid enough
    to steer on; both estimators run on the camera stream whatever steers. The truth's view: the camera's cone."""

    source: str = "crhf"
    field_of_view_deg: float = 58.0  # about the seed 000 camera's (512 px, fx 458.5 px)
    max_range_m: float = 4.0  # the ToF sensors' long-distance range

    def validate(self, prefix: str = "perception") -> None:
        perception_source(self.source, f"{prefix}.source", "deck")
        require_offered(self.source, f"{prefix}.source", "deck-landing has no marker stream: choose a source that "
                        "steers on its tag estimators or the truth", None)  # the camera: its rendered stream
        SeamConfig.validate(self, prefix)
        require(0 < self.field_of_view_deg <= 180, f"{prefix}.field_of_view_deg must be in (0, 180]")
        require_positive(self.max_range_m, f"{prefix}.max_range_m")


@dataclass
class DeckLandingConfig(FlightConfig):
    seed: int = 0  # of every noise source (pixels, ranges), of a random-walk deck and of random_deck_time_s
    platform: StewartPlatformConfig = field(default_factory=StewartPlatformConfig)
    # > 0: the deck's motion starts at a time drawn from the seed, uniform in [0, random_deck_time_s), after
    # platform.time_offset_s, so that a campaign's runs meet the deck in different phases of its motion.
    random_deck_time_s: float = 0.0
    camera: CameraConfig = field(default_factory=CameraConfig)  # seed 000's, 20 Hz
    tof: TofConfig = field(default_factory=TofConfig)
    crhf: CrhfConfig = field(default_factory=CrhfConfig)
    tracker: DeckTrackerConfig = field(default_factory=DeckTrackerConfig)
    window: LandingWindowConfig = field(default_factory=LandingWindowConfig)
    perception: DeckPerceptionConfig = field(default_factory=DeckPerceptionConfig)
    # Camera frames from exposure to estimate (issue 13's latency, as in the Stewart scenes): ATDA and CRHF get
    # each frame's detection and ranges this late, the deck tracker the UAV's pose at that frame's exposure.
    estimate_latency_frames: int = 0

    def validate(self) -> None:
        FlightConfig.validate(self)
        for name in ("platform", "camera", "tof", "crhf", "tracker", "window", "perception"):
            getattr(self, name).validate(name)
        require(self.integration.discrete, "integration.discrete must be true in deck-landing")
        require(self.random_deck_time_s >= 0, "random_deck_time_s must not be negative")
        require(self.estimate_latency_frames >= 0, "estimate_latency_frames must not be negative")
        if self.window.prediction == "autoregressive":
            self.window.predictor.validate_frames(self.camera.period_s, "window.predictor")
        top = self.deck_top_m
        require(self.landing.initial_height_m > top + self.landing.landing_height_m,
                f"landing.initial_height_m ({self.landing.initial_height_m:g} m above the ground) must be above the "
                f"deck's top ({top:.2f} m) plus landing.landing_height_m")
        reach_x, reach_y, highest = self.deck_reach()
        over_deck = abs(self.start.xy_m[0]) <= reach_x and abs(self.start.xy_m[1]) <= reach_y
        require(not over_deck or self.start.height_m > highest + self.landing.touchdown_height_m,
                f"start.height_m ({self.start.height_m:g} m) at start.xy_m {list(self.start.xy_m)}, where the moving "
                f"deck reaches, must be above the highest its top goes ({highest:.2f} m) plus "
                f"landing.touchdown_height_m: the UAV would start under it")

    def check_motion(self, duration_s: float) -> None:
        """The deck's motion within the legs' stroke over the run (ConfigError naming where it is not)."""
        require_within_stroke(self.deck(), duration_s, self.seed)

    def deck(self) -> StewartPlatformConfig:
        """The platform as this run meets it: platform.time_offset_s plus the seed's draw of random_deck_time_s."""
        if self.random_deck_time_s <= 0:
            return self.platform
        drawn = float(sample_rng(self.seed, "deck_time", 0).uniform(0.0, self.random_deck_time_s))
        return replace(self.platform, time_offset_s=self.platform.time_offset_s + drawn)

    @property
    def pad_size_m(self) -> float:
        """The side of the square landed on: the deck's."""
        return self.platform.deck_size_m

    def deck_reach(self) -> tuple[float, float, float]:
        """Bounds on where the deck's top square goes under its motion (sums of the amplitudes, which also bound a
        random walk), from O [m]: along x and along y, half its side h turned by the largest yaw, h (cos + sin) up to
        45 deg, widened by the largest tilt's (roll plus pitch) sin^2 and the axis's sway; up, the nominal top plus
        the heave and its corner (h sqrt 2 out) lifted by the tilt."""
        p = self.platform
        bound = {axis: float(np.sum(np.abs(getattr(p, name)))) for axis, name in (
            ("x", "x_amplitude_m"), ("y", "y_amplitude_m"), ("z", "z_amplitude_m"), ("roll", "roll_amplitude_deg"),
            ("pitch", "pitch_amplitude_deg"), ("yaw", "yaw_amplitude_deg"))}
        yaw = np.radians(min(bound["yaw"], 45.0))
        tilt = np.radians(min(bound["roll"] + bound["pitch"], 90.0))
        half = p.deck_size_m / 2
        side = half * (np.cos(yaw) + np.sin(yaw)) * (1.0 + np.sin(tilt) ** 2)
        return (float(side + bound["x"]), float(side + bound["y"]),
                float(self.deck_top_m + bound["z"] + half * np.sqrt(2.0) * np.sin(tilt)))

    @property
    def deck_top_m(self) -> float:
        """The deck's top surface at its nominal pose, above the ground [m]."""
        return float(StewartGeometry.from_config(self.platform).X_SP0.translation()[2])

    @property
    def X_BC(self) -> RigidTransform:
        return self.camera.X_BC

    def carrier(self) -> PlatformConfig:
        """The deck as the landing monitor's carrier: a pad of the deck's size at its nominal top, and the
        deck itself (its footprint, down to its underside) as the body a UAV may crash into."""
        size, thickness = self.platform.deck_size_m, self.platform.deck_thickness_m
        return PlatformConfig(height_m=self.deck_top_m, pad_size_m=size, pad_thickness_m=thickness, pad_offset_m=0.0,
                              body_length_m=size, body_width_m=size, rear_overhang_m=size / 2)
