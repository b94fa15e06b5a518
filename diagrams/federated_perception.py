"""Seed 001's perception in a diagram: the camera's stream -> the three vision nodes -> the federated
filter, driven by the IMU on the UAV's true motion.

    ports = add_federated_perception(builder, config.federated, config.platform.rqrlp, seed, color_image,
                                     X_WB, V_WB, A_WB)

The camera itself is the scene's (systems/sensors/camera.py's `add_camera` with `camera`): the
gv scenarios add it for `perception.source: federated`, rqrlp-maneuvers always.
"""

from dataclasses import dataclass, field

from pydrake.systems.framework import DiagramBuilder, OutputPort
from pydrake.systems.primitives import LogVectorOutput, VectorLogSink

from systems.config import require
from systems.estimators.federated.engine import NODES, FederatedConfig
from systems.estimators.federated.system import FederatedFilterSystem, require_camera_steps
from systems.perception.rqrlp.node_systems import AdjustmentNode, ApproachNode, NodeMeasurementToVector, TouchdownNode
from systems.perception.rqrlp.pattern import RqrlpLayout
from systems.sensors.camera import CameraConfig
from systems.sensors.imu import Imu, ImuConfig


def seed001_camera() -> CameraConfig:
    """Seed 001 Table 1's camera (GoPro 4: 1080p at 50 fps, f 1280 px, principal point (948.9,
    543.2), distortion (-0.00908, -0.03128, 0.00109, -0.00198, 0)) at half its resolution, the same
    field of view: 1080p renders 3.8x slower here (docs/results.md gives both's cost and accuracy).
    Its principal point is Table 1's halved; a sensor binned 2 x 2 would have it at (c - 0.5) / 2, a quarter
    pixel up and left (pixel centres at whole numbers). Kept, as docs/results.md's figures were measured with
    it; renderer and estimators share it. Pixel noise as the other scenes' cameras."""
    return CameraConfig(width=960, height=540, fx=640.0, fy=640.0, cx=474.45, cy=271.6, rate_hz=50.0,
                        pixel_noise_std=2.0, distortion=[-0.00908, -0.03128, 0.00109, -0.00198, 0.0])


@dataclass
class FederatedPerceptionConfig:
    """Seed 001's camera, its IMU (Table 1, systems/sensors/imu.py) and the federated filter."""

    camera: CameraConfig = field(default_factory=seed001_camera)
    imu: ImuConfig = field(default_factory=ImuConfig)
    filter: FederatedConfig = field(default_factory=FederatedConfig)

    def validate(self, prefix: str = "federated") -> None:
        self.camera.validate(f"{prefix}.camera")
        self.imu.validate(f"{prefix}.imu")
        self.filter.validate(f"{prefix}.filter")
        require_camera_steps(self.filter, self.imu.period_s, self.camera.period_s, prefix)
        require(self.filter.gravity_m_s2 == self.imu.gravity_m_s2,
                f"{prefix}.filter.gravity_m_s2 must be the IMU's ({self.imu.gravity_m_s2:g})")


@dataclass
class FederatedPorts:
    """The federated perception's systems in a diagram; `logs` sample at the camera's rate:
    `federated` (FED_* layout) and one node_vector per node."""

    imu: Imu
    nodes: dict
    filter: FederatedFilterSystem
    logs: dict[str, VectorLogSink]


def add_federated_perception(builder: DiagramBuilder, config: FederatedPerceptionConfig, layout: RqrlpLayout,
                             seed: int, color_image: OutputPort, X_WB: OutputPort, V_WB: OutputPort,
                             A_WB: OutputPort) -> FederatedPorts:
    """The IMU on the UAV's kinematics (X_WB, V_WB, A_WB, its truth), the nodes on `color_image`
    (the camera of `config.camera`), the filter on both; X_WB and V_WB also as the UAV's own
    navigation that puts the pattern in W."""
    camera = config.camera
    imu = builder.AddNamedSystem("imu", Imu(config.imu, seed))
    for port, name in ((X_WB, "X_WB"), (V_WB, "V_WB"), (A_WB, "A_WB")):
        builder.Connect(port, imu.GetInputPort(name))
    nodes = {"approach": builder.AddNamedSystem("approach_node", ApproachNode(camera, layout)),
             "adjustment": builder.AddNamedSystem("adjustment_node", AdjustmentNode(camera, layout)),
             "touchdown": builder.AddNamedSystem("touchdown_node", TouchdownNode(camera, layout))}
    for node in nodes.values():
        builder.Connect(color_image, node.GetInputPort("color_image"))
    builder.Connect(nodes["adjustment"].get_output_port(), nodes["touchdown"].GetInputPort("anchor"))
    federated = builder.AddNamedSystem("federated_filter", FederatedFilterSystem(
        config.filter, camera.X_BC, config.imu.period_s, camera.period_s))
    builder.Connect(imu.get_output_port(), federated.GetInputPort("imu"))
    for name in NODES:
        builder.Connect(nodes[name].get_output_port(), federated.GetInputPort(name))
    builder.Connect(X_WB, federated.GetInputPort("X_WB"))
    builder.Connect(V_WB, federated.GetInputPort("V_WB"))
    logs = {"federated": LogVectorOutput(federated.GetOutputPort("federated_vector"), builder, camera.period_s)}
    for name, node in nodes.items():
        vector = builder.AddNamedSystem(f"{name}_vector", NodeMeasurementToVector())
        builder.Connect(node.get_output_port(), vector.get_input_port())
        logs[name] = LogVectorOutput(vector.get_output_port(), builder, camera.period_s)
    return FederatedPorts(imu, nodes, federated, logs)
