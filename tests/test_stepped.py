"""systems/stepped.py: a SteppedValue shows the step of t_k at t_k, before the update stores it, and is not
stepped again between steps; is_step_time forgives the rounding of k T."""

from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import LeafSystem

from systems.stepped import SteppedValue, is_step_time

PERIOD_S = 0.05


class Counter(LeafSystem):
    """Counts its steps: the value is (time of the last step or None, steps taken)."""

    def __init__(self):
        super().__init__()
        self.stepped = SteppedValue(self, "count", (None, 0), PERIOD_S, lambda context, value: (
            context.get_time(), value[1] + 1), lambda value: value[0])


def test_a_stepped_value_shows_its_step_at_the_step_time_and_holds_it_between_steps():
    """Stepped every 50 ms from 0: at t = 0.1 s, before the update there, `now` already has the steps of 0, 0.05
    and 0.1 (the stored state only the first two); at t = 0.125 s, between steps, it is still those three."""
    counter = Counter()
    simulator = Simulator(counter)
    context = simulator.get_mutable_context()
    simulator.AdvanceTo(0.1)
    assert counter.stepped.now.Eval(context) == (0.1, 3)
    assert context.get_abstract_state(0).get_value()[1] == 2
    simulator.AdvanceTo(0.125)
    assert counter.stepped.now.Eval(context) == (0.1, 3)
    assert context.get_abstract_state(0).get_value() == (0.1, 3)


def test_a_step_time_is_a_multiple_of_the_period_within_the_rounding():
    """0.3 is 6 periods of 0.05 though 0.3 - 6 * 0.05 is -5.6e-17 in doubles; 0.125 is none."""
    assert 0.3 != 6 * PERIOD_S
    assert is_step_time(0.3, PERIOD_S) and is_step_time(6 * PERIOD_S, PERIOD_S) and is_step_time(0.0, PERIOD_S)
    assert not is_step_time(0.125, PERIOD_S) and not is_step_time(0.3 + 1e-6, PERIOD_S)
