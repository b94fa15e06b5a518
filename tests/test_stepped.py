"""systems/stepped.py: a SteppedValue shows the step of t_k at t_k, before the update stores it, and is not
stepped again between steps; is_step_time forgives the rounding of k T."""

from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import BasicVector, LeafSystem

from systems.stepped import SteppedValue, in_intervals, is_step_time

PERIOD_S = 0.05


class Counter(LeafSystem):
    """Counts its steps: the value is (time of the last step or None, steps taken)."""

    def __init__(self):
        super().__init__()
        self.stepped = SteppedValue(self, "count", (None, 0), PERIOD_S, lambda context, value: (
            context.get_time(), value[1] + 1), lambda value: value[0])


class Sampler(LeafSystem):
    """Samples its input: the value is (time of the last step or None, the input then)."""

    def __init__(self):
        super().__init__()
        self.input = self.DeclareVectorInputPort("u", BasicVector(1))
        self.stepped = SteppedValue(self, "sample", (None, None), PERIOD_S, lambda context, value: (
            context.get_time(), float(self.input.Eval(context)[0])), lambda value: value[0])


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
    assert not is_step_time(0.3 + 1e-8, PERIOD_S)  # ten times the tolerance off: no step


def test_a_step_already_taken_at_this_time_is_not_taken_again():
    """A context at t = 0.1 s whose state already holds the step of 0.1 s: `now` is that state, one step, not two."""
    counter = Counter()
    context = counter.CreateDefaultContext()
    context.SetTime(0.1)
    context.get_mutable_abstract_state(0).set_value((0.1, 3))
    assert counter.stepped.now.Eval(context) == (0.1, 3)


def test_the_pending_step_follows_the_time_and_the_inputs():
    """`now` at a step time is computed from the context then: set to the next step's time, it takes that step
    (from the stored state, where no update stored the first); with another input at the same time, it takes the
    step on that input."""
    counter = Counter()
    context = counter.CreateDefaultContext()
    assert counter.stepped.now.Eval(context) == (0.0, 1)
    context.SetTime(PERIOD_S)
    assert counter.stepped.now.Eval(context) == (PERIOD_S, 1)
    sampler = Sampler()
    context = sampler.CreateDefaultContext()
    sampler.input.FixValue(context, [1.0])
    assert sampler.stepped.now.Eval(context) == (0.0, 1.0)
    sampler.input.FixValue(context, [2.0])
    assert sampler.stepped.now.Eval(context) == (0.0, 2.0)


def test_a_time_lies_in_any_of_the_intervals_bounds_included_within_the_rounding():
    """12 * 0.05 is 0.6000000000000001 in doubles: the end of [0, 0.6] all the same; 1e-8 past it is not."""
    assert 12 * PERIOD_S > 0.6
    assert in_intervals(12 * PERIOD_S, [(0.0, 0.6)]) and in_intervals(0.6 - 1e-10, [(0.6, 1.0)])
    assert not in_intervals(0.6 + 1e-8, [(0.0, 0.6)]) and not in_intervals(0.6 - 1e-8, [(0.6, 1.0)])
    assert in_intervals(2.5, [(0.0, 1.0), (2.0, 3.0)])  # in the second
    assert not in_intervals(1.5, [(0.0, 1.0), (2.0, 3.0)]) and not in_intervals(1.0, [])
