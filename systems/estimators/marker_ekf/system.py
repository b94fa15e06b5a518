"""`MarkerFilterSystem`: a marker filter (engine.py) stepped in a Drake diagram."""

import copy

from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.systems.framework import LeafSystem, ValueProducer

from systems.estimators.estimate import PoseEstimate
from systems.estimators.marker_ekf.engine import ESTIMATE_VECTOR_SIZE, FilterStats, MarkerFilter
from systems.stepped import SteppedValue


class MarkerFilterSystem(LeafSystem):
    """A marker filter stepped at t_k = k config.period_s by a periodic update.

    Inputs: `marker_measurements` (list of MarkerMeasurement arriving at this step) and `X_WB`
    (RigidTransform, the UAV body). The outputs at any time t are the estimate from everything that
    has arrived by t, predicted to t. At a step time that includes the step itself, computed from
    the inputs then (the update stores the same filter): so a logger or a controller reading at t_k
    sees the measurements that arrived at t_k, whatever the order of events.
    Outputs: `X_WP_estimate` (PoseEstimate of the pad frame P in W), `v_WP_estimate` (3, m/s) and
    `a_WP_estimate` (3, m/s^2) in W, `estimate_vector` (engine.ESTIMATE_VECTOR_SIZE: the EST_*
    layout), `p_WM_estimate` (3 n: the marker centres in W, m; NaN before the start) and
    `filter_stats` (FilterStats).
    """

    def __init__(self, marker_filter: MarkerFilter):
        super().__init__()
        self._period = marker_filter.config.period_s
        self._measurements = self.DeclareAbstractInputPort("marker_measurements", AbstractValue.Make([]))
        self._X_WB = self.DeclareAbstractInputPort("X_WB", AbstractValue.Make(RigidTransform()))
        self._now = SteppedValue(self, "filter", marker_filter, self._period, self._step, lambda f: f.time).now
        self._estimate = self.DeclareCacheEntry("estimate", ValueProducer(
            allocate=lambda: AbstractValue.Make(marker_filter.estimate()),
            calc=lambda c, v: v.set_value(self._now.Eval(c).estimate(c.get_time()))), {self._now.ticket()})
        estimate = {self._estimate.ticket()}
        n = len(marker_filter.layout.ids)
        self.DeclareAbstractOutputPort("X_WP_estimate", lambda: AbstractValue.Make(PoseEstimate()),
                                       lambda c, o: o.set_value(self._estimate.Eval(c).X_WP), estimate)
        for name, size, part in (("v_WP_estimate", 3, lambda e: e.v_WP), ("a_WP_estimate", 3, lambda e: e.a_WP),
                                 ("estimate_vector", ESTIMATE_VECTOR_SIZE, lambda e: e.vector),
                                 ("p_WM_estimate", 3 * n, lambda e: e.p_WM.ravel())):
            self.DeclareVectorOutputPort(name, size, lambda c, o, part=part: o.SetFromVector(
                part(self._estimate.Eval(c))), estimate)
        self.DeclareAbstractOutputPort("filter_stats", lambda: AbstractValue.Make(FilterStats()),
                                       lambda c, o: o.set_value(self._now.Eval(c).stats), {self._now.ticket()})

    def _step(self, context, marker_filter: MarkerFilter) -> MarkerFilter:
        stepped = copy.copy(marker_filter)
        stepped.step(context.get_time(), self._X_WB.Eval(context), self._measurements.Eval(context))
        return stepped
