"""The search spiral about the rendezvous target (systems/perception/rendezvous_search.py)."""

import math

import numpy as np
import pytest
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.analysis import Simulator

from systems.perception.rendezvous import RendezvousConfig
from systems.perception.rendezvous_search import RendezvousSearch, spiral_offset
from systems.perception.seam import P_BP_B, P_BP_W, V_WP, VALID, seam_vector

SPACING, RADIUS, SPEED = 4.0, 8.0, 2.0


def test_the_spiral_is_archimedean_swept_at_its_speed_and_its_rate_is_the_offsets_derivative():
    wrap = (math.pi * RADIUS**2 / SPACING - SPACING / (4 * math.pi)) / SPEED  # [s] out to the radius
    taus = np.linspace(0.0, wrap - 0.01, 4001)
    offsets = np.array([spiral_offset(t, SPACING, RADIUS, SPEED)[0] for t in taus])
    r, theta = np.hypot(*offsets.T), np.unwrap(np.arctan2(offsets[:, 1], offsets[:, 0]))
    np.testing.assert_allclose(r, SPACING * theta / (2 * math.pi), rtol=1e-9)  # r = b theta / (2 pi)
    assert r.max() == pytest.approx(RADIUS, abs=0.01) and r[0] == pytest.approx(SPACING / (2 * math.pi))
    late = taus > 5.0  # away from the centre the arc is swept at the speed given (the s ~ theta^2 law is asymptotic)
    path_speed = np.hypot(*np.gradient(offsets, taus, axis=0).T)
    assert np.all(np.abs(path_speed[late][1:-1] - SPEED) < 0.05 * SPEED)
    for tau in (0.3, 3.0, 17.0):
        h = 1e-6
        numeric = (spiral_offset(tau + h, SPACING, RADIUS, SPEED)[0] - spiral_offset(tau - h, SPACING, RADIUS,
                                                                                     SPEED)[0]) / (2 * h)
        np.testing.assert_allclose(spiral_offset(tau, SPACING, RADIUS, SPEED)[1], numeric, rtol=1e-5, atol=1e-8)
    # Out to the radius, then again from the centre: the turns cover the disc at the spacing.
    assert np.hypot(*spiral_offset(wrap + 0.01, SPACING, RADIUS, SPEED)[0]) < 1.0
    np.testing.assert_array_equal(spiral_offset(-0.1, SPACING, RADIUS, SPEED)[0], np.zeros(2))


def test_the_search_moves_the_target_only_after_vision_has_been_lost_for_its_delay():
    system = RendezvousSearch(SPACING, RADIUS, SPEED, after_s=2.0)
    simulator = Simulator(system)
    context = simulator.get_mutable_context()
    X_WB = RigidTransform(RotationMatrix.MakeZRotation(0.7), [1.0, 2.0, 8.0])
    coarse = seam_vector(X_WB, np.array([6.0, 2.0, 1.6]), np.array([12.0, 0.0, 0.0]), np.zeros(3), True)
    vision = coarse.copy()
    system.GetInputPort("rendezvous").FixValue(context, coarse)
    system.GetInputPort("vision").FixValue(context, vision)
    system.GetInputPort("X_WB").FixValue(context, X_WB)
    out = system.get_output_port()
    simulator.AdvanceTo(3.05)  # seen throughout (the last sample at 3.0 s): the broadcast as it is
    np.testing.assert_array_equal(out.Eval(context), coarse)
    vision[VALID] = 0.0
    system.GetInputPort("vision").FixValue(context, vision)
    simulator.AdvanceTo(4.5)  # lost at 3.0 s (its last valid sample): 1.5 s < 2 s, no search yet
    np.testing.assert_array_equal(out.Eval(context), coarse)
    simulator.AdvanceTo(8.0)
    searched = out.Eval(context)
    offset, rate = spiral_offset(8.0 - 3.0 - 2.0, SPACING, RADIUS, SPEED)
    np.testing.assert_allclose(searched[P_BP_W], coarse[P_BP_W] + [*offset, 0.0])
    np.testing.assert_allclose(searched[V_WP], coarse[V_WP] + [*rate, 0.0])
    np.testing.assert_allclose(searched[P_BP_B], X_WB.rotation().inverse().multiply(searched[P_BP_W]))
    assert searched[VALID] == 1.0
    coarse[VALID] = 0.0  # no broadcast: nothing to search about
    system.GetInputPort("rendezvous").FixValue(context, coarse)
    np.testing.assert_array_equal(out.Eval(context), coarse)


@pytest.mark.parametrize("setting, message", [
    ({"search_spacing_m": -1.0}, "rendezvous.search_spacing_m must not be negative"),
    ({"search_spacing_m": 10.0}, "rendezvous.search_spacing_m must not exceed rendezvous.search_radius_m"),
    ({"search_speed_m_s": 0.0}, "rendezvous.search_speed_m_s must be positive"),
    ({"latency_periods": 10}, r"rendezvous.max_age_s \(1 s\) must be at least the oldest a held message gets, "
                              r"\(rendezvous.latency_periods \+ 1\) / rate_hz \(1.1 s\)"),
])
def test_bad_search_settings_are_named(setting, message):
    with pytest.raises(ValueError, match=message):
        RendezvousConfig(source="broadcast", **setting).validate()


def test_the_search_spacing_may_equal_the_radius_but_not_exceed_it():
    RendezvousConfig(source="broadcast", search_spacing_m=8.0, search_radius_m=8.0).validate()  # one turn: allowed
    with pytest.raises(ValueError, match="rendezvous.search_spacing_m must not exceed rendezvous.search_radius_m"):
        RendezvousConfig(source="broadcast", search_spacing_m=8.01, search_radius_m=8.0).validate()


def test_the_sweep_starts_at_the_spirals_inner_end_the_moment_the_delay_is_over():
    """Vision never valid (its last sample the start, 0 s): at exactly after_s the target is already moved to the
    spiral's start (module docstring): r0 = b / (2 pi) out, at theta0 = 2 pi r0 / b = 1 rad, moving at the
    speed tangentially and, there, as fast radially."""
    system = RendezvousSearch(SPACING, RADIUS, SPEED, after_s=2.0)
    context = system.CreateDefaultContext()
    coarse = seam_vector(RigidTransform(), np.array([6.0, 2.0, 1.6]), np.zeros(3), np.zeros(3), True)
    vision = coarse.copy()
    vision[VALID] = 0.0
    system.GetInputPort("rendezvous").FixValue(context, coarse)
    system.GetInputPort("vision").FixValue(context, vision)
    system.GetInputPort("X_WB").FixValue(context, RigidTransform())
    context.SetTime(2.0)
    searched = system.get_output_port().Eval(context)
    r0, theta0 = SPACING / (2 * math.pi), 1.0
    radial_out, along = np.array([math.cos(theta0), math.sin(theta0)]), np.array([-math.sin(theta0), math.cos(theta0)])
    np.testing.assert_allclose(searched[P_BP_W], coarse[P_BP_W] + [*(r0 * radial_out), 0.0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(searched[V_WP], [*(SPEED * (radial_out + along)), 0.0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(searched[P_BP_B], searched[P_BP_W], rtol=0, atol=1e-12)  # X_WB: the identity
