"""A LeafSystem's periodic step whose result is seen at the step's own time.

Drake's periodic update computes the next state from the context at t_k, but an output computed
from the state shows the step at t_k only after the update. `SteppedValue` keeps the value in
abstract state and a cache entry `now` that, at a step time whose step the state has not taken yet,
takes it from the inputs then; the update stores the same value. So a logger, a controller or a
downstream filter reading at t_k sees the step of t_k, whatever the order of events.

    self._stepped = SteppedValue(self, "filter", initial, period_s, self._step, lambda v: v.time)
    ... self._stepped.now.Eval(context)   # the value at the context's time
"""

from collections.abc import Callable

from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem, ValueProducer

TIME_TOLERANCE_S = 1e-9


def in_intervals(t: float, intervals) -> bool:
    """t [s] lies in one of the [start, end] intervals [s], bounds included within TIME_TOLERANCE_S: an event
    time k T lands a rounding off the bound it was meant to hit (20 Hz: 12 * 0.05 = 0.6000000000000001)."""
    return any(start - TIME_TOLERANCE_S <= t <= end + TIME_TOLERANCE_S for start, end in intervals)


def is_step_time(t: float, period_s: float) -> bool:
    """t [s] is a multiple of period_s (within TIME_TOLERANCE_S)."""
    return abs(t - round(t / period_s) * period_s) <= TIME_TOLERANCE_S


class SteppedValue:
    """Declares on `system` an abstract state `name` holding `initial`, the cache entry `now` and a
    periodic unrestricted update every `period_s` from 0. `step(context, value)` returns the value
    after the step at the context's time (without changing `value`); `time_of(value)` is the time of
    the value's last step, or None before the first."""

    def __init__(self, system: LeafSystem, name: str, initial, period_s: float,
                 step: Callable, time_of: Callable):
        self._period, self._step, self._time_of = period_s, step, time_of
        self._state = system.DeclareAbstractState(AbstractValue.Make(initial))
        self.now = system.DeclareCacheEntry(f"{name}_now", ValueProducer(
            allocate=lambda: AbstractValue.Make(initial), calc=self._calc_now),
            {system.time_ticket(), system.abstract_state_ticket(self._state), system.all_input_ports_ticket()})
        system.DeclarePeriodicUnrestrictedUpdateEvent(period_s, 0.0, self._update)

    def _calc_now(self, context, value):
        stored = context.get_abstract_state(self._state).get_value()
        t, last = context.get_time(), self._time_of(stored)
        if is_step_time(t, self._period) and (last is None or t > last + TIME_TOLERANCE_S):
            stored = self._step(context, stored)
        value.set_value(stored)

    def _update(self, context, state):
        state.get_mutable_abstract_state(self._state).set_value(self.now.Eval(context))
