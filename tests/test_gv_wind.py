"""Wind in the gv scenarios: the `wind` section through the scenario loader, the WindSystem wired to
the quadrotor's rotor drag in the diagram, logged, reported in metrics.json and wind.png."""

import msgpack
import numpy as np
import pytest
from pydrake.geometry import Meshcat, MeshcatParams
from pydrake.systems.analysis import Simulator

from diagrams.gv_landing import build_gv_landing
from diagrams.gv_landing_run import fly, fly_diagram
from diagrams.runner import load_scenario
from diagrams.wind_report import plot_wind, wind_metrics
from systems.config import ConfigError
from systems.environment.wind import GustConfig, WindConfig
from systems.vehicles.quadrotor import Q_WB, V_WB, rotation_from_quaternion
from systems.viewers import MeshcatArrow, arrow_polyline

pytestmark = pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")

DRAG = "quadrotor.rotor_drag_coefficient=8.06428e-5"


def test_the_wind_section_loads_gusts_and_names_its_mistakes():
    _, config = load_scenario("gv-landing", overrides=[
        DRAG, "wind.mean_m_s=5", "wind.turbulence=light",
        "wind.gusts=[{start_s: 2.0, duration_s: 1.5, magnitude_m_s: 3.0, direction_deg: 90.0}]"])
    assert config.wind.gusts == [GustConfig(start_s=2.0, duration_s=1.5, magnitude_m_s=3.0, direction_deg=90.0)]
    with pytest.raises(ConfigError, match="rotor_drag_coefficient"):
        load_scenario("gv-landing", overrides=["wind.mean_m_s=5"])  # seed 002's airframe feels no air
    with pytest.raises(ConfigError, match=r"wind\.turbulence"):
        load_scenario("gv-landing", overrides=[DRAG, "wind.turbulence=strong"])
    with pytest.raises(ConfigError, match=r"wind\.gusts\[0\]\.duration_s"):
        load_scenario("gv-landing", overrides=[DRAG, "wind.gusts=[{duration_s: 0.0, magnitude_m_s: 1.0}]"])
    with pytest.raises(ConfigError, match=r"wind\.gusts\[0\]\.speed"):
        load_scenario("gv-landing", overrides=[DRAG, "wind.gusts=[{speed: 1.0}]"])


def test_a_steady_crosswind_reaches_the_quadrotor_which_leans_into_it(tmp_path):
    # 5 m/s toward +y while the UAV climbs from its start (the vehicle stands still).
    _, config = load_scenario("gv-landing", overrides=[DRAG, "wind.mean_m_s=5", "wind.direction_deg=90",
                                                       "vehicle.speed=0.0"])
    metrics, flight = fly(config, 3.0)
    log = flight.log
    np.testing.assert_allclose(log["wind"], np.tile([0.0, 5.0, 0.0], (len(log["t"]), 1)), atol=1e-12)
    assert metrics["wind"]["at_uav"]["mean_W_m_s"] == pytest.approx([0.0, 5.0, 0.0], abs=1e-12)
    # Climbing, the thrust leans upwind by the rotor drag over the weight, k_rd 4 w_hover (5 - v_y) / (m g),
    # v_y the UAV's own drift downwind.
    quad, climb = config.quadrotor, (log["t"] > 1.0) & (log["t"] < 3.0)
    states = log["quadrotor_state"][climb]
    thrust_y = np.array([rotation_from_quaternion(q)[1, 2] for q in states[:, Q_WB]])
    drag_y = quad.rotor_drag_coefficient * 4 * quad.hover_rotor_speed() * (5.0 - states[:, V_WB][:, 1])
    np.testing.assert_allclose(thrust_y, -drag_y / (quad.mass_kg * quad.gravity_m_s2), rtol=0.05)
    assert np.all(states[:, V_WB][:, 1] > 0.1)  # and it drifts downwind
    _, calm = fly(load_scenario("gv-landing", overrides=[DRAG, "vehicle.speed=0.0"])[1], 3.0)
    assert "wind" not in calm.log and np.allclose(calm.log["quadrotor_state"][:, V_WB][:, 1], 0.0, atol=1e-9)
    plot_wind(log, tmp_path)
    assert (tmp_path / "wind.png").stat().st_size > 0


def test_the_wind_is_drawn_in_meshcat_as_an_arrow_at_the_uav():
    _, config = load_scenario("gv-landing", overrides=[DRAG, "wind.mean_m_s=5", "wind.direction_deg=90"])
    meshcat = Meshcat(params=MeshcatParams(host="localhost"))
    diagram, handles = build_gv_landing(config, meshcat)
    fly_diagram(diagram, handles, 0.5)
    assert meshcat.HasPath("/drake/gv_landing/wind")


def test_an_arrow_runs_along_its_vector_with_its_head_at_the_tip():
    tail, vector = np.array([1.0, 2.0, 3.0]), np.array([0.0, 2.0, 0.0])
    points = arrow_polyline(tail, vector)
    np.testing.assert_allclose(points[1], tail + vector)
    np.testing.assert_allclose(points[3], tail + vector)
    for barb in (points[2], points[4]):  # 20 % of the length, 25 deg off the shaft, behind the tip
        offset = barb - (tail + vector)
        assert np.linalg.norm(offset) == pytest.approx(0.4)
        assert np.degrees(np.arccos(-offset @ vector / (np.linalg.norm(offset) * 2.0))) == pytest.approx(25.0)


def test_an_arrows_barbs_lie_on_either_side_of_its_shaft():
    """The head's two barbs mirror each other across the shaft: both end 0.4 cos 25 deg behind the tip along
    it, 0.4 sin 25 deg off it on opposite sides."""
    tail, vector = np.array([1.0, 2.0, 3.0]), np.array([0.0, 2.0, 0.0])
    points = arrow_polyline(tail, vector)
    along = vector / 2.0
    np.testing.assert_allclose((points[2] + points[4]) / 2, tail + vector - 0.4 * np.cos(np.radians(25)) * along,
                               atol=1e-12)
    apart = points[2] - points[4]
    assert apart @ along == pytest.approx(0.0, abs=1e-12)
    assert np.linalg.norm(apart) == pytest.approx(2 * 0.4 * np.sin(np.radians(25)))


def test_an_arrow_for_a_vector_under_min_norm_is_hidden():
    """MeshcatArrow hides the arrow, drawing nothing, for a vector under min_norm (0.05, here 0.03) or from a
    non-finite position, and draws and shows it for one at or over it."""
    meshcat = Meshcat(params=MeshcatParams(host="localhost"))
    for path, position, vector, shown in (("/calm", [0.0, 0.0, 1.0], [0.03, 0.0, 0.0], False),
                                          ("/wind", [0.0, 0.0, 1.0], [1.0, 0.0, 0.0], True),
                                          ("/edge", [0.0, 0.0, 1.0], [0.05, 0.0, 0.0], True),  # min_norm: shown
                                          ("/nowhere", [np.nan, 0.0, 1.0], [1.0, 0.0, 0.0], False)):  # no tail
        arrow = MeshcatArrow(meshcat, path)
        simulator = Simulator(arrow)
        arrow.GetInputPort("position").FixValue(simulator.get_mutable_context(), position)
        arrow.GetInputPort("vector").FixValue(simulator.get_mutable_context(), vector)
        simulator.AdvanceTo(0.3)
        assert msgpack.unpackb(meshcat._GetPackedProperty(path, "visible"))["value"] is shown, path
        assert bool(meshcat._GetPackedObject(path)) is shown, path  # the line, drawn or not


def test_an_arrow_is_drawn_scale_metres_per_unit_of_its_vector():
    """A 5 m/s wind at scale 0.4 (the class's example) is a 2 m arrow: the line runs from the position to
    position + 0.4 * vector."""
    meshcat = Meshcat(params=MeshcatParams(host="localhost"))
    arrow = MeshcatArrow(meshcat, "/wind", scale=0.4)
    simulator = Simulator(arrow)
    arrow.GetInputPort("position").FixValue(simulator.get_mutable_context(), [1.0, 2.0, 3.0])
    arrow.GetInputPort("vector").FixValue(simulator.get_mutable_context(), [0.0, 5.0, 0.0])
    simulator.AdvanceTo(0.05)
    line = msgpack.unpackb(meshcat._GetPackedObject("/wind"))["object"]["geometries"][0]
    points = np.frombuffer(line["data"]["attributes"]["position"]["array"].data, np.float32).reshape(-1, 3)
    np.testing.assert_allclose(points[:2], [[1.0, 2.0, 3.0], [1.0, 4.0, 3.0]], atol=1e-6)


def test_a_vertical_arrows_barbs_lie_along_x():
    """Along z the cross product with z that sides the barbs vanishes: they lie in the x-z plane, 0.2 of the
    1 m arrow at 25 deg off it behind the tip, at (+-0.2 sin 25 deg, 0, 1 - 0.2 cos 25 deg)."""
    points = arrow_polyline(np.zeros(3), np.array([0.0, 0.0, 1.0]))
    out, back = 0.2 * np.sin(np.radians(25)), 0.2 * np.cos(np.radians(25))
    np.testing.assert_allclose(sorted(points[[2, 4]].tolist()), [[-out, 0.0, 1.0 - back], [out, 0.0, 1.0 - back]],
                               atol=1e-12)


def test_the_wind_report_gives_the_standard_deviation_and_the_largest_speed():
    """The air at the UAV (3, 4, 0) then (-3, -4, 0) m/s: a standard deviation (not variance) of (3, 4, 0) m/s
    per axis and a largest speed of 5 m/s (the vector's norm, not its largest component)."""
    out = wind_metrics({"wind": np.array([[3.0, 4.0, 0.0], [-3.0, -4.0, 0.0]])}, WindConfig())["at_uav"]
    np.testing.assert_allclose(out["mean_W_m_s"], 0.0)
    np.testing.assert_allclose(out["std_W_m_s"], [3.0, 4.0, 0.0])
    assert out["max_speed_m_s"] == pytest.approx(5.0)


def test_the_wind_report_gives_the_configured_wind_and_draws_each_axis(tmp_path, monkeypatch):
    """metrics.json's `wind` repeats the configuration (the direction as configured, the number of gusts), and
    wind.png's line for each W axis is the logged air velocity on that axis, over the supervisor's modes shaded."""
    from diagrams import wind_report
    from systems.control.landing import Mode

    config = WindConfig(mean_m_s=5.0, direction_deg=30.0, turbulence="light",
                        gusts=[GustConfig(start_s=1.0, magnitude_m_s=2.0, direction_deg=90.0)])
    t = np.linspace(0.0, 1.0, 4)
    log = {"t": t, "mode": np.array([int(Mode.FOLLOW)] * 2 + [int(Mode.LAND)] * 2),
           "wind": np.column_stack([1.0 + t, -2.0 * t, 0.5 - t])}
    out = wind_metrics(log, config)
    assert (out["mean_m_s"], out["direction_deg"], out["turbulence"], out["gusts"]) == (5.0, 30.0, "light", 1)
    figures = []
    monkeypatch.setattr(wind_report, "save_figure", lambda fig, path: figures.append(fig))
    plot_wind(log, tmp_path)
    lines = {line.get_label(): line.get_ydata() for line in figures[0].axes[0].get_lines()}
    for i, axis in enumerate("xyz"):
        np.testing.assert_allclose(lines[f"wind {axis}"], log["wind"][:, i])
    assert len(figures[0].axes[0].patches) == 2  # the modes shaded: FOLLOW, then LAND
