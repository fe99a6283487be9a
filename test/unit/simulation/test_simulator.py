# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The simulated hand controller, driven as a host would: real bytes over a real pty."""
import contextlib
import os
import pathlib
import select
import shutil
import signal
import subprocess
import sys
import time

from harness import REPO
from kraft_master_driver.core import kinematics
from kraft_master_driver.core.calibration import ArmCalibration, POT_MAX
from kraft_master_driver.link.device import KmcDevice
from kraft_master_driver.link.protocol import (
    CODECS, DEFAULT_TORQUE_LIMIT, DEFAULT_TORQUE_SCALE, get_codec, STATUS_AMPLIFIERS_ENABLED,
    STATUS_COMMAND_CLAMPED, STATUS_COMMAND_TIMEOUT, STATUS_CORRUPT_COMMAND)
from kraft_master_driver.simulation.master.model import (
    actuators_to_joints, joints_to_actuators, Workspace)
from kraft_master_driver.simulation.master.operators import PushOperator, TaskOperator
from kraft_master_driver.simulation.master.simulator import SimulatedKraftMaster
import numpy as np
import pytest
import serial

CODEC = get_codec('kraft-default')
ZERO = (0,) * 5
HOME = Workspace().home()


def wait_for(condition, timeout=20.0, poll=None):
    """Call `poll` and check `condition` until it holds; fail after `timeout` seconds."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if poll is not None:
            poll()
        if condition():
            return
        if poll is None:
            time.sleep(0.005)
    raise AssertionError(f'condition not met within {timeout} s')


def counts_for(axis, torque_nm):
    """Command counts that ask for `torque_nm` on one axis (0-based) at the default scale."""
    counts = [0] * 5
    counts[axis] = round(torque_nm * DEFAULT_TORQUE_SCALE[axis])
    return tuple(counts)


class Host:
    """The host end of the link: pyserial on the simulator's port and this project's codec."""

    def __init__(self, path):
        """Open the port like a driver would."""
        self.port = serial.serial_for_url(path, baudrate=1_000_000, timeout=0.02)
        self.decoder = CODEC.reply_decoder()
        self.frames = []
        self.bytes_received = 0
        self._sequence = 0

    def send(self, counts=ZERO, sequence=None):
        """Write one command; return its sequence number."""
        if sequence is None:
            sequence = self._sequence
            self._sequence = (sequence + 1) % 256
        self.port.write(CODEC.encode_command(sequence, counts))
        return sequence

    def poll(self):
        """Read what has arrived and decode it into self.frames."""
        data = self.port.read(max(1, self.port.in_waiting))
        self.bytes_received += len(data)
        self.frames.extend(self.decoder.feed(data))

    def exchange(self, counts=ZERO, timeout=10.0):
        """Send one command; return the reply with its sequence, or None after `timeout` s."""
        sequence = self.send(counts)
        start = len(self.frames)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self.poll()
            for frame in self.frames[start:]:
                if frame.sequence == sequence:
                    return frame
        return None

    def angles(self, calibration):
        """Exchange a zero-torque command; return the joint angles its reply reads."""
        return calibration.pots_to_joints(self.exchange().pots)

    def close(self):
        """Close the port."""
        self.port.close()


@pytest.fixture
def rig():
    """Return make(**options) -> (simulator, host), all stopped and closed after the test."""
    cleanups = []

    def make(**options):
        simulator = SimulatedKraftMaster(**options)
        cleanups.append(simulator.stop)
        host = Host(simulator.start())
        cleanups.append(host.close)
        return simulator, host

    yield make
    for cleanup in reversed(cleanups):
        cleanup()


def shifted_calibration(arm, shift):
    """Return the arm's nominal calibration with every pot line moved by `shift` counts."""
    nominal = ArmCalibration.nominal(arm)
    return ArmCalibration(arm, nominal.pot_a + shift, nominal.pot_b + shift,
                          nominal.angle_a, nominal.angle_b, source='shifted')


def expected_pots(calibration, theta):
    """Return the 12-bit pot counts a noiseless device with `calibration` reads at `theta`."""
    return tuple(int(x) for x in np.clip(np.rint(calibration.joints_to_pots(theta)), 0, POT_MAX))


@pytest.mark.parametrize('transport', ['pty', 'tcp'])
def test_every_command_gets_one_reply_with_its_sequence(rig, transport):
    simulator, host = rig(transport=transport)
    for count in range(1, 601):
        frame = host.exchange()
        assert frame is not None
        assert len(simulator.received) == count  # recorded before its reply left
    assert [frame.sequence for frame in host.frames] == [i % 256 for i in range(600)]
    wait_for(lambda: simulator.stats['replies'] == 600)
    stats = simulator.stats
    assert stats['commands'] == 600
    assert sum(stats['decode_errors'].values()) == 0
    assert sum(host.decoder.errors.values()) == 0
    assert [command.sequence for _, command in simulator.received] == [
        i % 256 for i in range(600)]


@pytest.mark.parametrize('arm', ['right', 'left'])
def test_pots_are_the_true_calibration_inverse_of_the_true_angles(rig, arm):
    truth = shifted_calibration(arm, 37.0)
    simulator, host = rig(arm=arm, calibration=truth)
    for _ in range(20):
        frame = host.exchange()
        assert frame.pots == expected_pots(truth, simulator.joint_angles())
        assert frame.pots != expected_pots(ArmCalibration.nominal(arm), HOME)
    np.testing.assert_allclose(simulator.joint_angles(), HOME, atol=1e-12)


def test_pots_saturate_at_the_12_bit_range(rig):
    nominal = ArmCalibration.nominal('right')
    pot_a, pot_b = nominal.pot_a.copy(), nominal.pot_b.copy()
    angle_a, angle_b = nominal.angle_a.copy(), nominal.angle_b.copy()
    # POT1 reads 0 deg beyond its top, POT6 below its bottom.
    pot_a[0], pot_b[0], angle_a[0], angle_b[0] = 3000, 4000, np.radians(90), np.radians(60)
    pot_a[5], pot_b[5], angle_a[5], angle_b[5] = 1000, 100, np.radians(45), np.radians(30)
    truth = ArmCalibration('right', pot_a, pot_b, angle_a, angle_b, source='saturating')
    _, host = rig(calibration=truth)
    pots = host.exchange().pots
    assert pots[0] == POT_MAX and pots[5] == 0
    assert pots[1:5] == expected_pots(nominal, HOME)[1:5]


def test_noisy_pots_scatter_around_the_truth_inside_the_range(rig):
    _, host = rig(pot_noise_counts=3.0)
    truth = ArmCalibration.nominal('right').joints_to_pots(HOME)
    errors = []
    for _ in range(300):
        pots = host.exchange().pots
        assert all(0 <= count <= POT_MAX for count in pots)
        errors.append(np.subtract(pots, truth))
    spread = np.std(errors, axis=0)
    assert np.all(spread > 1.0) and np.all(spread < 10.0)


def test_hold_with_zero_torque_keeps_the_arm_still(rig):
    simulator, host = rig(operator='hold')
    first = host.exchange().pots
    assert first == expected_pots(ArmCalibration.nominal('right'), HOME)
    for _ in range(300):
        assert host.exchange().pots == first
    np.testing.assert_allclose(simulator.joint_angles(), HOME, atol=1e-12)


def driven_coordinate(coupling, theta, axis):
    """Return the coordinate a torque on `axis` drives: actuator q or joint th (coupling)."""
    return (joints_to_actuators(theta) if coupling == 'actuator' else theta)[axis]


@pytest.mark.parametrize('coupling', ['actuator', 'joint'])
@pytest.mark.parametrize('axis', range(5))
def test_torque_moves_the_arm_in_its_direction(rig, coupling, axis):
    _, host = rig(coupling=coupling)
    calibration = ArmCalibration.nominal('right')
    rest = driven_coordinate(coupling, host.angles(calibration), axis)
    for torque in (0.5, -0.5):
        def moved(torque=torque):
            frame = host.exchange(counts_for(axis, torque))
            theta = calibration.pots_to_joints(frame.pots)
            return (driven_coordinate(coupling, theta, axis) - rest) * np.sign(torque) > 0.01
        wait_for(moved)


@pytest.mark.parametrize('coupling', ['actuator', 'joint'])
def test_elbow_torque_reaches_the_shoulder_only_in_joint_coupling(rig, coupling):
    _, host = rig(coupling=coupling)
    calibration = ArmCalibration.nominal('right')
    rest = joints_to_actuators(host.angles(calibration))
    q = [rest]

    def elbow_moved():
        q[0] = joints_to_actuators(calibration.pots_to_joints(
            host.exchange(counts_for(2, 0.5)).pots))
        return q[0][2] - rest[2] > 0.01

    wait_for(elbow_moved)
    if coupling == 'actuator':
        assert q[0][1] == rest[1]
    else:
        wait_for(lambda: calibration.pots_to_joints(
            host.exchange(counts_for(2, 0.5)).pots)[1] < rest[1] - 0.01)


def test_end_stops_hold_the_joints_inside_table_ii_limits(rig):
    simulator, host = rig(torque_scale=(100.0,) * 5, torque_limit=(32767,) * 5)
    # Far beyond what the hand resists: every driven joint ends on a stop. The elbow is pushed
    # both with and against the shoulder, to reach the corners of its coupled range.
    for signs in ((1, 1, 1, 1, 1), (-1, -1, -1, -1, -1), (1, 1, -1, -1, 1), (-1, -1, 1, 1, -1)):
        def at_stops(signs=np.array(signs)):
            frame = host.exchange(tuple(int(x) for x in signs * 32767))
            theta = simulator.joint_angles()
            assert kinematics.limit_violations(theta) == []
            assert all(0 <= count <= POT_MAX for count in frame.pots)
            assert not frame.status & STATUS_COMMAND_CLAMPED
            lower, upper = kinematics.joint_limits(theta[1])
            return np.allclose(theta[:5], np.where(signs > 0, upper[:5], lower[:5]), atol=1e-9)
        wait_for(at_stops)


def status_bits(frame):
    """Return the status bits of a reply other than the watchdog's, which a loaded host trips."""
    return frame.status & ~STATUS_COMMAND_TIMEOUT


def test_status_bits_report_clamp_and_corruption(rig):
    simulator, host = rig()
    assert status_bits(host.exchange()) == STATUS_AMPLIFIERS_ENABLED

    over = (DEFAULT_TORQUE_LIMIT[0] + 1, 0, 0, 0, -DEFAULT_TORQUE_LIMIT[4] - 1)
    assert status_bits(host.exchange(over)) == STATUS_AMPLIFIERS_ENABLED | STATUS_COMMAND_CLAMPED
    assert simulator.received[-1][1].counts == over
    assert simulator.stats['clamped'] == 1
    assert status_bits(host.exchange()) == STATUS_AMPLIFIERS_ENABLED

    damaged = bytearray(CODEC.encode_command(99, ZERO))
    damaged[-1] ^= 0x01
    host.port.write(damaged)
    assert status_bits(host.exchange()) == STATUS_AMPLIFIERS_ENABLED | STATUS_CORRUPT_COMMAND
    assert status_bits(host.exchange()) == STATUS_AMPLIFIERS_ENABLED
    assert simulator.stats['decode_errors']['bad_crc'] == 1


def test_watchdog_zeroes_the_torque_and_reports_it(rig):
    simulator, host = rig(command_timeout=0.05)
    wait_for(lambda: host.exchange(counts_for(0, 1.0)) and simulator.joint_angles()[0] > 0.03)
    # No more commands: the watchdog zeroes the torque and the hand takes the arm back.
    wait_for(lambda: abs(simulator.joint_angles()[0] - HOME[0]) < 0.003)
    timeouts = simulator.stats['timeouts']
    assert timeouts >= 1
    assert host.exchange().status == STATUS_AMPLIFIERS_ENABLED | STATUS_COMMAND_TIMEOUT
    frame = host.exchange()
    assert (frame.status & STATUS_COMMAND_TIMEOUT) == 0 or simulator.stats['timeouts'] > timeouts


@pytest.mark.slow
def test_sweep_moves_each_joint_inside_its_limits(rig):
    simulator, host = rig(operator='sweep', operator_period=0.3)
    calibration = ArmCalibration.nominal('right')
    seen = [host.angles(calibration)]

    def sample():
        seen.append(calibration.pots_to_joints(host.exchange().pots))
        assert kinematics.limit_violations(simulator.joint_angles()) == []

    wait_for(lambda: np.all(np.ptp(seen, axis=0) > np.radians(10.0)), timeout=30.0, poll=sample)


def test_random_walk_wanders_inside_the_limits(rig):
    simulator, host = rig(operator='random_walk', operator_period=0.2, seed=3)
    calibration = ArmCalibration.nominal('right')
    seen = [host.angles(calibration)]

    def sample():
        seen.append(calibration.pots_to_joints(host.exchange().pots))
        assert kinematics.limit_violations(simulator.joint_angles()) == []

    wait_for(lambda: np.all(np.ptp(seen, axis=0) > np.radians(5.0)), timeout=30.0, poll=sample)


def send_in_batches(simulator, host, count, batch=20):
    """Send `count` commands, sequences 0.., in bursts; read every byte the device sends."""
    for start in range(0, count, batch):
        for sequence in range(start, min(start + batch, count)):
            host.send(sequence=sequence)
        wait_for(lambda: simulator.stats['commands'] == min(start + batch, count),
                 poll=host.poll)
    # A reply is counted once written, so count first, then wait for its bytes.
    wait_for(lambda: simulator.stats['replies'] + simulator.stats['dropped'] == count)
    wait_for(lambda: host.bytes_received == CODEC.reply_size * simulator.stats['replies'],
             poll=host.poll)


def test_dropped_replies_are_missing_and_counted(rig):
    simulator, host = rig(drop_reply_rate=0.5)
    send_in_batches(simulator, host, 200)
    stats = simulator.stats
    assert 50 < stats['dropped'] < 150
    assert stats['replies'] + stats['dropped'] == 200
    sequences = [frame.sequence for frame in host.frames]
    assert len(sequences) == stats['replies']
    assert sequences == sorted(set(sequences))


def test_corrupted_bytes_fail_the_host_crc(rig):
    simulator, host = rig(corrupt_byte_rate=0.02)
    send_in_batches(simulator, host, 240)
    stats = simulator.stats
    assert stats['replies'] == 240 and stats['corrupted_bytes'] > 0
    assert host.decoder.errors['bad_crc'] > 0
    assert 0 < len(host.frames) < 240
    still = expected_pots(ArmCalibration.nominal('right'), HOME)
    assert all(frame.pots == still and frame.status == STATUS_AMPLIFIERS_ENABLED
               for frame in host.frames)
    sequences = [frame.sequence for frame in host.frames]
    assert sequences == sorted(set(sequences))


@pytest.mark.slow
def test_stall_consumes_commands_without_answering(rig):
    simulator, host = rig()
    assert host.exchange() is not None
    simulator.stall(1000)
    stalled = host.send(counts_for(0, 1.0))
    wait_for(lambda: simulator.stats['stalled'] == 1)
    wait_for(lambda: host.exchange(timeout=0.05) is not None)
    assert stalled not in [frame.sequence for frame in host.frames]
    wait_for(lambda: simulator.stats['replies'] == len(host.frames))
    np.testing.assert_allclose(simulator.joint_angles(), HOME, atol=1e-12)


def test_unplug_fails_the_host_and_replug_serves_the_same_path(rig):
    simulator, host = rig()
    path = simulator.port
    assert host.exchange() is not None
    simulator.unplug()
    assert not os.path.lexists(path)
    with pytest.raises(serial.SerialException):
        host.port.read(1)
    simulator.replug()
    assert os.path.realpath(path).startswith('/dev/pts/')
    again = Host(path)
    try:
        assert again.exchange() is not None
    finally:
        again.close()


@pytest.mark.slow
def test_tcp_unplug_closes_the_connection_and_replug_serves_the_same_url(rig):
    simulator, host = rig(transport='tcp')
    url = simulator.port
    assert url.startswith('socket://127.0.0.1:')
    assert host.exchange() is not None
    simulator.unplug()
    with pytest.raises(serial.SerialException):
        host.exchange(timeout=1.0)
    with pytest.raises(serial.SerialException):
        Host(url)  # nothing listens
    simulator.replug()
    assert simulator.port == url
    again = Host(url)
    try:
        assert again.exchange() is not None
    finally:
        again.close()


@pytest.mark.slow
def test_tcp_serves_one_host_at_a_time(rig):
    simulator, host = rig(transport='tcp')
    assert host.exchange() is not None
    second = Host(simulator.port)
    try:
        with pytest.raises(serial.SerialException):  # the connection is closed at once
            second.exchange(timeout=1.0)
    finally:
        second.close()
    assert host.exchange() is not None
    host.close()
    third = Host(simulator.port)
    try:
        wait_for(lambda: third.exchange(timeout=0.2) is not None)
    finally:
        third.close()


def test_garbage_is_skipped_by_the_host_decoder(rig):
    simulator, host = rig()
    assert host.exchange() is not None
    simulator.send_garbage(100)
    assert host.exchange() is not None
    assert host.decoder.errors['garbage_bytes'] == 100
    assert simulator.stats['garbage_sent'] == 100


def test_wire_timing_caps_the_cycle_rate(rig):
    baud = 115200
    wire_time = CODEC.wire_cycle_time(baud)
    _, host = rig(baudrate=baud)
    start = time.monotonic()
    for _ in range(40):
        sent = time.monotonic()
        assert host.exchange() is not None
        assert time.monotonic() - sent >= wire_time
    assert time.monotonic() - start >= 40 * wire_time

    burst_start = time.monotonic()
    for _ in range(20):
        host.send()
    wait_for(lambda: len(host.frames) == 60, poll=host.poll)
    assert time.monotonic() - burst_start >= 20 * wire_time


def test_stop_cleans_up():
    simulator = SimulatedKraftMaster()
    path = simulator.start()
    directory = os.path.dirname(path)
    assert os.path.isdir(directory)
    simulator.stop()
    simulator.stop()
    assert not os.path.exists(directory)
    assert simulator.port is None
    with pytest.raises(RuntimeError, match='start'):
        simulator.unplug()


@pytest.mark.parametrize('options, message', [
    ({'operator': 'dance'}, 'operator'),
    ({'coupling': 'belt'}, 'coupling'),
    ({'arm': 'middle'}, 'arm'),
    ({'codec': 'kmc-secret'}, 'codec'),
    ({'calibration': ArmCalibration.nominal('left')}, 'left arm'),
    ({'torque_scale': (1.0, 2.0)}, 'torque_scale'),
    ({'torque_scale': (0.0,) * 5}, 'torque_scale'),
    ({'torque_limit': (40000,) * 5}, 'torque_limit'),
    ({'drop_reply_rate': 1.5}, 'drop_reply_rate'),
    ({'corrupt_byte_rate': -0.1}, 'corrupt_byte_rate'),
    ({'pot_noise_counts': -1.0}, 'pot_noise_counts'),
    ({'baudrate': 0}, 'baud'),
    ({'command_timeout': 0.0}, 'command_timeout'),
    ({'priority': 100}, 'priority'),
    ({'priority': 1.5}, 'priority'),
    ({'transport': 'usb'}, 'transport'),
])
def test_bad_options_are_refused_by_name(options, message):
    with pytest.raises(ValueError, match=message):
        SimulatedKraftMaster(**options)


@contextlib.contextmanager
def running_cli(*arguments, wrapper=()):
    """Run the simulator CLI as a subprocess of this Python; kill it and close its pipes after."""
    env = dict(os.environ, PYTHONPATH=str(REPO), PYTHONUNBUFFERED='1')
    process = subprocess.Popen(
        [*wrapper, sys.executable, '-m', 'kraft_master_driver.simulation.master.simulator',
         *arguments],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=REPO)
    try:
        yield process
    finally:
        process.kill()
        process.wait()
        process.stdout.close()
        process.stderr.close()


def read_port_line(process, timeout=30.0):
    """Return the port path from the CLI's `port: PATH` line."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if select.select([process.stdout], [], [], 0.1)[0]:
            line = process.stdout.readline()
            assert line.startswith('port: '), line + process.stderr.read()
            return line[len('port: '):].strip()
    raise AssertionError('the simulator CLI printed no port line')


@pytest.mark.process
@pytest.mark.parametrize('signum', [signal.SIGINT, signal.SIGTERM], ids=['SIGINT', 'SIGTERM'])
def test_cli_serves_the_printed_port_and_exits_cleanly(signum):
    with running_cli('--operator', 'sweep', '--noise', '1',
                     '--calibration', str(REPO / 'config' / 'left_arm.yaml')) as process:
        path = read_port_line(process)
        host = Host(path)
        try:
            frame = host.exchange()
            assert frame is not None and frame.sequence == 0
        finally:
            host.close()
        process.send_signal(signum)
        assert process.wait(timeout=20) == 0
        assert not os.path.exists(os.path.dirname(path))


@pytest.mark.process
def test_cli_serves_tcp_to_the_driver_device_code():
    with running_cli('--tcp') as process:
        url = read_port_line(process)
        assert url.startswith('socket://127.0.0.1:')
        with KmcDevice(url) as device:
            results = [device.cycle([0.0] * 5) for _ in range(100)]
        assert all(result is not None for result in results)
        process.send_signal(signal.SIGINT)
        assert process.wait(timeout=20) == 0


@pytest.mark.parametrize('codec', sorted(CODECS))
def test_each_described_frame_drives_the_device(codec):
    with SimulatedKraftMaster(codec=codec, command_timeout=0.05) as simulator:
        device = KmcDevice(simulator.port, codec=codec, reply_timeout=0.5)
        with device:
            first = device.cycle((0.0,) * 5)
            assert first is not None and first.frame.status & STATUS_AMPLIFIERS_ENABLED
            # The simulator undoes the description's torque sign (-1 on axis 5 in the example):
            # +1 N*m on axis 5 turns th5 positive, whatever the sign on the wire.
            wait_for(lambda: device.cycle((0.0, 0.0, 0.0, 0.0, 1.0)) and
                     simulator.joint_angles()[4] > HOME[4] + 0.03)
            assert simulator.received[-1][1].counts[4] == round(device.torque_scale[4])
            clamped = device.cycle((0.0, 0.0, 0.0, 0.0, 1e3))
            assert clamped is not None and device.stats['clamped_commands'] == 1
            # The device itself clamps, so the simulator's clamp bit stays clear.
            assert not clamped.frame.status & STATUS_COMMAND_CLAMPED
            wait_for(lambda: simulator.stats['timeouts'] >= 1)
            assert device.cycle((0.0,) * 5).frame.status & STATUS_COMMAND_TIMEOUT
        assert simulator.received[-1][1].counts == ZERO  # written on close
        assert sum(simulator.stats['decode_errors'].values()) == 0


@pytest.mark.process
def test_cli_speaks_the_frame_it_is_given():
    with running_cli('--tcp', '--codec', 'example-be-crc8') as process:
        url = read_port_line(process)
        with KmcDevice(url, codec='example-be-crc8') as device:
            results = [device.cycle([0.0] * 5) for _ in range(100)]
        assert all(result is not None and result.frame.sequence is None for result in results)
        with KmcDevice(url, reply_timeout=0.005, timeouts_before_reconnect=1000) as device:
            assert not any(device.cycle([0.0] * 5) for _ in range(20))  # another frame
        process.send_signal(signal.SIGINT)
        assert process.wait(timeout=20) == 0


@pytest.mark.process
def test_cli_refuses_a_bad_frame_description_in_one_line(tmp_path):
    bad = tmp_path / 'bad_frame.yaml'
    bad.write_text('name: bad\n')
    result = subprocess.run(
        [sys.executable, '-m', 'kraft_master_driver.simulation.master.simulator',
         '--codec', str(bad)], capture_output=True, text=True, cwd=REPO,
        env=dict(os.environ, PYTHONPATH=str(REPO)), timeout=60)
    assert result.returncode == 2
    assert f'frame description {bad}: command: missing' in result.stderr.splitlines()[-1]


@pytest.mark.process
def test_a_killed_simulator_leaves_a_dangling_link():
    with running_cli() as process:
        path = read_port_line(process)
        assert os.path.realpath(path).startswith('/dev/pts/')
        process.kill()
        process.wait(timeout=20)
        # A stale link must not lead a reconnecting driver to another process's pty.
        assert os.path.lexists(path) and not os.path.exists(path)
    shutil.rmtree(os.path.dirname(path))


def test_priority_runs_the_serving_thread_sched_fifo():
    with SimulatedKraftMaster(priority=20) as simulator:
        assert simulator.priority_error is None
        thread_id = simulator._thread.native_id
        assert os.sched_getscheduler(thread_id) == os.SCHED_FIFO
        assert os.sched_getparam(thread_id).sched_priority == 20
        assert os.sched_getscheduler(0) == os.SCHED_OTHER  # the caller's thread is untouched
        host = Host(simulator.port)
        try:
            assert host.exchange() is not None
        finally:
            host.close()


@pytest.mark.process
def test_cli_runs_its_main_thread_one_below_the_serving_thread():
    with running_cli('--priority', '20') as process:
        host = Host(read_port_line(process))
        try:
            assert host.exchange() is not None
            priorities = {int(task.name): os.sched_getparam(int(task.name)).sched_priority
                          for task in pathlib.Path(f'/proc/{process.pid}/task').iterdir()}
        finally:
            host.close()
        # The main thread looks for a stop and shares the interpreter lock with the serving
        # thread: preempted while holding it, at normal priority, it would hold up replies.
        assert priorities[process.pid] == 19
        assert 20 in priorities.values()
        process.send_signal(signal.SIGINT)
        assert process.wait(timeout=20) == 0


@pytest.mark.process
def test_cli_warns_when_the_priority_is_refused_and_serves_anyway():
    without_sys_nice = ['setpriv', '--inh-caps', '-sys_nice', '--bounding-set', '-sys_nice']
    with running_cli('--priority', '20', wrapper=without_sys_nice) as process:
        host = Host(read_port_line(process))
        try:
            assert host.exchange() is not None
        finally:
            host.close()
        process.send_signal(signal.SIGINT)
        assert process.wait(timeout=20) == 0
        assert 'warning: SCHED_FIFO 20 refused' in process.stderr.read()


@pytest.mark.process
def test_cli_refuses_an_unreadable_calibration():
    result = subprocess.run(
        [sys.executable, '-m', 'kraft_master_driver.simulation.master.simulator',
         '--calibration', '/no/such.yaml'],
        capture_output=True, text=True, timeout=60, env=dict(os.environ, PYTHONPATH=str(REPO)))
    assert result.returncode == 2
    assert '/no/such.yaml: cannot read' in result.stderr


def test_push_operator_moves_the_wrist_straight_down_and_back():
    workspace = Workspace()
    operator = PushOperator(workspace, period=2.0)

    def wrist(t):
        return kinematics.forward(actuators_to_joints(np.array(operator.target(t))))[:3, 3]

    top, bottom, back = wrist(0.0), wrist(2.0), wrist(4.0)
    np.testing.assert_allclose(bottom - top, (0.0, 0.0, -PushOperator.DEPTH), atol=0.005)
    np.testing.assert_allclose(back, top, atol=1e-9)
    assert wrist(1.0)[2] == pytest.approx(top[2] - PushOperator.DEPTH / 2, abs=0.005)


def test_task_operator_moves_holds_touches_down_and_lifts_round_after_round():
    workspace = Workspace()
    operator = TaskOperator(workspace, period=2.0, rng=np.random.default_rng(5))

    def wrist(t):
        return kinematics.forward(actuators_to_joints(np.array(operator.target(t))))[:3, 3]
    home = kinematics.forward(workspace.home())[:3, 3]
    ends = np.cumsum([share * 2.0 for _, share in TaskOperator.PHASES])
    points = []
    for round_start in (0.0, ends[-1], 2 * ends[-1]):  # its time only goes forward
        moved, held, pressed, lifted = (wrist(round_start + ends[i]) for i in (0, 1, 3, 4))
        sideways = moved - home
        assert abs(sideways[2]) < 0.002 and np.abs(sideways[:2]).max() <= 0.031
        np.testing.assert_allclose(held, moved, atol=1e-9)
        np.testing.assert_allclose(pressed - moved, (0.0, 0.0, -TaskOperator.DEPTH), atol=0.005)
        np.testing.assert_allclose(lifted, moved, atol=1e-6)
        points.append(moved)
    # Each round goes somewhere else, and the path is continuous across the rounds.
    assert min(np.linalg.norm(a - b) for a, b in zip(points, points[1:])) > 1e-3
    operator = TaskOperator(workspace, period=2.0, rng=np.random.default_rng(5))
    times = np.arange(0.0, 3 * ends[-1], 0.001)
    steps = np.linalg.norm(np.diff([wrist(t) for t in times], axis=0), axis=1)
    assert steps.max() < 2e-4


@pytest.mark.slow
def test_push_operator_takes_hold_at_the_hosts_first_command():
    with SimulatedKraftMaster(operator='push') as simulator:
        time.sleep(1.5)  # three quarters of a stroke, had the push started with the simulator
        np.testing.assert_allclose(simulator.joint_angles(), HOME, atol=1e-12)
        host = Host(simulator.port)
        assert host.exchange() is not None
        top = kinematics.forward(HOME)[2, 3]
        wait_for(lambda: kinematics.forward(simulator.joint_angles())[2, 3] < top - 0.01,
                 poll=host.exchange)
        host.port.close()


def test_hold_at_moves_the_held_pose_and_only_for_the_hold_operator():
    start = joints_to_actuators(Workspace().home())
    target = joints_to_actuators(np.radians([10.0, 50.0, -100.0, 5.0, 10.0, 0.0]))
    with SimulatedKraftMaster(operator='hold') as simulator:
        simulator.hold_at(target)
        simulator.start()

        def error():
            return np.abs(joints_to_actuators(simulator.joint_angles()) - target).max()

        deadline = time.monotonic() + 20.0
        while error() > 0.01 and time.monotonic() < deadline:
            time.sleep(0.05)
        # Coulomb friction leaves the hand's spring a small static offset.
        assert error() < 0.01 < np.abs(start - target).max()
    with pytest.raises(ValueError, match='hold'):
        SimulatedKraftMaster(operator='sweep').hold_at(target)
