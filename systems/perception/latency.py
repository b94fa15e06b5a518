"""Measurement latency: what a sensor acquired at one sample reaches its consumers whole samples later.

Seed 002 budgets 25 ms to acquire a frame and 10 ms to process it, so the measurements taken at
t_k reach the filters at t_{k+1}. `delay_queue` is the pure first-in first-out queue;
`MeasurementLatency` is the system that holds it between samples.
"""

from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from systems.config import require, require_positive


def due(queue: tuple, delay_steps: int) -> list:
    """What is due from a queue of `delay_steps` >= 1 samples (tuples, oldest first): its oldest
    sample once it is full, else nothing."""
    return list(queue[0]) if len(queue) == delay_steps else []


def delay_queue(queue: tuple, acquired, delay_steps: int) -> tuple[tuple, list]:
    """One sample: (the queue after this sample's `acquired` list joins it, the list due now: the
    one acquired `delay_steps` samples ago, or [] before the first one is due)."""
    if delay_steps == 0:
        return (), list(acquired)
    return (queue + (tuple(acquired),))[-delay_steps:], due(queue, delay_steps)


class MeasurementLatency(LeafSystem):
    """Input `measurements` (a list, acquired at the samples t_k = k period_s); output `delayed` (a
    list): at t_k, what was acquired at t_{k - delay_steps} (none before). Its periodic update
    acquires at every sample; consumers read the output at the same samples. delay_steps 0 passes
    the input through."""

    def __init__(self, period_s: float, delay_steps: int):
        super().__init__()
        require_positive(period_s, "latency period_s")
        require(delay_steps >= 0, f"latency delay_steps must not be negative, got {delay_steps}")
        self._delay_steps = delay_steps
        self._input = self.DeclareAbstractInputPort("measurements", AbstractValue.Make([]))
        if delay_steps:
            self._queue = self.DeclareAbstractState(AbstractValue.Make(()))
            self.DeclarePeriodicUnrestrictedUpdateEvent(period_s, 0.0, self._acquire)
            self.DeclareAbstractOutputPort("delayed", lambda: AbstractValue.Make([]), self._calc,
                                           {self.abstract_state_ticket(self._queue)})
        else:
            self.DeclareAbstractOutputPort("delayed", lambda: AbstractValue.Make([]),
                                           lambda c, o: o.set_value(list(self._input.Eval(c))))

    def _acquire(self, context, state):
        queue = context.get_abstract_state(self._queue).get_value()
        state.get_mutable_abstract_state(self._queue).set_value(
            delay_queue(queue, self._input.Eval(context), self._delay_steps)[0])

    def _calc(self, context, output):
        output.set_value(due(context.get_abstract_state(self._queue).get_value(), self._delay_steps))
