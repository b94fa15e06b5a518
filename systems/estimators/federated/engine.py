"""Seed 001's federated EKF (Sec. 4.2) as a pure function of time, the IMU and the nodes'
measurements: one local filter per vision node (local_filter.py), fused and reset (fusion.py).

    state = FederatedState()                                  # not started
    state = step(state, t, imu, {"approach": m1, "adjustment": None, "touchdown": m3}, config, X_BC)

Every step predicts each local filter over the time since the last with the IMU sample (f_B, w_B);
a step with measurements (a camera frame: a dict, even of Nones) updates each node's own filter
with its node's measurement, then fuses the filters (Eq. 7-9) and shares the fused covariance and
the process noise out to them (Eq. 6, 9; `FederatedConfig.reset_states`: the states too). The filter
starts at the first measurement of any node, and again at the first after max_coast_s without one
accepted. Frames: B the UAV body, P the pattern (level, z up),
C the camera at X_BC in B. Units: m, s, rad.
"""

from dataclasses import dataclass, field, replace

import numpy as np
from pydrake.math import RigidTransform, RotationMatrix

from systems.config import require_positive
from systems.estimators.federated.fusion import fuse, reset
from systems.estimators.federated.local_filter import (
    LocalFilterConfig,
    LocalState,
    centre_in_body,
    initial_state,
    initial_velocity_covariance,
    position_first,
    predict,
    update_centre_in_camera,
    update_pattern_in_camera,
    update_pose,
)
from systems.perception.rqrlp.measurements import NodeMeasurement

NODES = ("approach", "adjustment", "touchdown")  # seed 001 Fig. 3, from far to near


@dataclass
class FederatedConfig(LocalFilterConfig):
    """The local filters' noise and gate (LocalFilterConfig) and when the fused estimate is valid
    (ours): measured by some node within `max_coast_s`, and the pattern's position relative to the
    body known to `max_relative_std_m` (sqrt of the trace); and whether the information sharing
    restarts the local filters from the fused state (`reset_states`) or only shares P and Q out."""

    max_coast_s: float = 0.5
    # Sec. 4.2: beta_i allocates "the prediction noise Q_i and the state covariance P_i for the local filters
    # at next time"; each filter keeps its own state while its node measures (Fig. 10d's LF1 and LF2, about twice
    # the fused error), and one whose node did not restarts from the fused estimate. True: Carlson's
    # fusion-reset, every filter restarts from the fused estimate (the centralised filter's estimate).
    reset_states: bool = False
    max_relative_std_m: float = 1.0
    gravity_m_s2: float = 9.81  # the IMU's (systems/sensors/imu.py ImuConfig.gravity_m_s2)

    def validate(self, prefix: str = "federated") -> None:
        LocalFilterConfig.validate(self, prefix)
        for name in ("max_coast_s", "max_relative_std_m", "gravity_m_s2"):
            require_positive(getattr(self, name), f"{prefix}.{name}")


@dataclass(frozen=True)
class NodeStats:
    """One node's record: measurements accepted by its filter, rejected by its gate, and the time of
    the last accepted one (None: never)."""

    accepted: int = 0
    gated: int = 0
    last_accepted_s: float | None = None


@dataclass(frozen=True)
class FederatedState:
    """time: of the last step [s] (None: not stepped). fused: the global estimate (None until a
    node measured). filters: the local filters after the last reset; local_estimates: each one's
    estimate after its own update, before the fusion (Fig. 10d's LF curves); betas: Eq. (9)'s."""

    time: float | None = None
    fused: LocalState | None = None
    filters: tuple[LocalState, ...] = ()
    local_estimates: tuple[LocalState, ...] = ()
    betas: np.ndarray = field(default_factory=lambda: np.full(len(NODES), 1.0 / len(NODES)))
    stats: tuple[NodeStats, ...] = tuple(NodeStats() for _ in NODES)
    last_imu: np.ndarray = field(default_factory=lambda: np.zeros(6))
    heading_known: bool = False  # a node has measured a full pose (the approaching node's centre has no heading)
    first_pose_doubted_s: float | None = None  # since when the first full poses disagree with the estimate
    last_pose_doubted_s: float | None = None  # the latest such pose: a run of them ends max_coast_s after it

    @property
    def started(self) -> bool:
        return self.fused is not None


def _first_state(measurement: NodeMeasurement, X_BC: RigidTransform, f_B: np.ndarray,
                 config: FederatedConfig) -> LocalState:
    """A filter started by a node's first measurement: a full pose as measured, the approaching
    node's centre with the tilt from the accelerometer and the heading unknown (initial_state)."""
    if measurement.X_PB is not None:  # the pose's whole covariance: its position and tilt errors are one orbit
        pose = [0, 1, 2, 6, 7, 8]  # about the pattern (correlated +1.00 at 2-5 m), which a diagonal understates 4x
        P = np.zeros((9, 9))
        P[np.ix_(pose, pose)] = position_first(measurement.pose_covariance(X_BC))
        P[3:6, 3:6] = initial_velocity_covariance(config)
        return LocalState(measurement.X_PB.translation(), np.zeros(3), measurement.X_PB.rotation().matrix(), P)
    R_BC = X_BC.rotation().matrix()
    return initial_state(X_BC.multiply(measurement.p_CP), R_BC @ measurement.covariance @ R_BC.T, f_B, config)


def _restart(state: FederatedState, measurement: NodeMeasurement, X_BC: RigidTransform, f_B: np.ndarray,
             config: FederatedConfig, lost: bool) -> tuple[LocalState, ...]:
    """Every local filter (re)started from one measurement, each with N times its covariance (so
    that their fusion has it): at the first measurement, after max_coast_s without one accepted
    (`lost`), and at the first full pose while the heading is unknown (an EKF update over a heading
    that far off would not be linear) that agrees with the estimate (`_agrees`; or any, after
    max_coast_s of poses that do not). A restart keeps the body's velocity, v_B, and its covariance,
    to which a lost filter adds the initial one (it may have drifted off)."""
    first = _first_state(measurement, X_BC, f_B, config)
    if state.started:
        R = first.R @ state.fused.R.T  # the new P's axes from the old's
        P = first.P.copy()
        P[3:6, 3:6] = R @ state.fused.P[3:6, 3:6] @ R.T + (initial_velocity_covariance(config) if lost else 0.0)
        first = replace(first, v=R @ state.fused.v, P=P)
    return tuple(replace(first, P=first.P * len(NODES), q_scale=float(len(NODES))) for _ in NODES)


def _agrees(filters: tuple[LocalState, ...], measurement: NodeMeasurement, X_BC: RigidTransform,
            config: FederatedConfig) -> bool:
    """Whether the first full pose agrees with the estimate the approaching node's centres built (their
    fusion, turned about P's z axis to the pose's heading, which they cannot tell): its update would pass
    the gate. A restart takes that one pose whole, so one that errs by many times its covariance (the
    adjustment node's first, at the edge of its range: 26 and 39 mm at 3.8 m against its 3 mm, on the
    moving pad) would put every filter there."""
    fused, _ = fuse(list(filters))
    R = measurement.X_PB.rotation().matrix() @ fused.R.T
    R_z = RotationMatrix.MakeZRotation(np.arctan2(R[1, 0] - R[0, 1], R[0, 0] + R[1, 1])).matrix()
    T = np.kron(np.eye(3), R_z)  # p, v and the attitude's error, each in P, turn alike
    turned = replace(fused, p=R_z @ fused.p, v=R_z @ fused.v, R=R_z @ fused.R, P=T @ fused.P @ T.T)
    return _update(turned, measurement, X_BC, config).accepted > turned.accepted


def _lost(state: FederatedState, config: FederatedConfig) -> bool:
    """No measurement accepted for over max_coast_s (every node lost, or gated: a filter that has
    drifted off rejects what would bring it back): the next measurement restarts it."""
    last = last_accepted_s(state)
    return last is None or state.time - last > config.max_coast_s


def _update(state: LocalState, measurement: NodeMeasurement, X_BC: RigidTransform,
            config: FederatedConfig) -> LocalState:
    if measurement.view is not None:  # linearised about the filter's own pose, as the EKF's measurement model is
        X_CP = RigidTransform(RotationMatrix(state.R), state.p).multiply(X_BC).inverse()
        view = measurement.view
        return update_pattern_in_camera(state, view.X_CP.translation(), view.X_CP.rotation().matrix(),
                                        view.covariance_at(X_CP), X_BC.rotation().matrix(), X_BC.translation(), config)
    if measurement.X_PB is not None:
        return update_pose(state, measurement.X_PB.translation(), measurement.X_PB.rotation().matrix(),
                           measurement.covariance, config)
    return update_centre_in_camera(state, measurement.p_CP, measurement.covariance, X_BC.rotation().matrix(),
                                   X_BC.translation(), config)


def step(state: FederatedState, time: float, imu: np.ndarray, measurements: dict | None,
         config: FederatedConfig, X_BC: RigidTransform) -> FederatedState:
    """The state at `time` [s]: predicted with the IMU sample imu = [f_B (m/s^2), w_B (rad/s)] over
    the time since the last step, then (measurements: a dict node -> NodeMeasurement or None, a
    camera frame) updated, fused and reset."""
    imu = np.asarray(imu, dtype=float)
    f_B, w_B = imu[:3], imu[3:]
    filters, fused = state.filters, state.fused
    moved = state.started and time > state.time
    if moved:
        filters = tuple(predict(s, f_B, w_B, time - state.time, config, config.gravity_m_s2) for s in filters)
    if measurements is None:
        # Between frames the fused estimate is predicted alike: the filters split its covariance and
        # process noise by the betas (P_i = P_g / beta_i, Q_i = Q / beta_i, sum beta_i = 1), so the
        # predicted filters' information sums to the predicted fused one's (to first order where some
        # keep their own states: their predictions linearise about their own attitudes).
        if moved:
            fused = predict(fused, f_B, w_B, time - state.time, config, config.gravity_m_s2)
        return replace(state, time=time, filters=filters, fused=fused, last_imu=imu)
    state = replace(state, time=time, last_imu=imu)
    present = [(i, measurements.get(node)) for i, node in enumerate(NODES)]
    present = [(i, m) for i, m in present if m is not None]
    stats = list(state.stats)
    for i, m in present:  # a non-finite measurement is gated, here as at an update: it never starts the filters
        if not m.finite:
            stats[i] = replace(stats[i], gated=stats[i].gated + 1)
    present = [(i, m) for i, m in present if m.finite]
    pose = next(((i, m) for i, m in present if m.X_PB is not None), None)
    if not state.started and not present:
        return replace(state, stats=tuple(stats))
    lost = state.started and _lost(state, config)
    doubted = state.first_pose_doubted_s
    if doubted is not None and time - state.last_pose_doubted_s > config.max_coast_s:
        doubted = None  # the disagreeing poses stopped: a new one starts a new run
    if (pose is not None and state.started and not lost and not state.heading_known
            and not _agrees(filters, pose[1], X_BC, config)):
        if doubted is None or time - doubted < config.max_coast_s:
            # Left out, and the poses of this frame with it (the touchdown node's is anchored on the
            # adjustment node's); after max_coast_s of poses that disagree, the filters restart from one.
            state = replace(state, first_pose_doubted_s=time if doubted is None else doubted, last_pose_doubted_s=time)
            for i, m in present:
                if m.X_PB is not None:
                    stats[i] = replace(stats[i], gated=stats[i].gated + 1)
            present = [(i, m) for i, m in present if m.X_PB is None]
            pose = None
    if present and (not state.started or lost or (not state.heading_known and pose is not None)):
        i, source = pose or present[0]
        filters = _restart(state, source, X_BC, f_B, config, lost)
        state = replace(state, heading_known=pose is not None, first_pose_doubted_s=None, last_pose_doubted_s=None)
        stats[i] = NodeStats(stats[i].accepted + 1, stats[i].gated, time)
        present = [(j, m) for j, m in present if j != i]
    updated, kept = list(filters), []
    for i, measurement in present:
        after = _update(filters[i], measurement, X_BC, config)
        accepted = after.accepted > filters[i].accepted
        stats[i] = NodeStats(stats[i].accepted + accepted, stats[i].gated + (not accepted),
                             time if accepted else stats[i].last_accepted_s)
        updated[i] = after
        if accepted and not config.reset_states:
            kept.append(i)
    fused, betas = fuse(updated)
    return replace(state, fused=fused, filters=tuple(reset(updated, fused, betas, kept)),
                   local_estimates=tuple(updated), betas=betas, stats=tuple(stats))


def last_accepted_s(state: FederatedState) -> float | None:
    """The latest time any node's measurement was accepted (None: never)."""
    times = [s.last_accepted_s for s in state.stats if s.last_accepted_s is not None]
    return max(times) if times else None


def relative_jacobian(fused: LocalState) -> np.ndarray:
    """(3x9) d(p_BP_B)/d(error state) (`centre_in_body`'s): p_BP_B = -R_PB^T p_PB, the pattern's centre
    seen from the body, what the landing steers on (independent of the heading when only the centre was seen)."""
    return centre_in_body(fused)[1]


def relative_std_m(fused: LocalState) -> float:
    """sqrt(trace) of p_BP_B's covariance [m]."""
    J = relative_jacobian(fused)
    return float(np.sqrt(max(np.trace(J @ fused.P @ J.T), 0.0)))


def is_valid(state: FederatedState, config: FederatedConfig) -> bool:
    """Started, a node measured within max_coast_s, the relative position within max_relative_std_m
    and every number finite."""
    last = last_accepted_s(state)
    if not state.started or last is None or state.time - last > config.max_coast_s:
        return False
    fused = state.fused
    finite = all(np.all(np.isfinite(x)) for x in (fused.p, fused.v, fused.R, fused.P))
    return finite and relative_std_m(fused) <= config.max_relative_std_m


def X_PB(estimate: LocalState) -> RigidTransform:
    """The estimate as the pose of B in P."""
    return RigidTransform(RotationMatrix.ProjectToRotationMatrix(estimate.R), estimate.p)
