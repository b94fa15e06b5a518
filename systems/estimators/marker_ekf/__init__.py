"""Pose of the landing pad on the ground vehicle from ArUco marker measurements (seed 002, Sec. 3).

Two discrete-time EKFs with the same measurements, tuning, gate and late-measurement handling,
`FILTERS` by name:
- `PaperMarkerEkf` ("paper_ekf", paper_ekf.py): the paper's 37-state filter, Eq. (11)-(12), a
  constant-velocity position per marker and the pad attitude;
- `ConstantTurnEkf` ("ct_ekf", constant_turn_ekf.py): the pad as one rigid body in a coordinated
  turn, 8 states.
`MarkerFilter` (engine.py) is their common machinery; `MarkerFilterSystem` (system.py) steps one in
a Drake diagram.

Measurements (`MarkerMeasurement`): the pose of marker i in the camera frame C. The camera C is
mounted at X_BC on the UAV body B whose pose X_WB (the UAV's own estimate) is a filter input: the
measurement model is Eq. (12) with the camera offset c of Eq. (4) included (the paper has c = 0):
p_CM = (D^{B/C})^T (D^{B/R} (p_WM - r) - c_B) and q^{M/C} = q^{B/C} (.) (q^{B/R})^-1 (.) q^{P/R}.
W is the paper's reference frame S_R, P the pad frame (at marker 0); quaternions are the paper's,
scalar last (systems/quaternion.py). Eq. (12) labels its position rows p^i_R, but they are the
camera-frame s^i_C of Eq. (4).

Units: m, s, rad. Measurement noise R: `position_std_m` on each position axis (seed 002 Sec. 4:
0.1 m) and `attitude_std_deg` (5 deg) per axis of a rotation vector. The paper gives no process
noise or initial covariance: those defaults are ours, identical for both filters.
"""

from systems.estimators.marker_ekf.constant_turn_ekf import ConstantTurnEkf
from systems.estimators.marker_ekf.engine import (Camera, FilterStats, MarkerEkfConfig, MarkerFilter,
                                                  MarkerFilterEstimate, cv_noise)
from systems.estimators.marker_ekf.paper_ekf import PaperMarkerEkf
from systems.estimators.marker_ekf.system import MarkerFilterSystem

FILTERS = {PaperMarkerEkf.name: PaperMarkerEkf, ConstantTurnEkf.name: ConstantTurnEkf}

__all__ = ["FILTERS", "Camera", "ConstantTurnEkf", "FilterStats", "MarkerEkfConfig", "MarkerFilter",
           "MarkerFilterEstimate", "MarkerFilterSystem", "PaperMarkerEkf", "cv_noise"]
