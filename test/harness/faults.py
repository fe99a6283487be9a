# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The fault suite's harness (integration/faults/), shared with scripts/soak.py.

FaultSession: the installed kraft_master_node runs on a SimulatedKraftMaster in this process,
watched by a client node here and fed by a wrench source in a separate process
(wrench_source.py). The faults the suite and the soak test inject (link faults, rejected
wrenches, a killed wrench source, a wrench flood) and how they are injected; the bad values of
a parameter. Times come from the commands the simulated device received (simulator.received,
time.time_ns() stamps); record() adds a row to FAULT_TABLE, which the suite's conftest.py
prints and writes to fault_table.json at the end of the run.
"""
import bisect
import itertools
import json
import math
import operator
import os
import pathlib
import re
import signal
import subprocess
import sys
import threading
import time
from typing import Callable, NamedTuple

from diagnostic_msgs.msg import DiagnosticArray
from harness import dds_shm
from harness.driver import (ClientNode, DriverProcess, installed_env, next_domain_id, wait_for,
                            WAIT_S)
from kraft_master_driver.nodes.driver_parameters import PARAMETERS
from kraft_master_driver.simulation.master.simulator import SimulatedKraftMaster
from rclpy.parameter_client import AsyncParameterClient
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState

LOOP_RATE_HZ = 200.0  # low enough for the Python client to follow every message
BASE = PARAMETERS['base_frame'].default
WRENCH = (3.0, -2.0, 4.0, 0.05, -0.1, 0.08)  # N, N*m in the base frame: torque on every axis
WRENCH_TIMEOUT_S = PARAMETERS['wrench_timeout'].default
LOG_THROTTLE_NS = 1_000_000_000  # the driver's repeated warnings (no wrench, no reply): 1 a second
SOURCE_RATE_HZ = 500.0  # the steady wrench stream
KILLED_SOURCE_RATE_HZ = 1000.0
FLOOD_RATE_HZ = 20000.0
FLOOD_S = 3.0
BAD_STREAM_S = 1.0  # how long a rejected input keeps streaming, more than SETTLE_S
FAULT_S = 2.0
GARBAGE_BYTES = 512  # per burst, a burst every ~10 ms while the flood lasts
RECORD_LENGTH = 100_000  # commands the simulator keeps: minutes at LOOP_RATE_HZ
FROZEN_MS = 1e9  # a stall that lasts until it is lifted
SETTLE_S = 0.5  # time for a change to reach every counter and command, generously
SIMULATOR_SWITCH_INTERVAL_S = 2e-4  # the GIL switch interval of this process during sessions
CHECK_INTERVAL_S = 0.005  # spin this long between two checks of a condition
STARTED = re.compile(r'Kraft Master on ')  # the driver's line once it runs
LOG_LINE = re.compile(r'^\[(\w+)\] \[(\d+)\.(\d+)\] \[[^\]]*\]: (.*)$')
DECODER_ERRORS = ('link bad_crc', 'link garbage_bytes', 'link truncated', 'link out_of_range')
WRENCH_SOURCE = pathlib.Path(__file__).resolve().parent / 'wrench_source.py'

SEVERAL_SOURCES = (('allow_multiple_wrench_sources', 'true'),)

FAULT_TABLE = []
SESSION_NUMBERS = itertools.count()
first_item = operator.itemgetter(0)


class MissingLogMessage(AssertionError):
    """The driver wrote no log line about a fault."""


def milliseconds(seconds):
    """Return seconds as milliseconds rounded to 0.1 (None stays None)."""
    return None if seconds is None else round(1e3 * seconds, 1)


def record(group, row, safe_s=None, recovery_s=None, how='', **details):
    """Add one row to FAULT_TABLE (times in ms; `how` the torque became zero) and print it."""
    entry = {'group': group, 'row': row, 'safe_ms': milliseconds(safe_s),
             'recovery_ms': milliseconds(recovery_s), 'how': how, **details}
    FAULT_TABLE.append(entry)
    print(json.dumps(entry))


def format_table(rows):
    """Return the rows with measured times as a text table, and a count of the others."""
    timed = [r for r in rows if r['safe_ms'] is not None or r['recovery_ms'] is not None]
    lines = [f'{"group":<8} {"fault":<38} {"zero torque (ms)":>16} {"recovery (ms)":>13}  how']
    for r in timed:
        safe, back = (('-' if r[key] is None else f'{r[key]:.1f}')
                      for key in ('safe_ms', 'recovery_ms'))
        lines.append(f'{r["group"]:<8} {r["row"]:<38} {safe:>16} {back:>13}  {r["how"]}')
    groups = {}
    for r in rows:
        if r not in timed:
            groups[r['group']] = groups.get(r['group'], 0) + 1
    lines += [f'{group}: {count} rows without times (see the JSON)'
              for group, count in groups.items()]
    return '\n'.join(lines)


# -- the processes -----------------------------------------------------------------------------


class Driver:
    """The installed driver process; its output is collected line by line while it runs."""

    def __init__(self, prefix, domain_id, parameters=(), namespace=None, params_file=None):
        """Start kraft_master_node with `-p name:=value` for each of `parameters`."""
        self.process = DriverProcess(prefix, domain_id, parameters, namespace=namespace,
                                     params_file=params_file).process
        self.lines = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self):
        for line in self.process.stdout:
            self.lines.append(line.rstrip('\n'))

    @property
    def output(self):
        """Everything the driver wrote so far."""
        return '\n'.join(self.lines)

    def log_since(self, time_ns, levels=('WARN', 'ERROR', 'FATAL')):
        """Messages the driver logged at one of `levels` at or after `time_ns`."""
        messages = []
        for line in list(self.lines):
            match = LOG_LINE.match(line)
            if match and match[1] in levels:
                stamp = int(match[2]) * 1_000_000_000 + int(match[3].ljust(9, '0')[:9])
                if stamp >= time_ns:
                    messages.append(match[4])
        return messages

    def started_or_exited(self):
        """Return the exit code, 'started' once the driver runs, or None while neither."""
        code = self.process.poll()
        if code is not None:
            self._reader.join(timeout=10.0)
            return code
        return 'started' if any(STARTED.search(line) for line in self.lines) else None

    def stop(self, sig=signal.SIGINT, timeout=WAIT_S):
        """Send `sig`, wait for the exit; return the exit code."""
        self.process.send_signal(sig)
        code = self.process.wait(timeout=timeout)
        self._reader.join(timeout=10.0)
        return code

    def kill(self):
        """Make sure the process is gone (SIGTERM first: its DDS participant tears down)."""
        dds_shm.end(self.process, timeout=WAIT_S)
        self._reader.join(timeout=10.0)


class WrenchSource:
    """wrench_source.py run as a separate process: publishes wrenches as told."""

    def __init__(self, env, namespace, wait):
        """Start the process in `env` and `namespace`; `wait(condition)` spins while waiting."""
        self.process = subprocess.Popen(
            [sys.executable, WRENCH_SOURCE, '--ros-args', '-r', f'__ns:={namespace}'],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env)
        self.replies = []
        self._wait = wait
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self):
        for line in self.process.stdout:
            self.replies.append(line.split())

    def wait_ready(self):
        """Wait until the source has matched the driver's subscription."""
        self._wait(lambda: self.replies or self.process.poll() is not None)
        assert self.replies and self.replies[0] == ['ready'], 'the wrench source failed'

    def switch(self, rate_hz, wrench=WRENCH, frame_id=BASE, stamp=0.0):
        """
        Publish `wrench` at `rate_hz` from now on (0: stop publishing).

        stamp: seconds added to the clock in each header, or 'zero' for an unset stamp.
        Return (time.time_ns() of the first message so published, messages published before).
        """
        count = len(self.replies)
        spec = {'rate_hz': rate_hz, 'wrench': list(wrench), 'frame_id': frame_id,
                'stamp': stamp}
        self.process.stdin.write(json.dumps(spec) + '\n')
        self.process.stdin.flush()
        self._wait(lambda: len(self.replies) > count)
        _, time_ns, published = self.replies[count]
        return int(time_ns), int(published)

    def kill(self):
        """SIGKILL the process; return time.time_ns() just before. Its shared memory is removed."""
        held = dds_shm.held_by(self.process.pid)
        killed_ns = time.time_ns()
        self.process.kill()
        self.process.wait(timeout=10.0)
        dds_shm.remove(dds_shm.orphaned(held))
        return killed_ns

    def close(self):
        """End the process (stdin closed) or kill it."""
        if self.process.poll() is None:
            try:
                self.process.stdin.close()
                self.process.wait(timeout=10.0)
            except (OSError, subprocess.TimeoutExpired):
                dds_shm.end(self.process)


class Diagnostics(NamedTuple):
    """One DiagnosticStatus of the driver."""

    stamp_ns: int
    level: int
    message: str
    values: dict

    def count(self, key):
        """Return the counter `key` as an int."""
        return int(self.values[key])


def watch_diagnostics(node, driver):
    """Subscribe `node` to /diagnostics; return the list the statuses of node `driver` go into."""
    received = []
    prefix = f'{driver}: '

    def on_diagnostics(msg):
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        for status in msg.status:
            if not status.name.startswith(prefix):
                continue
            level = status.level
            received.append(Diagnostics(
                stamp, level[0] if isinstance(level, bytes) else int(level), status.message,
                {kv.key: kv.value for kv in status.values}))
    node.create_subscription(DiagnosticArray, '/diagnostics', on_diagnostics, 10)
    return received


class FaultSession:
    """The simulated device in this process, the driver on its pty, a client, a wrench source."""

    def __init__(self, prefix, parameters=(), wrench_source=True, loop_rate_hz=LOOP_RATE_HZ,
                 record=RECORD_LENGTH):
        """Start everything; `record` is the number of commands the simulator keeps."""
        # The simulated device stands in for hardware: it must answer within reply_timeout
        # even while this process's main thread is busy, so hand the GIL over often; and
        # while the machine is busy, so its thread runs at the driver loop's real-time priority.
        self._switch_interval = sys.getswitchinterval()
        sys.setswitchinterval(SIMULATOR_SWITCH_INTERVAL_S)
        self.domain_id = next_domain_id()
        # A namespace of its own: other test runs on this machine may share the domain.
        self.namespace = f'/faults_{os.getpid()}_{next(SESSION_NUMBERS)}'
        self.simulator = SimulatedKraftMaster(arm='right', operator='hold', record=record,
                                              priority=PARAMETERS['loop_priority'].default)
        self.port = self.simulator.start()
        # Only what the suite needs: harness.driver.RosClient's three 200 Hz subscriptions
        # would compete with the simulator thread of this process.
        self.client = ClientNode(self.domain_id, 'fault_observer', self.namespace)
        self.states = 0
        self.client.node.create_subscription(
            JointState, 'joint_states', self._count_state,
            QoSProfile(depth=10000, reliability=ReliabilityPolicy.RELIABLE))
        self.diagnostics = self.watch(self.namespace)
        self.driver = Driver(prefix, self.domain_id, [
            ('port', self.port), ('loop_rate_hz', loop_rate_hz),
            ('force_enabled_at_start', 'true'), *parameters], namespace=self.namespace)
        self.source = WrenchSource(installed_env(prefix, self.domain_id), self.namespace,
                                   self.wait) if wrench_source else None
        self._parameters = None
        try:
            self.wait(lambda: self.states or self.driver.process.poll() is not None)
            assert self.states, 'the driver publishes no joint_states'
            # Messages published before the driver's publisher matched this client are lost
            # to it: count from here.
            self.baseline = self.frozen_counts()
            if self.source is not None:
                self.source.wait_ready()
                self.source.switch(SOURCE_RATE_HZ)
                self.wait_torque()
        except AssertionError as error:
            self.close()
            raise AssertionError(f'{error}; driver output:\n{self.driver.output}') from None
        except BaseException:
            self.close()
            raise

    def wait(self, condition, timeout=WAIT_S):
        """Spin the client until `condition()` is truthy; return its value."""
        return wait_for(condition, timeout, spin=lambda: self.client.spin(CHECK_INTERVAL_S))

    def _count_state(self, _msg):
        self.states += 1

    def watch(self, namespace):
        """Collect the DiagnosticStatus messages of the driver in `namespace` into a list."""
        return watch_diagnostics(self.client.node, f'{namespace}/kraft_master_node')

    def diagnostics_after(self, time_ns, received=None):
        """Wait for the first diagnostics stamped at or after `time_ns` and return it."""
        received = self.diagnostics if received is None else received

        def fresh():
            return next((d for d in received if d.stamp_ns >= time_ns), None)
        return self.wait(fresh)

    def force_diagnostics_after(self, time_ns):
        """
        Wait for the first diagnostics at or after `time_ns` that reports a force state.

        A snapshot taken just after a cycle whose reply was late reports 'no_state' (no pot
        frame, no torques computed); the next one says what the force reflection is doing.
        """
        def fresh():
            return next((d for d in self.diagnostics if d.stamp_ns >= time_ns
                         and d.values['force state'] != 'no_state'), None)
        return self.wait(fresh)

    def commands(self, since_ns=0, until_ns=math.inf):
        """Commands the device received in [since_ns, until_ns): (time_ns, TorqueCommand)."""
        received = list(self.simulator.received)  # a copy: the simulator thread appends
        start = bisect.bisect_left(received, since_ns, key=first_item)
        end = bisect.bisect_left(received, until_ns, key=first_item)
        return received[start:end]

    def first_command(self, since_ns, zero):
        """Time of the first (zero or non-zero torque) command at or after `since_ns`."""
        return next((t for t, c in self.commands(since_ns) if any(c.counts) != zero), None)

    def wait_command(self, since_ns, zero, timeout=WAIT_S):
        """Wait for a (zero or non-zero torque) command at or after `since_ns`; its time."""
        return self.wait(lambda: self.first_command(since_ns, zero), timeout)

    def wait_torque(self):
        """Wait until the device receives a non-zero torque command."""
        self.wait_command(time.time_ns(), zero=False)

    def parameter_client(self):
        """Return a parameter client of the driver node."""
        if self._parameters is None:
            self._parameters = AsyncParameterClient(self.client.node,
                                                    f'{self.namespace}/kraft_master_node')
            assert self._parameters.wait_for_services(timeout_sec=WAIT_S)
        return self._parameters

    def call(self, future):
        """Spin until `future` is done; return its result."""
        self.wait(future.done)
        return future.result()

    def expect_log(self, since_ns, pattern, timeout=2.0):
        """Wait for a warning or error logged since `since_ns` that matches `pattern`."""
        regex = re.compile(pattern, re.IGNORECASE)
        try:
            return self.wait(lambda: any(regex.search(m) for m in
                                         self.driver.log_since(since_ns)), timeout)
        except AssertionError:
            raise MissingLogMessage(
                f'no warning or error matching {pattern!r} in the driver log since the fault '
                f'({since_ns}); its last lines:\n' + '\n'.join(self.driver.lines[-10:])) from None

    def assert_alive(self):
        """Check that the driver runs and has not crashed."""
        assert self.driver.process.poll() is None, f'driver exited:\n{self.driver.output}'
        assert 'Traceback' not in self.driver.output, self.driver.output

    def frozen_counts(self):
        """
        Stall the device until the frame counters settle; return (diagnostics, states).

        The diagnostics are the first stamped SETTLE_S after the stall began, states the
        joint_states messages counted here by then.
        """
        frozen_ns = time.time_ns()
        self.simulator.stall(FROZEN_MS)
        try:
            return self.diagnostics_after(frozen_ns + int(SETTLE_S * 1e9)), self.states
        finally:
            self.simulator.stall(0)

    def frame_counts(self):
        """
        Freeze the frames and return their counters.

        'link replies', 'pot frames received', 'pot frames published' as the driver counts
        them; 'published since start' and 'joint_states received since start': the messages
        published and received here since the first frozen count.
        """
        (start, states_at_start), (final, states) = self.baseline, self.frozen_counts()
        counts = {key: final.count(key) for key in
                  ('link replies', 'pot frames received', 'pot frames published')}
        counts['published since start'] = (counts['pot frames published'] -
                                           start.count('pot frames published'))
        counts['joint_states received since start'] = states - states_at_start
        return counts

    def assert_nothing_lost(self):
        """
        Check that nothing was lost since the session started; return the frames counted.

        Every pot frame the link received was published once (publish_decimation 1), and
        every message published since the first frozen count reached the client.
        """
        counts = self.frame_counts()
        assert (counts['link replies'] == counts['pot frames received'] ==
                counts['pot frames published']), counts
        assert (counts['joint_states received since start'] ==
                counts['published since start']), counts
        return counts['published since start']

    def close(self):
        """Stop everything, whatever state the test left it in."""
        if self.source is not None:
            self.source.close()
        self.driver.kill()
        self.client.close()
        self.simulator.stop()
        sys.setswitchinterval(self._switch_interval)


def counter_growth(before, after, keys):
    """Return {key: growth} of diagnostics counters between two snapshots."""
    return {key: after.count(key) - before.count(key) for key in keys}


def zero_commands(commands):
    """Count the zero-torque commands among (time_ns, TorqueCommand) pairs."""
    return sum(not any(c.counts) for _, c in commands)


def longest_zero_run_s(commands):
    """Longest time torque stayed zero: a zero command to the next non-zero one (s)."""
    longest, started = 0.0, None
    for t, c in commands:
        if not any(c.counts):
            started = t if started is None else started
        elif started is not None:
            longest, started = max(longest, (t - started) / 1e9), None
    return longest


def zeroing_times_s(commands):
    """For each fall of torque to zero: time from the last torque command to the zero one."""
    return [(b - a) / 1e9 for (a, before), (b, after) in zip(commands, commands[1:])
            if any(before.counts) and not any(after.counts)]


def start_of_final_zero_run(commands):
    """Time of the first command of the zero-torque run that ends `commands`, or None."""
    start = None
    for t, c in commands:
        start = (start or t) if not any(c.counts) else None
    return start


def seconds_between(start_ns, end_ns):
    """(end - start) in seconds, None when end is None."""
    return None if end_ns is None else (end_ns - start_ns) / 1e9


# -- link faults -------------------------------------------------------------------------------


def set_rate(name, rate):
    """Return a fault switch that sets the simulator's rate attribute `name` to `rate`."""
    return lambda simulator: setattr(simulator, name, rate)


def no_action(_simulator):
    """Nothing to do at this stage of the fault."""


class LinkFault(NamedTuple):
    """One link fault: how to start it, keep it up and clear it, and what it must show."""

    row: str
    start: Callable
    seconds: float
    clear: Callable
    counters: tuple  # diagnostics counters of which at least one must grow
    log: str  # regex of the driver's message
    repeat: Callable = no_action  # called every few ms while the fault lasts
    link_down: bool = False  # the link is lost: diagnostics report ERROR, then a reconnect
    # The simulator's stats counter of the fault taking effect: the fault lasts until it grows.
    effect: str | None = None


LINK_FAULTS = [
    LinkFault('device unplugged, replugged after 2 s', SimulatedKraftMaster.unplug, FAULT_S,
              SimulatedKraftMaster.replug, ('link link_faults',), r'link.*(down|lost|fail)',
              link_down=True),
    LinkFault('1 reply in 10 dropped', set_rate('drop_reply_rate', 0.1), FAULT_S,
              set_rate('drop_reply_rate', 0.0), ('link timeouts',), r'time(d )?out|no reply',
              effect='dropped'),
    LinkFault('corrupt bytes at 1e-3', set_rate('corrupt_byte_rate', 1e-3), FAULT_S,
              set_rate('corrupt_byte_rate', 0.0), DECODER_ERRORS, r'crc|corrupt',
              effect='corrupted_bytes'),
    LinkFault('corrupt bytes at 1e-2', set_rate('corrupt_byte_rate', 1e-2), FAULT_S,
              set_rate('corrupt_byte_rate', 0.0), DECODER_ERRORS, r'crc|corrupt',
              effect='corrupted_bytes'),
    LinkFault('device stalls 200 ms', lambda simulator: simulator.stall(200), 0.2, no_action,
              ('link timeouts',), r'time(d )?out|no reply'),
    LinkFault('garbage flood', no_action, FAULT_S, no_action, ('link garbage_bytes',),
              r'garbage', repeat=lambda simulator: simulator.send_garbage(GARBAGE_BYTES),
              effect='garbage_sent'),
]


def hold_fault(session, fault, effects_before):
    """
    Keep `fault` up; return when the device's own watchdog fired (ns), or None.

    It lasts fault.seconds, and beyond them (WAIT_S at most) until the device's count of
    fault.effect has grown past `effects_before`: a busy machine exchanges fewer replies in
    that time, and the simulator's seeded draws may hit none of them (a fresh fault random
    corrupts byte 3480 first at 1e-3: reply 194, 1 s at 200 Hz).
    """
    simulator = session.simulator
    device_timeouts = simulator.stats['timeouts']
    watchdog_ns = None
    end = time.monotonic() + fault.seconds

    def lasting():
        now = time.monotonic()
        taken = fault.effect is None or simulator.stats[fault.effect] > effects_before
        return now < end or (not taken and now < end + WAIT_S)
    while lasting():
        fault.repeat(simulator)
        session.client.spin(0.01)
        if watchdog_ns is None and simulator.stats['timeouts'] > device_timeouts:
            watchdog_ns = time.time_ns()
    return watchdog_ns


class Injected(NamedTuple):
    """One injected fault: its times (time.time_ns()) and its time to zero torque."""

    fault_ns: int
    clear_ns: int
    back_ns: int  # the first torque command after the fault cleared
    safe_s: object  # seconds to zero torque; None where torque never fell
    how: str  # what zeroed the torque
    before: object = None  # Diagnostics taken just before the fault, where needed
    during: object = None  # Diagnostics taken while the fault held, where needed

    @property
    def recovery_s(self):
        """Seconds from the fault clearing to the first torque command."""
        return (self.back_ns - self.clear_ns) / 1e9


def inject_link_fault(session, fault):
    """Start `fault`, hold it, clear it and wait for torque again; return the Injected."""
    simulator = session.simulator
    effects_before = simulator.stats[fault.effect] if fault.effect else None
    fault_ns = time.time_ns()
    fault.start(simulator)
    watchdog_ns = hold_fault(session, fault, effects_before)
    clear_ns = time.time_ns()
    fault.clear(simulator)
    back_ns = session.wait_command(clear_ns, zero=False)
    if fault.link_down:
        # No command reaches the device: it zeroes itself on its command timeout.
        return Injected(fault_ns, clear_ns, back_ns, seconds_between(fault_ns, watchdog_ns),
                        'device command timeout')
    zeroing = zeroing_times_s(session.commands(fault_ns, back_ns + 1))
    return Injected(fault_ns, clear_ns, back_ns, max(zeroing, default=None),
                    'next command after a lost reply (max)')


# -- wrench input ------------------------------------------------------------------------------


class BadWrench(NamedTuple):
    """A wrench the driver must reject: torques zero while it streams."""

    row: str
    wrench: tuple
    frame_id: str
    stamp: object  # seconds from now, or 'zero'
    counter: str  # the diagnostics counter that counts the rejection
    log: str  # regex of the driver's warning


BAD_WRENCHES = [
    BadWrench('NaN force', (math.nan, 0.0, 0.0, 0.0, 0.0, 0.0), BASE, 0.0,
              'force rejected_non_finite', r'rejected.*non_finite'),
    BadWrench('infinite moment', (0.0, 0.0, 0.0, 0.0, 0.0, math.inf), BASE, 0.0,
              'force rejected_non_finite', r'rejected.*non_finite'),
    BadWrench('1e9 N force', (1e9, 0.0, 0.0, 0.0, 0.0, 0.0), BASE, 0.0,
              'force rejected_force_limit', r'rejected.*force_limit'),
    BadWrench('empty frame_id', WRENCH, '', 0.0, 'force rejected_unknown_frame',
              r"rejected.*frame_id ''"),
    BadWrench('unknown frame_id', WRENCH, 'map', 0.0, 'force rejected_unknown_frame',
              r"rejected.*frame_id 'map'"),
    BadWrench('stamp 10 s in the future', WRENCH, BASE, 10.0, 'force rejected_bad_timestamp',
              r'rejected.*stamp is [-+]?(9\.9|10\.0)'),
    BadWrench('stamp 1 h in the past', WRENCH, BASE, -3600.0, 'force rejected_bad_timestamp',
              r'rejected.*stamp is [-+]?(3599\.9|3600\.0)'),
]


def inject_bad_wrench(session, bad):
    """Stream `bad` in place of the steady wrench for BAD_STREAM_S; return the Injected."""
    fault_ns, _ = session.source.switch(SOURCE_RATE_HZ, bad.wrench, bad.frame_id, bad.stamp)
    session.wait_command(fault_ns, zero=True)
    session.client.spin(BAD_STREAM_S)
    clear_ns, _ = session.source.switch(SOURCE_RATE_HZ)
    back_ns = session.wait_command(clear_ns, zero=False)
    zero_ns = start_of_final_zero_run(session.commands(fault_ns, clear_ns))
    return Injected(fault_ns, clear_ns, back_ns, seconds_between(fault_ns, zero_ns),
                    'wrench rejected')


def inject_source_kill(session, env):
    """
    SIGKILL a wrench source mid-stream; return the Injected (fault_ns: the kill).

    A second source, started in `env`, drives the torque alone while the steady one pauses
    (no watchdog trip before the kill); the steady one resumes once the watchdog has zeroed
    the torque and the diagnostics (`during`) show it.
    """
    killed = WrenchSource(env, session.namespace, session.wait)
    try:
        killed.wait_ready()
        killed.switch(KILLED_SOURCE_RATE_HZ)
        paused_ns, _ = session.source.switch(0.0)
        session.wait_command(paused_ns + int(2 * WRENCH_TIMEOUT_S * 1e9), zero=False)
        before = session.diagnostics_after(time.time_ns())
        # Torque on after `before`: a stall of the source on a loaded machine may have tripped
        # the watchdog already; the zero after the kill must then come from a trip of its own.
        session.wait_command(before.stamp_ns, zero=False)
        kill_ns = killed.kill()
    finally:
        killed.close()
    session.wait_command(kill_ns, zero=True)
    during = session.force_diagnostics_after(time.time_ns() + int(SETTLE_S * 1e9))
    clear_ns, _ = session.source.switch(SOURCE_RATE_HZ)
    back_ns = session.wait_command(clear_ns, zero=False)
    zero_ns = start_of_final_zero_run(session.commands(kill_ns, clear_ns))
    return Injected(kill_ns, clear_ns, back_ns, seconds_between(kill_ns, zero_ns),
                    'wrench watchdog', before, during)


def inject_flood(session):
    """Flood valid wrenches at FLOOD_RATE_HZ for FLOOD_S; return the figures of the loop."""
    start_ns, published_before = session.source.switch(FLOOD_RATE_HZ)
    session.client.spin(FLOOD_S)
    end_ns, published_after = session.source.switch(SOURCE_RATE_HZ)
    flood_s = (end_ns - start_ns) / 1e9
    window = session.commands(start_ns, end_ns)
    return {
        'flood_published_hz': round((published_after - published_before) / flood_s),
        'loop_hz': round(len(window) / flood_s, 1),
        'loop_hz_before': round(
            len(session.commands(start_ns - int(flood_s * 1e9), start_ns)) / flood_s, 1),
        'largest_command_gap_ms': milliseconds(max(
            (b - a) / 1e9 for (a, _), (b, _) in zip(window, window[1:]))),
        'commands': len(window),
        'zero_commands': zero_commands(window),
        'largest_count': max(max(abs(x) for x in c.counts) for _, c in window),
    }


# -- bad parameter values ----------------------------------------------------------------------


def wrong_type(spec):
    """Return a value of the wrong type for a parameter like `spec` (a list keeps its length)."""
    default = spec.default
    if isinstance(default, list):
        return ['x'] * len(default)
    if isinstance(default, str):
        return 42
    return 'fast'


def out_of_range(spec):
    """Return a value ten times above the parameter's upper bound (one element of a list)."""
    if isinstance(spec.default, list):
        value = list(spec.default)
        value[0] = type(value[0])(10 * spec.high)
        return value
    return type(spec.default)(10 * spec.high)


def bad_values(name, spec):
    """(kind, value) pairs a parameter must refuse; value None is an unset (empty) value."""
    cases = [('wrong type', wrong_type(spec))]
    if spec.high is not None:
        cases.append(('out of range', out_of_range(spec)))
    if spec.length:
        cases.append(('wrong length', spec.default[:-1]))
    if spec.choices:
        cases.append(('not a choice', 'nonsense'))
    if isinstance(spec.default, float):
        cases.append(('NaN', math.nan))
    cases.append(('empty', None))
    return cases
