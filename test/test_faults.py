# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Fault injection: one test per row of the fault table, against the installed driver.

The installed kraft_master_node runs on a SimulatedKraftMaster in this process, watched by a
client node here and fed by a wrench source in a separate process. Each test injects one fault
and asserts the outcome: no crash, zero torque (or the input refused), a message in the
driver's log, a diagnostics counter, recovery once the fault clears, and nothing lost (every
pot frame received is published once and reaches the client). It also measures, from the
commands the simulated device received (simulator.received, time.time_ns() stamps), the time
to zero torque: for a lost reply, from the last torque command to the zero one that follows;
for rejected wrenches, a killed wrench source and signals, from the fault to the zero-torque
run that lasts; with the device unplugged, until the device's own command timeout zeroes it.
And the time to recovery, from the moment the fault clears to the first torque command. The
figures collect in FAULT_TABLE; after the last test of the module they are printed and written
to fault_table.json in the pytest tmp dir.

Run the suite alone with `pytest -m faults`. Run as a script, this file is the wrench source:
it publishes WrenchStamped messages as the JSON lines on its stdin say.
"""
import bisect
import concurrent.futures
import itertools
import json
import math
import operator
import os
import re
import select
import signal
import statistics
import subprocess
import sys
import threading
import time
from typing import Callable, NamedTuple

import dds_shm
from diagnostic_msgs.msg import DiagnosticArray
from driver_harness import (
    DriverProcess, installed_env, next_domain_id, REPO, wait_for, WAIT_S)
from geometry_msgs.msg import WrenchStamped
from kraft_master_driver.nodes.driver_parameters import PARAMETERS
from kraft_master_driver.simulation.simulator import SimulatedKraftMaster
import pytest
from rcl_interfaces.msg import Parameter as ParameterMsg
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
import yaml

pytestmark = [pytest.mark.faults, pytest.mark.integration]

LOOP_RATE_HZ = 200.0  # low enough for the Python client to follow every message
PERIOD_S = 1.0 / LOOP_RATE_HZ
BASE, WRIST = PARAMETERS['base_frame'].default, PARAMETERS['wrist_frame'].default
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
COUNT_LIMIT = round(max(PARAMETERS['torque_limits'].default) *
                    max(PARAMETERS['torque_scale'].default))
# Cycles a wrench may take from its publisher to the driver's watchdog clock on a busy machine.
DELIVERY_SLACK_CYCLES = 10
RECORD_LENGTH = 100_000  # commands the simulator keeps: minutes at LOOP_RATE_HZ
FROZEN_MS = 1e9  # a stall that lasts until it is lifted
SETTLE_S = 0.5  # time for a change to reach every counter and command, generously
STARTUP_WORKERS = 4
SIMULATOR_SWITCH_INTERVAL_S = 2e-4  # the GIL switch interval of this process during sessions
CHECK_INTERVAL_S = 0.005  # spin this long between two checks of a condition
STARTED = re.compile(r'Kraft Master on ')  # the driver's line once it runs
LOG_LINE = re.compile(r'^\[(\w+)\] \[(\d+)\.(\d+)\] \[[^\]]*\]: (.*)$')
DECODER_ERRORS = ('link bad_crc', 'link garbage_bytes', 'link truncated', 'link out_of_range')
# Counters that tell why a cycle gave zero torque or ran late.
CYCLE_COUNTERS = ('link timeouts', 'link stale_replies', 'force watchdog_trips', 'late cycles',
                  'missed cycles')

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


@pytest.fixture(scope='module', autouse=True)
def fault_table(request, tmp_path_factory):
    """After the module: print FAULT_TABLE and write it to fault_table.json in the tmp dir."""
    yield FAULT_TABLE
    if not FAULT_TABLE:
        return
    path = tmp_path_factory.getbasetemp() / 'fault_table.json'
    path.write_text(json.dumps(FAULT_TABLE, indent=2))
    capture = request.config.pluginmanager.getplugin('capturemanager')
    with capture.global_and_fixture_disabled():
        print(f'\n{format_table(FAULT_TABLE)}\nfault table written to {path}')


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
    """This file run as a separate process that publishes wrenches as told."""

    def __init__(self, env, namespace, wait):
        """Start the process in `env` and `namespace`; `wait(condition)` spins while waiting."""
        self.process = subprocess.Popen(
            [sys.executable, __file__, '--ros-args', '-r', f'__ns:={namespace}'],
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


class Observer:
    """
    A client node in this process with only what the suite needs.

    Lighter than driver_harness.RosClient, whose three 200 Hz subscriptions would compete
    with the simulator thread of this process.
    """

    def __init__(self, domain_id, namespace):
        """Join DDS domain `domain_id`, in `namespace`."""
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = rclpy.create_node('fault_observer', namespace=namespace,
                                      context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def spin(self, seconds=0.0):
        """Process callbacks for about `seconds` (at least once)."""
        deadline = time.monotonic() + seconds
        self.executor.spin_once(timeout_sec=0.01)
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.01)

    def close(self):
        """Leave the domain."""
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


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
        # even while this process's main thread is busy, so hand the GIL over often.
        self._switch_interval = sys.getswitchinterval()
        sys.setswitchinterval(SIMULATOR_SWITCH_INTERVAL_S)
        self.domain_id = next_domain_id()
        # A namespace of its own: other test runs on this machine may share the domain.
        self.namespace = f'/faults_{os.getpid()}_{next(SESSION_NUMBERS)}'
        self.simulator = SimulatedKraftMaster(arm='right', operator='hold', record=record)
        self.port = self.simulator.start()
        self.client = Observer(self.domain_id, self.namespace)
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


LINK_FAULTS = [
    LinkFault('device unplugged, replugged after 2 s', SimulatedKraftMaster.unplug, FAULT_S,
              SimulatedKraftMaster.replug, ('link link_faults',), r'link.*(down|lost|fail)',
              link_down=True),
    LinkFault('1 reply in 10 dropped', set_rate('drop_reply_rate', 0.1), FAULT_S,
              set_rate('drop_reply_rate', 0.0), ('link timeouts',), r'time(d )?out|no reply'),
    LinkFault('corrupt bytes at 1e-3', set_rate('corrupt_byte_rate', 1e-3), FAULT_S,
              set_rate('corrupt_byte_rate', 0.0), DECODER_ERRORS, r'crc|corrupt'),
    LinkFault('corrupt bytes at 1e-2', set_rate('corrupt_byte_rate', 1e-2), FAULT_S,
              set_rate('corrupt_byte_rate', 0.0), DECODER_ERRORS, r'crc|corrupt'),
    LinkFault('device stalls 200 ms', lambda simulator: simulator.stall(200), 0.2, no_action,
              ('link timeouts',), r'time(d )?out|no reply'),
    LinkFault('garbage flood', no_action, FAULT_S, no_action, ('link garbage_bytes',),
              r'garbage', repeat=lambda simulator: simulator.send_garbage(GARBAGE_BYTES)),
]


def link_fault_case(fault):
    """Return the pytest.param of a link fault."""
    return pytest.param(fault, id=fault.row)


def hold_fault(session, fault):
    """Keep `fault` up for its duration; return when the device's own watchdog fired (ns)."""
    simulator = session.simulator
    device_timeouts = simulator.stats['timeouts']
    watchdog_ns = None
    end = time.monotonic() + fault.seconds
    while time.monotonic() < end:
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
    fault_ns = time.time_ns()
    fault.start(simulator)
    watchdog_ns = hold_fault(session, fault)
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


@pytest.fixture(scope='class')
def link_session(install_prefix):
    """One driver session shared by the link fault rows; each row clears its fault."""
    session = FaultSession(install_prefix)
    yield session
    session.close()


class TestLinkFaults:
    """Faults of the serial link, injected by the simulated device."""

    @pytest.mark.parametrize('fault', [link_fault_case(f) for f in LINK_FAULTS])
    def test_link_fault(self, link_session, fault):
        session = link_session
        session.wait_torque()
        before = session.diagnostics_after(time.time_ns())
        states = session.states
        injected = inject_link_fault(session, fault)
        session.wait(lambda: session.states > states)
        after = session.diagnostics_after(injected.back_ns)
        session.assert_alive()

        growth = counter_growth(before, after, fault.counters + CYCLE_COUNTERS)
        assert sum(growth[key] for key in fault.counters) > 0, growth
        # Zero torque on the cycle after each lost reply: at least one zero command per timeout.
        window = session.commands(before.stamp_ns, after.stamp_ns + int(SETTLE_S * 1e9))
        assert zero_commands(window) >= growth['link timeouts'], (zero_commands(window), growth)
        assert (after.level, after.message) == (0, 'running')
        if fault.link_down:
            assert any(d.level == 2 and 'link down' in d.message for d in session.diagnostics
                       if injected.fault_ns <= d.stamp_ns < injected.clear_ns)
            assert after.count('link reconnects') > before.count('link reconnects')
        faulty = session.commands(injected.fault_ns, injected.back_ns + 1)
        record('link', fault.row, injected.safe_s, injected.recovery_s, injected.how,
               first_zero_after_fault_ms=milliseconds(seconds_between(
                   injected.fault_ns, session.first_command(injected.fault_ns, zero=True))),
               falls_to_zero=len(zeroing_times_s(faulty)),
               longest_zero_torque_ms=milliseconds(longest_zero_run_s(faulty)),
               counters=growth, simulator=session.simulator.stats)
        # A repeated warning comes at most once a second: a lost reply in the second before the
        # fault (a busy machine has some) may be the one the log shows.
        session.expect_log(injected.fault_ns - LOG_THROTTLE_NS, fault.log)

    def test_nothing_lost_across_the_link_faults(self, link_session):
        link_session.assert_alive()
        assert link_session.assert_nothing_lost() > 0


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


@pytest.fixture(scope='class')
def wrench_session(install_prefix):
    """
    One driver session shared by the wrench input rows; each row restores the stream.

    The killed-source row runs a second source beside the steady one, and a SIGKILLed
    publisher stays matched until DDS notices it is gone: these rows allow several sources
    (test_node.py tests the one-source rule).
    """
    session = FaultSession(install_prefix, SEVERAL_SOURCES)
    yield session
    session.close()


class TestWrenchInput:
    """Bad, late, flooding and vanishing wrench input."""

    @pytest.mark.parametrize('bad', BAD_WRENCHES, ids=[b.row for b in BAD_WRENCHES])
    def test_rejected_wrench_zeroes_torque(self, wrench_session, bad):
        session = wrench_session
        session.wait_torque()
        before = session.diagnostics_after(time.time_ns())
        injected = inject_bad_wrench(session, bad)
        held = session.commands(injected.fault_ns + int(SETTLE_S * 1e9), injected.clear_ns)
        assert held and zero_commands(held) == len(held), (
            f'a rejected wrench gave torque: {len(held) - zero_commands(held)} commands')
        after = session.diagnostics_after(injected.back_ns)
        session.assert_alive()
        assert after.count(bad.counter) > before.count(bad.counter)
        assert after.count('internal errors') == 0
        record('wrench', bad.row, injected.safe_s, injected.recovery_s, injected.how,
               rejected=after.count(bad.counter) - before.count(bad.counter))
        session.expect_log(injected.fault_ns, bad.log)

    def test_zero_stamp_is_accepted(self, wrench_session):
        session = wrench_session
        session.wait_torque()
        before = session.diagnostics_after(time.time_ns())
        start_ns, _ = session.source.switch(SOURCE_RATE_HZ, stamp='zero')
        session.client.spin(BAD_STREAM_S)
        end_ns, _ = session.source.switch(SOURCE_RATE_HZ)
        after = session.diagnostics_after(end_ns)
        window = session.commands(start_ns, end_ns)
        # A lost reply zeroes the next command: on a loaded machine, not the wrench's doing.
        lost = counter_growth(before, after, ('link timeouts',))['link timeouts']
        assert window and zero_commands(window) - lost < len(window) / 2, (
            f'zero stamp not accepted: {zero_commands(window)} of {len(window)} commands zero, '
            f'{lost} after a lost reply')
        assert (after.count('force rejected_bad_timestamp') ==
                before.count('force rejected_bad_timestamp'))

    def test_wrench_flood_keeps_the_loop_and_torques_safe(self, wrench_session):
        session = wrench_session
        session.wait_torque()
        before = session.diagnostics_after(time.time_ns())
        figures = inject_flood(session)
        after = session.diagnostics_after(time.time_ns())
        session.assert_alive()
        # The loop keeps going (a quarter of its rate just before catches a stalled loop; the
        # publisher takes a core of its own, and a loaded machine slows the loop further).
        # The torques stay within their limits, and on: the wrench is valid.
        assert figures['loop_hz'] > 0.25 * figures['loop_hz_before'], figures
        assert figures['largest_count'] <= COUNT_LIMIT, figures
        growth = counter_growth(before, after, ('late cycles', 'missed cycles',
                                                'force watchdog_trips', 'link timeouts'))
        # A lost reply zeroes the next command: on a loaded machine, not the flood's doing.
        assert (figures['zero_commands'] - growth['link timeouts'] <
                figures['commands'] / 2), (figures, growth)
        assert after.count('internal errors') == 0
        record('wrench', 'wrench flood at 20 kHz', None, None, 'torque stays on (valid wrench)',
               counters=growth, **figures)

    def test_wrench_source_killed_mid_stream(self, wrench_session, install_prefix):
        session = wrench_session
        injected = inject_source_kill(
            session, installed_env(install_prefix, session.domain_id))
        session.assert_alive()
        assert injected.safe_s is not None, 'torque did not stay zero after the kill'
        # Counted in cycles, not seconds: a slow machine runs fewer cycles, never more.
        late_torque = len(session.commands(injected.fault_ns,
                                           injected.fault_ns + int(injected.safe_s * 1e9)))
        bound = math.ceil(WRENCH_TIMEOUT_S / PERIOD_S) + 1 + DELIVERY_SLACK_CYCLES
        assert late_torque <= bound, (late_torque, bound)
        before, during = injected.before, injected.during
        assert during.count('force watchdog_trips') > before.count('force watchdog_trips')
        assert during.values['force state'] == 'stale'
        record('process', 'wrench source SIGKILLed mid-stream', injected.safe_s,
               injected.recovery_s, injected.how, torque_cycles_after_kill=late_torque)
        # The driver logs the watchdog at most once a second: a trip in the second before the
        # kill (a stall of the source, see inject_source_kill) may be the one the log shows.
        session.expect_log(injected.fault_ns - LOG_THROTTLE_NS,
                           r'stale|no wrench|watchdog')

    def test_nothing_lost_across_the_wrench_faults(self, wrench_session):
        wrench_session.assert_alive()
        assert wrench_session.assert_nothing_lost() > 0


# -- parameters --------------------------------------------------------------------------------


def yaml_literal(value):
    """Return `value` in the YAML syntax of a `-p name:=value` on the ROS command line."""
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, (list, tuple)):
        return '[' + ', '.join(yaml_literal(v) for v in value) + ']'
    if isinstance(value, float):
        return repr(value) if math.isfinite(value) else {'nan': '.nan'}.get(str(value), '.inf')
    return str(value)


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


class StartupCase(NamedTuple):
    """A driver start with bad parameters: it must exit 1 with a message naming `names`."""

    name: str
    parameters: tuple = ()  # (name, YAML literal) pairs for -p
    params_file: object = None  # a parameter file as a dict
    names: tuple = ()


def startup_case(case):
    """Return the pytest.param of a start-up case."""
    return pytest.param(case, id=case.name)


def parameter_start_cases():
    """
    Every parameter set to each kind of bad value at start-up.

    NaN goes through the same range checks as an out-of-range value (it is tried at run
    time); an empty value is tried once per kind of parameter (bool, int, float, str, choice,
    list), as it takes the same path for all parameters of a kind.
    """
    cases, kinds_tried = [], set()
    for name, spec in PARAMETERS.items():
        kind_of_parameter = (type(spec.default), bool(spec.choices))
        for kind, value in bad_values(name, spec):
            if kind == 'NaN' or (value is None and kind_of_parameter in kinds_tried):
                continue
            literal = '[]' if value is None else yaml_literal(value)
            cases.append(startup_case(
                StartupCase(f'{name} {kind}', ((name, literal),), names=(name,))))
        kinds_tried.add(kind_of_parameter)
    return cases


def calibration_file(change):
    """config/right_arm.yaml as a dict, its calibration mapping changed by `change`."""
    params = yaml.safe_load((REPO / 'config' / 'right_arm.yaml').read_text())
    change(params['/**']['ros__parameters']['calibration'])
    return params


def calibration_cases():
    """Calibration parameter files with a key missing, misspelt, too short, or a point twice."""
    keys = ('pot_a', 'pot_b', 'angle_a_deg', 'angle_b_deg')
    cases = []
    for key in keys:
        cases.append(startup_case(StartupCase(
            f'calibration {key} missing', params_file=calibration_file(lambda c: c.pop(key)),
            names=(f'calibration.{key}',))))
        cases.append(startup_case(StartupCase(
            f'calibration {key} with 5 values',
            params_file=calibration_file(lambda c: c[key].pop()),
            names=(f'calibration.{key}',))))
    cases.append(startup_case(StartupCase(
        'calibration pot_a misspelt', params_file=calibration_file(
            lambda c: c.update(pot_A=c.pop('pot_a'))), names=('calibration.pot_a',))))
    for first, second in (('pot_a', 'pot_b'), ('angle_a_deg', 'angle_b_deg')):
        cases.append(startup_case(StartupCase(
            f'calibration POT3 {first} == {second}', params_file=calibration_file(
                lambda c: c[second].__setitem__(2, c[first][2])),
            names=(f'calibration.{second}', 'POT3'))))
    return cases


STARTUP_CASES = parameter_start_cases() + calibration_cases()


class StartupRuns:
    """Runs the selected start-up cases a few at a time, once, when the first is needed."""

    def __init__(self, prefix, directory, cases):
        """Run `cases` (StartupCase) with the driver installed at `prefix`."""
        self.prefix, self.directory, self.cases = prefix, directory, cases
        self.results = {}

    def result(self, case):
        """Return (exit code or 'started', output, seconds) of `case`."""
        if case.name not in self.results:
            with concurrent.futures.ThreadPoolExecutor(STARTUP_WORKERS) as pool:
                pending = [c for c in self.cases if c.name not in self.results] or [case]
                for pending_case, outcome in zip(pending, pool.map(self._run, pending)):
                    self.results[pending_case.name] = outcome
        return self.results[case.name]

    def _run(self, case):
        params_file = None
        if case.params_file is not None:
            params_file = self.directory / (re.sub(r'\W+', '_', case.name) + '.yaml')
            params_file.write_text(yaml.safe_dump(case.params_file))
        started = time.monotonic()
        driver = Driver(self.prefix, next_domain_id(), case.parameters, params_file=params_file)
        try:
            outcome = driver.started_or_exited()
            deadline = started + WAIT_S
            while outcome is None and time.monotonic() < deadline:
                time.sleep(0.02)
                outcome = driver.started_or_exited()
        finally:
            driver.kill()
        return outcome, driver.output, time.monotonic() - started


@pytest.fixture(scope='module')
def startup_runs(install_prefix, tmp_path_factory, request):
    """Start-up outcomes of the cases of this session's selected tests."""
    selected = [item.callspec.params['case'] for item in request.session.items
                if item.originalname == 'test_bad_start_up_parameters_exit_1_naming_them']
    return StartupRuns(install_prefix, tmp_path_factory.mktemp('startup'), selected)


@pytest.mark.parametrize('case', STARTUP_CASES)
def test_bad_start_up_parameters_exit_1_naming_them(startup_runs, case):
    code, output, seconds = startup_runs.result(case)
    group = 'calibration' if case.params_file else 'start-up'
    record(group, case.name, outcome=code, seconds=round(seconds, 2))
    assert code == 1, f'exit {code!r}:\n{output}'
    assert 'Traceback' not in output, output
    for name in case.names:
        assert name in output, output


def run_time_cases():
    """Parameter changes the running driver must refuse."""
    cases = []
    for name, spec in PARAMETERS.items():
        if spec.read_only:
            cases.append(pytest.param(name, 'read-only', spec.default, id=f'{name} read-only'))
            continue
        cases += [pytest.param(name, kind, value, id=f'{name} {kind}')
                  for kind, value in bad_values(name, spec)]
    return cases


@pytest.fixture(scope='class')
def parameter_session(install_prefix):
    """Run a driver session for the run-time parameter rows."""
    session = FaultSession(install_prefix)
    yield session
    session.close()


def parameter_message(name, value):
    """Return a Parameter message of `value`, typed as rclpy infers; None gives an unset one."""
    if value is None:
        return ParameterMsg(name=name)
    return Parameter(name, value=value).to_parameter_msg()


def torque_on(session, since_ns, count=20):
    """Wait for `count` torque commands from `since_ns` on; return their median counts."""
    def on():
        commands = [c.counts for _, c in session.commands(since_ns) if any(c.counts)]
        return commands[:count] if len(commands) >= count else None
    return [statistics.median(axis) for axis in zip(*session.wait(on))]


class TestRunTimeParameters:
    """Bad parameter changes through the parameter service of the running driver."""

    @pytest.mark.parametrize('name, kind, value', run_time_cases())
    def test_refused_and_torque_unchanged(self, parameter_session, name, kind, value):
        session = parameter_session
        client = session.parameter_client()
        torque = torque_on(session, time.time_ns())
        (current,) = session.call(client.get_parameters([name])).values
        result = session.call(client.set_parameters([parameter_message(name, value)])).results[0]
        assert not result.successful, f'{name} {kind} accepted'
        assert result.reason
        (unchanged,) = session.call(client.get_parameters([name])).values
        assert unchanged == current
        later = torque_on(session, time.time_ns())
        session.assert_alive()
        # The held arm settles a little under its torque; a refused change must not move it.
        assert all(abs(a - b) <= max(5.0, 0.05 * abs(a)) for a, b in zip(torque, later)), (
            torque, later)
        record('run time', f'{name} {kind}', outcome=result.reason)

    def test_a_valid_change_is_applied(self, parameter_session):
        """The control: force_scale 0.5 halves the torque, and 1.0 restores it."""
        session = parameter_session
        client = session.parameter_client()
        torque = torque_on(session, time.time_ns())
        for scale in (0.5, 1.0):
            result = session.call(client.set_parameters(
                [parameter_message('force_scale', scale)])).results[0]
            assert result.successful, result.reason
            session.client.spin(SETTLE_S)
            later = torque_on(session, time.time_ns())
            assert all(abs(scale * a - b) <= max(5.0, 0.05 * abs(a))
                       for a, b in zip(torque, later)), (torque, later)

    def test_nothing_lost_across_the_parameter_changes(self, parameter_session):
        parameter_session.assert_alive()
        assert parameter_session.assert_nothing_lost() > 0


# -- process -----------------------------------------------------------------------------------


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM], ids=['SIGINT', 'SIGTERM'])
def test_signal_zeroes_torque_last_and_exits_0(install_prefix, sig):
    session = FaultSession(install_prefix)
    try:
        session.wait_torque()
        signal_ns = time.time_ns()
        code = session.driver.stop(sig)
        assert code == 0, session.driver.output
        assert 'Traceback' not in session.driver.output, session.driver.output
        session.wait(lambda: not any(session.commands()[-1][1].counts))
        zero_ns = session.first_command(signal_ns, zero=True)
        after_zero = session.commands(zero_ns)
        assert zero_commands(after_zero) == len(after_zero), 'torque after the zero command'
        record('process', signal.Signals(sig).name, seconds_between(signal_ns, zero_ns),
               None, 'zero command before exit',
               commands_after_signal=len(session.commands(signal_ns)))
    finally:
        session.close()


def test_second_driver_on_the_same_port_retries_and_leaves_the_first_alone(install_prefix):
    session = FaultSession(install_prefix)
    second = None
    try:
        second_namespace = f'{session.namespace}_second'
        second_diagnostics = session.watch(second_namespace)
        session.wait_torque()
        before = session.diagnostics_after(time.time_ns())
        device_errors = session.simulator.stats['decode_errors']
        start_ns = time.time_ns()
        second = Driver(install_prefix, session.domain_id, [
            ('port', session.port), ('loop_rate_hz', LOOP_RATE_HZ),
            ('force_enabled_at_start', 'true')], namespace=second_namespace)
        session.wait(lambda: second.log_since(start_ns, ('ERROR', 'WARN')))
        assert re.search(r'busy|lock', second.output, re.IGNORECASE), second.output
        first = session.diagnostics_after(start_ns, second_diagnostics)
        assert first.level == 2, first
        retried = session.wait(lambda: next(
            (d for d in second_diagnostics
             if d.count('link failed_opens') > first.count('link failed_opens')), None))
        assert second.stop() == 0, second.output
        end_ns = time.time_ns()
        after = session.diagnostics_after(end_ns)
        session.assert_alive()

        # The first driver is undisturbed, as far as a second opener could disturb it: no
        # foreign command (every command in sequence) or byte at the device, no reply bytes
        # taken from it, no link fault; the second never got a frame.
        window = session.commands(start_ns, end_ns)
        sequences = [c.sequence for _, c in window]
        assert all((b - a) % 256 == 1 for a, b in zip(sequences, sequences[1:]))
        assert session.simulator.stats['decode_errors'] == device_errors
        growth = counter_growth(before, after, ('link link_faults', 'link timeouts') +
                                DECODER_ERRORS)
        assert growth['link link_faults'] == 0, growth
        assert sum(growth[key] for key in DECODER_ERRORS) == 0, growth
        assert retried.count('pot frames received') == 0
        session.assert_nothing_lost()
        record('process', 'second driver on the same port', None, None,
               second_failed_opens=retried.count('link failed_opens'),
               first_counters=growth, first_zero_commands=zero_commands(window))
    finally:
        if second is not None:
            second.kill()
        session.close()


# -- the wrench source process -----------------------------------------------------------------


def run_wrench_source():
    """
    Publish WrenchStamped on `wrench` as the JSON lines on stdin say, until stdin closes.

    Each line is {"rate_hz", "wrench", "frame_id", "stamp"}; prints 'ready' once the driver
    subscribes and 'switched <time_ns> <messages published before>' as each line takes effect.
    """
    rclpy.init(args=sys.argv)
    node = rclpy.create_node('fault_wrench_source')
    publisher = node.create_publisher(
        WrenchStamped, 'wrench', QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT))
    while publisher.get_subscription_count() == 0:
        time.sleep(0.01)
    print('ready', flush=True)
    message = WrenchStamped()
    period_ns = offset_ns = published = 0
    zero_stamp = switched = False
    pending = b''
    due = time.monotonic_ns()
    while True:
        ahead = (due - time.monotonic_ns()) / 1e9 if period_ns else 0.1
        if select.select([0], [], [], ahead if ahead > 2e-4 else 0.0)[0]:
            chunk = os.read(0, 4096)
            if not chunk:
                break
            *lines, pending = (pending + chunk).split(b'\n')
            for line in lines:
                spec = json.loads(line)
                period_ns = int(1e9 / spec['rate_hz']) if spec['rate_hz'] else 0
                zero_stamp = spec['stamp'] == 'zero'
                offset_ns = 0 if zero_stamp else int(spec['stamp'] * 1e9)
                message.header.frame_id = spec['frame_id']
                w = message.wrench
                (w.force.x, w.force.y, w.force.z,
                 w.torque.x, w.torque.y, w.torque.z) = spec['wrench']
                switched, due = True, time.monotonic_ns()
            continue
        if not period_ns:
            if switched:
                print(f'switched {time.time_ns()} {published}', flush=True)
                switched = False
            continue
        now = time.monotonic_ns()
        if now < due:
            continue
        stamp_ns = 0 if zero_stamp else time.time_ns() + offset_ns
        message.header.stamp.sec, message.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
        sent_ns = time.time_ns()
        publisher.publish(message)
        if switched:
            print(f'switched {sent_ns} {published}', flush=True)
            switched = False
        published += 1
        due += period_ns
        due = max(due, now - 100_000_000)  # fallen far behind: do not burst to catch up
    rclpy.try_shutdown()


if __name__ == '__main__':
    sys.exit(run_wrench_source())
