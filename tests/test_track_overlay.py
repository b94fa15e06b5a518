"""--video for the hybrid source: the fisheye stream with the detector's boxes and the tracker's target drawn
(systems/viewers.py `draw_boxes`, `TrackOverlay`), and the scene's recorder wired to it."""

import cv2
import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.sensors import ImageRgba8U

from diagrams.gv_landing import build_gv_landing
from diagrams.runner import load_scenario
from systems.viewers import TrackOverlay, VideoRecorder, draw_boxes

GREEN, ORANGE, YELLOW = (0, 230, 0), (255, 140, 0), (255, 220, 0)


def test_draw_boxes_marks_each_box_and_leaves_the_input():
    image = np.full((100, 120, 4), 50, np.uint8)
    drawn = draw_boxes(image, [(np.array([10.0, 20.0, 30.0, 15.0]), 0.9)], np.array([60.0, 40.0, 20.0, 20.0]), True,
                       np.array([3.0, 1.0]))
    assert drawn.shape == (100, 120, 3) and np.all(image == 50)
    assert tuple(drawn[20, 25]) == YELLOW and tuple(drawn[34, 25]) == YELLOW  # the detection's top and bottom
    assert tuple(drawn[40, 70]) == GREEN and tuple(drawn[50, 60]) == GREEN  # the locked, matched target
    assert tuple(drawn[5, 5]) == (50, 50, 50)
    predicted = draw_boxes(image, [], np.array([60.0, 40.0, 20.0, 20.0]), True, np.array([3.0, 0.0]))
    assert tuple(predicted[40, 70]) == ORANGE
    assert np.all(draw_boxes(image, [], np.full(4, np.nan), False, np.array([-1.0, 0.0])) == 50)
    # a finite box whose track is not valid (a lost target's last box) is not drawn either
    assert np.all(draw_boxes(image, [], np.array([60.0, 40.0, 20.0, 20.0]), False, np.array([3.0, 1.0])) == 50)


def test_overlay_system_outputs_the_drawn_frame():
    overlay = TrackOverlay(120, 100)
    context = overlay.CreateDefaultContext()
    frame = ImageRgba8U(120, 100)
    frame.mutable_data[:] = 50
    overlay.GetInputPort("color_image").FixValue(context, frame)
    overlay.GetInputPort("detections").FixValue(context, [])
    overlay.GetInputPort("target_box").FixValue(context, [60.0, 40.0, 20.0, 20.0])
    overlay.GetInputPort("target_valid").FixValue(context, [1.0])
    overlay.GetInputPort("lock").FixValue(context, [3.0, 1.0])
    out = overlay.GetOutputPort("image").Eval(context).data
    assert tuple(out[40, 70]) == (*GREEN, 255) and tuple(out[5, 5]) == (50, 50, 50, 255)


def test_hybrid_scene_records_its_own_stream(tmp_path):
    _, scenario = load_scenario("ugv-hybrid")
    assert scenario.has_video and scenario.camera() is None
    _, handles = build_gv_landing(scenario, video_path=tmp_path / "camera.mp4")
    assert isinstance(handles.video, VideoRecorder) and handles.video.path == tmp_path / "camera.mp4"
    assert list(tmp_path.iterdir()) == []  # the recorder opens its file at the first frame, not while built
    handles.video.discard()
    _, plain = load_scenario("gv-landing")
    assert not plain.has_video


def test_the_recorder_writes_its_partial_file_from_the_first_frame_and_renames_it_when_finished(tmp_path):
    recorder = VideoRecorder(tmp_path / "camera.mp4", 0.1, 32, 24)
    assert list(tmp_path.iterdir()) == []
    simulator = Simulator(recorder)
    recorder.get_input_port().FixValue(simulator.get_mutable_context(), ImageRgba8U(32, 24))
    simulator.AdvanceTo(0.25)  # three frames
    assert [p.name for p in tmp_path.iterdir()] == [".camera.partial.mp4"]
    recorder.finish()
    assert [p.name for p in tmp_path.iterdir()] == ["camera.mp4"]


def test_the_recorder_writes_the_frames_colours_at_the_camera_rate(tmp_path):
    """Red RGBA frames every 0.1 s come back from the finished video, read by cv2.VideoCapture, as red (BGR
    (0, 0, 255) within the codec's error), 10 frames at 10 frames per second."""
    recorder = VideoRecorder(tmp_path / "camera.mp4", 0.1, 64, 48)
    simulator = Simulator(recorder)
    red = ImageRgba8U(64, 48)
    red.mutable_data[:] = (255, 0, 0, 255)
    recorder.get_input_port().FixValue(simulator.get_mutable_context(), red)
    simulator.AdvanceTo(0.95)  # frames at 0, 0.1, ..., 0.9 s
    recorder.finish()
    capture = cv2.VideoCapture(str(tmp_path / "camera.mp4"))
    try:
        fps, frames = capture.get(cv2.CAP_PROP_FPS), []
        while (frame := capture.read())[0]:
            frames.append(frame[1])
    finally:
        capture.release()
    assert fps == pytest.approx(10.0) and len(frames) == 10
    assert np.abs(np.array(frames, dtype=float) - [0.0, 0.0, 255.0]).max() < 10
