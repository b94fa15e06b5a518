"""systems/vehicles/airframe.py: the airframe geometry checks its own dimensions, so a caller that builds it
directly (not through a scenario's config) gets a ConfigError naming the field, not a failure inside Drake."""

import numpy as np
import pytest
from pydrake.geometry import Box, Cylinder, Role, SceneGraph
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix

from systems.config import ConfigError
from systems.vehicles.airframe import AirframeConfig, AirframeGeometry, PrescribedPose


@pytest.mark.parametrize("field", ["body_size_m", "body_height_m", "rotor_arm_m", "propeller_radius_m"])
def test_a_dimension_that_is_not_positive_is_a_config_error_naming_it(field):
    """Each dimension at zero: the geometry refuses it by name (unchecked, Drake's Box or Cylinder failed)."""
    with pytest.raises(ConfigError, match=rf"uav\.{field} must be positive"):
        AirframeGeometry(AirframeConfig(**{field: 0.0}), SceneGraph())


def test_prescribed_pose_moves_at_its_constant_velocity_without_rotating():
    """From X_WB0 at t = 0 at v_WB = (0.5, -0.25, 2) m/s: at t = 2 s the body is at p0 + 2 v = (2, 1.5, 7) with the
    rotation of X_WB0; V_WB is [w_WB; v_WB] = [0; v_WB] (angular first) and A_WB is zero."""
    R_WB0 = RotationMatrix(RollPitchYaw(0.1, 0.2, 0.3))
    source = PrescribedPose(RigidTransform(R_WB0, [1.0, 2.0, 3.0]), (0.5, -0.25, 2.0))
    context = source.CreateDefaultContext()
    context.SetTime(2.0)
    X_WB = source.GetOutputPort("X_WB").Eval(context)
    np.testing.assert_allclose(X_WB.translation(), [2.0, 1.5, 7.0], atol=1e-12)
    assert X_WB.rotation().IsNearlyEqualTo(R_WB0, 1e-12)
    np.testing.assert_array_equal(source.GetOutputPort("V_WB").Eval(context), [0.0, 0.0, 0.0, 0.5, -0.25, 2.0])
    np.testing.assert_array_equal(source.GetOutputPort("A_WB").Eval(context), np.zeros(6))


def test_the_airframe_is_a_body_with_four_arms_and_propellers_at_45_degrees_red_in_front():
    """AirframeConfig's docstring: rotors at 45 degrees off the axes, rotor_arm_m from the centre (the camera axis).
    The body a body_size_m square, body_height_m high, centred on B; arm i a bar rotor_arm_m long from the centre to
    rotor i, along its own x (turned by Z(a_i)); propeller i a thin disc of propeller_radius_m at rotor i on top of the
    body (z = body_height_m / 2). The two front rotors (x_B > 0) red, the back ones not, for camera and Meshcat."""
    config = AirframeConfig()
    scene_graph = SceneGraph()
    airframe = AirframeGeometry(config, scene_graph)
    inspector = scene_graph.model_inspector()
    geometry = {inspector.GetName(g): g for g in inspector.GetGeometries(airframe.body_frame_id, Role.kPerception)}
    assert sorted(geometry) == sorted(["uav_body"] + [f"uav_{part}{i}" for part in ("arm", "propeller")
                                                      for i in range(4)])
    body = inspector.GetShape(geometry["uav_body"])
    assert isinstance(body, Box)
    assert (body.width(), body.depth(), body.height()) == (config.body_size_m, config.body_size_m,
                                                           config.body_height_m)
    assert inspector.GetPoseInFrame(geometry["uav_body"]).IsExactlyIdentity()

    angles, colours = [], {}
    for i in range(4):
        propeller, arm = geometry[f"uav_propeller{i}"], geometry[f"uav_arm{i}"]
        disc = inspector.GetShape(propeller)
        assert isinstance(disc, Cylinder)
        assert disc.radius() == config.propeller_radius_m and disc.length() < config.body_height_m
        p = inspector.GetPoseInFrame(propeller).translation()
        angle = np.degrees(np.arctan2(p[1], p[0])) % 360.0
        angles.append(angle)
        a = np.radians(angle)
        direction = np.array([np.cos(a), np.sin(a), 0.0])
        np.testing.assert_allclose(p, config.rotor_arm_m * direction + [0.0, 0.0, config.body_height_m / 2],
                                   atol=1e-12)
        bar = inspector.GetShape(arm)
        assert isinstance(bar, Box)
        assert bar.width() == config.rotor_arm_m and max(bar.depth(), bar.height()) < config.body_height_m
        X_BA = inspector.GetPoseInFrame(arm)
        np.testing.assert_allclose(X_BA.translation(), config.rotor_arm_m / 2 * direction, atol=1e-12)
        assert X_BA.rotation().IsNearlyEqualTo(RotationMatrix.MakeZRotation(a), 1e-12)
        for properties in (inspector.GetPerceptionProperties(propeller),
                           inspector.GetIllustrationProperties(propeller)):
            colours.setdefault("front" if p[0] > 0 else "back", []).append(
                tuple(properties.GetProperty("phong", "diffuse").rgba))
    np.testing.assert_allclose(sorted(angles), [45.0, 135.0, 225.0, 315.0], atol=1e-9)
    assert len(colours["front"]) == len(colours["back"]) == 4  # two rotors each, two roles
    assert len(set(colours["front"])) == 1 and len(set(colours["back"])) == 1
    (r, g, b, _), (back_r, back_g, back_b, _) = colours["front"][0], colours["back"][0]
    assert r > 2 * max(g, b) and not back_r > 2 * max(back_g, back_b)  # red in front only
