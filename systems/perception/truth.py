"""Perfect perception: the seam (systems/perception/seam.py) computed from the true states.

The `truth` perception source, kept as the reference every estimator is compared with, and the
true relative state that metrics and the run's monitor read whatever steers. "Valid" is the pad
inside the downward view (a cone about the body's -z, seed 003's 150 deg fisheye by default) and
range, so a UAV that strays loses the target as a real one would.

The pad moves with the vehicle (seed 002 Eq. 6): at r = pad_offset_m ahead of the rear axle, along
the heading h = (cos a, sin a) with n = (-sin a, cos a), turning at w = v tan(steering) / d,
    v_P = v h + r w n,   a_P = (dv/dt - r w^2) h + (v w + r dw/dt) n.
"""

import math

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.systems.framework import LeafSystem

from systems.perception.seam import P_BP_B, RELATIVE_STATE_SIZE, VALID, seam_vector
from systems.vehicles.ground_vehicle import GroundVehicleConfig, bicycle_state_derivative
from systems.vehicles.ground_vehicle_geometry import PlatformConfig

STEERING = 3  # index of the steering angle in the vehicle's state [x, y, heading, steering]


def turn_rate(steering: float, speed: float, vehicle: GroundVehicleConfig) -> float:
    """The vehicle's yaw rate w = v tan(steering) / d [rad/s] at `speed` [m/s] and `steering` [rad]."""
    return speed * math.tan(steering) / vehicle.wheelbase_m


def pad_motion(vehicle_state, speed: float, speed_rate: float, steering_rate: float, vehicle: GroundVehicleConfig,
               platform: PlatformConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(p_WP [m], v_WP [m/s], a_WP [m/s^2]) of the pad centre in W for the vehicle's state [x, y,
    heading, steering], speed [m/s] and the rates of its speed [m/s^2] and steering [rad/s]."""
    x, y, heading, steering = (float(v) for v in vehicle_state[:4])
    c, s = math.cos(heading), math.sin(heading)
    r = platform.pad_offset_m
    tan_steering = math.tan(steering)
    yaw_rate = turn_rate(steering, speed, vehicle)
    yaw_accel = (speed_rate * tan_steering + speed * steering_rate * (1.0 + tan_steering**2)) / vehicle.wheelbase_m
    along, across = speed_rate - r * yaw_rate**2, speed * yaw_rate + r * yaw_accel
    return (np.array([x + c * r, y + s * r, platform.height_m]),
            np.array([speed * c - yaw_rate * s * r, speed * s + yaw_rate * c * r, 0.0]),
            np.array([along * c - across * s, along * s + across * c, 0.0]))


def in_view(p_BP_B: np.ndarray, field_of_view_deg: float, max_range_m: float) -> bool:
    """The pad centre at p_BP_B (body frame, m) inside the cone of `field_of_view_deg` (full angle)
    about -z_B and within `max_range_m`."""
    distance = float(np.linalg.norm(p_BP_B))
    cos_angle = -p_BP_B[2] / distance if distance > 0 else 1.0
    return distance <= max_range_m and cos_angle >= math.cos(math.radians(field_of_view_deg / 2))


class RelativeStateTruth(LeafSystem):
    """Inputs `X_WB` (RigidTransform, the UAV body), `vehicle_state` (4), `vehicle_speed` (2: speed
    [m/s] and its rate [m/s^2]), `vehicle_steering_command` (1, rad: with the state, the steering's
    rate). Output `relative_state` (RELATIVE_STATE_SIZE), computed when pulled; valid while the pad
    is `in_view`."""

    def __init__(self, vehicle: GroundVehicleConfig, platform: PlatformConfig, field_of_view_deg: float = 150.0,
                 max_range_m: float = 30.0):
        super().__init__()
        self._vehicle, self._platform, self._view = vehicle, platform, (field_of_view_deg, max_range_m)
        self._X_WB = self.DeclareAbstractInputPort("X_WB", AbstractValue.Make(RigidTransform()))
        self._state = self.DeclareVectorInputPort("vehicle_state", 4)
        self._speed = self.DeclareVectorInputPort("vehicle_speed", 2)
        self._steering = self.DeclareVectorInputPort("vehicle_steering_command", 1)
        self.DeclareVectorOutputPort("relative_state", RELATIVE_STATE_SIZE, self._calc)

    def _calc(self, context, output):
        state = self._state.Eval(context)
        speed, speed_rate = self._speed.Eval(context).tolist()
        steering_rate = float(bicycle_state_derivative(state, float(self._steering.Eval(context)[0]), speed,
                                                       self._vehicle)[STEERING])
        p_WP, v_WP, a_WP = pad_motion(state, speed, speed_rate, steering_rate, self._vehicle, self._platform)
        values = seam_vector(self._X_WB.Eval(context), p_WP, v_WP, a_WP, True)
        if not in_view(values[P_BP_B], *self._view):
            values[VALID] = 0.0
        output.SetFromVector(values)


class PadMotionTruth(LeafSystem):
    """The seam from a pad whose motion is given: inputs `X_WB` (RigidTransform, the UAV body) and
    `pad_motion` (9: p_WP [m], v_WP [m/s], a_WP [m/s^2] in W, e.g. the Stewart deck's). Output
    `relative_state` (RELATIVE_STATE_SIZE), computed when pulled; valid while the pad is `in_view`."""

    def __init__(self, field_of_view_deg: float = 150.0, max_range_m: float = 30.0):
        super().__init__()
        self._view = (field_of_view_deg, max_range_m)
        self._X_WB = self.DeclareAbstractInputPort("X_WB", AbstractValue.Make(RigidTransform()))
        self._motion = self.DeclareVectorInputPort("pad_motion", 9)
        self.DeclareVectorOutputPort("relative_state", RELATIVE_STATE_SIZE, self._calc)

    def _calc(self, context, output):
        motion = self._motion.Eval(context)
        values = seam_vector(self._X_WB.Eval(context), motion[:3], motion[3:6], motion[6:], True)
        if not in_view(values[P_BP_B], *self._view):
            values[VALID] = 0.0
        output.SetFromVector(values)


class PadVelocity(LeafSystem):
    """Inputs `vehicle_state` (4) and `vehicle_speed` (2: speed [m/s], its rate); output `V_WP` (6): the pad
    frame P's spatial velocity [w; v] in W (rad/s, m/s), turning with the vehicle at w = v tan(steering) / d."""

    def __init__(self, vehicle: GroundVehicleConfig, platform: PlatformConfig):
        super().__init__()
        state = self.DeclareVectorInputPort("vehicle_state", 4)
        speed = self.DeclareVectorInputPort("vehicle_speed", 2)

        def calc(context, output):
            x = state.Eval(context)
            v = float(speed.Eval(context)[0])
            v_WP = pad_motion(x, v, 0.0, 0.0, vehicle, platform)[1]
            output.SetFromVector(np.r_[0.0, 0.0, turn_rate(float(x[STEERING]), v, vehicle), v_WP])

        self.DeclareVectorOutputPort("V_WP", 6, calc)


class PadPose(LeafSystem):
    """Input `vehicle_state` (4); output `X_WP` (RigidTransform): the pad frame P in W."""

    def __init__(self, platform: PlatformConfig):
        super().__init__()
        state = self.DeclareVectorInputPort("vehicle_state", 4)
        self.DeclareAbstractOutputPort("X_WP", lambda: AbstractValue.Make(RigidTransform()),
                                       lambda context, output: output.set_value(platform.X_WP(state.Eval(context))))
