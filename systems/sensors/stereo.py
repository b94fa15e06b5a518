"""Seed 003's downward stereo camera (section 2.1, the MYNT EYE S1030-IR): two rectified pinhole
RgbdSensor colour cameras on the airframe, the right eye one baseline along the left eye's +x.

Focal length in pixels: the table gives the lens (2.1 mm) and the resolution (752 x 480) but not the
sensor. The S1030 is built on a 1/3-inch global-shutter WVGA sensor of 6.0 um square pixels (Aptina
MT9V034 class: 752 x 480 x 6 um = 4.51 x 2.88 mm), so f = 2.1 mm / 6.0 um = 350 px. We take the pixel
pitch rather than the quoted field of view because the quoted angle (about 120 degrees across) is the
raw wide-angle lens's, with its distortion, not the rectified pinhole the depth is computed in; the
MYNT EYE SDK's default rectified intrinsics (fx 362, fy 364 px) agree with 350 px within 4 %.
That gives a 94 x 69 degree pinhole field of view.

Frames: the left eye L is the reference (the depth map is the left image's, as OpenCV's and the
MYNT SDK's are). `mount_xyz_m` places L in the body frame B; both eyes look down with C's axes as the
project's downward camera (+z_C = -z_B, +x_C = +x_B); the right eye R is at X_LR = [I, (baseline, 0, 0)],
so a ground point at depth Z has disparity d = x_L - x_R = f * baseline / Z > 0 (seed 003 Eq. 11).

Pixel noise: each eye through its own `NoisyCamera`, seeded by a stream of its own (the two sensors'
noise is independent).
"""

from dataclasses import dataclass, field

import numpy as np
from pydrake.geometry import SceneGraph
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.sensors import RgbdSensor

from systems.config import require, require_positive
from systems.noise import stream_id
from systems.sensors.camera import CameraConfig, NoisyCamera, make_camera, require_render_limits

MYNT_EYE_PIXEL_PITCH_M = 6.0e-6  # 1/3" WVGA global-shutter sensor (MT9V034 class), see the module docstring
MYNT_EYE_FOCAL_LENGTH_M = 2.1e-3  # seed 003 section 2.1 table


@dataclass
class StereoConfig:
    """The rectified stereo pair: intrinsics in pixels (OpenCV convention, both eyes alike), baseline in
    metres, rate in Hz, pixel noise in 8-bit levels."""

    width: int = 752  # seed 003 section 2.1 table
    height: int = 480  # seed 003 section 2.1 table
    focal_length_px: float = MYNT_EYE_FOCAL_LENGTH_M / MYNT_EYE_PIXEL_PITCH_M  # 350 px
    cx: float = 375.5  # the image centre (OpenCV: pixel centres at integers)
    cy: float = 239.5
    baseline_m: float = 0.12  # seed 003 section 2.1 table: 120.0 mm
    rate_hz: float = 60.0  # seed 003 section 2.1 table: 60 fps
    pixel_noise_std: float = 0.0  # std of additive Gaussian noise per channel, 8-bit levels
    near_m: float = 0.1
    far_m: float = 50.0
    # The left eye L in the body frame B: with the default the pair's centre is under the body origin,
    # 5 cm down, the baseline along the body's forward axis.
    mount_xyz_m: list[float] = field(default_factory=lambda: [-0.06, 0.0, -0.05])
    # seed 003 section 2.1: effective range 0.7-8 m. The nearest sets the disparity search
    # (StereoDepthConfig.num_disparities); a window altitude beyond the farthest is invalid.
    min_altitude_m: float = 0.7
    max_altitude_m: float = 8.0

    def validate(self, prefix: str = "stereo") -> None:
        require(isinstance(self.width, int) and isinstance(self.height, int) and self.width > 0 and self.height > 0,
                f"{prefix}.width and {prefix}.height must be positive integers, got {self.width} x {self.height}")
        for name in ("focal_length_px", "baseline_m", "rate_hz", "near_m"):
            require_positive(getattr(self, name), f"{prefix}.{name}")
        require_render_limits(self, prefix)
        require(self.pixel_noise_std >= 0, f"{prefix}.pixel_noise_std must not be negative, got "
                                           f"{self.pixel_noise_std}")
        require(len(self.mount_xyz_m) == 3, f"{prefix}.mount_xyz_m needs 3 numbers, got {len(self.mount_xyz_m)}")
        require(0 < self.min_altitude_m < self.max_altitude_m,
                f"{prefix}: need 0 < min_altitude_m < max_altitude_m, got {self.min_altitude_m} and "
                f"{self.max_altitude_m}")
        require(self.near_m < self.min_altitude_m and self.max_altitude_m < self.far_m,
                f"{prefix}: the altitude range [{self.min_altitude_m}, {self.max_altitude_m}] m must lie within "
                f"the clipping range [near_m, far_m] = [{self.near_m}, {self.far_m}] m")
        max_disparity = self.max_disparity_px
        require(max_disparity < self.width / 2,
                f"{prefix}: the disparity at min_altitude_m ({max_disparity:.0f} px = focal_length_px * baseline_m "
                f"/ min_altitude_m) must be under half the image width ({self.width / 2:g} px)")

    @property
    def period_s(self) -> float:
        return 1.0 / self.rate_hz

    @property
    def max_disparity_px(self) -> float:
        """The disparity (px) of the ground at `min_altitude_m`: f * baseline / Z (Eq. 11)."""
        return self.focal_length_px * self.baseline_m / self.min_altitude_m

    def eye(self) -> CameraConfig:
        """Either eye as the project's CameraConfig (same intrinsics, rate and noise; rectified pair)."""
        return CameraConfig(width=self.width, height=self.height, fx=self.focal_length_px, fy=self.focal_length_px,
                            cx=self.cx, cy=self.cy, rate_hz=self.rate_hz, pixel_noise_std=self.pixel_noise_std,
                            near_m=self.near_m, far_m=self.far_m, mount_xyz_m=list(self.mount_xyz_m))

    @property
    def X_BL(self) -> RigidTransform:
        """Pose of the left eye L in the body frame B (looking down: a half turn about x)."""
        return RigidTransform(RotationMatrix.MakeXRotation(np.pi), self.mount_xyz_m)

    @property
    def X_LR(self) -> RigidTransform:
        """Pose of the right eye R in L: the same orientation, one baseline along +x_L."""
        return RigidTransform([self.baseline_m, 0.0, 0.0])

    @property
    def X_BR(self) -> RigidTransform:
        return self.X_BL.multiply(self.X_LR)


@dataclass
class StereoPair:
    """What `add_stereo_pair` added: the two RgbdSensors and their NoisyCameras (whose `color_image`
    outputs are the left and right streams)."""

    left_sensor: RgbdSensor
    right_sensor: RgbdSensor
    left: NoisyCamera
    right: NoisyCamera

    @property
    def left_image(self):
        return self.left.get_output_port()

    @property
    def right_image(self):
        return self.right.get_output_port()


def eye_seed(seed: int, eye: str) -> int:
    """The NoisyCamera seed of one eye: independent streams per eye (and apart from other cameras')."""
    return stream_id(f"stereo_{eye}/{int(seed)}")


def add_stereo_pair(builder: DiagramBuilder, scene_graph: SceneGraph, body_frame_id, config: StereoConfig,
                    seed: int = 0) -> StereoPair:
    """The pair on the SceneGraph frame `body_frame_id` (left at config.X_BL, right at config.X_BR),
    each eye's images through a NoisyCamera with its own seeded noise. The scene graph needs
    `systems.sensors.camera.add_renderer`. Images render only when evaluated: read them at the
    camera rate."""
    config.validate()
    eye = config.eye()
    sensors, noisy = [], []
    for name, X_BC in (("left", config.X_BL), ("right", config.X_BR)):
        sensor = builder.AddSystem(make_camera(eye, body_frame_id, X_BC))
        sensor.set_name(f"stereo_{name}_sensor")
        builder.Connect(scene_graph.get_query_output_port(), sensor.query_object_input_port())
        camera = builder.AddSystem(NoisyCamera(eye, eye_seed(seed, name)))
        camera.set_name(f"stereo_{name}")
        builder.Connect(sensor.color_image_output_port(), camera.GetInputPort("rendered_image"))
        sensors.append(sensor)
        noisy.append(camera)
    return StereoPair(sensors[0], sensors[1], noisy[0], noisy[1])
