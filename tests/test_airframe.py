"""systems/vehicles/airframe.py: the airframe geometry checks its own dimensions, so a caller that builds it
directly (not through a scenario's config) gets a ConfigError naming the field, not a failure inside Drake."""

import pytest
from pydrake.geometry import SceneGraph

from systems.config import ConfigError
from systems.vehicles.airframe import AirframeConfig, AirframeGeometry


@pytest.mark.parametrize("field", ["body_size_m", "body_height_m", "rotor_arm_m", "propeller_radius_m"])
def test_a_dimension_that_is_not_positive_is_a_config_error_naming_it(field):
    """Each dimension at zero: the geometry refuses it by name (unchecked, Drake's Box or Cylinder failed)."""
    with pytest.raises(ConfigError, match=rf"uav\.{field} must be positive"):
        AirframeGeometry(AirframeConfig(**{field: 0.0}), SceneGraph())
