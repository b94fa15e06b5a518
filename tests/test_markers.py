"""Seed 002 marker layout, pad texture, synthetic measurements, ArUco detection + per-marker PnP, the
measurement latency and the stream as a logged vector."""

import copy

import cv2
import numpy as np
import pytest
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder, LeafSystem
from pydrake.systems.primitives import ConstantVectorSource
from scipy.spatial.transform import Rotation

from systems.config import ConfigError
from systems.noise import sample_rng
from systems.perception.aruco import subpix_detector, to_grey
from systems.perception.latency import MeasurementLatency, delay_queue
from systems.perception.marker_detector import MarkerDetectorSystem, detect_marker_poses
from systems.perception.markers import MarkerLayout, MarkerMeasurement, measurements_vector, pad_texture
from systems.perception.synthetic_markers import (
    STREAM,
    SyntheticMarkerSource,
    noisy_marker_poses,
    synthetic_marker_measurements,
)
from systems.quaternion import drake_to_paper, paper_to_drake
from systems.sensors.camera import CameraConfig, distortion_maps
from tests.conftest import pose, render_plane, rgba

CAMERA = CameraConfig()
K = CAMERA.K
LAYOUT = MarkerLayout()
PAD_M = 1.0  # the default pad's edge (diagrams/gv_landing.PlatformConfig)
LOOKING_DOWN = RotationMatrix.MakeXRotation(np.pi)  # R_CP of a level pad under a level downward camera


def render_pad(X_CP: RigidTransform, supersample: int = 4, background: int = 90,
               camera: CameraConfig = CAMERA) -> np.ndarray:
    """The pad texture as `camera` (default: the default camera, 512x512) sees it at X_CP (grey): the plane's
    homography at `supersample` times the resolution, averaged down (a renderer's antialiasing; render_plane)."""
    return render_plane(pad_texture(LAYOUT, PAD_M), PAD_M, X_CP, camera, supersample, background)


def X_CP_at(height_m: float, xy=(0.03, -0.02), yaw_deg: float = 23.0) -> RigidTransform:
    return RigidTransform(LOOKING_DOWN.multiply(RotationMatrix.MakeZRotation(np.radians(yaw_deg))), [*xy, height_m])


def true_X_CM(X_CP: RigidTransform, marker_id: int) -> RigidTransform:
    return X_CP.multiply(RigidTransform(LAYOUT.p_PM[LAYOUT.index(marker_id)]))


def angle_between(R_a: RotationMatrix, R_b: RotationMatrix) -> float:
    return R_a.InvertAndCompose(R_b).ToAngleAxis().angle()


# ---- layout and texture ----------------------------------------------------------------------


@pytest.mark.parametrize("change, message", [
    (dict(dictionary="DICT_NOPE"), "dictionary"),
    (dict(ids=[0, 1, 2, 3, 3]), "ids"),
    (dict(ids=[0, 1, 2, 3, 50]), "ids"),
    (dict(ids=[], offsets_m=[], sizes_m=[]), "ids"),  # no marker at all, not even the pad frame's
    (dict(sizes_m=[0.2, 0.3, 0.3, 0.3]), "sizes_m"),
    (dict(sizes_m=[0.0, 0.3, 0.3, 0.3, 0.3]), "sizes_m"),  # a size of 0 is not positive
    (dict(offsets_m=[[0.1, 0, 0], [0.3, 0.3, 0], [-0.3, 0.3, 0], [-0.3, -0.3, 0], [0.3, -0.3, 0]]), "offsets_m"),
])
def test_layout_validation_names_the_field(change, message):
    with pytest.raises(ConfigError, match=message):
        MarkerLayout(**change).validate()


@pytest.mark.parametrize("layout, marker_id", [
    (LAYOUT, 1),
    # the corner at (-0.3, -0.3) alone: its reach is |x| (|y|) + half its 0.3 m edge + one cell (a sixth of the edge),
    # 0.3 + 0.15 + 0.05 = 0.5 m, on either side of the centre
    (MarkerLayout(ids=[0, 3], offsets_m=[[0.0, 0.0, 0.0], [-0.3, -0.3, 0.0]], sizes_m=[0.2, 0.3]), 3),
])
def test_layout_must_fit_the_pad_with_its_margins(layout, marker_id):
    layout.validate(pad_size_m=PAD_M)  # corner markers' margins reach the pad's edge exactly
    with pytest.raises(ConfigError, match=f"marker {marker_id} with its margin reaches 0.500 m from the centre, "
                                          "off the 0.99 m pad"):
        layout.validate(pad_size_m=0.99)


CORNERS = [[0.3, 0.3, 0.0], [-0.3, 0.3, 0.0], [-0.3, -0.3, 0.0], [0.3, -0.3, 0.0]]


@pytest.mark.parametrize("offsets, message", [
    # marker 2 on marker 1: pad_texture paints 2 over 1, which is then never seen
    ([[0.0, 0.0, 0.0], [0.3, 0.3, 0.0], [0.3, 0.3, 0.0], *CORNERS[2:]], "marker 1 with its one-cell white margin "
                                                                         "covers part of marker 2"),
    # a corner marker 0.01 m nearer the centre: its margin covers the centre marker's corner
    ([[0.0, 0.0, 0.0], [0.29, 0.29, 0.0], *CORNERS[1:]], "marker 1 with its one-cell white margin covers part of "
                                                         "marker 0"),
    # raised: the texture draws it flat, where the filters would take it 0.25 m up
    ([[0.0, 0.0, 0.0], [0.3, 0.3, 0.25], *CORNERS[1:]], "marker 1's offset z must be 0"),
])
def test_a_layout_the_flat_texture_cannot_draw_is_refused(offsets, message):
    with pytest.raises(ConfigError, match=message):
        MarkerLayout(offsets_m=offsets).validate()


def test_margins_may_meet_a_black_square_and_each_other():
    LAYOUT.validate()  # a corner marker's margin meets the centre marker at one corner point
    # marker-landing-wind's nested nine: four 6 cm markers on the axes 0.2 m out, between the others' margins
    MarkerLayout(ids=list(range(9)), offsets_m=[[0.0, 0.0, 0.0], *CORNERS, [0.2, 0.0, 0.0], [0.0, 0.2, 0.0],
                                                [-0.2, 0.0, 0.0], [0.0, -0.2, 0.0]],
                 sizes_m=[0.2, 0.3, 0.3, 0.3, 0.3, 0.06, 0.06, 0.06, 0.06]).validate()


def test_pad_texture_places_each_marker_where_the_layout_says():
    texture = pad_texture(LAYOUT, PAD_M)
    corners, ids, _ = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)).detectMarkers(
        texture)
    assert sorted(ids.ravel()) == LAYOUT.ids
    scale = texture.shape[0] / PAD_M
    for marker_id, c in zip(ids.ravel(), corners):
        c = c.reshape(4, 2)
        i = LAYOUT.index(marker_id)
        # texel (col, row) -> P: x = (col + 0.5) / scale - 0.5, y = 0.5 - (row + 0.5) / scale
        centre = np.array([(c[:, 0].mean() + 0.5) / scale - 0.5, 0.5 - (c[:, 1].mean() + 0.5) / scale])
        np.testing.assert_allclose(centre, LAYOUT.p_PM[i, :2], atol=1.5 / scale)
        edge = np.linalg.norm(c[1] - c[0]) / scale
        assert edge == pytest.approx(LAYOUT.sizes_m[i], abs=1.5 / scale)
        # upright: ArUco's first corner (top-left of the marker) is up and left in the image
        assert c[0, 0] < c[1, 0] and c[0, 1] < c[3, 1]


def test_a_marker_may_fill_the_whole_pad():
    """One 1 m marker on the 1 m pad: the texture is OpenCV's image of the marker, edge to edge."""
    texture = pad_texture(MarkerLayout(ids=[0], offsets_m=[[0.0, 0.0, 0.0]], sizes_m=[1.0]), 1.0, 1200)
    marker = cv2.aruco.generateImageMarker(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50), 0, 1200,
                                           borderBits=1)
    np.testing.assert_array_equal(texture, marker)


# ---- synthetic measurements (seed 002 Sec. 4) ------------------------------------------------


def test_noise_free_synthetic_measurements_are_the_true_marker_poses():
    X_CP = pose([0.4, -0.2, 3.0], [175, 4, 60])
    measurements = synthetic_marker_measurements(X_CP, LAYOUT, np.random.default_rng(0), 0.0, 0.0, time=1.5)
    assert [m.marker_id for m in measurements] == LAYOUT.ids
    for m in measurements:
        X_CM = true_X_CM(X_CP, m.marker_id)
        np.testing.assert_allclose(m.p_CM, X_CM.translation(), atol=1e-12)
        assert angle_between(RotationMatrix(paper_to_drake(m.q_CM)), X_CM.rotation()) < 1e-9
        assert m.time == 1.5


def test_synthetic_noise_has_the_papers_standard_deviations():
    X_CP = pose([0.1, 0.2, 3.0], [180, 0, 30])
    rng = np.random.default_rng(1)
    p_errors, angle_errors = [], []
    for _ in range(400):
        for m in synthetic_marker_measurements(X_CP, LAYOUT, rng):
            X_CM = true_X_CM(X_CP, m.marker_id)
            p_errors.append(m.p_CM - X_CM.translation())
            dR = X_CM.rotation().inverse().multiply(RotationMatrix(paper_to_drake(m.q_CM)))  # Exp(dtheta), in M
            angle_errors.append(Rotation.from_matrix(dR.matrix()).as_rotvec())
    p_errors, angle_errors = np.array(p_errors), np.degrees(angle_errors)
    np.testing.assert_allclose(p_errors.mean(axis=0), 0.0, atol=0.01)
    np.testing.assert_allclose(p_errors.std(axis=0), 0.1, rtol=0.05)
    np.testing.assert_allclose(angle_errors.mean(axis=0), 0.0, atol=0.5)
    np.testing.assert_allclose(angle_errors.std(axis=0), 5.0, rtol=0.05)


def test_the_attitude_noise_is_a_rotation_vector_in_the_marker_frame():
    """R_CM = R_CP Exp(dtheta), the noise in the marker frame (noisy_marker_poses): with a fixed dtheta per marker
    and the pad at a general attitude, R_CP^T R_CM is SciPy's Exp(dtheta) (noise in C would make it
    R_CM R_CP^T instead); the position noise simply adds."""
    R_CP = RotationMatrix(RollPitchYaw(2.0, 0.3, 0.7))
    dtheta = np.array([[0.05, -0.02, 0.08], [-0.3, 0.1, 0.2]])
    dp = np.array([[0.01, 0.02, -0.03], [0.0, -0.1, 0.2]])
    p_CM = np.array([[0.1, 0.2, 3.0], [-0.4, 0.0, 2.5]])
    p, q = noisy_marker_poses(p_CM, drake_to_paper(R_CP), dp, dtheta)
    np.testing.assert_allclose(p, p_CM + dp, atol=1e-15)
    for q_CM, d in zip(q, dtheta, strict=True):
        R_CM = RotationMatrix(paper_to_drake(q_CM)).matrix()
        np.testing.assert_allclose(R_CP.matrix().T @ R_CM, Rotation.from_rotvec(d).as_matrix(), atol=1e-12)


@pytest.mark.parametrize("noise", [{"sigma_p": -0.1}, {"sigma_deg": -1.0}])
def test_negative_synthetic_noise_is_refused(noise):
    with pytest.raises(ConfigError, match="marker measurement noise must not be negative"):
        SyntheticMarkerSource(LAYOUT, CAMERA.X_BC, **noise)


def test_the_synthetic_source_refuses_a_bad_layout():
    """A layout with marker id 0 twice is a ConfigError naming the ids when the source is built."""
    with pytest.raises(ConfigError, match="ids"):
        SyntheticMarkerSource(MarkerLayout(ids=[0, 0, 1, 2, 3]), CAMERA.X_BC)


def test_measurements_are_immutable_and_copies_share_them():
    m = MarkerMeasurement(0.0, 0, [0.0, 0.0, 1.0], [0.0, 0.0, 0.0, 1.0])
    with pytest.raises(ValueError):
        m.p_CM[0] = 1.0
    assert copy.deepcopy([m])[0] is m
    np.testing.assert_allclose(m.X_CM.translation(), [0, 0, 1])


def test_the_pose_of_a_measurement_normalises_its_quaternion():
    """A quaternion of norm 2, the paper's scalar-last [0, 0, 1.2, 1.6]: X_CM turns by its unit quaternion's angle
    about z, 2 atan2(0.6, 0.8), where Drake refuses the raw quaternion."""
    X_CM = MarkerMeasurement(0.0, 0, [0.0, 0.0, 1.0], [0.0, 0.0, 1.2, 1.6]).X_CM
    assert angle_between(X_CM.rotation(), RotationMatrix.MakeZRotation(2 * np.arctan2(0.6, 0.8))) < 1e-12
    np.testing.assert_allclose(X_CM.translation(), [0, 0, 1])


def fixed_pose_source(source: SyntheticMarkerSource, X_WB: RigidTransform, X_WP: RigidTransform):
    context = source.CreateDefaultContext()
    source.GetInputPort("X_WB").FixValue(context, X_WB)
    source.GetInputPort("X_WP").FixValue(context, X_WP)
    return context


@pytest.mark.parametrize("settings, time, seed, sample", [
    (dict(period_s=0.035, seed=3), 0.35, 3, 10),
    # the defaults: seed 0 and seed 002's T_s of 35 ms (Sec. 4: 25 ms to acquire a frame, 10 to process it), so
    # 0.105 s is sample 3
    (dict(), 0.105, 0, 3),
])
def test_synthetic_source_system_samples_seeded_noise_per_sample(settings, time, seed, sample):
    X_WB, X_WP = pose([1.0, 2.0, 5.0], [2, -3, 40]), pose([1.2, 1.9, 1.6], [0, 0, 10])
    source = SyntheticMarkerSource(LAYOUT, CAMERA.X_BC, **settings)
    context = fixed_pose_source(source, X_WB, X_WP)
    context.SetTime(time)
    measurements = source.get_output_port().Eval(context)
    X_CP = X_WB.multiply(CAMERA.X_BC).InvertAndCompose(X_WP)
    expected = synthetic_marker_measurements(X_CP, LAYOUT, sample_rng(seed, STREAM, sample), time=time)
    for m, e in zip(measurements, expected, strict=True):
        np.testing.assert_allclose(m.p_CM, e.p_CM, atol=1e-12)
        np.testing.assert_allclose(m.q_CM, e.q_CM, atol=1e-12)
        assert m.time == time


class SampleCounter(LeafSystem):
    """A stand-in sensor: at sample k its list of measurements is [k]."""

    def __init__(self, period_s: float):
        super().__init__()
        self.DeclareAbstractOutputPort("measurements", lambda: AbstractValue.Make([]),
                                       lambda c, o: o.set_value([round(c.get_time() / period_s)]))


def _counted_latency(delay_steps: int):
    """A MeasurementLatency of `delay_steps` on the sample counter at 35 ms: (it, its simulator, its context)."""
    builder = DiagramBuilder()
    sensor = builder.AddSystem(SampleCounter(0.035))
    latency = builder.AddSystem(MeasurementLatency(0.035, delay_steps))
    builder.Connect(sensor.get_output_port(), latency.get_input_port())
    simulator = Simulator(builder.Build())
    context = latency.GetMyContextFromRoot(simulator.get_context())
    return latency, simulator, context


@pytest.mark.parametrize("delay_steps", [0, 1, 2])
def test_the_latency_delivers_what_was_acquired_whole_samples_before(delay_steps):
    latency, simulator, context = _counted_latency(delay_steps)
    queue = ()
    for k in range(6):
        simulator.AdvanceTo(k * 0.035)  # before this time's update (but t = 0's, done by the first AdvanceTo)
        expected = [] if k < delay_steps else [k - delay_steps]
        if k > 0:
            assert latency.get_output_port().Eval(context) == expected
        queue, due = delay_queue(queue, [k], delay_steps)  # the pure queue, one sample at a time
        assert due == expected


def test_the_latency_delays_one_value_or_a_vector_too():
    builder = DiagramBuilder()
    sensor = builder.AddSystem(SampleCounter(0.035))
    one = builder.AddSystem(MeasurementLatency(0.035, 2, model_value=("none yet",)))
    vector = builder.AddSystem(MeasurementLatency(0.035, 1, model_value=np.full(2, np.nan)))
    source = builder.AddSystem(ConstantVectorSource([4.0, 5.0]))
    builder.Connect(sensor.get_output_port(), one.get_input_port())
    builder.Connect(source.get_output_port(), vector.get_input_port())
    simulator = Simulator(builder.Build())
    one_context, vector_context = (s.GetMyContextFromRoot(simulator.get_context()) for s in (one, vector))
    # Between samples the output holds what was due at the sample before (as in the test below).
    simulator.AdvanceTo(0.035 * 0.5)
    assert one.get_output_port().Eval(one_context) == ("none yet",)
    assert np.isnan(vector.get_output_port().Eval(vector_context)).all()  # acquired at t_0, due from t_1
    simulator.AdvanceTo(0.035 * 1.5)
    np.testing.assert_array_equal(vector.get_output_port().Eval(vector_context), [4.0, 5.0])
    simulator.AdvanceTo(0.035 * 3.5)
    assert one.get_output_port().Eval(one_context) == [1]  # acquired at t_1, due from t_3 until t_4


def test_without_delay_the_output_follows_a_new_input_at_the_same_time():
    # delay 0 passes the input through: the output depends on the input, not only on the time, so a new input at
    # the same time is the new output, not a stale cached one
    latency = MeasurementLatency(0.035, 0)
    context = latency.CreateDefaultContext()
    latency.get_input_port().FixValue(context, AbstractValue.Make([1]))
    assert latency.get_output_port().Eval(context) == [1]
    latency.get_input_port().FixValue(context, AbstractValue.Make([2]))
    assert latency.get_output_port().Eval(context) == [2]


@pytest.mark.parametrize("delay_steps", [1, 2])
def test_the_latency_holds_between_samples_and_after_their_update(delay_steps):
    # Read at any time t in [t_k, t_{k+1}), before or after the update at t_k: what was acquired at t_{k-d}.
    latency, simulator, context = _counted_latency(delay_steps)
    for k in range(1, 7):
        expected = [] if k < delay_steps else [k - delay_steps]
        simulator.AdvanceTo(k * 0.035)
        assert latency.get_output_port().Eval(context) == expected, (k, "before its update")
        simulator.AdvancePendingEvents()
        assert latency.get_output_port().Eval(context) == expected, (k, "after its update")
        for fraction in (0.3, 0.9):
            simulator.AdvanceTo((k + fraction) * 0.035)
            assert latency.get_output_port().Eval(context) == expected, (k + fraction, "between samples")


def test_a_latency_must_be_whole_samples():
    with pytest.raises(ConfigError, match="delay_steps"):
        MeasurementLatency(0.035, -1)


def test_the_stream_as_a_vector_has_nan_for_markers_not_measured():
    X_CP = pose([0.4, -0.2, 3.0], [175, 4, 60])
    measurements = synthetic_marker_measurements(X_CP, LAYOUT, np.random.default_rng(0))
    measured = [measurements[0], measurements[3], MarkerMeasurement(0.0, 42, [0, 0, 1], [0, 0, 0, 1])]
    vector = measurements_vector(measured, LAYOUT).reshape(5, 7)
    np.testing.assert_array_equal(vector[0], np.r_[measurements[0].p_CM, measurements[0].q_CM])
    np.testing.assert_array_equal(vector[3], np.r_[measurements[3].p_CM, measurements[3].q_CM])
    assert np.isnan(vector[[1, 2, 4]]).all()  # and the unknown id 42 is nowhere


# ---- the real pipeline: ArUco detection and per-marker solvePnP -------------------------------


def test_a_marker_measured_twice_is_nan_in_the_stream_vector():
    """Two measurements of one marker in a sample are ambiguous: its row is NaN; a marker measured once is logged."""
    twice = MarkerMeasurement(0.0, LAYOUT.ids[1], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0, 1.0])
    once = MarkerMeasurement(0.0, LAYOUT.ids[2], [0.1, 0.2, 1.5], [0.0, 0.0, 0.6, 0.8])
    vector = measurements_vector([twice, once, twice], LAYOUT).reshape(5, 7)
    assert np.isnan(vector[[0, 1, 3, 4]]).all()
    np.testing.assert_array_equal(vector[2], [0.1, 0.2, 1.5, 0.0, 0.0, 0.6, 0.8])


@pytest.mark.parametrize("p_CM, q_CM, norm", [
    ([0.0, 0.0, 1.0], [0.0, 0.0, 0.6, 0.8], 1.0), ([0.0, 0.0, 1.0], [0.0, 0.0, 1.2, 1.6], 2.0),
    ([0.0, 1.0], [0.0, 0.0, 0.6, 0.8], np.nan), ([0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.6, 0.8], np.nan),
    ([0.0, 0.0, 1.0], [0.0, 0.6, 0.8], np.nan), ([0.0, np.nan, 1.0], [0.0, 0.0, 0.6, 0.8], np.nan)])
def test_a_malformed_measurement_has_a_nan_quaternion_norm(p_CM, q_CM, norm):
    """quaternion_norm is |q_CM| for a well-formed, finite measurement; NaN for a p_CM not of 3 numbers, a q_CM not
    of 4, or a non-finite entry."""
    np.testing.assert_equal(MarkerMeasurement(0.0, 0, p_CM, q_CM).quaternion_norm, norm)


def test_detected_marker_poses_match_the_truth():
    X_CP = X_CP_at(2.0)
    measurements = detect_marker_poses(render_pad(X_CP), K, LAYOUT, time=0.7)
    assert sorted(m.marker_id for m in measurements) == LAYOUT.ids
    for m in measurements:
        X_CM = true_X_CM(X_CP, m.marker_id)
        assert np.linalg.norm(m.p_CM - X_CM.translation()) < 0.02  # m, at 2 m
        # one small square's tilt is weakly observed (the centre marker spans 46 px here); its yaw is not
        assert np.degrees(angle_between(m.X_CM.rotation(), X_CM.rotation())) < 5.0
        R_error = m.X_CM.rotation().matrix() @ X_CM.rotation().matrix().T
        assert abs(np.degrees(np.arctan2(R_error[1, 0], R_error[0, 0]))) < 1.0
        assert np.linalg.norm(m.q_CM) == pytest.approx(1.0)
        assert m.time == 0.7


def measured_by_the_system(grey: np.ndarray, K: np.ndarray, layout: MarkerLayout, D=None) -> list:
    """MarkerDetectorSystem's measurements of a grey frame given as its colour image."""
    system = MarkerDetectorSystem(K, layout, grey.shape[1], grey.shape[0], D=D)
    context = system.CreateDefaultContext()
    system.get_input_port().FixValue(context, rgba(grey))
    return system.get_output_port().Eval(context)


@pytest.mark.parametrize("measure", [detect_marker_poses, measured_by_the_system])
def test_a_distorted_image_is_measured_through_the_lens_model(measure):
    # Barrel distortion remapped onto the render, as NoisyCamera applies it: with D the detector undoes it;
    # without, the markers off the axis come out centimetres off. The detector system passes its D on.
    lens = CameraConfig(distortion=[-0.2, 0.0, 0.0, 0.0, 0.0])
    X_CP = X_CP_at(2.0, xy=(0.35, 0.25))
    distorted = cv2.remap(render_pad(X_CP), *distortion_maps(lens), cv2.INTER_LINEAR)

    def worst_error(D):
        measurements = measure(distorted, K, LAYOUT, D=D)
        assert len(measurements) >= 4
        return max(np.linalg.norm(m.p_CM - true_X_CM(X_CP, m.marker_id).translation()) for m in measurements)

    assert worst_error(lens.D) < 0.02  # m, at 2 m: as the undistorted image's
    assert worst_error(None) > 0.03


def test_a_tilted_view_gives_the_tilted_pose():
    X_CP = RigidTransform(LOOKING_DOWN.multiply(RotationMatrix(Rotation.from_euler("xyz", [12, -8, 70], degrees=True)
                                                               .as_matrix())), [0.1, 0.05, 2.5])
    measurements = detect_marker_poses(render_pad(X_CP), K, LAYOUT)
    assert len(measurements) >= 4
    for m in measurements:
        assert np.degrees(angle_between(m.X_CM.rotation(), X_CP.rotation())) < 5.0


def test_range_of_the_layout_centre_marker_close_up_and_corner_markers_from_10_m():
    close = detect_marker_poses(render_pad(X_CP_at(0.36)), K, LAYOUT)  # the end of the descent
    assert [m.marker_id for m in close] == [0]
    assert np.linalg.norm(close[0].p_CM - true_X_CM(X_CP_at(0.36), 0).translation()) < 0.005
    far = detect_marker_poses(render_pad(X_CP_at(10.0)), K, LAYOUT)
    assert {1, 2, 3, 4} <= {m.marker_id for m in far}


def test_markers_out_of_view_are_simply_absent():
    X_CP = X_CP_at(1.0, xy=(0.55, 0.55), yaw_deg=0.0)  # the camera over the rear-right corner of the pad
    measurements = detect_marker_poses(render_pad(X_CP), K, LAYOUT)
    seen = {m.marker_id for m in measurements}
    assert 0 < len(seen) < 5
    for m in measurements:
        assert np.linalg.norm(m.p_CM - true_X_CM(X_CP, m.marker_id).translation()) < 0.02
    assert detect_marker_poses(np.full((512, 512, 3), 128, np.uint8), K, LAYOUT) == []


def test_a_marker_seen_twice_and_one_outside_the_layout_are_not_measured():
    """Marker 1 drawn twice (which copy is the pad's is unknown) and marker 49 (in the dictionary, not in the
    layout): neither is measured; marker 2, drawn once, is."""
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, LAYOUT.dictionary))
    image = np.full((512, 512), 200, np.uint8)
    for marker_id, (row, col) in [(1, (60, 60)), (1, (60, 300)), (2, (300, 60)), (49, (300, 300))]:
        image[row:row + 120, col:col + 120] = cv2.aruco.generateImageMarker(dictionary, marker_id, 120)
    assert 49 not in LAYOUT.ids
    assert [m.marker_id for m in detect_marker_poses(image, K, LAYOUT)] == [2]


def test_one_threshold_window_is_the_detectors_only_window():
    """subpix_detector with a threshold window sets OpenCV's smallest and largest adaptive windows both to it
    (one thresholding pass), and without one keeps OpenCV's defaults (3 to 23 px)."""
    one = subpix_detector(LAYOUT.dictionary, 13).getDetectorParameters()
    assert (one.adaptiveThreshWinSizeMin, one.adaptiveThreshWinSizeMax) == (13, 13)
    default, opencv = subpix_detector(LAYOUT.dictionary).getDetectorParameters(), cv2.aruco.DetectorParameters()
    assert (default.adaptiveThreshWinSizeMin, default.adaptiveThreshWinSizeMax) == (
        opencv.adaptiveThreshWinSizeMin, opencv.adaptiveThreshWinSizeMax)
    assert default.cornerRefinementMethod == one.cornerRefinementMethod == cv2.aruco.CORNER_REFINE_SUBPIX


def test_to_grey_reads_rgb_and_rgba_as_rgb():
    """Random colours (red and blue weigh differently in the grey): an RGB and an RGBA image give OpenCV's
    RGB-to-grey, a grey image is returned as it is."""
    rgb = np.random.default_rng(0).integers(0, 256, (16, 16, 3), np.uint8)
    expected = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    assert not np.array_equal(expected, cv2.cvtColor(rgb, cv2.COLOR_BGR2GRAY))
    np.testing.assert_array_equal(to_grey(rgb), expected)
    np.testing.assert_array_equal(to_grey(np.dstack([rgb, np.full((16, 16), 255, np.uint8)])), expected)
    assert to_grey(expected) is expected


def test_detector_system_reads_the_colour_image():
    system = MarkerDetectorSystem(K, LAYOUT, CAMERA.width, CAMERA.height)
    context = system.CreateDefaultContext()
    context.SetTime(1.05)
    system.get_input_port().FixValue(context, AbstractValue.Make(rgba(render_pad(X_CP_at(2.0)))))
    measurements = system.get_output_port().Eval(context)
    assert sorted(m.marker_id for m in measurements) == LAYOUT.ids
    assert all(m.time == 1.05 for m in measurements)
    assert drake_to_paper(measurements[0].X_CM.rotation()) @ measurements[0].q_CM == pytest.approx(1.0, abs=1e-9)
