"""Shared fixtures: built Stewart scenes (a diagram is built once per session; every test takes a
fresh context from it) and one short simulated run of the stewart-dynamic scenario; and image helpers (a
textured plane's pinhole view by its homography, a grey frame as a camera's colour image)."""

import sys
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pytest
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import Diagram
from pydrake.systems.sensors import ImageRgba8U
from scipy.spatial.transform import Rotation

from diagrams.runner import load_scenario
from diagrams.stewart_run import collect_log
from diagrams.stewart_scene import StewartSceneConfig, StewartSceneHandles, build_stewart_scene
from systems.platforms.stewart import StewartPlatformConfig

# Fixtures that render camera images or spawn processes: a test using one is marked slow.
SLOW_FIXTURES = {"hover_scene", "tilted_scene", "dynamic_run", "build_scene", "scene", "console_runs", "short_run",
                 "pool_campaigns", "local_cluster", "detector_run", "federated_landing", "covered_landing", "maneuvers"}


def pytest_collection_modifyitems(items):
    for item in items:
        if SLOW_FIXTURES & set(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.slow)


@pytest.fixture(autouse=True)
def _close_figures():
    """Closes the matplotlib figures a test leaves open (those that capture save_figure keep theirs)."""
    yield
    if "matplotlib.pyplot" in sys.modules:
        sys.modules["matplotlib.pyplot"].close("all")


def wiring(diagram) -> dict[tuple[str, str], tuple[str, str]]:
    """A built Diagram's connections by name: (system, input port) -> (source system, output port)."""
    return {(system.get_name(), system.get_input_port(i).get_name()):
            (source.get_name(), source.get_output_port(j).get_name())
            for (system, i), (source, j) in diagram.connection_map().items()}


class InlinePool:
    """ProcessPoolExecutor's stand-in for the benchmarks' tests: maps in this process (a forked worker would
    inherit this process's render context, and spawned ones import Drake again)."""

    def __init__(self, *args, **kwargs):
        pass

    def __enter__(self):
        return self

    def __exit__(self, *args):
        return False

    def map(self, fn, *iterables):
        return map(fn, *iterables)


def landing_sim_command() -> list[str]:
    """The installed `landing-sim` command, or the module when the console script is missing."""
    script = Path(sys.executable).with_name("landing-sim")
    return [str(script)] if script.exists() else [sys.executable, "-m", "diagrams.cli"]


def pose(xyz, rpy_deg) -> RigidTransform:
    """A pose from a translation and roll, pitch, yaw (deg) about fixed x, y, z, with the rotation
    built by SciPy (extrinsic 'xyz'), not by Drake, so the tests' truth is independent of it."""
    return RigidTransform(RotationMatrix(Rotation.from_euler("xyz", rpy_deg, degrees=True).as_matrix()),
                          np.asarray(xyz, dtype=float))


def render_plane(texture: np.ndarray, edge_m: float, X_CP: RigidTransform, camera, supersample: int = 4,
                 background: int = 90) -> np.ndarray:
    """The square grey `texture`, covering an `edge_m` square of the plane z = 0 of frame P centred on P's origin
    (P's x to the right and y up in the texture), as a pinhole camera with `camera`'s K and size (a CameraConfig)
    sees it at X_CP: the plane's homography at `supersample` times the resolution, averaged down (a renderer's
    antialiasing)."""
    scale, half = texture.shape[0] / edge_m, edge_m / 2
    texel_to_P = np.array([[1 / scale, 0, 0.5 / scale - half], [0, -1 / scale, half - 0.5 / scale], [0, 0, 1]])
    K_big = camera.K.copy()
    K_big[:2] *= supersample
    K_big[:2, 2] = (camera.K[:2, 2] + 0.5) * supersample - 0.5
    R, t = X_CP.rotation().matrix(), X_CP.translation()
    homography = K_big @ np.column_stack([R[:, 0], R[:, 1], t]) @ texel_to_P
    size = (camera.width * supersample, camera.height * supersample)
    big = cv2.warpPerspective(texture, homography, size, flags=cv2.INTER_LINEAR, borderValue=background)
    return cv2.resize(big, (camera.width, camera.height), interpolation=cv2.INTER_AREA)


def rgba(grey: np.ndarray) -> ImageRgba8U:
    """A camera's colour image (ImageRgba8U, alpha 255) of a grey frame."""
    image = ImageRgba8U(grey.shape[1], grey.shape[0])
    image.mutable_data[:, :, :3] = grey[:, :, None]
    image.mutable_data[:, :, 3] = 255
    return image


@dataclass
class Scene:
    """A built scene and the hand-computed poses it should have."""

    config: StewartSceneConfig
    diagram: Diagram
    handles: StewartSceneHandles

    def context(self, t: float = 0.0):
        context = self.diagram.CreateDefaultContext()
        context.SetTime(t)
        return context

    def eval(self, system, port_name: str, root_context):
        return system.GetOutputPort(port_name).Eval(system.GetMyContextFromRoot(root_context))

    def nominal_deck_z(self) -> float:
        p = self.config.platform
        return p.base_joint_height_m + p.nominal_height_m + p.deck_thickness_m

    def X_WB(self) -> RigidTransform:
        """The hover pose by hand: camera `height_above_deck_m` above the nominal deck top."""
        h, mount_z = self.config.hover, self.config.camera.mount_xyz_m[2]
        return pose([h.offset_xy_m[0], h.offset_xy_m[1], self.nominal_deck_z() + h.height_above_deck_m - mount_z],
                    [h.roll_deg, h.pitch_deg, h.yaw_deg])

    def X_WC(self) -> RigidTransform:
        """Camera pose by hand: at mount_xyz_m in B, +z_C = -z_B, +x_C = +x_B (a half turn about x)."""
        return self.X_WB().multiply(pose(self.config.camera.mount_xyz_m, [180.0, 0.0, 0.0]))

    def X_WP_static(self) -> RigidTransform:
        """Deck pose by hand for a deck held at a constant offset (see `constant_offset_platform`)."""
        p = self.config.platform
        if p.motion == "static":
            return pose([0.0, 0.0, self.nominal_deck_z()], [0.0, 0.0, 0.0])
        a = {axis: (getattr(p, f"{axis}_amplitude_{'m' if axis in 'xyz' else 'deg'}") or [0.0])[0]
             for axis in ("x", "y", "z", "roll", "pitch", "yaw")}
        return pose([a["x"], a["y"], self.nominal_deck_z() + a["z"]], [a["roll"], a["pitch"], a["yaw"]])


def constant_offset_platform(x=0.0, y=0.0, z=0.0, roll=0.0, pitch=0.0, yaw=0.0) -> StewartPlatformConfig:
    """A deck held at a constant offset from its nominal pose: each axis a zero-frequency sinusoid with
    a 90 degree phase, A sin(0 t + 90 deg) = A."""
    config = StewartPlatformConfig(motion="sinusoid")
    for axis, value in (("x", x), ("y", y), ("z", z), ("roll", roll), ("pitch", pitch), ("yaw", yaw)):
        unit = "m" if axis in "xyz" else "deg"
        setattr(config, f"{axis}_amplitude_{unit}", [value])
        setattr(config, f"{axis}_frequency_hz", [0.0])
        setattr(config, f"{axis}_phase_deg", [90.0])
    return config


def build(config: StewartSceneConfig) -> Scene:
    diagram, handles = build_stewart_scene(config)
    return Scene(config, diagram, handles)


@pytest.fixture
def recorded_simulators(monkeypatch) -> list:
    """Every Simulator that diagrams.simulate makes during the test, in order (to read its integrator)."""
    import diagrams.simulate

    simulators, make = [], diagrams.simulate.Simulator

    def record(diagram):
        simulators.append(make(diagram))
        return simulators[-1]

    monkeypatch.setattr(diagrams.simulate, "Simulator", record)
    return simulators


@pytest.fixture(scope="session")
def build_scene():
    """Builds a scene from a StewartSceneConfig: `build_scene(config) -> Scene`."""
    return build


@pytest.fixture(scope="session")
def hover_scene() -> Scene:
    """The stewart-hover scenario's scene (static level deck, camera 2 m above it), without pixel or
    range noise."""
    _, config = load_scenario("stewart-hover")
    config.estimators = []  # the scene's sensors only
    config.camera.pixel_noise_std = 0.0
    config.tof.noise_std_m = 0.0
    return build(config)


@pytest.fixture(scope="session")
def tilted_scene() -> Scene:
    """A deck tilted and shifted off its nominal pose under a drone that hovers offset, yawed and a
    little tilted; no pixel or range noise."""
    config = StewartSceneConfig()
    config.platform = constant_offset_platform(x=0.08, y=-0.05, z=0.03, roll=12.0, pitch=-9.0, yaw=30.0)
    config.hover.offset_xy_m = [0.05, -0.03]
    config.hover.roll_deg, config.hover.pitch_deg, config.hover.yaw_deg = 4.0, -3.0, 20.0
    return build(config)


@pytest.fixture(scope="session")
def dynamic_run():
    """The stewart-dynamic scenario simulated for 2 s: (scene, final context, log arrays)."""
    _, scenario = load_scenario("stewart-dynamic", duration_s=2.0)
    diagram, handles = build_stewart_scene(scenario)
    simulator = Simulator(diagram)
    simulator.Initialize()
    simulator.AdvanceTo(scenario.duration_s)
    context = simulator.get_context()
    return Scene(scenario, diagram, handles), context, collect_log(handles, context, scenario)
