import numpy as np
import pytest
from pydrake.common.yaml import yaml_load_typed
from pydrake.systems.analysis import Simulator

from systems.control.pid import (
    HeightScheduledPid, PidGains, TrackingPid, TrackingPidConfig, feed_forward, gains_for_height,
)


def test_defaults_are_seed_003_table_2_simulation_row():
    config = TrackingPidConfig()
    assert config.switch_height_m == 4.0
    assert (config.gains_above.kp, config.gains_above.ki, config.gains_above.kd) == (0.80, 0.0, 0.35)
    assert (config.gains_below.kp, config.gains_below.ki, config.gains_below.kd) == (1.50, 0.0, 0.50)
    # Sec. 3.1.1: AirSim gave 3-5 frames/s, one PID step per frame; Kd acts per frame, so the gains hold at the
    # middle of that range, 4 Hz.
    assert config.rate_hz == 4.0
    # Not in the paper: the limit must let the UAV follow the fastest ground vehicle of seed 002 (12 m/s).
    assert config.max_speed_m_s > 12.0


def test_hand_worked_sequence():
    # Kp 0.5, Ki 0.1, Kd 0.2 on e_x = 1.0, 0.8, 0.5 and e_y = -2, -1, 0:
    #   k=0: sums (1.0, -2), no difference  -> x 0.5 + 0.10 + 0     = 0.60, y -1.0 - 0.2 + 0   = -1.2
    #   k=1: sums (1.8, -3), diff (-0.2, 1) -> x 0.4 + 0.18 - 0.04  = 0.54, y -0.5 - 0.3 + 0.2 = -0.6
    #   k=2: sums (2.3, -3), diff (-0.3, 1) -> x 0.25 + 0.23 - 0.06 = 0.42, y  0.0 - 0.3 + 0.2 = -0.1
    gains = PidGains(kp=0.5, ki=0.1, kd=0.2)
    pid = HeightScheduledPid(TrackingPidConfig(gains_above=gains, gains_below=gains))
    outputs = [pid.step(e, height=5.0) for e in ([1.0, -2.0], [0.8, -1.0], [0.5, 0.0])]
    np.testing.assert_allclose(outputs, [[0.60, -1.2], [0.54, -0.6], [0.42, -0.1]], atol=1e-12)


def test_height_switches_between_table_2_gain_sets():
    config = TrackingPidConfig()
    assert gains_for_height(4.0, config) is config.gains_above  # ">= 4 m"
    assert gains_for_height(3.99, config) is config.gains_below
    high, low = HeightScheduledPid(config), HeightScheduledPid(config)
    for pid, height, expected in ((high, 7.5, [0.80, 0.8 * 0.8 - 0.35 * 0.2]),
                                  (low, 2.0, [1.50, 1.5 * 0.8 - 0.50 * 0.2])):
        np.testing.assert_allclose([pid.step([1.0, 0.0], height)[0],
                                    pid.step([0.8, 0.0], height)[0]], expected)


def test_target_velocity_is_fed_forward_and_speed_limited():
    np.testing.assert_allclose(feed_forward(np.array([0.5, -0.2]), [3.0, 1.0], 15.0), [3.5, 0.8])
    limited = feed_forward(np.array([20.0, 0.0]), [0.0, 15.0], 15.0)
    assert np.linalg.norm(limited) == pytest.approx(15.0)
    np.testing.assert_allclose(limited / 15.0, np.array([20.0, 15.0]) / 25.0)


def test_the_sum_does_not_wind_up_against_the_speed_limit():
    # Conditional integration: 40 frames 10 m behind the target hold the command at the 2 m/s limit without
    # adding to the sum (unclamped it reaches 400 m, and the command points forward for 397 frames after the
    # error turns to -1 m); the first frame at -1 m reverses it: Kp e + Ki e = -0.5 - 0.2.
    gains = PidGains(kp=0.5, ki=0.2, kd=0.0)
    pid = HeightScheduledPid(TrackingPidConfig(gains_above=gains, gains_below=gains, max_speed_m_s=2.0))
    for _ in range(40):
        np.testing.assert_allclose(pid.step([10.0, 0.0], height=5.0), [2.0, 0.0])
    np.testing.assert_allclose(pid.memory[0:2], [0.0, 0.0])
    np.testing.assert_allclose(pid.step([-1.0, 0.0], height=5.0), [-0.7, 0.0])


def test_a_command_exactly_at_the_speed_limit_still_integrates():
    # Kp 0.5, Ki 0.25 on e = (2, 0): Kp e + Ki e = 1.0 + 0.5 = 1.5 m/s, exactly the limit, not beyond it: the error is
    # integrated (sum 2 m) and the command is 1.5 m/s (clamped, it would be Kp e alone, 1.0 m/s, with a sum of 0).
    gains = PidGains(kp=0.5, ki=0.25, kd=0.0)
    pid = HeightScheduledPid(TrackingPidConfig(gains_above=gains, gains_below=gains, max_speed_m_s=1.5))
    np.testing.assert_allclose(pid.step([2.0, 0.0], height=5.0), [1.5, 0.0], atol=1e-12)
    np.testing.assert_allclose(pid.memory[0:2], [2.0, 0.0], atol=1e-12)


def test_the_command_of_a_clamped_sample_has_the_clamped_sum():
    # Kp 0.5, Ki 0.2, limit 2 m/s; e = (10, 0) with the target at (0, 1.5) m/s: v_ugv + Kp e + Ki e = (7, 1.5) is
    # beyond the limit, so x's error is left out of the sum (0) and v_ctrl = Kp e = (5, 0), not (7, 0) with the
    # unclamped sum. Eq. (27): v_ugv + v_ctrl = (5, 1.5), scaled to 2 m/s.
    gains = PidGains(kp=0.5, ki=0.2, kd=0.0)
    pid = HeightScheduledPid(TrackingPidConfig(gains_above=gains, gains_below=gains, max_speed_m_s=2.0))
    command = pid.step([10.0, 0.0], height=5.0, target_velocity=[0.0, 1.5])
    np.testing.assert_allclose(command, np.array([5.0, 1.5]) * 2.0 / np.hypot(5.0, 1.5), atol=1e-12)
    np.testing.assert_allclose(pid.memory[0:2], [0.0, 0.0])


def test_a_saturated_command_still_integrates_the_error_against_it():
    # The target's own 20 m/s saturates the command: x's error against it (-1 m) is integrated (it unwinds),
    # y's along its y component (+1 m) is not; the target velocity is part of the limit's test.
    gains = PidGains(kp=0.5, ki=0.2, kd=0.0)
    pid = HeightScheduledPid(TrackingPidConfig(gains_above=gains, gains_below=gains, max_speed_m_s=15.0))
    pid.step([-1.0, 1.0], height=5.0, target_velocity=[20.0, 5.0])
    np.testing.assert_allclose(pid.memory[0:2], [-1.0, 0.0])
    free = HeightScheduledPid(TrackingPidConfig(gains_above=gains, gains_below=gains, max_speed_m_s=15.0))
    free.step([-1.0, 1.0], height=5.0, target_velocity=[2.0, 0.5])  # within the limit: both integrated
    np.testing.assert_allclose(free.memory[0:2], [-1.0, 1.0])


def test_system_samples_the_anti_windup_with_the_target_velocity():
    # The system's sample sees the same saturation as the pure PID: the target's 14.5 m/s plus Kp e saturate.
    gains = PidGains(kp=0.5, ki=0.2, kd=0.0)
    config = TrackingPidConfig(gains_above=gains, gains_below=gains)
    system = TrackingPid(config)
    simulator = Simulator(system)
    context = simulator.get_mutable_context()
    for name, value in (("target_offset", [3.0, 0.0]), ("target_velocity", [14.5, 0.0]),
                        ("target_acceleration", [0.0, 0.0]), ("height", [6.0]), ("target_valid", [1.0])):
        system.GetInputPort(name).FixValue(context, value)
    reference = HeightScheduledPid(config)
    period = 1.0 / config.rate_hz
    for k in range(5):
        reference.step([3.0, 0.0], 6.0, target_velocity=[14.5, 0.0])
    simulator.AdvanceTo(4 * period + period / 2)
    np.testing.assert_allclose(reference.memory[0:2], [0.0, 0.0])
    system.GetInputPort("target_offset").FixValue(context, [-1.0, 0.0])
    system.GetInputPort("target_velocity").FixValue(context, [0.0, 0.0])
    simulator.AdvanceTo(5 * period + period / 2)
    np.testing.assert_allclose(system.GetOutputPort("velocity_command").Eval(context),
                               reference.step([-1.0, 0.0], 6.0), atol=1e-12)


def test_negative_gain_is_rejected_by_name():
    config = yaml_load_typed(schema=TrackingPidConfig, data="gains_below: {kd: -0.1}")
    with pytest.raises(ValueError, match="pid.gains_below.kd"):
        TrackingPid(config)


@pytest.mark.parametrize("name", ["rate_hz", "switch_height_m", "max_speed_m_s"])
def test_a_zero_rate_switch_height_or_speed_limit_is_rejected_by_name(name):
    with pytest.raises(ValueError, match=f"pid.{name} must be positive, got 0.0"):
        TrackingPidConfig(**{name: 0.0}).validate()


def test_system_matches_pure_pid_at_its_rate_and_restarts_on_loss():
    config = TrackingPidConfig()
    system = TrackingPid(config)
    simulator = Simulator(system)
    context = simulator.get_mutable_context()
    ports = {name: system.GetInputPort(name)
             for name in ("target_offset", "target_velocity", "height", "target_valid")}
    ports["target_velocity"].FixValue(context, [0.4, 0.1])
    ports["height"].FixValue(context, [6.0])
    ports["target_valid"].FixValue(context, [1.0])
    reference = HeightScheduledPid(config)
    period = 1.0 / config.rate_hz
    output = system.GetOutputPort("velocity_command")

    for k, offset in enumerate([[2.0, -1.0], [1.5, -0.5], [1.2, 0.0]]):
        ports["target_offset"].FixValue(context, offset)
        simulator.AdvanceTo(k * period + period / 2)  # the sample at k * period has been taken
        np.testing.assert_allclose(output.Eval(context),
                                   reference.step(offset, 6.0, target_velocity=[0.4, 0.1]))

    ports["target_valid"].FixValue(context, [0.0])
    simulator.AdvanceTo(3 * period + period / 2)
    np.testing.assert_allclose(output.Eval(context), [0.4, 0.1])
    ports["target_valid"].FixValue(context, [1.0])
    ports["target_offset"].FixValue(context, [1.0, 1.0])
    simulator.AdvanceTo(4 * period + period / 2)
    np.testing.assert_allclose(output.Eval(context), [0.4 + 0.8, 0.1 + 0.8])  # no derivative kick


@pytest.mark.parametrize("latest, acceleration", [(True, True), (False, False)])
def test_feed_forwards_between_samples(latest, acceleration):
    # Ours beyond Eq. (24)-(27): the latest target velocity and the target's acceleration (on), or
    # the velocity of the last sample and no acceleration (off: the paper's loop alone).
    config = TrackingPidConfig(latest_feed_forward=latest, acceleration_feed_forward=acceleration)
    system = TrackingPid(config)
    simulator = Simulator(system)
    context = simulator.get_mutable_context()
    for name, value in (("target_offset", [1.0, 0.0]), ("target_velocity", [0.4, 0.1]),
                        ("target_acceleration", [0.05, -0.02]), ("height", [6.0]), ("target_valid", [1.0])):
        system.GetInputPort(name).FixValue(context, value)
    velocity, accel = system.GetOutputPort("velocity_command"), system.GetOutputPort("acceleration_command")
    simulator.AdvanceTo(0.1)  # the sample at t = 0: v_ctrl = Kp e = 0.8 along x
    np.testing.assert_allclose(velocity.Eval(context), [0.4 + 0.8, 0.1])
    np.testing.assert_allclose(accel.Eval(context), [0.05, -0.02] if acceleration else [0.0, 0.0])
    system.GetInputPort("target_velocity").FixValue(context, [0.5, 0.2])  # between samples
    np.testing.assert_allclose(velocity.Eval(context), [0.5 + 0.8, 0.2] if latest else [0.4 + 0.8, 0.1])
    system.GetInputPort("target_valid").FixValue(context, [0.0])
    np.testing.assert_allclose(accel.Eval(context), [0.0, 0.0])  # no feed-forward of an unseen target
    # ... and at once, before the next sample, no held PID term either: the target's velocity alone
    np.testing.assert_allclose(velocity.Eval(context), [0.5, 0.2] if latest else [0.4, 0.1])


def test_a_nan_valid_flag_is_an_unseen_target():
    """NaN on target_valid is no valid flag (bool(nan) is True): no PID term is sampled or held, no acceleration is
    fed forward; the command is the target's velocity alone."""
    system = TrackingPid(TrackingPidConfig(acceleration_feed_forward=True))
    simulator = Simulator(system)
    context = simulator.get_mutable_context()
    for name, value in (("target_offset", [1.0, 0.0]), ("target_velocity", [0.4, 0.1]),
                        ("target_acceleration", [0.05, -0.02]), ("height", [6.0]), ("target_valid", [np.nan])):
        system.GetInputPort(name).FixValue(context, value)
    simulator.AdvanceTo(0.1)  # the sample at t = 0
    np.testing.assert_array_equal(system.GetOutputPort("velocity_command").Eval(context), [0.4, 0.1])
    np.testing.assert_array_equal(system.GetOutputPort("acceleration_command").Eval(context), [0.0, 0.0])
    system.GetInputPort("target_valid").FixValue(context, [1.0])  # seen now, between samples: no PID term was held
    np.testing.assert_array_equal(system.GetOutputPort("velocity_command").Eval(context), [0.4, 0.1])


def test_a_change_of_source_restarts_the_pid_without_a_derivative_kick():
    # The vision seam hands over to the broadcast 2 m away (its GNSS error): the first sample on the
    # broadcast is Kp e alone, not Kp e + Kd * 2 m; the next one on the same source has its derivative.
    config = TrackingPidConfig()
    system = TrackingPid(config)
    simulator = Simulator(system)
    context = simulator.get_mutable_context()
    for name, value in (("target_velocity", [0.0, 0.0]), ("target_acceleration", [0.0, 0.0]),
                        ("height", [6.0]), ("target_valid", [1.0]), ("target_offset", [0.2, 0.0]),
                        ("source", [1.0])):
        system.GetInputPort(name).FixValue(context, value)
    period, gains = 1.0 / config.rate_hz, config.gains_above
    output = system.GetOutputPort("velocity_command")
    simulator.AdvanceTo(period + period / 2)  # two samples on the vision seam
    np.testing.assert_allclose(output.Eval(context), [gains.kp * 0.2, 0.0])
    system.GetInputPort("source").FixValue(context, [0.0])
    system.GetInputPort("target_offset").FixValue(context, [2.2, 0.0])
    simulator.AdvanceTo(2 * period + period / 2)
    np.testing.assert_allclose(output.Eval(context), [gains.kp * 2.2, 0.0])
    system.GetInputPort("target_offset").FixValue(context, [2.0, 0.0])
    simulator.AdvanceTo(3 * period + period / 2)
    np.testing.assert_allclose(output.Eval(context), [gains.kp * 2.0 + gains.kd * (2.0 - 2.2), 0.0])
