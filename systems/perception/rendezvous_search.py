"""A search around the rendezvous target (issue 10): the vehicle's broadcast position is off by its GNSS
error (2 m per axis, drifting over a minute: several metres at times), which can hold the pad outside the
downward camera's footprint while the UAV follows the broadcast. While the vision seam has not been valid
for `after_s`, the coarse target is swept along an Archimedean spiral about the broadcast position,
r = b theta / (2 pi) with b = `spacing_m` between turns (less than the camera's footprint at IH, so the
footprints overlap), at `speed_m_s` along the spiral, out to `radius_m` and then again from the centre.
Once vision is valid the search ends (the vision seam steers; SeamSelect).

Along the spiral, arc length s ~ b theta^2 / (4 pi) (exact for large theta), so theta = sqrt(4 pi s / b)
and r = sqrt(b s / pi); the sweep's speed is `speed_m_s` tangentially and v sqrt(b / (pi s)) / 2
radially. It starts at s0 = b / (4 pi) (r0 = b / (2 pi), where the radial speed equals the tangential).
Frames: World W (z up), offsets horizontal; m, s.
"""

import math

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.systems.framework import LeafSystem

from systems.flags import is_set
from systems.perception.seam import P_BP_B, P_BP_W, RELATIVE_STATE_SIZE, V_WP, VALID


def spiral_offset(tau_s: float, spacing_m: float, radius_m: float, speed_m_s: float) -> tuple[np.ndarray, np.ndarray]:
    """(offset (2, m), its rate (2, m/s)) in W of the sweep `tau_s` [s] after it began (module docstring);
    zero before it begins."""
    if tau_s < 0.0:
        return np.zeros(2), np.zeros(2)
    s0 = spacing_m / (4.0 * math.pi)
    s_max = math.pi * radius_m**2 / spacing_m  # the arc length at radius_m
    s = s0 + (speed_m_s * tau_s) % max(s_max - s0, 1e-9)
    theta = math.sqrt(4.0 * math.pi * s / spacing_m)
    r = spacing_m * theta / (2.0 * math.pi)
    radial, tangential = speed_m_s * math.sqrt(spacing_m / (math.pi * s)) / 2.0, speed_m_s
    c, si = math.cos(theta), math.sin(theta)
    return r * np.array([c, si]), np.array([radial * c - tangential * si, radial * si + tangential * c])


class RendezvousSearch(LeafSystem):
    """Inputs `rendezvous` (the coarse seam, systems/perception/rendezvous.py), `vision` (the vision seam:
    its valid flag is read) and `X_WB` (RigidTransform, the UAV's navigation). Output `relative_state`: the rendezvous seam with its
    target moved along the search spiral while vision has been invalid for `after_s` (module docstring).
    Discrete state: the last time vision was valid [s] (0 at the start), updated at `rate_hz`."""

    def __init__(self, spacing_m: float, radius_m: float, speed_m_s: float, after_s: float, rate_hz: float = 10.0):
        super().__init__()
        self._pattern = (spacing_m, radius_m, speed_m_s)
        self._after = after_s
        self._rendezvous = self.DeclareVectorInputPort("rendezvous", RELATIVE_STATE_SIZE)
        self._vision = self.DeclareVectorInputPort("vision", RELATIVE_STATE_SIZE)
        self._X_WB = self.DeclareAbstractInputPort("X_WB", AbstractValue.Make(RigidTransform()))
        self._last_seen = self.DeclareDiscreteState(1)
        self.DeclarePeriodicDiscreteUpdateEvent(1.0 / rate_hz, 0.0, self._update)
        self.DeclareVectorOutputPort("relative_state", RELATIVE_STATE_SIZE, self._calc)

    def _update(self, context, discrete_state):
        if is_set(self._vision.Eval(context)[VALID]):
            discrete_state.set_value(self._last_seen, [context.get_time()])

    def _calc(self, context, output):
        seam = self._rendezvous.Eval(context).copy()
        tau = context.get_time() - context.get_discrete_state(self._last_seen).get_value()[0] - self._after
        if is_set(seam[VALID]) and tau >= 0.0:
            offset, rate = spiral_offset(tau, *self._pattern)
            seam[P_BP_W][:2] += offset  # pad minus UAV: the target moved by the offset
            seam[P_BP_B] = self._X_WB.Eval(context).rotation().inverse().multiply(seam[P_BP_W])
            seam[V_WP][:2] += rate
        output.SetFromVector(seam)
