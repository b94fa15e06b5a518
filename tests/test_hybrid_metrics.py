"""The UGV detector's scores (diagrams/hybrid_metrics.detection_scores) on constructed boxes."""

import numpy as np
import pytest

from diagrams.hybrid_metrics import detection_scores


@pytest.mark.parametrize("found, expected", [([400.0, 300.0, 40.0, 30.0], 0.0), ([100.0, 100.0, 40.0, 30.0], 1.0)])
def test_f1_is_zero_when_no_box_matches_and_one_when_every_box_does(found, expected):
    truth = [np.array([100.0, 100.0, 40.0, 30.0])] * 20  # the UGV in view in every frame: [x, y, w, h] px
    detections = np.zeros((20, 15))
    detections[:, 0], detections[:, 1:5] = 1.0, found  # one box a frame
    scores = detection_scores(detections, truth)
    assert scores["precision"] == scores["recall"] == scores["f1"] == expected
