"""The marker filters' common machinery: `MarkerFilter`, its configuration, camera and records.

A subclass gives the model (paper_ekf.py, constant_turn_ekf.py): its state, process, predicted
measurements, Jacobian and innovations. `MarkerFilter` runs it on the measurements of Eq. (12) (the
package docstring):
- update: the EKF of Sec. 3 with the Joseph-form covariance as the paper writes it, on the stacked
  rows of the markers seen in the step (any subset), the state renormalised by the model after it;
- a chi-square gate per marker measurement: its innovation's normalised squared length against
  the chi-square quantile `gate_probability` for the measurement's degrees of freedom
  (`gate_dof`: 6 for a pose, though the paper's has 7 rows); rejected ones are counted, and
  after `reset_after_rejected_steps` steps in a row whose measurements were all rejected, the
  filter restarts from the newest ones (a lost track must not gate out the truth for ever);
- screening: NaN, a quaternion of norm at most MIN_QUATERNION_NORM or off 1 by more than
  `max_quaternion_norm_error`, an unknown marker id, or a time in the future: rejected and
  counted, never fused;
- late measurements: seed 002 budgets 25 ms to acquire a frame and 10 ms to process it, so a
  measurement of time t_m can arrive a step or more later. The filter keeps `history_s` of steps
  (time, UAV pose, the measurements of (previous step, step], posterior); a late measurement joins
  the step it was taken in and the filter re-runs from there, so it is fused exactly as if it had
  arrived on time (the UAV pose at t_m comes from the history; between two steps it is
  interpolated). Older than the history: rejected and counted as too late.
"""

import copy
import math
from dataclasses import dataclass
from operator import attrgetter
from time import perf_counter
from typing import NamedTuple

import numpy as np
from pydrake.math import RigidTransform, RotationMatrix
from scipy.linalg import lapack
from scipy.stats import chi2

from systems.config import require, require_positive
from systems.estimators.estimate import PoseEstimate
from systems.perception.markers import MarkerLayout, MarkerMeasurement
from systems.quaternion import dcm, drake_to_paper, inverse, odot_matrix, paper_to_drake
from systems.stepped import TIME_TOLERANCE_S

MIN_QUATERNION_NORM = 1e-6  # a measured quaternion this short has no direction: rejected
_TIME = attrgetter("time")


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
    max_quaternion_norm_error: float = 0.05  # | |q| - 1 | above this: the measurement is rejected (in (0, 1))
    max_valid_position_std_m: float = 1.0  # the estimate is valid while the pad's position std is below this

    def validate(self, prefix: str = "filter") -> None:
        for name in ("period_s", "position_std_m", "attitude_std_deg", "acceleration_psd",
                     "vertical_acceleration_psd", "angular_acceleration_psd", "initial_velocity_std_mps",
                     "initial_angular_velocity_std_radps", "max_valid_position_std_m"):
            require_positive(getattr(self, name), f"{prefix}.{name}")
        require(0 < self.max_quaternion_norm_error < 1,
                f"{prefix}.max_quaternion_norm_error must be in (0, 1) (at 1 a zero quaternion would pass), "
                f"got {self.max_quaternion_norm_error}")
        require(0 < self.gate_probability < 1, f"{prefix}.gate_probability must be in (0, 1)")
        require(self.reset_after_rejected_steps >= 1, f"{prefix}.reset_after_rejected_steps must be at least 1")
        require(self.history_s >= 0, f"{prefix}.history_s must not be negative")


@dataclass(frozen=True)
class FilterStats:
    """Counts of marker measurements (one per marker per frame) and of restarts."""

    accepted: int = 0  # fused (or used to start the filter)
    gated: int = 0  # rejected by the chi-square gate
    invalid: int = 0  # NaN, non-unit or zero quaternion, unknown marker id, or time in the future
    too_late: int = 0  # older than the history
    resets: int = 0  # restarts after reset_after_rejected_steps fully gated steps

    def __add__(self, other: "FilterStats") -> "FilterStats":
        return FilterStats(self.accepted + other.accepted, self.gated + other.gated, self.invalid + other.invalid,
                           self.too_late + other.too_late, self.resets + other.resets)


_NO_COUNTS = FilterStats()

# A filter's estimate as one vector (`MarkerFilter.estimate_vector`, logged every filter step).
EST_VALID, EST_P_WP, EST_YAW, EST_V_WP, EST_A_WP, EST_POSITION_STD, EST_LAST_MEASUREMENT, EST_Q_WP = (
    0, slice(1, 4), 4, slice(5, 8), slice(8, 11), 11, 12, slice(13, 17))
ESTIMATE_VECTOR_SIZE = 17


@dataclass(frozen=True)
class MarkerFilterEstimate:
    """What a filter says about the pad at X_WP.time (NaN arrays when it has not started):
    X_WP: PoseEstimate of the pad frame P (at marker 0) in W, covariance over [roll, pitch, yaw, x, y, z];
    vector: [valid, p_WP (3, m), yaw_WP (rad, P's x axis from W's), v_WP (3, m/s), a_WP (3, m/s^2;
      zero in a model without acceleration), position std (m), acquisition time of the newest
      measurement fused (s), q_WP (4: unit quaternion [w, x, y, z] of R_WP, X_WP's rotation; level
      in a model that estimates the yaw alone, `MarkerFilter.attitude_axes`)] (the EST_* indices);
    p_WM: (n, 3) the marker centres in W [m]."""

    X_WP: PoseEstimate
    vector: np.ndarray
    p_WM: np.ndarray

    @property
    def v_WP(self) -> np.ndarray:
        return self.vector[EST_V_WP]

    @property
    def a_WP(self) -> np.ndarray:
        return self.vector[EST_A_WP]


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
    last_fused: float  # acquisition time of the newest measurement fused up to this step [s]; -inf: none


def _solve(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """A^-1 B by LAPACK's dgesv, the routine np.linalg.solve calls, without its per-call overhead
    (twice per update, on matrices of 30-35 rows)."""
    _, _, X, info = lapack.dgesv(A, B)
    if info != 0:
        raise np.linalg.LinAlgError(f"singular matrix in the marker filter update (dgesv info {info})")
    return X


def cv_noise(psd: float, dt: float) -> np.ndarray:
    """2x2 covariance of [position, velocity] after dt under white acceleration of spectral
    density psd: psd [[dt^3/3, dt^2/2], [dt^2/2, dt]]."""
    return psd * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])


class MarkerFilter:
    """A marker filter's common machinery (module docstring). Subclasses give the model:
    `n` states, `rows` rows per marker measurement, `gate_dof` degrees of freedom of its innovation
    (its chi-square gate's), and the methods marked model hooks.

    Use: `step(t, X_WB, measurements)` once per period (t increasing), then `estimate(t)`.
    Copying a filter is cheap (copy.deepcopy shares its immutable history), so a Drake abstract
    state can hold one.
    """

    name = ""
    n = 0
    rows = 0
    gate_dof = 0
    attitude_axes: tuple[str, ...] = ()  # of the pad's roll, pitch and yaw, those the model estimates

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
        self._R_marker = self.marker_noise(self.config.position_std_m, sigma_q)  # diagonal
        require(np.count_nonzero(self._R_marker - np.diag(np.diag(self._R_marker))) == 0,
                f"{self.name}: the marker noise R must be diagonal")
        self._gate = chi2.ppf(self.config.gate_probability, self.gate_dof)
        self._R_stacked: dict[int, tuple] = {}  # shared by copies: a cache of constants
        self._constants_by_dt: dict[float, object] = {}  # shared by copies, like _R_stacked
        # Predictions already made, by (id of the prior belief, time): a late measurement re-runs
        # the step it belongs to from the same prior to the same time (a pure function of both).
        # Holds the prior, so its id stays its own while cached; shared by copies like the above.
        self._predictions: dict[tuple[int, float], tuple[_Belief, _Belief]] = {}
        self._I = np.eye(self.n)
        self._history: tuple[_Step, ...] = ()
        self._settled = FilterStats()  # counts no re-run can change: dropped steps', intake rejections
        self._has_evicted = False
        self.compute_s = 0.0  # wall time spent in step() [s], for reports (no result depends on it)

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

    # Stack hooks: the above on S runs at once, for stack.py (states x (S, n); every marker, in layout order).

    def process_stack(self, x: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """(f(x) (S, n), F (S, n, n)) of `process` on a stack."""
        raise NotImplementedError

    def process_noise_stack(self, x: np.ndarray, dt: float) -> np.ndarray:
        """Q (S, n, n), or (n, n) for every run, of `process_noise` on a stack."""
        raise NotImplementedError

    def innovations_stack(self, x: np.ndarray, camera: Camera, p_CM: np.ndarray, q_MC: np.ndarray) -> np.ndarray:
        """(S, m, rows) `innovations` of every marker for one camera, measured p_CM (S, m, 3), q^{M/C} (S, m, 4)."""
        raise NotImplementedError

    def jacobian_stack(self, x: np.ndarray, camera: Camera) -> np.ndarray:
        """H (S, m rows, n), or (m rows, n) for every run, of every marker for one camera."""
        raise NotImplementedError

    def normalized_stack(self, x: np.ndarray) -> np.ndarray:
        return x

    def platform(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(p_WP (..., 3), q^{P/R} (..., 4), p_WM (..., n, 3)) of states x (..., n), one or a stack;
        p_WP is x[..., :3] in every model."""
        raise NotImplementedError

    def platform_covariance(self, x: np.ndarray, P: np.ndarray) -> np.ndarray:
        """6x6 covariance of [roll, pitch, yaw, x, y, z] of the pad frame P."""
        raise NotImplementedError

    def platform_rates(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(v_WP (..., 3) [m/s], a_WP (..., 3) [m/s^2]) of the pad frame's origin in W for states x
        (..., n); a_WP zero where the model has no acceleration."""
        raise NotImplementedError

    # ---- camera ------------------------------------------------------------------------------

    def camera(self, p_WB: np.ndarray, q_BR: np.ndarray) -> Camera:
        """The camera's pose for the UAV at p_WB [m] with attitude q^{B/R}: p_WB (3,) and q_BR (4,), or
        stacks (..., 3) and (..., 4) for a Camera of stacked fields (`Camera(*(f[k] for f in
        cameras))` is the k-th)."""
        D_BR = dcm(q_BR)
        q_RC = inverse(q_BR) @ self._odot_q_BC.T  # q^{B/C} (.) (q^{B/R})^-1 of Eq. (12), = q^{R/C}
        return Camera(p_WB, q_BR, self._D_CB @ D_BR, p_WB + self._c_B @ D_BR, odot_matrix(q_RC))

    def camera_at(self, X_WB: RigidTransform) -> Camera:
        return self.camera(X_WB.translation().copy(), drake_to_paper(X_WB.rotation()))

    def _interpolate(self, a: Camera, b: Camera, s: float) -> Camera:
        """The camera at fraction s from a to b: linear position, normalised linear quaternion."""
        q = (1 - s) * a.q_BR + s * np.sign(a.q_BR @ b.q_BR) * b.q_BR
        return self.camera((1 - s) * a.p_WB + s * b.p_WB, q / np.linalg.norm(q))

    # ---- filter steps ------------------------------------------------------------------------

    def step(self, t: float, X_WB: RigidTransform | None, measurements, camera: Camera | None = None) -> None:
        """Advances the filter to time t [s], later than the previous step's, with the UAV at X_WB
        (at t) and the marker measurements that arrived since the previous step (any order, late
        ones included). `camera`: `camera_at(X_WB)` when the caller has it already (filters with
        the same camera mount can share one); X_WB is then not read."""
        start = perf_counter()
        history = self._history
        if history and t <= history[-1].time + TIME_TOLERANCE_S:
            raise ValueError(f"step at t = {t} s does not follow the previous step at {history[-1].time} s")
        usable, invalid = self._screen(measurements, t)
        too_late = 0
        current, late = [], {}  # late: history index -> measurements taken in that step
        index = {}  # step index by measurement time (a frame's markers share one)
        for m in usable:
            j = index[m.time] if m.time in index else index.setdefault(m.time, self._step_index(m.time, t))
            if j is None:
                too_late += 1
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
        settled = self._settled
        if invalid or too_late:
            settled = settled + FilterStats(invalid=invalid, too_late=too_late)
        while len(steps) > 1 and steps[0].time < t - self.config.history_s - TIME_TOLERANCE_S:
            settled = settled + steps.pop(0).stats
            self._has_evicted = True
        self._settled = settled
        self._history = tuple(steps)
        self.compute_s += perf_counter() - start

    def _screen(self, measurements, t: float) -> tuple[list[MarkerMeasurement], int]:
        """The measurements that can be fused, and the count of those that cannot."""
        measurements = list(measurements)
        usable = [m for m in measurements if self._usable(m, t)]
        return usable, len(measurements) - len(usable)

    def _usable(self, m: MarkerMeasurement, t: float) -> bool:
        """A known marker, taken by time t, finite, with a unit quaternion (to tolerance; never a zero one)."""
        try:
            if type(m) is not MarkerMeasurement:
                m = MarkerMeasurement(m.time, m.marker_id, m.p_CM, m.q_CM)
            norm = m.quaternion_norm
            return (m.marker_id in self._slot and m.time <= t + TIME_TOLERANCE_S and norm > MIN_QUATERNION_NORM
                    and abs(norm - 1.0) <= self.config.max_quaternion_norm_error)
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
        last_fused = previous.last_fused if previous else -math.inf
        accepted = gated = resets = 0
        groups = {}
        for m in sorted(measurements, key=_TIME):
            groups.setdefault(m.time, []).append(m)
        last = None
        for tm, group in groups.items():
            if tm >= time - TIME_TOLERANCE_S or previous is None:
                cam = camera
            else:
                cam = self._interpolate(previous.camera, camera, (tm - previous.time) / (time - previous.time))
            last = (tm, group, cam)
            if belief is None:
                belief, last_fused = self._start(tm, group, cam), tm
                accepted += len(group)
                continue
            belief, fused = self._update(self._predict_to(belief, tm), group, cam)
            accepted += fused
            gated += len(group) - fused
            if fused:
                last_fused = tm
        if groups:
            streak = streak + 1 if accepted == 0 else 0
        if streak >= self.config.reset_after_rejected_steps:  # restarted from the newest group: used, not gated
            belief, streak, resets, last_fused = self._start(*last), 0, 1, last[0]
            accepted, gated = accepted + len(last[1]), gated - len(last[1])
        if belief is not None:
            belief = self._predict_to(belief, time)
        stats = FilterStats(accepted, gated, 0, 0, resets) if accepted or gated or resets else _NO_COUNTS
        return _Step(time, camera, tuple(measurements), belief, stats, streak, last_fused)

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
        R, r, blocks = self._stacked_noise(k)
        PHt = P @ H.T  # P^XY
        S = H @ PHt + R  # P^Y
        # chi-square gate, one marker measurement at a time: nu_i^T S_ii^-1 nu_i, every S_ii^-1 nu_i
        # from one solve with the block diagonal of S (the blocks do not mix: each is solved alone)
        nu = nu.ravel()
        nis = (nu * _solve(S * blocks, nu)).reshape(k, d).sum(axis=1)
        keep = nis <= self._gate
        fused = int(keep.sum())
        if fused == 0:
            return belief, 0
        if fused < k:
            rows = ((d * np.flatnonzero(keep))[:, None] + np.arange(d)).ravel()
            S, PHt, H, nu, r = S[np.ix_(rows, rows)], PHt[:, rows], H[rows], nu[rows], r[rows]
        K = _solve(S, PHt.T).T  # K = P^XY (P^Y)^-1
        x = self.normalized(x + K @ nu)
        I_KH = self._I - K @ H
        P = I_KH @ P @ I_KH.T + (K * r) @ K.T  # Joseph form, as Sec. 3 writes it (R diagonal: K R = K * r)
        return _Belief(belief.time, x, (P + P.T) / 2), fused

    def _stacked_noise(self, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(R of k stacked marker measurements (block diagonal), its diagonal, the 0/1 mask of its
        blocks), cached."""
        if k not in self._R_stacked:
            R = np.kron(np.eye(k), self._R_marker)
            self._R_stacked[k] = R, np.diag(R).copy(), np.kron(np.eye(k), np.ones(self._R_marker.shape))
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

    @property
    def time(self) -> float | None:
        """The latest step's time [s], None before the first step."""
        return self._history[-1].time if self._history else None

    def estimate(self, t: float | None = None) -> MarkerFilterEstimate:
        """The pad's pose, rates and marker positions, predicted from the latest posterior to t
        (default: the latest step's time). Invalid before the start and while the pad position's
        standard deviation, sqrt(trace), exceeds max_valid_position_std_m."""
        if not self.started:
            time = 0.0 if t is None else t
            vector = np.full(ESTIMATE_VECTOR_SIZE, np.nan)
            vector[EST_VALID] = 0.0
            return MarkerFilterEstimate(PoseEstimate.invalid(time, "W", "P"), vector,
                                        np.full((len(self.p_PM), 3), np.nan))
        belief = self._latest(t)
        vector, p_WM, q_PR = self.estimate_vectors(belief.x, self._position_variance(belief.P),
                                                   self._history[-1].last_fused)
        X_WP = RigidTransform(RotationMatrix(paper_to_drake(q_PR)), vector[EST_P_WP])
        covariance = self.platform_covariance(belief.x, belief.P)
        estimate = PoseEstimate(belief.time, X_WP, bool(vector[EST_VALID]), covariance, "W", "P")
        return MarkerFilterEstimate(estimate, vector, p_WM)

    def estimate_vector(self, t: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """`estimate(t)`'s vector and p_WM without its Drake objects (for loops over many steps)."""
        if not self.started:
            vector = np.full(ESTIMATE_VECTOR_SIZE, np.nan)
            vector[EST_VALID] = 0.0
            return vector, np.full((len(self.p_PM), 3), np.nan)
        belief = self._latest(t)
        vector, p_WM, _ = self.estimate_vectors(belief.x, self._position_variance(belief.P),
                                                self._history[-1].last_fused)
        return vector, p_WM

    def record(self) -> tuple[np.ndarray, float, float] | None:
        """What `estimate_vectors` needs of the latest step, None before the start: (x, the pad
        position's variance [m^2], the newest fused measurement's time [s]). A loop over many steps
        keeps one per step and makes every estimate vector at the end, at once."""
        if not self.started:
            return None
        belief = self._history[-1].belief
        return belief.x, self._position_variance(belief.P), self._history[-1].last_fused

    def estimate_vectors(self, x: np.ndarray, position_variance, last_measurement_s
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(estimate vectors (..., ESTIMATE_VECTOR_SIZE) in the EST_* layout, p_WM (..., n, 3) [m],
        unit q^{P/R} (..., 4)) of states x (..., n) with the pad position's variance (...) [m^2] and
        the newest fused measurement's time (...) [s] (-inf: none yet): one step, or a stack of
        steps (`record`) at once. Valid while the pad's position std is at most max_valid_position_std_m
        and every figure reported (the vector's, but the measurement time, and p_WM) is finite."""
        p_WP, q_PR, p_WM = self.platform(x)
        q_PR = q_PR / np.linalg.norm(q_PR, axis=-1, keepdims=True)
        position_std = np.sqrt(position_variance)
        qx, qy, qz, qw = np.moveaxis(q_PR, -1, 0)  # scalar last; yaw = atan2(R_WP[1, 0], R_WP[0, 0])
        yaw = np.arctan2(2.0 * (qx * qy + qw * qz), 1.0 - 2.0 * (qy * qy + qz * qz))
        v_WP, a_WP = self.platform_rates(x)
        last = np.where(np.isfinite(last_measurement_s), last_measurement_s, np.nan)
        yaw, position_std, last = (np.asarray(c, dtype=float)[..., None] for c in (yaw, position_std, last))
        q_WP = q_PR[..., [3, 0, 1, 2]]  # q^{P/R} scalar last: Drake's [w, x, y, z] of R_WP (paper_to_drake)
        valid = np.zeros_like(position_std)  # set below, from the rest
        vector = np.concatenate([valid, p_WP, yaw, v_WP, a_WP, position_std, last, q_WP], axis=-1)
        reported = np.delete(vector, [EST_VALID, EST_LAST_MEASUREMENT], axis=-1)  # the time: NaN before any
        vector[..., EST_VALID] = ((vector[..., EST_POSITION_STD] <= self.config.max_valid_position_std_m)
                                  & np.isfinite(reported).all(axis=-1) & np.isfinite(p_WM).all(axis=(-2, -1)))
        return vector, p_WM, q_PR

    def _latest(self, t: float | None) -> _Belief:
        """The latest posterior predicted to t (default: the latest step's time)."""
        belief = self._history[-1].belief
        return belief if t is None else self._predict_to(belief, t)

    @staticmethod
    def _position_variance(P: np.ndarray) -> float:
        """trace of the covariance of p_WP = x[:3] [m^2]."""
        return P[0, 0] + P[1, 1] + P[2, 2]
