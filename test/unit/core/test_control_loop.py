# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Tests of the control loop without ROS.

The timing rules run on a fake clock against a scripted device that answers each receive()
as told: a reply, a late reply, a timeout or an exception. The rest runs the real KmcDevice
against the simulated hand controller on a pseudo-terminal.
"""
import subprocess
import sys
import threading
import time

from kraft_master_driver.core import kinematics
from kraft_master_driver.core.calibration import ArmCalibration
from kraft_master_driver.core.control_loop import ControlLoop, ZERO_TORQUES
from kraft_master_driver.core.force_reflection import ForceReflection
from kraft_master_driver.core.passivity import MasterPort
from kraft_master_driver.core.velocity_filter import VelocityFilter
from kraft_master_driver.core.wrench_admission import BASE_FRAME, WrenchInput
from kraft_master_driver.link.device import CycleResult, KmcDevice
from kraft_master_driver.link.protocol import PotFrame
from kraft_master_driver.simulation.master.simulator import SimulatedKraftMaster
import pytest

PERIOD_NS = 1_000_000  # 1 kHz
CALIBRATION = ArmCalibration.nominal('right')
THETA = [0.1, 0.6, -0.9, 0.1, 0.2, 0.3]  # rad, a pose inside the workspace
POTS = tuple(round(count) for count in CALIBRATION.joints_to_frame(THETA))
WAIT_S = 60.0  # upper bound for conditions to come true on a loaded machine
MOMENT_Z = 0.5  # N*m about the base z axis: the torque of axis 1, whatever the pose
WRENCH = (0.0, 0.0, 0.0, 0.0, 0.0, MOMENT_Z)


class FakeClock:
    """Time that moves only when the loop sleeps or the device says a reply took long."""

    def __init__(self):
        """Start at 0 ns."""
        self.now_ns = 0

    def monotonic_ns(self):
        return self.now_ns

    def thread_time_ns(self):
        return self.now_ns

    def sleep(self, seconds):
        self.now_ns += round(seconds * 1e9)


def wait_for(condition, timeout=WAIT_S):
    """Poll condition() until it is true (return True) or timeout seconds pass (False)."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.001)
    return True


def reply(delay_ns=0):
    """Return a script step: the reply comes after delay_ns."""
    return ('reply', delay_ns)


TIMEOUT = ('timeout', None)


def failure(error):
    """Return a script step: receive() raises `error`."""
    return ('raise', error)


class ScriptedDevice:
    """Stands in for KmcDevice: each receive() does what the next step of its script says."""

    port = 'scripted'
    reply_timeout = 0.01

    def __init__(self, clock, script, events=None):
        """Answer with `script`; note each send in `events` as 'send'."""
        self.clock = clock
        self.script = list(script)
        self.events = [] if events is None else events
        self.sent = []  # (time ns, torques)
        self.received_at = []  # time ns each reply was handed over
        self.link_up = True
        self.failed_opens = 0
        self.last_error = ''
        self.closed = False
        self._sequence = 0

    @property
    def stats(self):
        return {'failed_opens': self.failed_opens}

    def send(self, torques_nm):
        self.events.append('send')
        self.sent.append((self.clock.now_ns, tuple(torques_nm)))
        if not self.link_up:
            self.failed_opens += 1
        return self.link_up

    def receive(self):
        kind, argument = self.script.pop(0)
        if kind == 'raise':
            raise argument
        if kind == 'timeout':
            return None
        self.clock.now_ns += argument
        self._sequence += 1
        self.received_at.append(self.clock.now_ns)
        return CycleResult(PotFrame(self._sequence % 256, POTS, 0), self.clock.now_ns, 1e-4,
                           self.sent[-1][1])

    def close(self):
        self.closed = True


class RecordingLog:
    """A logger that keeps (level, message) of each call."""

    def __init__(self):
        """Start empty."""
        self.records = []

    def _record(self, level, message, **_options):
        self.records.append((level, message))

    def info(self, message, **options):
        self._record('info', message, **options)

    def warning(self, message, **options):
        self._record('warning', message, **options)

    def error(self, message, **options):
        self._record('error', message, **options)

    def messages(self, level):
        return [message for kind, message in self.records if kind == level]


def make_loop(device, clock=None, publish=None, force=None, take_inputs=None, **options):
    """Return a ControlLoop on `device`; unless told, force output on and WRENCH at each take."""
    force = ForceReflection(enabled=True) if force is None else force
    now_ns = clock.monotonic_ns if clock else time.monotonic_ns
    if take_inputs is None:
        def take_inputs():
            force.hold(WrenchInput(WRENCH, BASE_FRAME, now_ns()))
    master_port = MasterPort()
    master_port.enabled = False  # the node's default: passivity off
    if clock is not None:
        options = {'clock': clock, 'keep_running': lambda: bool(device.script), **options}
    return ControlLoop(
        device, force, publish or (lambda result, estimate: None), calibration=CALIBRATION,
        arm='right', lengths=kinematics.LinkLengths(*kinematics.NOMINAL_LENGTHS),
        velocity=VelocityFilter(50.0), master_port=master_port, log=RecordingLog(),
        rate_hz=1e9 / PERIOD_NS, take_inputs=take_inputs, **options)


def run_script(script, **options):
    """Run a loop on a fake clock until its scripted device has no step left."""
    clock = FakeClock()
    device = ScriptedDevice(clock, script)
    loop = make_loop(device, clock, **options)
    loop.run()
    return loop, device, clock


def is_zero(torques):
    return tuple(torques) == ZERO_TORQUES


# -- timing ------------------------------------------------------------------------------------


def test_cycles_on_time_send_at_each_deadline():
    loop, device, _ = run_script([reply()] * 5)
    assert [time_ns for time_ns, _ in device.sent] == [i * PERIOD_NS for i in range(6)]
    assert loop.statistics.late == loop.statistics.missed == 0
    assert loop.statistics.frames == loop.statistics.published == 5
    assert device.closed


def test_a_late_cycle_sends_at_once_and_skips_the_periods_it_cannot_catch_up():
    # The second reply comes 3.5 periods after its command: past the deadline at 2 periods.
    loop, device, _ = run_script([reply(), reply(3_500_000), reply(), reply()])
    late_reply_ns = device.received_at[1]
    assert late_reply_ns == 4_500_000
    times = [time_ns for time_ns, _ in device.sent]
    # Sent at once on the late reply (no sleep), then back on the grid: 3 and 4 were skipped.
    assert times == [0, 1_000_000, late_reply_ns, 5_000_000, 6_000_000]
    assert loop.statistics.late == 1
    assert loop.statistics.missed == 2
    # What went at once are the torques of the late reply's own estimate.
    assert device.sent[2][1][0] == pytest.approx(MOMENT_Z)


def test_a_late_cycle_publishes_after_its_command_is_on_the_wire():
    clock = FakeClock()
    device = ScriptedDevice(clock, [reply(), reply(1_500_000), reply()])
    published_after_sends = []
    loop = make_loop(device, clock,
                     publish=lambda result, estimate: published_after_sends.append(
                         len(device.sent)))
    loop.run()
    # On time: published before the cycle's command; late: after it.
    assert published_after_sends == [1, 3, 3]


def test_a_missing_reply_zeroes_the_torques_and_says_so():
    loop, device, _ = run_script([reply(), reply(), TIMEOUT, reply(), reply()])
    torques = [sent for _, sent in device.sent]
    assert is_zero(torques[0])  # no estimate before the first reply
    assert [is_zero(sent) for sent in torques[1:]] == [False, False, True, False, False]
    assert loop.output is not None and loop.statistics.frames == 4
    warnings = loop.log.messages('warning')
    assert warnings == ['no reply within reply_timeout 0.01 s (1 in a row): torques zeroed']
    assert loop.log.messages('info') == ['the device answers again']


def test_after_a_missing_reply_the_force_ramps_back_in():
    force = ForceReflection(enabled=True, force_ramp_time=20 * PERIOD_NS / 1e9)
    _, device, _ = run_script([reply()] * 25 + [TIMEOUT] + [reply()] * 5, force=force)
    shares = [sent[0] / MOMENT_Z for _, sent in device.sent]
    # Ramped in from the first estimate (1/20 a cycle), zero at the missing reply, ramped again:
    # that cycle waited reply_timeout, so the first step is the most a cycle takes, a tenth.
    expected = [0.0, 0.0] + [min(n / 20, 1.0) for n in range(1, 25)] + [0.0] + [
        n / 20 for n in range(2, 7)]
    assert shares == pytest.approx(expected, abs=1e-12)


def test_a_down_link_is_reported_less_often_as_reopens_keep_failing():
    clock = FakeClock()
    device = ScriptedDevice(clock, [])
    device.link_up = False
    device.last_error = 'scripted: cannot open: No such file or directory'
    loop = make_loop(device, clock, keep_running=lambda: len(device.sent) < 20)
    loop.run()
    assert all(is_zero(sent) for _, sent in device.sent)
    assert loop.log.messages('warning') == [
        f'waiting for the device: cannot open: No such file or directory ({n} attempts): '
        'torques zero' for n in (2, 4, 8, 16)]


@pytest.mark.parametrize('where', ['receive', 'publish', 'take_inputs'])
def test_an_exception_in_a_cycle_zeroes_the_torques_and_the_loop_goes_on(where):
    clock = FakeClock()
    error = RuntimeError('scripted fault')
    script = [reply()] * 6
    if where == 'receive':
        script[2] = failure(error)
    device = ScriptedDevice(clock, script)
    calls = []

    def maybe_fail(name):
        calls.append(name)
        if name == where and calls.count(name) == 3:
            raise error

    force = ForceReflection(enabled=True)

    def take_inputs():
        maybe_fail('take_inputs')
        force.hold(WrenchInput(WRENCH, BASE_FRAME, clock.monotonic_ns()))

    loop = make_loop(device, clock, publish=lambda result, estimate: maybe_fail('publish'),
                     force=force, take_inputs=take_inputs)
    loop.run()
    torques = [sent for _, sent in device.sent]
    zeroed = [i for i, sent in enumerate(torques) if is_zero(sent)]
    assert zeroed[0] == 0 and len(zeroed) == 2, torques  # the first send, and the fault's
    assert not any(map(is_zero, torques[zeroed[1] + 1:]))  # torques again after the fault
    assert loop.statistics.internal_errors == 1
    assert loop.log.messages('error') == [f'cycle failed, torques zeroed: {error!r}']
    # A period's pause after the fault, then the next cycle: no busy loop if it recurs.
    assert device.sent[zeroed[1] + 1][0] - device.sent[zeroed[1]][0] == 2 * PERIOD_NS
    assert device.closed


# -- publishing and inputs ---------------------------------------------------------------------


def test_every_nth_frame_is_published():
    published = []
    loop, device, _ = run_script(
        [reply()] * 10, publish_decimation=3,
        publish=lambda result, estimate: published.append(result.frame.sequence))
    assert published == [3, 6, 9]
    assert loop.statistics.published == 3 and loop.statistics.frames == 10


def test_the_inputs_are_taken_before_each_send_and_used_by_it():
    clock = FakeClock()
    events = []
    device = ScriptedDevice(clock, [reply()] * 5 + [TIMEOUT] + [reply()] * 3, events)
    force = ForceReflection(enabled=True)
    moments = []

    def take_inputs():
        events.append('take')
        moments.append(0.01 * len(moments))  # a new wrench each time
        force.hold(WrenchInput((0.0, 0.0, 0.0, 0.0, 0.0, moments[-1]), BASE_FRAME,
                               clock.monotonic_ns()))

    loop = make_loop(device, clock, force=force, take_inputs=take_inputs)
    loop.run()
    assert events == ['take', 'send'] * len(device.sent)
    axis1 = [torques[0] for _, torques in device.sent]
    with_estimate = [i for i in range(len(axis1)) if i not in (0, 6)]  # first; after timeout
    assert [axis1[i] for i in with_estimate] == pytest.approx([moments[i] for i in with_estimate])
    assert axis1[0] == axis1[6] == 0.0


def test_a_wrench_that_stops_coming_zeroes_the_torques_once_stale():
    clock = FakeClock()
    device = ScriptedDevice(clock, [reply()] * 80)
    force = ForceReflection(enabled=True)
    force.hold(WrenchInput(WRENCH, BASE_FRAME, 0))  # only once: stale after wrench_timeout (50 ms)
    loop = make_loop(device, clock, force=force, take_inputs=lambda: None)
    loop.run()
    active = [not is_zero(sent) for _, sent in device.sent]
    assert active[1:51] == [True] * 50 and not any(active[51:])
    assert loop.log.messages('warning') == [
        'no wrench for 0.05 s (wrench_timeout): torques zeroed']


def test_the_estimate_is_the_kinematics_of_the_frame():
    estimates = []
    loop, _, _ = run_script([reply()] * 3,
                            publish=lambda result, estimate: estimates.append(estimate))
    theta = CALIBRATION.frame_to_joints(POTS)
    pose = kinematics.forward(theta, 'right')
    estimate = estimates[-1]
    assert estimate.theta == pytest.approx(theta)
    assert estimate.velocity == pytest.approx([0.0] * 6)  # the pots stand still
    assert loop.pose() == pytest.approx(pose)
    assert [x for row in estimate.rotation for x in row] == pytest.approx(
        pose[:3, :3].ravel())


# -- the real device and the simulated hand controller -----------------------------------------


def run_on_simulator(publishes, **options):
    """Run a loop on a KmcDevice to the simulator until `publishes` states went out."""
    with SimulatedKraftMaster(operator='hold') as simulator:
        device = KmcDevice(simulator.port, reply_timeout=0.5)
        assert device.open()
        done = threading.Event()

        def publish(result, estimate):
            if loop.statistics.published + 1 >= publishes:
                done.set()

        loop = make_loop(device, publish=publish, **options)
        thread = threading.Thread(target=loop.run)
        thread.start()
        try:
            assert done.wait(WAIT_S), 'the loop published too little'
        finally:
            loop.stop()
            thread.join(WAIT_S)
        written = device.stats['cycles'] + device.stats['zero_commands']
        assert wait_for(lambda: len(simulator.received) == written)
        commands = [command.counts for _, command in simulator.received]
    return loop, commands


AXIS1_COUNTS = round(MOMENT_Z * 1000.0)  # the default torque scale: 1000 counts per N*m


def test_on_the_simulator_the_torques_reach_the_device_and_end_at_zero():
    loop, commands = run_on_simulator(50)
    assert commands[0] == (0,) * 5  # no pot frame yet
    assert commands[-1] == (0,) * 5  # closed: zero torques written last
    inner = [counts[0] for counts in commands[1:-1]]
    assert set(inner) <= {AXIS1_COUNTS, 0}
    # One command with torque per pot frame; zero after a reply that did not come in time.
    assert inner.count(AXIS1_COUNTS) == loop.statistics.frames >= 50
    assert inner.count(0) == loop.device.stats['timeouts']
    assert loop.statistics.internal_errors == 0
    assert loop.statistics.published == loop.statistics.frames


def test_on_the_simulator_an_exception_in_a_cycle_sends_zero_torques():
    force = ForceReflection(enabled=True)
    takes = []

    def take_inputs():
        takes.append(True)
        if len(takes) == 10:
            raise RuntimeError('scripted fault')
        force.hold(WrenchInput(WRENCH, BASE_FRAME, time.monotonic_ns()))

    loop, commands = run_on_simulator(30, force=force, take_inputs=take_inputs)
    inner = [counts[0] for counts in commands[1:-1]]
    assert loop.statistics.internal_errors == 1
    # The fault's zero command in place of its frame's torques, and one per missing reply.
    assert inner.count(0) == 1 + loop.device.stats['timeouts']
    assert inner.count(AXIS1_COUNTS) == loop.statistics.frames - 1
    assert commands[-1] == (0,) * 5


@pytest.mark.process
def test_the_loop_imports_no_rclpy():
    code = 'import sys, kraft_master_driver.core.control_loop; sys.exit("rclpy" in sys.modules)'
    assert subprocess.run([sys.executable, '-c', code], timeout=60).returncode == 0
