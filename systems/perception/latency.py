"""Measurement latency: what a sensor acquired at one sample reaches its consumers whole samples later.

Seed 002 budgets 25 ms to acquire a frame and 10 ms to process it, so the measurements taken at
t_k reach the filters at t_{k+1}. `delay_queue` is the pure first-in first-out queue;
`MeasurementLatency` is the system that holds it between samples: with a delay of d samples, what
was acquired at t_k is its output from t_{k+d} (before and after that sample's update) until t_{k+d+1}.
"""

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from systems.config import require, require_positive
from systems.stepped import TIME_TOLERANCE_S, is_step_time


def due(queue: tuple, delay_steps: int) -> list:
    """What is due at the sample after a queue's newest (samples as tuples, oldest first): the one
    `delay_steps` >= 1 samples before that sample, or nothing while the queue is too short."""
    return list(queue[-delay_steps]) if len(queue) >= delay_steps else []


def delay_queue(queue: tuple, acquired, delay_steps: int) -> tuple[tuple, list]:
    """One sample: (the queue after this sample's `acquired` list joins it, keeping `delay_steps` + 1
    samples; the list due now: the one acquired `delay_steps` samples ago, or [] before the first one
    is due)."""
    if delay_steps == 0:
        return (), list(acquired)
    return (queue + (tuple(acquired),))[-(delay_steps + 1):], due(queue, delay_steps)


class MeasurementLatency(LeafSystem):
    """Input `measurements` (a list, acquired at the samples t_k = k period_s); output `delayed` (a
    list): at any time in [t_k, t_{k+1}), what was acquired at t_{k - delay_steps} (none before),
    whether read before or after the update at t_k. Its periodic update acquires at every sample.
    delay_steps 0 passes the input through.

    With `model_value` (any value, or a numpy vector for vector ports) it delays one value instead of a
    list: ports of that value's type, and `model_value` itself before the first sample is due."""

    def __init__(self, period_s: float, delay_steps: int, model_value=None):
        super().__init__()
        require_positive(period_s, "latency period_s")
        require(delay_steps >= 0, f"latency delay_steps must not be negative, got {delay_steps}")
        self._period, self._delay_steps, self._model = period_s, delay_steps, model_value
        if isinstance(model_value, np.ndarray):
            self._input = self.DeclareVectorInputPort("measurements", model_value.size)
        else:
            self._input = self.DeclareAbstractInputPort("measurements", AbstractValue.Make(self._default()))
        if delay_steps:
            self._queue = self.DeclareAbstractState(AbstractValue.Make(()))
            self._last = self.DeclareAbstractState(AbstractValue.Make(-float("inf")))  # the last sample's time [s]
            self.DeclarePeriodicUnrestrictedUpdateEvent(period_s, 0.0, self._acquire)
            self._declare_output(self._due, {self.time_ticket(), self.abstract_state_ticket(self._queue),
                                             self.abstract_state_ticket(self._last)})
        else:
            self._declare_output(lambda c: self._as_output(self._acquired(c)), {self.all_input_ports_ticket()})

    def _default(self):
        return [] if self._model is None else self._model

    def _declare_output(self, calc, tickets) -> None:
        if isinstance(self._model, np.ndarray):
            self.DeclareVectorOutputPort("delayed", self._model.size, lambda c, o: o.SetFromVector(calc(c)), tickets)
        else:
            self.DeclareAbstractOutputPort("delayed", lambda: AbstractValue.Make(self._default()),
                                           lambda c, o: o.set_value(calc(c)), tickets)

    def _acquired(self, context) -> list:
        value = self._input.Eval(context)
        return list(value) if self._model is None else [np.array(value) if isinstance(value, np.ndarray) else value]

    def _as_output(self, items: list):
        if self._model is None:
            return items
        return items[0] if items else self._model

    def _acquire(self, context, state):
        queue = context.get_abstract_state(self._queue).get_value()
        state.get_mutable_abstract_state(self._queue).set_value(
            delay_queue(queue, self._acquired(context), self._delay_steps)[0])
        state.get_mutable_abstract_state(self._last).set_value(context.get_time())

    def _due(self, context):
        """At a sample not acquired yet, what is due then from the queue (as `delay_queue` gives it);
        otherwise what was due at the newest sample in the queue, the queue as it was before it."""
        queue, t = context.get_abstract_state(self._queue).get_value(), context.get_time()
        if not (is_step_time(t, self._period) and t > context.get_abstract_state(self._last).get_value()
                + TIME_TOLERANCE_S):
            queue = queue[:-1]
        return self._as_output(due(queue, self._delay_steps))
