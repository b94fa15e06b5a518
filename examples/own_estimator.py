"""Fly the UAV on an estimator of your own: a LeafSystem written here, wired behind the perception
seam of the marker-landing scenario, without changing the package.

    .venv/bin/python examples/own_estimator.py                       # the rendered camera (about 20 s)
    .venv/bin/python examples/own_estimator.py --set estimation.source=synthetic

The estimator: every marker measured in a frame gives the pad's pose (the markers are aligned with
the pad, at known offsets), computed with the UAV's pose when the frame was taken; their mean feeds
an alpha-beta filter of the pad's position and velocity, stamped with the frame's time and
predicted to whenever the controller asks. It is valid while it has seen a marker within the last
1.5 s: enough to coast through the end of the descent, where the camera is too close to see one.
"""

import argparse
import sys
from pathlib import Path

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.systems.framework import LeafSystem

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # run from a checkout without installing

from diagrams.gv_landing_run import fly  # noqa: E402
from diagrams.perception_sources import PerceptionSource, add_estimate_to_seam, register_source  # noqa: E402
from diagrams.runner import load_scenario  # noqa: E402
from systems.config import ConfigError  # noqa: E402
from systems.estimators.estimate import PoseEstimate  # noqa: E402


class AveragedMarkers(LeafSystem):
    """Inputs `marker_measurements` (list of MarkerMeasurement) and `X_WB` (the UAV); outputs
    `X_WP_estimate` (PoseEstimate of the pad in W) and `v_WP_estimate` (3, m/s), predicted to the
    context's time. State: [time of the track, x, y, z, yaw, vx, vy, vz, last seen], and the UAV's
    recent poses."""

    ALPHA, BETA, MAX_AGE_S = 0.5, 0.1, 1.5

    def __init__(self, layout, X_BC: RigidTransform, period_s: float):
        super().__init__()
        self._p_PM, self._ids, self._X_BC, self._period = layout.p_PM, list(layout.ids), X_BC, period_s
        self._measurements = self.DeclareAbstractInputPort("marker_measurements", AbstractValue.Make([]))
        self._X_WB = self.DeclareAbstractInputPort("X_WB", AbstractValue.Make(RigidTransform()))
        self._track = self.DeclareDiscreteState(np.r_[np.full(8, np.nan), -np.inf])
        self._poses = self.DeclareAbstractState(AbstractValue.Make(()))  # ((time, X_WB), ...), newest last
        self.DeclarePeriodicUnrestrictedUpdateEvent(period_s, 0.0, self._update)
        self.DeclareAbstractOutputPort("X_WP_estimate", lambda: AbstractValue.Make(PoseEstimate()), self._pose)
        self.DeclareVectorOutputPort("v_WP_estimate", 3, lambda c, o: o.SetFromVector(
            np.nan_to_num(c.get_discrete_state(self._track).get_value()[5:8])))

    def _pad_from(self, m, X_WB) -> np.ndarray:
        """[x, y, z, yaw] of the pad from one marker measured with the UAV at X_WB."""
        X_WM = X_WB.multiply(self._X_BC).multiply(m.X_CM)
        p_WP = X_WM.multiply(-self._p_PM[self._ids.index(m.marker_id)])  # the marker's frame is the pad's, shifted
        return np.r_[p_WP, RollPitchYaw(X_WM.rotation()).yaw_angle()]

    def _update(self, context, state):
        t, X_WB = context.get_time(), self._X_WB.Eval(context)
        poses = (context.get_abstract_state(self._poses).get_value() + ((t, X_WB),))[-8:]
        track = context.get_discrete_state(self._track).get_value().copy()
        seen = [m for m in self._measurements.Eval(context) if m.marker_id in self._ids]
        if seen:
            t = seen[0].time  # when the frame was taken (its latency is behind us)
            taken = min(poses, key=lambda pose: abs(pose[0] - t))[1]  # the UAV then
            pads = np.array([self._pad_from(m, taken) for m in seen])
            measured = np.r_[pads[:, :3].mean(axis=0), np.arctan2(np.sin(pads[:, 3]).mean(), np.cos(pads[:, 3]).mean())]
            if np.isnan(track[0]):
                track[1:8] = np.r_[measured, 0.0, 0.0, 0.0]
            else:
                dt = t - track[0]
                predicted = track[1:4] + dt * track[5:8]
                residual = measured[:3] - predicted
                track[1:4] = predicted + self.ALPHA * residual
                track[5:8] += self.BETA / dt * residual
                track[4] = measured[3]
            track[0], track[8] = t, t
        state.get_mutable_discrete_state(self._track).set_value(track)
        state.get_mutable_abstract_state(self._poses).set_value(poses)

    def _pose(self, context, output):
        track = context.get_discrete_state(self._track).get_value()
        t = context.get_time()
        if np.isnan(track[0]):
            output.set_value(PoseEstimate.invalid(t, "W", "P"))
            return
        p_WP = track[1:4] + (t - track[0]) * track[5:8]
        output.set_value(PoseEstimate(t, RigidTransform(RollPitchYaw(0.0, 0.0, track[4]), p_WP),
                                      valid=t - track[8] <= self.MAX_AGE_S, reference="W", target="P"))


def add_averaged_markers(builder, inputs):
    """The perception source: the estimator on the scene's marker stream, behind the seam."""
    config = inputs.config
    estimator = builder.AddNamedSystem("averaged_markers", AveragedMarkers(
        config.platform.markers, config.estimation.X_BC, config.estimation.ekf.period_s))
    builder.Connect(inputs.marker_measurements, estimator.GetInputPort("marker_measurements"))
    builder.Connect(inputs.X_WB, estimator.GetInputPort("X_WB"))
    return add_estimate_to_seam(builder, inputs, estimator.GetOutputPort("X_WP_estimate"),
                                estimator.GetOutputPort("v_WP_estimate"))


def main(argv=None) -> dict:
    """Flies marker-landing on the example's estimator and returns its metrics; a bad --set is one line on
    stderr and exit status 2."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    args = parser.parse_args(argv)
    register_source("averaged_markers", PerceptionSource(add_averaged_markers, needs_markers=True))
    try:
        _, scenario = load_scenario("marker-landing", overrides=["perception.source=averaged_markers", *args.overrides])
        metrics, _ = fly(scenario, scenario.duration_s)
    except ConfigError as e:
        parser.exit(2, f"{parser.prog}: error: {e}\n")
    landing, perception = metrics["landing"], metrics["perception"]
    if landing["success"]:
        print(f"landed {landing['touchdown_error_m']:.3f} m from the pad centre at "
              f"{landing['touchdown_rel_speed_mps']:.2f} m/s (touchdown by the {landing['touchdown_by']}, "
              f"{landing['touchdown_gap_m']:.3f} m fallen)")
    else:
        print(f"no landing: {landing['failure_reason']} ({landing['failure_detail']})")
    print(f"averaged_markers steering: RMS position {perception.get('rms_position_m', float('nan')):.3f} m, valid "
          f"{perception['valid_fraction']:.0%} of the flight")
    for name, m in metrics["estimators"].items():
        print(f"{name} watching: RMS position {m.get('rms_position_m', float('nan')):.3f} m")
    return metrics


if __name__ == "__main__":
    main()
