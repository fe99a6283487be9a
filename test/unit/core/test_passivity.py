# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""Unit tests of the time-domain passivity observers and controllers (no ROS)."""
import collections
import math
import random

from kraft_master_driver.core.force_reflection import ForceReflection
from kraft_master_driver.core.passivity import MASTER_RESERVE_J, MasterPort, SlavePort
from kraft_master_driver.core.wrench_admission import WrenchInput
import numpy as np
import pytest

MS = 1_000_000  # ns


def stepped(port, force, velocity, steps=1, start_ms=0):
    """Run `steps` master cycles 1 ms apart, each moving at `velocity`; return the last force."""
    port.step([0.0] * 6, [0.0] * 6, start_ms * MS)  # sets the clock
    port.moved([0.0] * 6)
    result = None
    for k in range(1, steps + 1):
        result = port.step(force, velocity, (start_ms + k) * MS)
        port.moved([1e-3 * v for v in velocity])
    return result


def test_observer_books_the_work_done_over_the_displacement():
    port = MasterPort()
    port.enabled = False
    # The hand pushes at 0.1 m/s against 5 N: 0.5 W into the channel for 10 ms.
    stepped(port, [-5.0, 0, 0, 0, 0, 0], [0.1, 0, 0, 0, 0, 0], steps=10)
    assert port.energy_in == pytest.approx(0.005)
    assert port.energy_out == 0.0
    # The device pushes the hand along: 0.5 W out for 4 ms, all of it let through when off.
    stepped(port, [5.0, 0, 0, 0, 0, 0], [0.1, 0, 0, 0, 0, 0], steps=4, start_ms=100)
    assert port.energy_out == pytest.approx(0.002)
    assert port.dissipated == 0.0
    # Moments and angular velocity count too.
    stepped(port, [0, 0, 0, 0, 0, -2.0], [0, 0, 0, 0, 0, 0.5], steps=2, start_ms=200)
    assert port.energy_in == pytest.approx(0.007)
    # The work is force times the displacement measured, whatever the velocity estimate was.
    port.step([3.0, 0, 0, 0, 0, 0], [0.0] * 6, 300 * MS)
    port.moved([0.001, 0, 0, 0, 0, 0])
    assert port.energy_out == pytest.approx(0.005)


def test_credit_is_monotone_and_ignores_bad_values():
    port = SlavePort()
    port.credit(1.0)
    port.credit(0.5)  # late, reordered
    port.credit(math.nan)
    port.credit(-math.inf)
    assert port.remote_in == 1.0
    port.credit(math.inf)
    assert port.remote_in == 1.0
    port.credit(2.0)
    assert port.remote_in == 2.0


def test_stamped_credit_starts_with_the_other_ends_first_sample():
    # A bridge started beside a driver that has run a while: the driver's energy in so far
    # was credit for the bridge before, not for this one.
    port = SlavePort()
    port.credit(5.0, stamp_ns=1_000)
    assert port.observed == 0.0
    port.credit(5.2, stamp_ns=2_000)
    assert port.observed == pytest.approx(0.2)


def test_a_restarted_other_end_gives_credit_again_from_where_its_books_start():
    port = MasterPort()
    port.credit(0.0, stamp_ns=1_000)
    port.credit(1.0, stamp_ns=2_000)
    port.energy_out = 0.4  # spent
    port.credit(0.5, stamp_ns=1_500)  # late, reordered: not a restart
    assert port.observed == pytest.approx(0.6)
    # The other end restarted: its energy in starts from zero again, stamped later.
    port.credit(0.0, stamp_ns=3_000)
    assert port.observed == 0.0, 'the unspent credit of the process before is dropped'
    port.credit(0.01, stamp_ns=4_000)
    assert port.observed == pytest.approx(0.01)
    port.credit(1.0, stamp_ns=2_500)  # late, from the process before the restart
    assert port.observed == pytest.approx(0.01)
    # Unstamped, a smaller value is only ever a late one: no credit until past the largest.
    unstamped = MasterPort()
    unstamped.credit(1.0)
    unstamped.energy_out = 0.4
    unstamped.credit(0.01)
    assert unstamped.observed == pytest.approx(0.6)


def test_a_deficit_is_kept_across_a_restart_of_the_other_end():
    port = MasterPort()
    port.credit(0.001, stamp_ns=1)
    port.credit(0.002, stamp_ns=2)
    port.energy_out = 0.003  # 2 mJ past the credit (the reserve paid for it)
    port.credit(0.0, stamp_ns=3)
    assert port.observed == pytest.approx(-0.002)
    port.credit(0.005, stamp_ns=4)
    assert port.observed == pytest.approx(0.003)


def test_master_controller_dissipates_exactly_the_excess():
    port = MasterPort()
    port.credit(0.001)
    force, velocity = [5.0, 1.0, 0, 0, 0, 0.5], [0.1, -0.05, 0, 0, 0, 0.2]
    power = float(np.dot(force, velocity))  # 0.55 W out: 0.55 mJ per step
    out = stepped(port, force, velocity, steps=1)
    assert out == force, 'within the credit nothing changes'
    out = stepped(port, force, velocity, steps=1, start_ms=10)
    excess = 2 * power * 1e-3 - 0.001
    assert port.dissipated == pytest.approx(excess)
    assert port.energy_out == pytest.approx(0.001)
    assert port.observed == pytest.approx(0.0, abs=1e-15)
    # The wrench is scaled down, direction kept, by just the excess.
    keep = 1.0 - excess / (power * 1e-3)
    assert out == pytest.approx([keep * f for f in force])
    assert float(np.dot(out, velocity)) * 1e-3 == pytest.approx(power * 1e-3 - excess)
    # No credit left: the next step hands out nothing.
    out = stepped(port, force, velocity, steps=1, start_ms=20)
    assert float(np.dot(out, velocity)) == pytest.approx(0.0, abs=1e-12)


def test_master_controller_leaves_energy_in_alone_and_stands_still():
    port = MasterPort()
    force = [-5.0, 0, 0, 0, 0, 0]
    assert stepped(port, force, [0.1, 0, 0, 0, 0, 0], steps=3) == force
    assert stepped(port, [5.0, 0, 0, 0, 0, 0], [0.0] * 6, steps=3, start_ms=10) == [
        5.0, 0, 0, 0, 0, 0]
    assert port.dissipated == 0.0


def test_with_a_rise_time_credit_after_a_dry_spell_lets_the_force_back_in_gradually():
    port = MasterPort(rise_time=0.05)
    force, velocity = [5.0, 0, 0, 0, 0, 0], [0.1, 0, 0, 0, 0, 0]
    # No credit: the force pushing the hand along is held back entirely.
    assert stepped(port, force, velocity, steps=5) == [0.0] * 6
    port.credit(1.0)
    shares = []
    for k in range(1, 61):
        shares.append(port.step(force, velocity, (5 + k) * MS)[0] / force[0])
        port.moved([1e-3 * v for v in velocity])
    # 1 ms over 50 ms a step: 1/50 more each time, up to the whole force.
    np.testing.assert_allclose(shares, np.minimum(np.arange(1, 61) / 50, 1.0), atol=1e-12)
    # It falls at once: when the credit (1 J at 0.5 W: 2 s) runs out, the force goes in one
    # step, and never more comes out than came in.
    given = []
    for k in range(61, 2200):
        given.append(port.step(force, velocity, (5 + k) * MS)[0])
        port.moved([1e-3 * v for v in velocity])
    first_short = next(index for index, value in enumerate(given) if value < force[0])
    assert given[first_short + 1] == pytest.approx(0.0, abs=1e-9)  # the rest, then nothing
    assert port.energy_out == pytest.approx(1.0)


def test_master_booking_follows_what_was_applied():
    port = MasterPort()
    port.enabled = False
    port.step([-4.0, 0, 0, 0, 0, 0], [1.0, 0, 0, 0, 0, 0], 0)
    port.scaled(0.25)
    port.moved([0.001, 0, 0, 0, 0, 0])
    assert port.energy_in == pytest.approx(0.001)
    port.step([4.0, 0, 0, 0, 0, 0], [1.0, 0, 0, 0, 0, 0], MS)
    port.idle(2 * MS)  # zero torque after all
    port.moved([0.001, 0, 0, 0, 0, 0])
    assert port.energy_out == 0.0
    port.moved([0.001, 0, 0, 0, 0, 0])  # no second booking of one wrench
    assert port.energy_out == 0.0


def test_a_count_flipping_under_a_held_force_is_paid_from_the_reserve():
    # A pot count flips back and forth under a held 10 N (one count: 0.16 mm along the force),
    # the velocity estimate too slow to see it: the prediction lets the whole wrench through.
    port = MasterPort()
    port.credit(0.001)
    force, count = [0.0, 0.0, 10.0, 0.0, 0.0, 0.0], 0.16e-3
    port.step(force, [0.0] * 6, 0)
    for k in range(1, 400):
        port.step(force, [0.0] * 6, k * MS)
        # Against the force first: what the hand put in stays at the port, up to the reserve.
        port.moved([0.0, 0.0, count if k % 2 == 0 else -count, 0.0, 0.0, 0.0])
    assert port.reserve == pytest.approx(10.0 * count)
    assert port.energy_out == 0.0, 'each flip along the force was paid from the reserve'
    assert port.energy_in == 0.0, 'and none of it was sent to the slave as credit'
    assert port.observed == pytest.approx(0.001)
    # Beyond the reserve, outflow is booked against the credit as before.
    port.step(force, [0.0] * 6, 500 * MS)
    port.moved([0.0, 0.0, 10 * count, 0.0, 0.0, 0.0])
    assert port.reserve == 0.0
    assert port.energy_out == pytest.approx(10.0 * 9 * count)


def test_a_deficit_beyond_the_reserve_fades_the_wrench_out_until_credit_covers_it():
    # The velocity estimate lags: it still says the hand pushes against the force (inflow)
    # while the hand already moves along it. The reserve is empty, so each step is a deficit.
    port = MasterPort()
    force, against = [0.0, 0.0, 10.0, 0.0, 0.0, 0.0], [0.0, 0.0, -0.05, 0.0, 0.0, 0.0]
    port.step(force, against, 0)
    port.step(force, against, MS)
    port.moved([0.0, 0.0, 1e-4, 0.0, 0.0, 0.0])
    assert port.observed == pytest.approx(-0.001)
    # Half the reserve's worth of deficit: half the wrench, whatever the estimate reads.
    assert port.step(force, against, 2 * MS) == pytest.approx([0.5 * f for f in force])
    port.moved([0.0, 0.0, 1e-4, 0.0, 0.0, 0.0])
    for k in range(3, 100):
        port.step(force, against, k * MS)
        port.moved([0.0, 0.0, 1e-4, 0.0, 0.0, 0.0])
    # The deficit stops where the wrench has faded out: no more work out, however long.
    assert port.step(force, against, 100 * MS) == [0.0] * 6
    assert -port.observed <= MASTER_RESERVE_J
    port.credit(port.energy_out)
    assert port.step(force, against, 101 * MS) == force


def test_force_reflection_books_what_is_sent_after_the_torque_limits():
    port = MasterPort()
    port.enabled = False
    jacobian = np.eye(6)
    reflection = ForceReflection(torque_limits=(1.0,) * 5, enabled=True)
    reflection.hold(WrenchInput((-4.0, 0, 0, 0, 0, 0), 'base', 0))
    out = reflection.compute(np.eye(3), jacobian, MS, cartesian_velocity=[1.0, 0, 0, 0, 0, 0],
                             port=port)
    port.moved([0.001, 0, 0, 0, 0, 0])
    assert out.saturated and out.actuator[0] == pytest.approx(-1.0)
    assert port.energy_in == pytest.approx(1.0 * 1e-3)  # 1 N applied, not 4
    reflection.enabled = False
    reflection.compute(np.eye(3), jacobian, 2 * MS, cartesian_velocity=[1.0, 0, 0, 0, 0, 0],
                       port=port)
    port.moved([0.001, 0, 0, 0, 0, 0])
    assert port.energy_in == pytest.approx(1e-3), 'zero torque: no energy'


def test_force_reflection_with_passivity_limits_the_felt_force():
    port = MasterPort()  # on, and no credit from the slave yet
    reflection = ForceReflection(torque_limits=(100.0,) * 5, enabled=True)
    reflection.hold(WrenchInput((5.0, 0, 0, 0, 0, 0), 'base', 0))
    velocity = [0.1, 0, 0, 0, 0, 0]
    reflection.compute(np.eye(3), np.eye(6), 0, cartesian_velocity=velocity, port=port)
    out = reflection.compute(np.eye(3), np.eye(6), MS, cartesian_velocity=velocity, port=port)
    assert out.actuator[0] == pytest.approx(0.0, abs=1e-12)
    port.credit(1.0)
    out = reflection.compute(np.eye(3), np.eye(6), 2 * MS, cartesian_velocity=velocity,
                             port=port)
    assert out.actuator[0] == pytest.approx(5.0)


def test_the_ports_damper_books_the_hands_work_as_energy_in():
    # 5 N*s/m on the wrist moving at 0.1 m/s along x: -0.5 N, with no reflected force at all.
    port = MasterPort(damping=5.0)
    velocity = [0.1, 0.0, 0.0, 0.3, 0.0, 0.0]
    assert port.damped(velocity) == [0.0] * 6, 'nothing before step()'
    port.step([0.0] * 6, velocity, 0)
    assert port.damped(velocity) == pytest.approx([-0.5, 0, 0, 0, 0, 0]), 'translation only'
    port.moved([1e-4, 0, 0, 0, 0, 0])
    # The hand's 0.05 mJ went into the reserve first; past it, energy in is sent as credit.
    assert port.reserve == pytest.approx(0.5 * 1e-4)
    for k in range(1, 100):
        port.step([0.0] * 6, velocity, k * MS)
        port.damped(velocity)
        port.moved([1e-4, 0, 0, 0, 0, 0])
    assert port.reserve == MASTER_RESERVE_J
    assert port.energy_in == pytest.approx(100 * 0.5 * 1e-4 - MASTER_RESERVE_J)
    assert port.energy_out == 0.0


def test_the_ports_damper_is_off_with_passivity_off_or_no_damping():
    for port in (MasterPort(damping=5.0), MasterPort()):
        port.enabled = port.damping == 0.0
        port.step([0.0] * 6, [0.1] + [0.0] * 5, 0)
        assert port.damped([0.1] + [0.0] * 5) == [0.0] * 6


def test_force_reflection_adds_the_ports_damper_after_contact_damping():
    port = MasterPort(damping=5.0)
    port.credit(1.0)
    reflection = ForceReflection(torque_limits=(100.0,) * 5, contact_damping=2.0, enabled=True)
    reflection.hold(WrenchInput((3.0, 0, 4.0, 0, 0, 0), 'base', 0))
    velocity = [0.1, 0, 0, 0, 0, 0]
    reflection.compute(np.eye(3), np.eye(6), 0, cartesian_velocity=velocity, port=port)
    port.moved([1e-4, 0, 0, 0, 0, 0])
    out = reflection.compute(np.eye(3), np.eye(6), MS, cartesian_velocity=velocity, port=port)
    # 3 N less contact damping (2 s/m * 5 N * 0.1 m/s) less the port's (5 N*s/m * 0.1 m/s).
    assert out.actuator[0] == pytest.approx(3.0 - 1.0 - 0.5)
    assert out.actuator[2] == pytest.approx(4.0)


def test_slave_controller_dissipates_exactly_the_excess_and_drifts():
    port = SlavePort(drift_gain=0.0)
    port.reset([0.0, 0.0, 0.0])
    port.credit(0.002)
    force = [0.0, 0.0, 20.0]  # the wall pushes up; the master asks to go down at 0.1 m/s
    port.step([0.0, 0.0, -0.0001], force, 1e-3)
    assert port.energy_out == pytest.approx(0.002)
    assert port.dissipated == pytest.approx(0.0)
    command = port.step([0.0, 0.0, -0.0002], force, 1e-3)
    assert port.energy_out == pytest.approx(0.002)
    assert port.dissipated == pytest.approx(0.002)
    assert command == pytest.approx([0.0, 0.0, -0.0001])
    assert port.drift == pytest.approx([0.0, 0.0, -0.0001])


def test_slave_gives_drift_back_in_free_space_and_only_with_spare_energy_in_contact():
    port = SlavePort(drift_gain=10.0)
    port.reset([0.0, 0.0, 0.0])
    force = [0.0, 0.0, 20.0]
    port.step([0.0, 0.0, -0.001], force, 1e-3)
    assert port.drift == pytest.approx([0.0, 0.0, -0.001])
    for _ in range(100):
        port.step([0.0, 0.0, -0.001], force, 1e-3)  # no credit: the drift stays
    assert port.drift == pytest.approx([0.0, 0.0, -0.001])
    port.credit(1.0)
    port.step([0.0, 0.0, -0.001], force, 1e-3)
    assert abs(port.drift[2]) < 0.001
    before = port.energy_out
    for _ in range(1000):
        port.step([0.0, 0.0, -0.001], [0.0, 0.0, 0.0], 1e-3)  # free space: no energy
    assert port.drift == pytest.approx([0.0, 0.0, 0.0], abs=1e-6)
    assert port.energy_out == before


def test_drift_given_back_never_moves_the_command_faster_than_max_speed():
    port = SlavePort(drift_gain=10.0, max_speed=0.25)
    port.reset([0.0, 0.0, 0.0])
    force = [0.0, 0.0, 20.0]
    port.step([0.0, 0.0, -0.05], force, 0.05)  # no credit: 50 mm of drift
    assert port.drift == pytest.approx([0.0, 0.0, -0.05])
    port.credit(100.0)
    commands = [port.command]
    for step in range(1, 80):  # the master moves sideways at half the speed limit
        commands.append(port.step([0.00625 * step, 0.0, -0.05], [0.0, 0.0, 0.0], 0.05))
    steps = np.linalg.norm(np.diff(commands, axis=0), axis=1)
    assert max(steps) == pytest.approx(0.0125)  # 0.25 m/s over 0.05 s, the drift's share in it
    assert port.drift == pytest.approx([0.0, 0.0, 0.0], abs=1e-4)
    # Without the bound the same drift comes back faster than the speed limit.
    free = SlavePort(drift_gain=10.0)
    free.reset([0.0, 0.0, 0.0])
    free.step([0.0, 0.0, -0.05], force, 0.05)
    free.credit(100.0)
    start = free.command
    assert np.linalg.norm(np.subtract(free.step([0.00625, 0.0, -0.05], [0.0, 0.0, 0.0], 0.05),
                                      start)) > 0.0125 * 1.05


def _channel(round_trip_steps, loss, seed, passivity=True, steps=2000):
    """
    Two ports across a delaying, lossy channel fed adversarial forces and motions.

    The master's velocity and the slave's force are random, and the force the channel hands
    the master is the slave's force from a random delay ago, not the one that came with its
    velocity: the worst case for energy. The master's velocity estimate is the motion of the
    next cycle (the guarantee holds to the accuracy of that prediction). Return (generated
    energy, master, slave).
    """
    rng = random.Random(seed)
    master, slave = MasterPort(), SlavePort(drift_gain=rng.uniform(0.0, 5.0))
    master.enabled = slave.enabled = passivity
    dt = 1e-3
    to_slave, to_master = collections.deque(), collections.deque()
    forces = collections.deque([[0.0] * 3], maxlen=round_trip_steps + 1)
    position, target = [0.0] * 3, [0.0] * 3
    slave.reset(position)
    master.step([0.0] * 6, [0.0] * 6, 0)
    for k in range(1, steps):
        velocity = [rng.uniform(-0.3, 0.3) for _ in range(3)]
        position = [p + v * dt for p, v in zip(position, velocity)]
        if rng.random() >= loss:
            to_slave.append((k + rng.randint(0, round_trip_steps), master.energy_in, position))
        while to_slave and to_slave[0][0] <= k:
            _, energy, target = to_slave.popleft()
            slave.credit(energy)
        env_force = [rng.uniform(-30.0, 30.0) for _ in range(3)]
        slave.step(target, env_force, dt)
        forces.append(env_force)
        if rng.random() >= loss:
            to_master.append((k + rng.randint(0, round_trip_steps), slave.energy_in))
        while to_master and to_master[0][0] <= k:
            master.credit(to_master.popleft()[1])
        felt = rng.choice(forces) + [rng.uniform(-1, 1) for _ in range(3)]
        twist = velocity + [rng.uniform(-1, 1) for _ in range(3)]
        master.step(felt, twist, k * MS)
        master.moved([dt * v for v in twist])
    generated = (master.energy_out + slave.energy_out) - (master.energy_in + slave.energy_in)
    return generated, master, slave


@pytest.mark.parametrize('round_trip_steps', [0, 20, 100, 500])
@pytest.mark.parametrize('loss', [0.0, 0.1, 0.5])
def test_channel_never_generates_energy_with_passivity_on(round_trip_steps, loss):
    for seed in range(2):
        generated, master, slave = _channel(round_trip_steps, loss, seed)
        # Each port hands out no more than the other has put in, to rounding.
        assert master.energy_out <= slave.energy_in + 1e-12
        assert slave.energy_out <= master.energy_in + 1e-12
        assert generated <= 1e-12


def test_the_same_channel_generates_energy_with_passivity_off():
    generated, _, _ = _channel(100, 0.1, 0, passivity=False)
    assert generated > 0.1
