"""A stereo pair over textured ground: seed 003's downward MYNT EYE on the airframe, a flat ground with a
random corner-rich texture (models/ground_texture.py), the stereo altimeter and the altitude filter.

The body pose is the diagram's input `X_WB` (fix it per case, or connect a flight), so one built diagram
serves every height:

    diagram, handles = build_stereo_hover()
    context = diagram.CreateDefaultContext()
    handles.fix_X_WB(diagram, context, RigidTransform([0, 0, 3.0]))
    handles.altimeter.GetOutputPort("altitude").Eval(handles.altimeter.GetMyContextFromRoot(context))
"""

from dataclasses import dataclass, field

import numpy as np
from pydrake.geometry import Mesh, SceneGraph
from pydrake.math import RigidTransform
from pydrake.systems.framework import Diagram, DiagramBuilder

from models.ground_texture import ground_texture_mesh
from systems.config import require
from systems.estimators.altitude_kf import AltitudeFilterSystem, AltitudeKfConfig
from systems.geometry import register_visual
from systems.perception.stereo_depth import StereoAltimeter, StereoDepthConfig
from systems.sensors.camera import add_renderer
from systems.sensors.stereo import StereoConfig, StereoPair, add_stereo_pair
from systems.vehicles.airframe import AirframeConfig, AirframeGeometry

# Meshcat's copy of the ground texture (px a side): the cameras' 4096 put 11 MB of PNG into every browser's
# scene and every meshcat.html; 1024 is 2 cm a texel on the 20 m ground.
GROUND_SHOWN_PIXELS = 1024
# ... drawn this much higher (m) than the cameras' one: a browser's depth buffer cannot tell 1 mm apart from
# tens of metres away, so over a plain ground 1 mm below Meshcat showed the plain one over most of it.
GROUND_SHOWN_LIFT_M = 0.01


@dataclass
class GroundConfig:
    """The textured ground: a square of `size_m` in z = 0 centred on the world origin, repeated side by side
    where a scene asks for more (`add_textured_ground`'s cover_xy)."""

    size_m: float = 20.0  # wider than the 17.2 x 11 m an image covers from 8 m
    texture_seed: int = 0
    texture_pixels: int = 4096  # 4.9 mm per texel over 20 m: the finest squares (2 texels) are 4.9 px at 0.7 m

    def validate(self, prefix: str = "ground") -> None:
        require(self.size_m > 0, f"{prefix}.size_m must be positive, got {self.size_m}")
        require(64 <= self.texture_pixels <= 8192, f"{prefix}.texture_pixels must lie in 64..8192")


@dataclass
class StereoHoverConfig:
    seed: int = 0
    stereo: StereoConfig = field(default_factory=StereoConfig)
    depth: StereoDepthConfig = field(default_factory=StereoDepthConfig)
    altitude_kf: AltitudeKfConfig = field(default_factory=AltitudeKfConfig)
    ground: GroundConfig = field(default_factory=GroundConfig)
    uav: AirframeConfig = field(default_factory=AirframeConfig)

    def validate(self) -> None:
        self.stereo.validate("stereo")
        self.depth.validate("depth", self.stereo)
        self.altitude_kf.validate("altitude_kf")
        self.ground.validate("ground")
        self.uav.validate("uav")


@dataclass
class StereoHoverHandles:
    scene_graph: SceneGraph
    airframe: AirframeGeometry
    pair: StereoPair
    altimeter: StereoAltimeter
    altitude_filter: AltitudeFilterSystem
    X_WB_input_index: int

    def fix_X_WB(self, diagram: Diagram, context, X_WB: RigidTransform) -> None:
        """Holds the body at X_WB in this (root) context."""
        diagram.get_input_port(self.X_WB_input_index).FixValue(context, X_WB)


def ground_tiles(size_m: float, lower_xy, upper_xy) -> list[np.ndarray]:
    """The centres (x, y) [m] of the squares of side size_m, on a grid with one centred on the origin,
    that cover the rectangle lower_xy..upper_xy (World x, y)."""
    lower, upper = (np.floor((np.asarray(c, float) + size_m / 2) / size_m).astype(int) for c in (lower_xy, upper_xy))
    return [size_m * np.array([i, j], float) for i in range(lower[0], upper[0] + 1)
            for j in range(lower[1], upper[1] + 1)]


def add_textured_ground(scene_graph: SceneGraph, config: GroundConfig, height_m: float = 0.0,
                        cover_xy: tuple | None = None) -> None:
    """The ground's textured square in z = `height_m` (m; 0: the ground) for the cameras, and for Meshcat a
    copy averaged down to GROUND_SHOWN_PIXELS a side, GROUND_SHOWN_LIFT_M higher; centred on the origin, or
    repeated side by side (`ground_tiles`) over `cover_xy` = (lower, upper) World x, y [m]. The renderer loads
    the texture once, whatever the number of squares."""
    source, world = scene_graph.RegisterSource("textured_ground"), scene_graph.world_frame_id()
    perceived = ground_texture_mesh(config.texture_seed, config.texture_pixels)
    shown = (ground_texture_mesh(config.texture_seed, config.texture_pixels, shown_pixels=GROUND_SHOWN_PIXELS)
             if config.texture_pixels > GROUND_SHOWN_PIXELS else perceived)
    centres = ground_tiles(config.size_m, *cover_xy) if cover_xy is not None else [np.zeros(2)]
    for k, (x, y) in enumerate(centres):
        suffix = f"_{k}" if k else ""
        register_visual(scene_graph, source, world, RigidTransform([x, y, height_m]),
                        Mesh(str(perceived), config.size_m), f"textured_ground{suffix}", rgba=None, illustrated=False)
        register_visual(scene_graph, source, world, RigidTransform([x, y, height_m + GROUND_SHOWN_LIFT_M]),
                        Mesh(str(shown), config.size_m), f"textured_ground_shown{suffix}", rgba=None, perceived=False)


def add_stereo_altimeter(builder: DiagramBuilder, pair: StereoPair, stereo: StereoConfig, depth: StereoDepthConfig,
                         altitude_kf: AltitudeKfConfig) -> tuple[StereoAltimeter, AltitudeFilterSystem]:
    """The altimeter on the pair's two images and the altitude filter on the altimeter (seed 003 Eq. 11-14),
    the filter told the altimeter's nearest range [m]."""
    altimeter = builder.AddNamedSystem("stereo_altimeter", StereoAltimeter(stereo, depth))
    builder.Connect(pair.left_image, altimeter.GetInputPort("left_image"))
    builder.Connect(pair.right_image, altimeter.GetInputPort("right_image"))
    altitude_filter = builder.AddNamedSystem("altitude_filter", AltitudeFilterSystem(altitude_kf, stereo.period_s,
                                                                                     altimeter.estimator.nearest_m))
    builder.Connect(altimeter.GetOutputPort("altitude"), altitude_filter.GetInputPort("altitude"))
    builder.Connect(altimeter.GetOutputPort("altitude_valid"), altitude_filter.GetInputPort("altitude_valid"))
    return altimeter, altitude_filter


def build_stereo_hover(config: StereoHoverConfig | None = None) -> tuple[Diagram, StereoHoverHandles]:
    """The scene, the pair, the altimeter on its images and the filter on the altimeter."""
    config = config or StereoHoverConfig()
    config.validate()
    builder = DiagramBuilder()
    scene_graph = builder.AddSystem(SceneGraph())
    add_renderer(scene_graph)
    add_textured_ground(scene_graph, config.ground)
    airframe = builder.AddSystem(AirframeGeometry(config.uav, scene_graph))
    builder.Connect(airframe.get_output_port(), scene_graph.get_source_pose_port(airframe.source_id))
    X_WB_input_index = builder.ExportInput(airframe.get_input_port(), "X_WB")
    pair = add_stereo_pair(builder, scene_graph, airframe.body_frame_id, config.stereo, config.seed)
    altimeter, altitude_filter = add_stereo_altimeter(builder, pair, config.stereo, config.depth, config.altitude_kf)
    diagram = builder.Build()
    return diagram, StereoHoverHandles(scene_graph, airframe, pair, altimeter, altitude_filter, X_WB_input_index)
