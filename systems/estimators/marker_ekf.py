"""Pose of the landing pad on the ground vehicle from ArUco marker measurements (seed 002, Sec. 3).

Two discrete-time EKFs with the same measurements, tuning, gate and late-measurement handling:

- `PaperMarkerEkf` ("paper_ekf"): the paper's 37-state filter, Eq. (11)-(12): each of the five
  markers has its own constant-velocity position (6 states each, in the World frame W, the paper's
  S_R), plus the pad attitude q^{P/R} (scalar last, quaternion.py) and angular velocity omega (in P)
  under constant angular velocity. The markers are not tied to each other or to the attitude.
- `ConstantTurnEkf` ("ct_ekf"): why the paper's filter degrades with speed (its Sec. 4 and 5): its
  model says every marker moves in a straight line at constant velocity, but the vehicle turns, so
  the error in each 35 ms prediction is the centripetal acceleration v^2 kappa (3.5 m/s^2 at
  12 m/s on Eq. 13's path against 0.2 m/s^2 at 3 m/s) and the filter lags on every bend. This
  filter models the pad as the rigid body it is, turning at a constant rate (the coordinated-turn
  model, Bar-Shalom et al. [10]): state [p_WP (3), v_WP (3), yaw psi, yaw rate omega],
  the horizontal velocity rotating at omega (exact for any point of a car in a steady turn, wherever
  the pad sits on it), the pad level; each marker is p_WP + R_z(psi) p_PM_i with the layout's
  known offsets, so all five markers and their attitudes inform one 8-state pose.

Measurements (`MarkerMeasurement`): the pose of marker i in the camera frame C. The camera C is
mounted at X_BC on the UAV body B whose pose X_WB (the UAV's own estimate) is a filter input: the
measurement model is Eq. (12) with the camera offset c of Eq. (4) included (the paper has c = 0):
p_CM = (D^{B/C})^T (D^{B/R} (p_WM - r) - c_B) and q^{M/C} = q^{B/C} (.) (q^{B/R})^-1 (.) q^{P/R}.
A measured quaternion is sign-aligned with the prediction (q and -q are the same attitude) before
the paper's additive innovation; `ConstantTurnEkf` takes the attitude innovation as the rotation
vector of q_meas (x) q_pred^-1 (both W-relative, Eq. 5) instead.

Common machinery (`MarkerFilter`):
- update: the EKF of Sec. 3 with the Joseph-form covariance as the paper writes it, on the stacked
  rows of the markers seen in the step (any subset), quaternion renormalised after the update;
- a chi-square gate per marker measurement: its innovation's normalised squared length against
  the chi-square quantile `gate_probability` for the row count; rejected ones are counted, and
  after `reset_after_rejected_steps` steps in a row whose measurements were all rejected, the
  filter restarts from the newest ones (a lost track must not gate out the truth for ever);
- screening: NaN, a quaternion whose norm is off 1 by more than `max_quaternion_norm_error`, an
  unknown marker id, or a time in the future: rejected and counted, never fused;
- late measurements: seed 002 budgets 25 ms to acquire a frame and 10 ms to process it, so a
  measurement of time t_m can arrive a step or more later. The filter keeps `history_s` of steps
  (time, UAV pose, the measurements of (previous step, step], posterior); a late measurement joins
  the step it was taken in and the filter re-runs from there, so it is fused exactly as if it had
  arrived on time (the UAV pose at t_m comes from the history; between two steps it is
  interpolated). Older than the history: rejected and counted as too late.

Reading the paper: Eq. (12) labels its position rows p^i_R, but they are the camera-frame s^i_C
of Eq. (4); its Eq. (11) omega is written like Eq. (7)'s omega_R, but Xi(q) omega / 2 is the
kinematics of a body-frame rate, so omega here is in P (the same for a pad turning about the
vertical); the typos of Eq. (3) and of the DCM are fixed in quaternion.py.

Units: m, s, rad. Measurement noise R: `position_std_m` on each position axis (seed 002 Sec. 4:
0.1 m); the attitude's `attitude_std_deg` (5 deg) is per axis of a rotation vector, which is
(sigma/2)^2 on each quaternion component for the paper's filter. The paper gives no process
noise or initial covariance: those defaults are ours, identical for both filters.
"""

import copy
import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.framework import LeafSystem, ValueProducer
from scipy.stats import chi2

from systems.config import require, require_positive
from systems.estimators.estimate import PoseEstimate
from systems.geometry import wrap_angle
from systems.estimators.quaternion import (dcm, drake_to_paper, inverse, odot_matrix, omega_matrix, paper_to_drake,
                                           rotation_vector, xi)
from systems.perception.markers import MarkerLayout, MarkerMeasurement

TIME_TOLERANCE_S = 1e-9


@dataclass
class MarkerEkfConfig:
    """Tuning shared by both filters (seed 002 values cited; the others are ours)."""

    period_s: float = 0.035  # T_s, seed 002 Sec. 4: 25 ms to acquire a frame plus 10 ms to process it
    position_std_m: float = 0.1  # R, seed 002 Sec. 4
    attitude_std_deg: float = 5.0  # R, seed 002 Sec. 4
    acceleration_psd: float = 0.5  # white horizontal acceleration, m^2/s^3 (paper filter: noise at 3 vs lag at 12 m/s)
    vertical_acceleration_psd: float = 0.01  # white vertical acceleration, m^2/s^3
    angular_acceleration_psd: float = 0.001  # white angular acceleration, rad^2/s^3
    initial_velocity_std_mps: float = 15.0  # the vehicle's speed is unknown at the first measurement
    initial_angular_velocity_std_radps: float = 0.5
    gate_probability: float = 0.9999  # chi-square gate per marker measurement
    reset_after_rejected_steps: int = 10  # steps in a row with every measurement gated out
    history_s: float = 0.5  # how late a measurement may arrive and still be fused
    max_quaternion_norm_error: float = 0.05  # | |q| - 1 | above this: the measurement is rejected
    max_valid_position_std_m: float = 1.0  # the estimate is valid while the pad's position std is below this

    def validate(self, prefix: str = "filter") -> None:
        for name in ("period_s", "position_std_m", "attitude_std_deg", "acceleration_psd",
                     "vertical_acceleration_psd", "angular_acceleration_psd", "initial_velocity_std_mps",
                     "initial_angular_velocity_std_radps", "max_quaternion_norm_error",
                     "max_valid_position_std_m"):
            require_positive(getattr(self, name), f"{prefix}.{name}")
        require(0 < self.gate_probability < 1, f"{prefix}.gate_probability must be in (0, 1)")
        require(self.reset_after_rejected_steps >= 1, f"{prefix}.reset_after_rejected_steps must be at least 1")
        require(self.history_s >= 0, f"{prefix}.history_s must not be negative")


@dataclass(frozen=True)
class FilterStats:
    """Counts of marker measurements (one per marker per frame) and of restarts."""

    accepted: int = 0  # fused (or used to start the filter)
    gated: int = 0  # rejected by the chi-square gate
    invalid: int = 0  # NaN, non-unit quaternion, unknown marker id, or time in the future
    too_late: int = 0  # older than the history
    resets: int = 0  # restarts after reset_after_rejected_steps fully gated steps

    def __add__(self, other: "FilterStats") -> "FilterStats":
        return FilterStats(self.accepted + other.accepted, self.gated + other.gated, self.invalid + other.invalid,
                           self.too_late + other.too_late, self.resets + other.resets)


@dataclass(frozen=True)
class MarkerFilterEstimate:
    """What a filter says about the pad at `pose.time`: pose.X_RT is X_WP (the pad frame P at
    marker 0), pose.covariance is over [roll, pitch, yaw, x, y, z]; p_WM (n, 3) the marker centres
    in W [m]; yaw_rad the heading of P's x axis from W's x axis. NaN arrays when not started."""

    pose: PoseEstimate
    p_WM: np.ndarray
    yaw_rad: float


class Camera(NamedTuple):
    """The camera's pose at one instant, in the forms Eq. (4), (5) and (12) use."""

    p_WB: np.ndarray  # r, the UAV position in W [m]
    q_BR: np.ndarray  # q^{B/R}, the UAV attitude (paper quaternion of R_WB)
    R_CW: np.ndarray  # (D^{B/C})^T D^{B/R}
    p_WC: np.ndarray  # r + c: the camera's position in W [m]
    Q_RC: np.ndarray  # [q^{B/C} (.)] [(q^{B/R})^-1 (.)] = [q^{R/C} (.)]: q^{M/C} = Q_RC q^{M/R}, Eq. (12)

    @property
    def M_CR(self) -> np.ndarray:
        """[q^{C/R} (.)]: q^{M/R} = q^{M/C} (x) q^{C/R} = M_CR q^{M/C}, Eq. (5), with q^{C/R} =
        (q^{R/C})^-1; [q^-1 (.)] = [q (.)]^T, so it is Q_RC^T."""
        return self.Q_RC.T


class _Belief(NamedTuple):
    time: float
    x: np.ndarray
    P: np.ndarray


class _Step(NamedTuple):
    """One filter step of the history."""

    time: float
    camera: Camera
    measurements: tuple  # MarkerMeasurements taken in (previous step's time, time]
    belief: _Belief | None  # posterior at `time`; None before the filter has started
    stats: FilterStats  # accepted, gated and resets of this step
    gated_streak: int  # steps in a row, up to this one, whose measurements were all gated out


def cv_noise(psd: float, dt: float) -> np.ndarray:
    """2x2 covariance of [position, velocity] after dt under white acceleration of spectral
    density psd: psd [[dt^3/3, dt^2/2], [dt^2/2, dt]]."""
    return psd * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])


class MarkerFilter:
    """A marker filter's common machinery (module docstring). Subclasses give the model:
    `n` states, `rows` rows per marker measurement, and the methods marked model hooks.

    Use: `step(t, X_WB, measurements)` once per period (t increasing), then `estimate(t)`.
    Copying a filter is cheap (copy.deepcopy shares its immutable history), so a Drake abstract
    state can hold one.
    """

    name = ""
    n = 0
    rows = 0

    def __init__(self, layout: MarkerLayout, X_BC: RigidTransform, config: MarkerEkfConfig | None = None):
        layout.validate()
        self.config = config or MarkerEkfConfig()
        self.config.validate()
        self.layout = layout
        self.p_PM = layout.p_PM
        self._slot = {marker_id: i for i, marker_id in enumerate(layout.ids)}
        self._q_BC = drake_to_paper(X_BC.rotation().inverse())  # q^{B/C}: D^{B/C} = R_BC
        self._D_CB = dcm(self._q_BC).T  # (D^{B/C})^T
        self._c_B = X_BC.translation().copy()  # c, the camera's position in B
        self._odot_q_BC = odot_matrix(self._q_BC)
        sigma_q = np.radians(self.config.attitude_std_deg)
        self._sigma_q = sigma_q
        self._R_marker = self.marker_noise(self.config.position_std_m, sigma_q)
        self._gate = chi2.ppf(self.config.gate_probability, self.rows)
        self._R_stacked: dict[int, np.ndarray] = {}  # shared by copies: a cache of constants
        self._constants_by_dt: dict[float, object] = {}  # shared by copies, like _R_stacked
        # Predictions already made, by (id of the prior belief, time): a late measurement re-runs
        # the step it belongs to from the same prior to the same time (a pure function of both).
        # Holds the prior, so its id stays its own while cached; shared by copies like the above.
        self._predictions: dict[tuple[int, float], tuple[_Belief, _Belief]] = {}
        self._I = np.eye(self.n)
        self._history: tuple[_Step, ...] = ()
        self._settled = FilterStats()  # counts no re-run can change: dropped steps', intake rejections
        self._has_evicted = False

    def __deepcopy__(self, memo):
        return copy.copy(self)  # step() rebinds attributes, never mutates them (caches of constants aside)

    # ---- model hooks -------------------------------------------------------------------------

    def marker_noise(self, sigma_p: float, sigma_q: float) -> np.ndarray:
        """R of one marker measurement (rows x rows)."""
        raise NotImplementedError

    def initial_state(self, slots: np.ndarray, p_WM: np.ndarray, q_MR: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(x, P) from the markers `slots` seen at W positions p_WM (k, 3) and attitudes q^{M/R} (k, 4)."""
        raise NotImplementedError

    def process(self, x: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """(f(x), F = df/dx) of the process model over dt seconds."""
        raise NotImplementedError

    def process_noise(self, x: np.ndarray, dt: float) -> np.ndarray:
        """Q over dt seconds."""
        raise NotImplementedError

    def constant_parts(self, dt: float):
        """Whatever parts of F and Q depend on dt alone (see `constants`)."""
        raise NotImplementedError

    def predict_measurements(self, x: np.ndarray, slots: np.ndarray, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
        """Predicted (p_CM (k, 3), q^{M/C} (4,)) of the markers `slots`: Eq. (12)."""
        raise NotImplementedError

    def measurement_jacobian(self, x: np.ndarray, slots: np.ndarray, camera: Camera) -> np.ndarray:
        """H (k rows, n) of the stacked marker measurements `slots`."""
        raise NotImplementedError

    def innovations(self, x: np.ndarray, slots: np.ndarray, camera: Camera, p_CM: np.ndarray,
                    q_MC: np.ndarray) -> np.ndarray:
        """(k, rows) measurement minus prediction for measured p_CM (k, 3) and q^{M/C} (k, 4)."""
        raise NotImplementedError

    def normalized(self, x: np.ndarray) -> np.ndarray:
        return x

    def platform(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(p_WP, q^{P/R}, p_WM (n, 3)) of the state x; p_WP is x[:3] in every model."""
        raise NotImplementedError

    def platform_covariance(self, x: np.ndarray, P: np.ndarray) -> np.ndarray:
        """6x6 covariance of [roll, pitch, yaw, x, y, z] of the pad frame P."""
        raise NotImplementedError

    # ---- camera ------------------------------------------------------------------------------

    def camera(self, p_WB: np.ndarray, q_BR: np.ndarray) -> Camera:
        """The camera's pose for the UAV at p_WB with attitude q^{B/R}."""
        D_BR = dcm(q_BR)
        q_RC = self._odot_q_BC @ inverse(q_BR)  # q^{B/C} (.) (q^{B/R})^-1 of Eq. (12), = q^{R/C}
        return Camera(p_WB, q_BR, self._D_CB @ D_BR, p_WB + self._c_B @ D_BR, odot_matrix(q_RC))

    def camera_at(self, X_WB: RigidTransform) -> Camera:
        return self.camera(X_WB.translation().copy(), drake_to_paper(X_WB.rotation()))

    def _interpolate(self, a: Camera, b: Camera, s: float) -> Camera:
        """The camera at fraction s from a to b: linear position, normalised linear quaternion."""
        q = (1 - s) * a.q_BR + s * np.sign(a.q_BR @ b.q_BR) * b.q_BR
        return self.camera((1 - s) * a.p_WB + s * b.p_WB, q / np.linalg.norm(q))

    # ---- filter steps ------------------------------------------------------------------------

    def step(self, t: float, X_WB: RigidTransform, measurements, camera: Camera | None = None) -> None:
        """Advances the filter to time t [s], later than the previous step's, with the UAV at X_WB
        (at t) and the marker measurements that arrived since the previous step (any order, late
        ones included). `camera`: `camera_at(X_WB)` when the caller has it already (filters with
        the same camera mount can share one)."""
        history = self._history
        if history and t <= history[-1].time + TIME_TOLERANCE_S:
            raise ValueError(f"step at t = {t} s does not follow the previous step at {history[-1].time} s")
        usable, settled = self._screen(measurements, t)
        current, late = [], {}  # late: history index -> measurements taken in that step
        for m in usable:
            j = self._step_index(m.time, t)
            if j is None:
                settled += FilterStats(too_late=1)
            elif j == len(history):
                current.append(m)
            else:
                late.setdefault(j, []).append(m)
        first = min(late, default=len(history))  # re-run the history from the oldest late measurement
        steps = list(history[:first])
        for j in range(first, len(history)):
            old = history[j]
            steps.append(self._run(steps[-1] if steps else None, old.time, old.camera,
                                   old.measurements + tuple(late.get(j, ()))))
        camera = self.camera_at(X_WB) if camera is None else camera
        steps.append(self._run(steps[-1] if steps else None, t, camera, tuple(current)))
        while len(steps) > 1 and steps[0].time < t - self.config.history_s - TIME_TOLERANCE_S:
            settled += steps.pop(0).stats
            self._has_evicted = True
        self._settled += settled
        self._history = tuple(steps)

    def _screen(self, measurements, t: float) -> tuple[list[MarkerMeasurement], FilterStats]:
        """The measurements that can be fused, and the count of those that cannot."""
        measurements = list(measurements)
        usable = [m for m in measurements if self._usable(m, t)]
        return usable, FilterStats(invalid=len(measurements) - len(usable))

    def _usable(self, m: MarkerMeasurement, t: float) -> bool:
        """A known marker, taken by time t, finite, with a unit quaternion (to tolerance)."""
        try:
            if type(m) is not MarkerMeasurement:
                m = MarkerMeasurement(m.time, m.marker_id, m.p_CM, m.q_CM)
            return (m.marker_id in self._slot and m.time <= t + TIME_TOLERANCE_S
                    and abs(m.quaternion_norm - 1.0) <= self.config.max_quaternion_norm_error)
        except (AttributeError, TypeError, ValueError):  # not a measurement, or nested arrays
            return False

    def _step_index(self, time: float, t: float) -> int | None:
        """The step a measurement taken at `time` belongs to: j < len(history) for history step j,
        which holds (time of step j - 1, time of step j]; len(history) for the new step at t; None
        when it is older than the history can re-run."""
        history = self._history
        if not history:
            return 0 if time >= t - TIME_TOLERANCE_S else None
        if time > history[-1].time + TIME_TOLERANCE_S:
            return len(history)
        for j in range(len(history) - 1, 0, -1):  # newest first: late measurements are mostly one step late
            if time > history[j - 1].time + TIME_TOLERANCE_S:
                return j
        # The oldest step re-runs only while it is the filter's first, and for its own time.
        return 0 if not self._has_evicted and time >= history[0].time - TIME_TOLERANCE_S else None

    def _run(self, previous: _Step | None, time: float, camera: Camera, measurements: tuple) -> _Step:
        """One step from the previous step's posterior: the measurements in time order, each group
        of one time fused at that time, then a prediction to `time`."""
        belief = previous.belief if previous else None
        streak = previous.gated_streak if previous else 0
        accepted = gated = resets = 0
        groups = {}
        for m in sorted(measurements, key=lambda m: m.time):
            groups.setdefault(m.time, []).append(m)
        last = None
        for tm, group in groups.items():
            if tm >= time - TIME_TOLERANCE_S or previous is None:
                cam = camera
            else:
                cam = self._interpolate(previous.camera, camera, (tm - previous.time) / (time - previous.time))
            last = (tm, group, cam)
            if belief is None:
                belief = self._start(tm, group, cam)
                accepted += len(group)
                continue
            belief, fused = self._update(self._predict_to(belief, tm), group, cam)
            accepted += fused
            gated += len(group) - fused
        if groups:
            streak = streak + 1 if accepted == 0 else 0
        if streak >= self.config.reset_after_rejected_steps:
            belief, streak, resets = self._start(*last), 0, 1
        if belief is not None:
            belief = self._predict_to(belief, time)
        return _Step(time, camera, tuple(measurements), belief, FilterStats(accepted, gated, 0, 0, resets), streak)

    def _start(self, time: float, group, camera: Camera) -> _Belief:
        slots, p_CM, q_MC = self._arrays(group)
        p_WM = camera.p_WC + p_CM @ camera.R_CW  # Eq. (4): r + c + s^i, s^i in W
        q_MR = q_MC @ camera.M_CR.T  # Eq. (5)
        return _Belief(time, *self.initial_state(slots, p_WM, q_MR))

    def _arrays(self, group):
        return (np.array([self._slot[m.marker_id] for m in group]), np.array([m.p_CM for m in group]),
                np.array([m.q_CM for m in group]))

    def constants(self, dt: float):
        """The model's `constant_parts(dt)`, cached by dt (to 1 ns: step times k T_s differ by T_s
        only to rounding); shared, so never modified in place."""
        key = round(dt, 9)
        parts = self._constants_by_dt.get(key)
        if parts is None:
            if len(self._constants_by_dt) >= 8:  # predictions to odd times (outputs between steps)
                self._constants_by_dt.clear()
            parts = self._constants_by_dt[key] = self.constant_parts(dt)
        return parts

    def predict(self, x: np.ndarray, P: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """Sec. 3's prediction over dt seconds: x = f(x), P = F P F^T + Q."""
        f, F = self.process(x, dt)
        return f, F @ P @ F.T + self.process_noise(x, dt)

    def _predict_to(self, belief: _Belief, time: float) -> _Belief:
        dt = time - belief.time
        if dt <= TIME_TOLERANCE_S:
            return belief
        key = (id(belief), time)
        cached = self._predictions.get(key)
        if cached is not None and cached[0] is belief:
            return cached[1]
        predicted = _Belief(time, *self.predict(belief.x, belief.P, dt))
        if len(self._predictions) >= 16:
            self._predictions.clear()
        self._predictions[key] = (belief, predicted)
        return predicted

    def _update(self, belief: _Belief, group, camera: Camera) -> tuple[_Belief, int]:
        """Sec. 3's update on the stacked rows of the markers that pass the gate; (belief, count fused)."""
        slots, p_CM, q_MC = self._arrays(group)
        x, P = belief.x, belief.P
        nu = self.innovations(x, slots, camera, p_CM, q_MC)
        H = self.measurement_jacobian(x, slots, camera)
        k, d = nu.shape
        PHt = P @ H.T  # P^XY
        S = H @ PHt + self._stacked_noise(k)  # P^Y
        # chi-square gate, one marker measurement at a time: nu_i^T S_ii^-1 nu_i
        blocks = np.arange(k)
        S_ii = S.reshape(k, d, k, d)[blocks, :, blocks, :]
        nis = np.einsum("ki,ki->k", nu, np.linalg.solve(S_ii, nu[:, :, None])[:, :, 0])
        keep = nis <= self._gate
        fused = int(keep.sum())
        if fused == 0:
            return belief, 0
        if fused < k:
            rows = ((d * blocks[keep])[:, None] + np.arange(d)).ravel()
            S, PHt, H, nu = S[np.ix_(rows, rows)], PHt[:, rows], H[rows], nu[keep]
        K = np.linalg.solve(S, PHt.T).T  # K = P^XY (P^Y)^-1
        x = self.normalized(x + K @ nu.ravel())
        I_KH = self._I - K @ H
        P = I_KH @ P @ I_KH.T + K @ self._stacked_noise(fused) @ K.T  # Joseph form, as Sec. 3 writes it
        return _Belief(belief.time, x, (P + P.T) / 2), fused

    def _stacked_noise(self, k: int) -> np.ndarray:
        """R of k stacked marker measurements (block diagonal), cached."""
        if k not in self._R_stacked:
            self._R_stacked[k] = np.kron(np.eye(k), self._R_marker)
        return self._R_stacked[k]

    # ---- results -----------------------------------------------------------------------------

    @property
    def started(self) -> bool:
        return bool(self._history) and self._history[-1].belief is not None

    @property
    def stats(self) -> FilterStats:
        """Counts since the filter was made (FilterStats)."""
        total = self._settled
        for s in self._history:
            total = total + s.stats
        return total

    @property
    def belief(self) -> tuple[float, np.ndarray, np.ndarray] | None:
        """(time, x, P) of the latest posterior, or None before the filter has started."""
        return self._history[-1].belief if self.started else None

    def estimate(self, t: float | None = None) -> MarkerFilterEstimate:
        """The pad's pose and the marker positions, predicted from the latest posterior to t
        (default: the latest step's time). Invalid before the start and while the pad position's
        standard deviation, sqrt(trace), exceeds max_valid_position_std_m."""
        if not self.started:
            time = 0.0 if t is None else t
            return MarkerFilterEstimate(PoseEstimate.invalid(time), np.full((len(self.p_PM), 3), np.nan), np.nan)
        belief, p_WP, q_PR, p_WM, valid, yaw = self._summary(t)
        R_WP = RotationMatrix(paper_to_drake(q_PR))
        covariance = self.platform_covariance(belief.x, belief.P)
        return MarkerFilterEstimate(PoseEstimate(belief.time, RigidTransform(R_WP, p_WP), valid, covariance), p_WM,
                                    yaw)

    def estimate_values(self, t: float | None = None) -> tuple[np.ndarray, float, np.ndarray, bool] | None:
        """`estimate(t)`'s (p_WP, yaw, p_WM, valid) without building its Drake objects (for loops
        over many steps, e.g. the Monte Carlo runs); None before the filter has started."""
        if not self.started:
            return None
        _, p_WP, _, p_WM, valid, yaw = self._summary(t)
        return p_WP, yaw, p_WM, valid

    def _summary(self, t: float | None):
        """(belief, p_WP, unit q^{P/R}, p_WM, valid, yaw) of the latest posterior predicted to t."""
        belief = self._history[-1].belief
        if t is not None:
            belief = self._predict_to(belief, t)
        p_WP, q_PR, p_WM = self.platform(belief.x)
        q_PR = q_PR / np.linalg.norm(q_PR)
        valid = bool(np.sqrt(np.trace(belief.P[:3, :3])) <= self.config.max_valid_position_std_m)  # p_WP = x[:3]
        x, y, z, w = q_PR.tolist()  # scalar last; yaw = atan2(R_WP[1, 0], R_WP[0, 0])
        yaw = math.atan2(2.0 * (x * y + w * z), 1.0 - 2.0 * (y * y + z * z))
        return belief, p_WP, q_PR, p_WM, valid, yaw


class PaperMarkerEkf(MarkerFilter):
    """Seed 002's EKF, Eq. (11)-(12). State x (6 n + 7; 37 for five markers):
    [p_WM_1, v_WM_1, ..., p_WM_n, v_WM_n (m, m/s, in W), q^{P/R} (scalar last), omega (rad/s, in P)]."""

    name = "paper_ekf"
    rows = 7  # p_CM (3), q^{M/C} (4)

    def __init__(self, layout: MarkerLayout, X_BC: RigidTransform, config: MarkerEkfConfig | None = None):
        self.n = 6 * len(layout.ids) + 7
        self._q = slice(self.n - 7, self.n - 3)
        self._w = slice(self.n - 3, self.n)
        super().__init__(layout, X_BC, config)

    def marker_noise(self, sigma_p, sigma_q):
        # A rotation vector dtheta ~ N(0, sigma^2 I3) moves q by about [dtheta / 2, 0]: (sigma/2)^2 per
        # component (the scalar's share is second order; giving it the same is conservative).
        return np.diag(np.r_[np.full(3, sigma_p**2), np.full(4, (sigma_q / 2) ** 2)])

    def initial_state(self, slots, p_WM, q_MR):
        c = self.config
        q = np.sum(q_MR * np.sign(q_MR @ q_MR[0])[:, None], axis=0)  # every marker's attitude is the pad's
        q /= np.linalg.norm(q)
        R_WP = dcm(q).T
        # markers not seen start where the layout puts them, from the mean of the seen ones
        origin = np.mean(p_WM - self.p_PM[slots] @ R_WP.T, axis=0)
        p = origin + self.p_PM @ R_WP.T
        p[slots] = p_WM
        m = len(self.p_PM)
        x = np.zeros(self.n)
        x[:6 * m].reshape(m, 6)[:, :3] = p
        x[self._q] = q
        variances = np.tile(np.r_[np.full(3, c.position_std_m**2), np.full(3, c.initial_velocity_std_mps**2)], m)
        return x, np.diag(np.r_[variances, np.full(4, (self._sigma_q / 2) ** 2),
                                np.full(3, c.initial_angular_velocity_std_radps**2)])

    def process(self, x, dt):
        """Eq. (11): markers at constant velocity, q_{k+1} = q_k + (T_s/2) Xi(q_k) omega_k, omega constant."""
        m = len(self.p_PM)
        f = x.copy()
        markers = f[:6 * m].reshape(m, 6)
        markers[:, :3] += dt * markers[:, 3:]
        q, omega = x[self._q], x[self._w]
        f[self._q] = q + dt / 2 * xi(q) @ omega
        F = self.constants(dt)[0].copy()
        F[self._q, self._q] += dt / 2 * omega_matrix(omega)
        F[self._q, self._w] = dt / 2 * xi(q)
        return f, F

    def process_noise(self, x, dt):
        """Q: white acceleration on each marker axis; white angular acceleration on omega, reaching
        q through Xi(q)/2 (the same [[dt^3/3, dt^2/2], [dt^2/2, dt]] shape)."""
        Q = self.constants(dt)[1].copy()
        G = xi(x[self._q]) / 2
        rotation = cv_noise(self.config.angular_acceleration_psd, dt)
        Q[self._q, self._q] = rotation[0, 0] * G @ G.T
        Q[self._q, self._w] = rotation[0, 1] * G
        Q[self._w, self._q] = rotation[0, 1] * G.T
        return Q

    def constant_parts(self, dt):
        """F and Q of Eq. (11) without the quaternion's blocks, which depend on the state."""
        c, m = self.config, len(self.p_PM)
        F = np.eye(self.n)
        F[:6 * m, :6 * m] = np.kron(np.eye(m), np.kron([[1.0, dt], [0.0, 1.0]], np.eye(3)))
        psd = np.diag([c.acceleration_psd, c.acceleration_psd, c.vertical_acceleration_psd])
        Q = np.zeros((self.n, self.n))
        Q[:6 * m, :6 * m] = np.kron(np.eye(m), np.kron(cv_noise(1.0, dt), psd))
        Q[self._w, self._w] = cv_noise(c.angular_acceleration_psd, dt)[1, 1] * np.eye(3)
        return F, Q

    def predict_measurements(self, x, slots, camera):
        m = len(self.p_PM)
        p_WM = x[:6 * m].reshape(m, 6)[slots, :3]
        return (p_WM - camera.p_WC) @ camera.R_CW.T, camera.Q_RC @ x[self._q]  # Eq. (12)

    def measurement_jacobian(self, x, slots, camera):
        k = len(slots)
        H = np.zeros((k, 7, self.n))
        H[np.arange(k)[:, None, None], np.arange(3)[None, :, None],
          6 * np.asarray(slots)[:, None, None] + np.arange(3)[None, None, :]] = camera.R_CW
        H[:, 3:, self._q] = camera.Q_RC
        return H.reshape(7 * k, self.n)

    def innovations(self, x, slots, camera, p_CM, q_MC):
        p_hat, q_hat = self.predict_measurements(x, slots, camera)
        q_MC = q_MC * np.where(q_MC @ q_hat < 0, -1.0, 1.0)[:, None]  # q and -q: the same attitude
        return np.hstack([p_CM - p_hat, q_MC - q_hat])

    def normalized(self, x):
        x[self._q] /= np.linalg.norm(x[self._q])
        return x

    def platform(self, x):
        m = len(self.p_PM)
        return x[:3].copy(), x[self._q].copy(), x[:6 * m].reshape(m, 6)[:, :3].copy()

    def platform_covariance(self, x, P):
        J = np.zeros((6, self.n))  # [small rotation in P; position of marker 0] from x
        J[:3, self._q] = 2 * xi(x[self._q]).T  # dtheta = 2 Xi(q)^T dq (Markley & Crassidis)
        J[3:, :3] = np.eye(3)
        return J @ P @ J.T


def _rot_z(psi: float) -> np.ndarray:
    """R_z(psi), a rotation by psi about z (3x3)."""
    c, s = np.cos(psi), np.sin(psi)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _yaw_quaternion(psi: float) -> np.ndarray:
    """q^{P/R} of a level pad yawed by psi about W's z."""
    return np.array([0.0, 0.0, np.sin(psi / 2), np.cos(psi / 2)])


def _turn_terms(theta: float) -> tuple[float, float, float, float]:
    """sin(th)/th, (1 - cos(th))/th and their derivatives in th, with series near th = 0."""
    if abs(theta) < 1e-4:
        return 1 - theta**2 / 6, theta / 2 - theta**3 / 24, -theta / 3, 0.5 - theta**2 / 8
    s, c = math.sin(theta), math.cos(theta)
    return s / theta, (1 - c) / theta, (theta * c - s) / theta**2, (theta * s - (1 - c)) / theta**2


class ConstantTurnEkf(MarkerFilter):
    """The coordinated-turn EKF (module docstring). State x (8): [p_WP (3, m), v_WP (3, m/s), psi
    (rad), omega (rad/s)]: the pad frame's origin (marker 0) and velocity in W, its yaw and yaw rate."""

    name = "ct_ekf"
    n = 8
    rows = 6  # p_CM (3), attitude rotation vector (3)
    PSI, OMEGA = 6, 7

    def marker_noise(self, sigma_p, sigma_q):
        return np.diag(np.r_[np.full(3, sigma_p**2), np.full(3, sigma_q**2)])

    def initial_state(self, slots, p_WM, q_MR):
        c = self.config
        R = np.array([dcm(q).T for q in q_MR])  # R_WM of each marker
        psi = np.arctan2(np.sum(R[:, 1, 0]), np.sum(R[:, 0, 0]))  # mean heading
        p = np.mean(p_WM - self.p_PM[slots] @ _rot_z(psi).T, axis=0)
        x = np.r_[p, 0.0, 0.0, 0.0, psi, 0.0]
        return x, np.diag(np.r_[np.full(3, c.position_std_m**2), np.full(3, c.initial_velocity_std_mps**2),
                                self._sigma_q**2, c.initial_angular_velocity_std_radps**2])

    def process(self, x, dt):
        """Exact coordinated turn over dt: the horizontal velocity turns by omega dt, the position
        follows the arc, p_xy += dt [[f1, -f2], [f2, f1]] v_xy with f1 = sin(omega dt)/(omega dt),
        f2 = (1 - cos(omega dt))/(omega dt); z at constant velocity; psi += omega dt; omega constant."""
        _, _, _, vx, vy, vz, _, omega = x.tolist()
        f1, f2, d1, d2 = _turn_terms(omega * dt)
        c, s = math.cos(omega * dt), math.sin(omega * dt)
        a, b = dt * f1, dt * f2
        f = x.copy()
        f[0] += a * vx - b * vy
        f[1] += b * vx + a * vy
        f[2] += dt * vz
        f[3], f[4] = c * vx - s * vy, s * vx + c * vy
        f[self.PSI] += omega * dt
        F = np.eye(8)
        F[0, 3], F[0, 4], F[1, 3], F[1, 4] = a, -b, b, a
        F[0, 7], F[1, 7] = dt * dt * (d1 * vx - d2 * vy), dt * dt * (d2 * vx + d1 * vy)
        F[3, 3], F[3, 4], F[4, 3], F[4, 4] = c, -s, s, c
        F[3, 7], F[4, 7] = -dt * (s * vx + c * vy), dt * (c * vx - s * vy)
        F[2, 5] = F[self.PSI, self.OMEGA] = dt
        return f, F

    def process_noise(self, x, dt):
        return self.constants(dt)

    def constant_parts(self, dt):
        """Q: white acceleration on each axis of the pad (as the paper's filter has on each marker),
        white angular acceleration on the yaw rate."""
        c = self.config
        Q = np.zeros((8, 8))
        for axis, psd in enumerate((c.acceleration_psd, c.acceleration_psd, c.vertical_acceleration_psd)):
            Q[axis::3, axis::3][:2, :2] = cv_noise(psd, dt)
        Q[6:, 6:] = cv_noise(c.angular_acceleration_psd, dt)
        return Q

    def predict_measurements(self, x, slots, camera):
        return self._predict_positions(x, slots, camera), camera.Q_RC @ _yaw_quaternion(x[self.PSI])  # Eq. (12)

    def _predict_positions(self, x, slots, camera):
        p_WM = x[:3] + self.p_PM[slots] @ _rot_z(x[self.PSI]).T
        return (p_WM - camera.p_WC) @ camera.R_CW.T

    def measurement_jacobian(self, x, slots, camera):
        k = len(slots)
        c, s = np.cos(x[self.PSI]), np.sin(x[self.PSI])
        dR_WP = np.array([[-s, -c, 0.0], [c, -s, 0.0], [0.0, 0.0, 0.0]])  # d R_z(psi) / d psi
        H = np.zeros((k, 6, 8))
        H[:, :3, :3] = camera.R_CW
        H[:, :3, self.PSI] = self.p_PM[slots] @ (camera.R_CW @ dR_WP).T
        H[:, 5, self.PSI] = 1.0  # the attitude error is a rotation about z by the yaw error
        return H.reshape(6 * k, 8)

    def innovations(self, x, slots, camera, p_CM, q_MC):
        # q^{M/R} = [q^{C/R} (.)] q^{M/C} (Eq. 5) = dq (x) q_pred: dq = [q_pred^-1 (.)] q^{M/R}
        to_error = odot_matrix(inverse(_yaw_quaternion(x[self.PSI]))) @ camera.M_CR
        return np.hstack([p_CM - self._predict_positions(x, slots, camera), rotation_vector(q_MC @ to_error.T)])

    def normalized(self, x):
        x[self.PSI] = wrap_angle(x[self.PSI])
        return x

    def platform(self, x):
        return x[:3].copy(), _yaw_quaternion(x[self.PSI]), x[:3] + self.p_PM @ _rot_z(x[self.PSI]).T

    def platform_covariance(self, x, P):
        J = np.zeros((6, 8))
        J[2, self.PSI] = 1.0  # roll and pitch: level by assumption, zero variance
        J[3:, :3] = np.eye(3)
        return J @ P @ J.T


FILTERS = {PaperMarkerEkf.name: PaperMarkerEkf, ConstantTurnEkf.name: ConstantTurnEkf}


class MarkerFilterSystem(LeafSystem):
    """A marker filter as a system, stepped by a periodic update every config.period_s.

    Inputs: `marker_measurements` (list of MarkerMeasurement that arrived since the last update)
    and `X_WB` (RigidTransform, the UAV body). Outputs, from the latest posterior predicted to the
    context's time (so a consumer at any rate, or before the update at the same time, sees no lag):
    `X_WP_estimate` (PoseEstimate of the pad frame P in W), `p_WM_estimate` (3 n: the marker centres
    in W, m; NaN before the filter starts) and `filter_stats` (FilterStats).
    """

    def __init__(self, marker_filter: MarkerFilter):
        super().__init__()
        self._measurements = self.DeclareAbstractInputPort("marker_measurements", AbstractValue.Make([]))
        self._X_WB = self.DeclareAbstractInputPort("X_WB", AbstractValue.Make(RigidTransform()))
        self._filter = self.DeclareAbstractState(AbstractValue.Make(marker_filter))
        self.DeclarePeriodicUnrestrictedUpdateEvent(marker_filter.config.period_s, 0.0, self._update)
        n = len(marker_filter.layout.ids)
        self._estimate = self.DeclareCacheEntry(
            "estimate", ValueProducer(
                allocate=lambda: AbstractValue.Make(marker_filter.estimate()),
                calc=lambda c, v: v.set_value(c.get_abstract_state(self._filter).get_value().estimate(c.get_time()))),
            {self.time_ticket(), self.abstract_state_ticket(self._filter)})
        self.DeclareAbstractOutputPort("X_WP_estimate", lambda: AbstractValue.Make(PoseEstimate()),
                                       lambda c, o: o.set_value(self._estimate.Eval(c).pose),
                                       {self._estimate.ticket()})
        self.DeclareVectorOutputPort("p_WM_estimate", 3 * n,
                                     lambda c, o: o.SetFromVector(self._estimate.Eval(c).p_WM.ravel()),
                                     {self._estimate.ticket()})
        self.DeclareAbstractOutputPort(
            "filter_stats", lambda: AbstractValue.Make(FilterStats()),
            lambda c, o: o.set_value(c.get_abstract_state(self._filter).get_value().stats),
            {self.abstract_state_ticket(self._filter)})

    def _update(self, context, state):
        marker_filter = state.get_mutable_abstract_state(self._filter).get_value()  # a copy of the context's
        marker_filter.step(context.get_time(), self._X_WB.Eval(context), self._measurements.Eval(context))
