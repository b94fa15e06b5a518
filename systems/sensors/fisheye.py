"""Seed 003's fisheye camera (section 2.1, Table 1: 512 x 512 px, 150 deg field of view; K(f, cx, cy)
and D(k1, k2) in OpenCV's fisheye model), composed from pinhole renders.

Model (OpenCV's `cv2.fisheye`, k3 = k4 = 0): a point p_C in the camera frame C (+z the optical axis,
+x right, +y down in the image) at theta = atan2(|p_xy|, p_z) from the axis lands at radius
r = f * theta_d, theta_d = theta (1 + k1 theta^2 + k2 theta^4), from the principal point (cx, cy);
pixel centres at integers, as everywhere in the project.

Intrinsics (ours; the paper calibrates K and D but prints no numbers):
- f = 200 px: the 150 deg circle then has radius f * theta_d(75 deg) = 253.6 px, inside the image's
  256 px half-width. Table 1's 3.5 mm lens would not fit 150 deg into 512 px on any pixel pitch that
  the sensor's binning gives, so f follows from the field of view, not from the lens.
- (cx, cy) = (255.5, 255.5), the image centre.
- k1 = -0.02, k2 = 0.001: small, plausible values between the ideal equidistant lens (0, 0) and the
  equisolid-angle lens most fisheyes approximate (-1/24, 1/1920: the Taylor coefficients of
  2 sin(theta / 2) / theta).

Rendering: Drake renders pinhole images only. Five RgbdSensor colour cameras ("faces") sit at the
fisheye's centre: `down` along the optical axis and four side faces tilted `side_axis_deg` from it
towards the image's right (+x_C), bottom (+y_C), left and top. Every fisheye pixel's ray goes to the
face whose axis is nearest; each face image is cropped to the rays it serves (plus a 2 px margin for
bilinear interpolation), all with one focal length, face_px / 2 (a cube face of face_px pixels spans
90 deg). `FisheyeCamera` stacks the faces into one atlas and remaps it into the fisheye image through
one lookup table computed once. The faces render with their own renderer, lit from fixed directions
in the world: the default VTK light is a headlight per camera, which would shade the same surface
differently on either side of a seam.
"""

from dataclasses import dataclass, field
from functools import cached_property

import cv2
import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import (
    ClippingRange,
    ColorRenderCamera,
    DepthRenderCamera,
    LightParameter,
    MakeRenderEngineVtk,
    RenderCameraCore,
    RenderEngineVtkParams,
    Rgba,
    SceneGraph,
)
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from pydrake.systems.framework import DiagramBuilder, LeafSystem
from pydrake.systems.sensors import ImageRgba8U, RgbdSensor

from systems.config import require, require_positive
from systems.sensors.camera import camera_info, depth_range, require_render_limits

FISHEYE_RENDERER_NAME = "vtk_fisheye"
FACE_NAMES = ("down", "right", "bottom", "left", "top")  # side faces: +x_C, +y_C, -x_C, -y_C
FACE_MARGIN_PX = 2  # rendered beyond the outermost sample, so bilinear interpolation stays inside
BLACK = (0, 0, 0, 255)  # outside the field of view


@dataclass
class FisheyeConfig:
    """The fisheye camera: image size and intrinsics in pixels (OpenCV convention), field of view in
    degrees, rate in Hz, face resolution in pixels, mount pose in the body frame B (m, deg)."""

    width: int = 512  # seed 003 Table 1
    height: int = 512  # seed 003 Table 1
    fov_deg: float = 150.0  # seed 003 Table 1 and section 2.1
    f: float = 200.0  # px; ours, from the field of view (module docstring)
    cx: float = 255.5  # the image centre
    cy: float = 255.5
    k1: float = -0.02  # ours, small and plausible (module docstring)
    k2: float = 0.001
    # Seed 003 runs its whole pipeline at about 9 Hz (Table 7: 110 ms a frame); its camera could give 90.
    rate_hz: float = 10.0
    face_px: int = 512  # pixels across a 90 deg cube face: face cameras' focal length face_px / 2
    side_axis_deg: float = 60.0  # side faces' axes from the optical axis: fewest rendered pixels (60-64 deg)
    near_m: float = 0.05
    far_m: float = 50.0
    # C in B: looking down (+z_C = -z_B), image +x along the body's forward axis, beside the stereo pair.
    mount_xyz_m: list[float] = field(default_factory=lambda: [0.0, 0.05, -0.05])
    mount_rpy_deg: list[float] = field(default_factory=lambda: [180.0, 0.0, 0.0])
    # The rectified pinhole view for detectors (seed 003 Table 7, "fisheye correction"): same size,
    # this horizontal field of view (100 deg keeps the centre's scale: focal 215 px against f = 200).
    rectified_fov_deg: float = 100.0

    def validate(self, prefix: str = "fisheye") -> None:
        require(isinstance(self.width, int) and isinstance(self.height, int) and self.width > 0 and self.height > 0,
                f"{prefix}.width and {prefix}.height must be positive integers, got {self.width} x {self.height}")
        require(0 < self.fov_deg < 180, f"{prefix}.fov_deg must lie in (0, 180) deg, got {self.fov_deg}")
        for name in ("f", "rate_hz", "near_m"):
            require_positive(getattr(self, name), f"{prefix}.{name}")
        require_render_limits(self, prefix)
        require(isinstance(self.face_px, int) and self.face_px >= 16,
                f"{prefix}.face_px must be an integer of at least 16, got {self.face_px}")
        require(30 <= self.side_axis_deg <= 90, f"{prefix}.side_axis_deg must lie in [30, 90] deg, "
                                                f"got {self.side_axis_deg}")
        require(len(self.mount_xyz_m) == 3, f"{prefix}.mount_xyz_m needs 3 numbers, got {len(self.mount_xyz_m)}")
        require(len(self.mount_rpy_deg) == 3, f"{prefix}.mount_rpy_deg needs 3 numbers, got {len(self.mount_rpy_deg)}")
        require(0 < self.rectified_fov_deg < 180,
                f"{prefix}.rectified_fov_deg must lie in (0, 180) deg, got {self.rectified_fov_deg}")
        fold = distortion_fold_deg(self)
        if fold is not None:
            require(False, f"{prefix}.k1 and {prefix}.k2 fold the image: theta_d stops growing at {fold:.1f} deg "
                           f"off-axis, inside the {self.fov_deg:g} deg field of view")

    @property
    def period_s(self) -> float:
        return 1.0 / self.rate_hz

    @property
    def K(self) -> np.ndarray:
        """The 3x3 intrinsic matrix (OpenCV convention)."""
        return np.array([[self.f, 0.0, self.cx], [0.0, self.f, self.cy], [0.0, 0.0, 1.0]])

    @property
    def D(self) -> np.ndarray:
        """cv2.fisheye's distortion vector [k1, k2, k3, k4]."""
        return np.array([self.k1, self.k2, 0.0, 0.0])

    @property
    def theta_max(self) -> float:
        """Half the field of view [rad]."""
        return np.radians(self.fov_deg) / 2

    @property
    def radius_px(self) -> float:
        """Radius of the field of view's circle in the image [px]."""
        return self.f * theta_distorted(self.theta_max, self.k1, self.k2)

    @property
    def X_BC(self) -> RigidTransform:
        """Pose of the camera frame C in the body frame B."""
        return RigidTransform(RollPitchYaw(np.radians(self.mount_rpy_deg)), self.mount_xyz_m)


def theta_distorted(theta, k1: float, k2: float):
    """OpenCV's fisheye theta_d(theta) [rad] with k3 = k4 = 0."""
    theta2 = np.square(theta)
    return theta * (1 + k1 * theta2 + k2 * theta2**2)


def distortion_fold_deg(config: FisheyeConfig) -> float | None:
    """None when theta_d grows monotonically out to half the field of view, else the angle [deg]
    from the axis where it stops growing (the image folds there)."""
    theta = np.linspace(0.0, config.theta_max, 2000)
    slope = 1 + 3 * config.k1 * theta**2 + 5 * config.k2 * theta**4
    bad = np.flatnonzero(slope <= 0)
    return float(np.degrees(theta[bad[0]])) if bad.size else None


def project_points(p_C: np.ndarray, config: FisheyeConfig) -> np.ndarray:
    """Pixels (N, 2) of points p_C (N, 3) [m] in the camera frame C (cv2.fisheye.projectPoints)."""
    points = np.asarray(p_C, dtype=float).reshape(-1, 1, 3)
    pixels, _ = cv2.fisheye.projectPoints(points, np.zeros(3), np.zeros(3), config.K, config.D)
    return pixels.reshape(-1, 2)


_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12)


def pixel_rays(uv: np.ndarray, config: FisheyeConfig) -> np.ndarray:
    """Unit rays (N, 3) in C of pixels uv (N, 2) (cv2.fisheye.undistortPoints). Pixels beyond the
    field of view's circle give rays of no meaning (use `in_field_of_view`)."""
    pixels = np.asarray(uv, dtype=float).reshape(-1, 1, 2)
    xy = cv2.fisheye.undistortPoints(pixels, config.K, config.D, criteria=_UNDISTORT_CRITERIA).reshape(-1, 2)
    rays = np.column_stack([xy, np.ones(len(xy))])
    return rays / np.linalg.norm(rays, axis=1, keepdims=True)


def in_field_of_view(uv: np.ndarray, config: FisheyeConfig) -> np.ndarray:
    """Whether pixels uv (N, 2) lie within the field of view's circle."""
    uv = np.asarray(uv, dtype=float).reshape(-1, 2)
    return np.hypot(uv[:, 0] - config.cx, uv[:, 1] - config.cy) <= config.radius_px


@dataclass(frozen=True)
class Face:
    """One pinhole face camera: its frame F in C (+z_F its axis), image size and OpenCV intrinsics [px]."""

    name: str
    R_CF: RotationMatrix
    width: int
    height: int
    focal_px: float
    cx: float
    cy: float

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.focal_px, 0.0, self.cx], [0.0, self.focal_px, self.cy], [0.0, 0.0, 1.0]])


def face_rotations(config: FisheyeConfig) -> list[RotationMatrix]:
    """R_CF of the faces in FACE_NAMES' order: identity, then side axes at `side_axis_deg` from +z_C
    in the azimuths of +x_C, +y_C, -x_C, -y_C."""
    tilt = RotationMatrix.MakeYRotation(np.radians(config.side_axis_deg))
    return [RotationMatrix()] + [RotationMatrix.MakeZRotation(k * np.pi / 2).multiply(tilt) for k in range(4)]


@dataclass(frozen=True)
class FisheyeLayout:
    """The faces and the lookup tables from fisheye pixels to them, computed once per config.

    `face_of_pixel` (H, W): index into `faces` of the face each pixel samples, -1 outside the field
    of view. `face_uv` (H, W, 2): where in that face image (OpenCV pixel coordinates)."""

    faces: tuple[Face, ...]
    face_of_pixel: np.ndarray
    face_uv: np.ndarray

    @cached_property
    def atlas_rows(self) -> np.ndarray:
        """First row of each face in the atlas (the faces stacked top to bottom, left-aligned)."""
        return np.cumsum([0] + [face.height for face in self.faces])

    @cached_property
    def atlas_maps(self) -> tuple[np.ndarray, np.ndarray]:
        """cv2.remap's fixed-point maps (1/32 px) from the fisheye image into the atlas; pixels beyond the
        field of view point far outside it (black)."""
        uv = np.full(self.face_uv.shape, -1000.0, dtype=np.float32)
        inside = self.face_of_pixel >= 0
        uv[inside] = self.face_uv[inside] + np.column_stack(
            [np.zeros(inside.sum()), self.atlas_rows[self.face_of_pixel[inside]]])
        return cv2.convertMaps(uv[..., 0], uv[..., 1], cv2.CV_16SC2)

    def compose(self, face_images, out: np.ndarray | None = None) -> np.ndarray:
        """The fisheye image (H, W, 4) from the face images (numpy RGBA, in `faces`' order): the faces
        copied into an atlas, then one cv2.remap (faster than a remap per face: benchmarks/fisheye.py).
        The atlas's unused corners are never read (the margins keep bilinear reads in each face)."""
        rows = self.atlas_rows
        atlas = np.empty((rows[-1], max(face.width for face in self.faces), 4), dtype=np.uint8)
        for image, top in zip(face_images, rows):
            atlas[top:top + image.shape[0], :image.shape[1]] = image
        if out is None:
            out = np.empty(self.face_of_pixel.shape + (4,), dtype=np.uint8)
        return cv2.remap(atlas, *self.atlas_maps, cv2.INTER_LINEAR, dst=out, borderMode=cv2.BORDER_CONSTANT,
                         borderValue=BLACK)


def fisheye_layout(config: FisheyeConfig) -> FisheyeLayout:
    """The faces (each cropped to the rays it serves) and the per-pixel lookup tables."""
    height, width = config.height, config.width
    u, v = np.meshgrid(np.arange(width, dtype=float), np.arange(height, dtype=float))
    uv = np.column_stack([u.ravel(), v.ravel()])
    inside = in_field_of_view(uv, config)
    rays = pixel_rays(uv[inside], config)
    rotations = face_rotations(config)
    axes = np.array([R.col(2) for R in rotations])
    nearest = np.argmax(rays @ axes.T, axis=1)
    focal = config.face_px / 2
    face_of_pixel = np.full(height * width, -1, dtype=int)
    face_uv = np.full((height * width, 2), -1000.0)
    faces = []
    for index, (name, R_CF) in enumerate(zip(FACE_NAMES, rotations)):
        mine = nearest == index
        r_F = rays[mine] @ R_CF.matrix()  # rows: (R_CF^T r_C)^T
        xy = focal * r_F[:, :2] / r_F[:, 2:]
        # Integer crop bounds with the principal point (xy = 0) strictly inside, as Drake requires; a face that
        # serves no pixel (a narrow field of view, or its side of the circle beyond the image) is 3 x 3, never read.
        if len(xy):
            low = np.minimum(np.floor(xy.min(axis=0)) - FACE_MARGIN_PX, -1)
            high = np.maximum(np.ceil(xy.max(axis=0)) + FACE_MARGIN_PX, 1)
        else:
            low, high = np.array([-1.0, -1.0]), np.array([1.0, 1.0])
        size = (high - low + 1).astype(int)
        faces.append(Face(name, R_CF, int(size[0]), int(size[1]), focal, float(-low[0]), float(-low[1])))
        targets = np.flatnonzero(inside)[mine]
        face_of_pixel[targets] = index
        face_uv[targets] = xy - low
    return FisheyeLayout(tuple(faces), face_of_pixel.reshape(height, width), face_uv.reshape(height, width, 2))


def rectified_K(config: FisheyeConfig) -> np.ndarray:
    """The pinhole K of the rectified view: focal length for `rectified_fov_deg` across the width,
    principal point at the image centre."""
    focal = (config.width / 2) / np.tan(np.radians(config.rectified_fov_deg) / 2)
    return np.array([[focal, 0.0, (config.width - 1) / 2], [0.0, focal, (config.height - 1) / 2], [0.0, 0.0, 1.0]])


def rectify_maps(config: FisheyeConfig) -> tuple[np.ndarray, np.ndarray]:
    """cv2.remap's maps from the fisheye image to the rectified pinhole view with `rectified_K`
    (cv2.fisheye.initUndistortRectifyMap; seed 003 section 2.1 and Table 7's fisheye correction)."""
    return cv2.fisheye.initUndistortRectifyMap(config.K, config.D, np.eye(3), rectified_K(config),
                                               (config.width, config.height), cv2.CV_16SC2)


def rectify(image: np.ndarray, maps: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """The rectified pinhole view of a fisheye image (black beyond the field of view)."""
    return cv2.remap(image, *maps, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=BLACK)


class FisheyeCamera(LeafSystem):
    """The fisheye image composed from the face renders (seed 003 section 2.1).

    Inputs `face_<name>` (ImageRgba8U, the face cameras' colour images, FACE_NAMES). Outputs
    `color_image` (ImageRgba8U, width x height, black beyond the field of view) and
    `rectified_image` (the rectified pinhole view, `rectified_K`). Both are computed, and the faces
    rendered, only when a consumer evaluates them: evaluate at the camera rate.
    """

    def __init__(self, config: FisheyeConfig, layout: FisheyeLayout | None = None):
        super().__init__()
        self.layout = layout or fisheye_layout(config)
        self._rectify_maps = rectify_maps(config)
        for face in self.layout.faces:
            self.DeclareAbstractInputPort(f"face_{face.name}", AbstractValue.Make(ImageRgba8U(face.width, face.height)))
        blank = ImageRgba8U(config.width, config.height)
        self._color = self.DeclareAbstractOutputPort("color_image", lambda: AbstractValue.Make(blank),
                                                     self._calc_image)
        self.DeclareAbstractOutputPort("rectified_image", lambda: AbstractValue.Make(blank), self._calc_rectified)

    def _calc_image(self, context, output):
        faces = [self.get_input_port(i).Eval(context).data for i in range(len(self.layout.faces))]
        self.layout.compose(faces, out=output.get_mutable_value().mutable_data)

    def _calc_rectified(self, context, output):
        image = self._color.Eval(context).data
        output.get_mutable_value().mutable_data[:] = rectify(image, self._rectify_maps)


def add_fisheye_renderer(scene_graph: SceneGraph) -> None:
    """The faces' VTK renderer, lit from fixed directions in the world (a seamless composite), unless
    the scene graph has it already. Clear colour as `systems.sensors.camera.add_renderer`'s."""
    if scene_graph.HasRenderer(FISHEYE_RENDERER_NAME):
        return
    white = Rgba(1.0, 1.0, 1.0, 1.0)
    lights = [LightParameter(type="directional", color=white, frame="world", intensity=0.75, direction=[0, 0, -1]),
              LightParameter(type="directional", color=white, frame="world", intensity=0.35,
                             direction=[0.6, 0.3, -0.74])]
    scene_graph.AddRenderer(FISHEYE_RENDERER_NAME, MakeRenderEngineVtk(RenderEngineVtkParams(
        default_clear_color=[0.85, 0.88, 0.9], lights=lights)))


def make_face_sensor(face: Face, config: FisheyeConfig, body_frame_id) -> RgbdSensor:
    """The face's RgbdSensor at X_BF = X_BC * [R_CF, 0] on `body_frame_id` (renderer
    FISHEYE_RENDERER_NAME; only its colour image is meant to be evaluated)."""
    core = RenderCameraCore(FISHEYE_RENDERER_NAME,
                            camera_info(face.width, face.height, face.focal_px, face.focal_px, face.cx, face.cy),
                            ClippingRange(config.near_m, config.far_m), RigidTransform())
    return RgbdSensor(body_frame_id, config.X_BC.multiply(RigidTransform(face.R_CF)), ColorRenderCamera(core, False),
                      DepthRenderCamera(core, depth_range(config.near_m, config.far_m)))


@dataclass
class FisheyeRig:
    """What `add_fisheye_camera` added: the face RgbdSensors (FACE_NAMES' order) and the FisheyeCamera
    (whose `color_image` is the fisheye stream)."""

    sensors: list[RgbdSensor]
    camera: FisheyeCamera

    @property
    def color_image(self):
        return self.camera.GetOutputPort("color_image")

    @property
    def rectified_image(self):
        return self.camera.GetOutputPort("rectified_image")


def add_fisheye_camera(builder: DiagramBuilder, scene_graph: SceneGraph, body_frame_id,
                       config: FisheyeConfig) -> FisheyeRig:
    """The fisheye at config.X_BC on the SceneGraph frame `body_frame_id`: five face RgbdSensors
    (renderer `add_fisheye_renderer`, added if missing) into a FisheyeCamera."""
    config.validate()
    add_fisheye_renderer(scene_graph)
    layout = fisheye_layout(config)
    camera = builder.AddSystem(FisheyeCamera(config, layout))
    camera.set_name("fisheye")
    sensors = []
    for face in layout.faces:
        sensor = builder.AddSystem(make_face_sensor(face, config, body_frame_id))
        sensor.set_name(f"fisheye_{face.name}_sensor")
        builder.Connect(scene_graph.get_query_output_port(), sensor.query_object_input_port())
        builder.Connect(sensor.color_image_output_port(), camera.GetInputPort(f"face_{face.name}"))
        sensors.append(sensor)
    return FisheyeRig(sensors, camera)
