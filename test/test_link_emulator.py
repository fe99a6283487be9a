# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The link emulator: its delay line (plain Python) and the installed node between two domains."""
import collections
import re
import shlex
import signal
import subprocess
import threading
import time

import dds_shm
from driver_harness import DriverProcess, executable as executable_path, installed_env
from driver_harness import next_domain_id, REPO, wait_for
from geometry_msgs.msg import PoseStamped, WrenchStamped
from kraft_master_driver.core.delay_line import DelayLine, LinkModel
from kraft_master_driver.nodes.link_emulator import PARAMETERS, parse_relay
import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy

PERIOD = 0.001  # s between admitted messages in the delay line's tests (1 kHz)


def admit_stream(line, count, period=PERIOD):
    """Admit `count` messages `period` apart; return their release times (None when lost)."""
    return [line.admit(i * period) for i in range(count)]


def burst_lengths(lost_flags):
    """Return the lengths of the runs of consecutive True in `lost_flags`."""
    runs, length = [], 0
    for lost in list(lost_flags) + [False]:
        if lost:
            length += 1
        elif length:
            runs.append(length)
            length = 0
    return runs


# -- the delay line ----------------------------------------------------------------------

def test_fixed_delay_releases_each_message_exactly_that_much_later():
    dues = admit_stream(DelayLine(LinkModel(delay=0.05)), 1000)
    assert dues == pytest.approx([i * PERIOD + 0.05 for i in range(1000)], abs=1e-12)


def test_jitter_stays_within_its_range_never_below_the_delay_and_keeps_order():
    line = DelayLine(LinkModel(delay=0.02, jitter=0.01), seed=3)
    dues = np.array(admit_stream(line, 20000))
    delays = dues - np.arange(20000) * PERIOD
    assert delays.min() >= 0.02
    # Order kept: a message never overtakes the one before; a late one holds the next back.
    assert np.all(np.diff(dues) >= 0.0)
    assert delays.max() <= 0.03 + 1e-12
    # The jitter is really there: the delays spread over most of the range.
    assert np.percentile(delays, 99) - delays.min() > 0.008


@pytest.mark.parametrize('loss, burst', [(0.01, 0.0), (0.1, 0.0), (0.1, 5.0), (0.3, 2.0)])
def test_loss_rate_and_mean_burst_length_match_the_model(loss, burst):
    count = 200000
    line = DelayLine(LinkModel(loss=loss, loss_burst=burst), seed=11)
    lost = [due is None for due in admit_stream(line, count)]
    runs = burst_lengths(lost)
    assert sum(lost) / count == pytest.approx(loss, rel=0.1)
    expected_burst = burst or 1.0 / (1.0 - loss)
    assert np.mean(runs) == pytest.approx(expected_burst, rel=0.1)
    assert line.stats.dropped == sum(lost) and line.stats.received == count


def test_bursty_loss_comes_in_long_runs_independent_loss_does_not():
    independent = burst_lengths(
        d is None for d in admit_stream(DelayLine(LinkModel(loss=0.05), seed=5), 100000))
    bursty = burst_lengths(
        d is None for d in admit_stream(
            DelayLine(LinkModel(loss=0.05, loss_burst=10.0), seed=5), 100000))
    assert max(independent) < 8 < max(bursty)


def test_the_same_seed_gives_the_same_fates():
    model = LinkModel(delay=0.01, jitter=0.005, loss=0.1, loss_burst=3.0)
    assert (admit_stream(DelayLine(model, seed=7), 5000)
            == admit_stream(DelayLine(model, seed=7), 5000))


def test_statistics_count_and_summarise_the_released_delays():
    line = DelayLine(LinkModel(delay=0.01))
    for i in range(100):
        due = line.admit(float(i))
        line.record(due + i * 1e-5, float(i))
    summary = line.stats.summary()
    assert (summary['received'], summary['relayed'], summary['dropped']) == (100, 100, 0)
    assert float(summary['delay min ms']) == pytest.approx(10.0)
    assert float(summary['delay max ms']) == pytest.approx(10.99)
    assert float(summary['delay p50 ms']) == pytest.approx(10.5, abs=0.01)


@pytest.mark.parametrize('model, fragment', [
    (LinkModel(delay=-0.1), 'delay must be a finite number >= 0'),
    (LinkModel(jitter=float('nan')), 'jitter must be a finite number >= 0'),
    (LinkModel(delay='1'), 'delay must be a finite number >= 0'),
    (LinkModel(loss=1.0), 'loss must be in [0, 1)'),
    (LinkModel(loss=0.1, loss_burst=0.5), 'loss_burst must be 0 (independent) or >= 1'),
    (LinkModel(loss=0.9, loss_burst=2.0), 'loss 0.9 needs loss_burst >= 9'),
])
def test_bad_models_raise_naming_the_field(model, fragment):
    with pytest.raises(ValueError, match=None) as raised:
        DelayLine(model)
    assert fragment in str(raised.value)


@pytest.mark.parametrize('spec, parsed', [
    ('pose', ('pose', 'pose', None)),
    ('pose:slave/pose', ('pose', 'slave/pose', None)),
    ('a:b:geometry_msgs/msg/PoseStamped', ('a', 'b', 'geometry_msgs/msg/PoseStamped')),
])
def test_relay_specs_parse(spec, parsed):
    assert parse_relay(spec) == parsed


@pytest.mark.parametrize('spec', ['', 'a::b', 'a:b:c:d', 'a:b:PoseStamped'])
def test_bad_relay_specs_raise(spec):
    with pytest.raises(ValueError, match='topics: relay'):
        parse_relay(spec)


# -- the node between two domains ----------------------------------------------------------

class Side:
    """A node of the test in one DDS domain, spun by its own thread."""

    def __init__(self, domain_id):
        """Join `domain_id`."""
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = rclpy.create_node('link_test', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self):
        try:
            self.executor.spin()
        except rclpy.executors.ExternalShutdownException:
            pass

    def close(self):
        """Leave the domain."""
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)
        self.thread.join(timeout=5.0)


class Arrivals:
    """Records (header stamp, receipt time) in seconds of one subscription, from the ROS clock."""

    def __init__(self, side, msg_type, topic):
        """Subscribe to `topic` on `side`."""
        self.clock = side.node.get_clock()
        self.records = []
        self.markers = collections.Counter()
        side.node.create_subscription(msg_type, topic, self._on_message,
                                      QoSProfile(depth=100,
                                                 reliability=ReliabilityPolicy.BEST_EFFORT))

    def _on_message(self, msg):
        if msg.header.frame_id in (WARM_UP, END):
            self.markers[msg.header.frame_id] += 1
            return
        now = self.clock.now().nanoseconds * 1e-9
        self.records.append((msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9, now))

    def delays(self):
        """Return the one-way delay (s) of each message that arrived so far."""
        return np.array([received - stamp for stamp, received in self.records])


WARM_UP, END = 'warm-up', 'end'


class Stream:
    """Stamped messages of one type published on one side, received on the other."""

    def __init__(self, source, destination, msg_type, topic):
        """Publish `topic` on side `source`, record it on side `destination`."""
        self.source = source
        self.msg_type = msg_type
        self.publisher = source.node.create_publisher(
            msg_type, topic, QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
        self.arrivals = Arrivals(destination, msg_type, topic)

    def publish(self, frame_id=''):
        """Publish one message stamped now."""
        msg = self.msg_type()
        msg.header.stamp = self.source.node.get_clock().now().to_msg()
        msg.header.frame_id = frame_id
        self.publisher.publish(msg)

    def send_until_crossed(self, marker):
        """Publish `marker` messages every 20 ms until one crossed the link."""
        def crossed():
            self.publish(marker)
            return self.arrivals.markers[marker]
        wait_for(crossed, timeout=60.0, interval=0.02)

    def warm_up(self):
        """Send until one message crossed: the whole path is matched then."""
        self.send_until_crossed(WARM_UP)

    def finish(self):
        """Send until one message crossed: the link keeps order, so all before it are through."""
        self.send_until_crossed(END)

    def burst(self, count, period):
        """Publish `count` messages `period` s apart (sleeping to deadlines)."""
        start = time.monotonic()
        for i in range(count):
            self.publish()
            time.sleep(max(0.0, start + (i + 1) * period - time.monotonic()))


def counts(output, direction):
    """Return (received, relayed, dropped) from the emulator's last log line on `direction`."""
    return tuple(map(int, re.findall(
        rf'{direction}: received (\d+), relayed (\d+), dropped (\d+)', output)[-1]))


@pytest.fixture
def two_domains(install_prefix):
    """Start the emulator (parameters given) between two fresh domains; yield (master, slave)."""
    started = []

    def start(parameters):
        master_domain, slave_domain = next_domain_id(), next_domain_id()
        emulator = DriverProcess(
            install_prefix, master_domain, [('slave_domain_id', slave_domain), *parameters],
            name='kraft_master_link_emulator')
        master, slave = Side(master_domain), Side(slave_domain)
        started.append((emulator, master, slave))
        return emulator, master, slave

    yield start
    for emulator, master, slave in started:
        master.close()
        slave.close()
        emulator.kill()


def test_node_delays_each_direction_by_at_least_its_delay_and_drops_nothing(two_domains):
    emulator, master, slave = two_domains([('to_slave.delay', 0.05), ('to_master.delay', 0.02)])
    poses = Stream(master, slave, PoseStamped, 'pose')
    wrenches = Stream(slave, master, WrenchStamped, 'wrench')
    for stream in (poses, wrenches):
        stream.warm_up()
        stream.burst(200, period=0.005)
        stream.finish()
        assert len(stream.arrivals.records) == 200
    pose_delays, wrench_delays = poses.arrivals.delays(), wrenches.arrivals.delays()
    # Never earlier than the delay; later by what a loaded machine adds, never by seconds.
    assert pose_delays.min() > 0.05 and wrench_delays.min() > 0.02
    assert np.median(pose_delays) < 0.05 + 1.0 and np.median(wrench_delays) < 0.02 + 1.0
    stamps = [stamp for stamp, _ in poses.arrivals.records]
    assert stamps == sorted(stamps)
    code, output = emulator.interrupt()
    assert code == 0, output
    for direction in ('to_slave', 'to_master'):
        received, relayed, dropped = counts(output, direction)
        # A message still in the line when Ctrl-C came is received, not relayed.
        assert received >= relayed >= 200 and dropped == 0


def test_node_loses_the_set_fraction_and_keeps_order_under_jitter(two_domains):
    emulator, master, slave = two_domains([
        ('to_slave.topics', "['pose:pose:geometry_msgs/msg/PoseStamped']"),
        ('to_slave.jitter', 0.01), ('to_slave.loss', 0.2), ('to_slave.loss_burst', 2.0),
        ('seed', 4)])
    poses = Stream(master, slave, PoseStamped, 'pose')
    poses.warm_up()
    poses.burst(1000, period=0.002)
    poses.finish()
    stamps = [stamp for stamp, _ in poses.arrivals.records]
    assert stamps == sorted(stamps)
    assert poses.arrivals.delays().min() > 0.0
    code, output = emulator.interrupt()
    assert code == 0, output
    # What a loaded machine's executor missed never reached the delay line: the fraction
    # lost is the emulator's own count.
    received, relayed, dropped = counts(output, 'to_slave')
    assert 0.1 < dropped / received < 0.3
    assert len(poses.arrivals.records) < relayed <= received - dropped


# -- the README ----------------------------------------------------------------------------

def readme_section():
    """Return the section of doc/teleoperation.md on the link emulator."""
    text = (REPO / 'doc' / 'teleoperation.md').read_text()
    start = text.index('## The link emulator')
    return text[start:text.index('\n## ', start + 1)]


def test_readme_table_lists_every_parameter_with_its_default():
    rows = {}
    for names, default in re.findall(r'^\| ((?:`[a-z_.]+`(?:, )?)+) \| `([^`]*)` \|',
                                     readme_section(), re.MULTILINE):
        for name in re.findall(r'`([a-z_.]+)`', names):
            rows[name] = default
    assert rows == {name: str(spec.default) for name, spec in PARAMETERS.items()}


def readme_example():
    """Return the README's example as [(domain, executable, arguments)], one per command."""
    block = readme_section().split('```\n')[1]
    commands = []
    for line in block.replace('\\\n', ' ').splitlines():
        if line.startswith('ROS_DOMAIN_ID='):
            words = shlex.split(line)
            assert words[1:4] == ['ros2', 'run', 'kraft_master_driver']
            commands.append((int(words[0].split('=')[1]), words[4], words[5:]))
    return commands


def test_the_readme_example_relays_pose_to_the_slave_and_its_wrench_back(install_prefix):
    domains = {}
    processes = []
    example = readme_example()
    assert [executable for _, executable, _ in example] == [
        'kraft_master_node', 'kraft_master_slave_sim', 'kraft_master_link_emulator']
    for domain, _, _ in example:
        domains.setdefault(domain, next_domain_id())
    sides = {}
    try:
        for domain, executable, arguments in example:
            arguments = [re.sub(r'^slave_domain_id:=(\d+)$',
                                lambda m: f'slave_domain_id:={domains[int(m.group(1))]}', a)
                         for a in arguments]
            processes.append(subprocess.Popen(
                [str(executable_path(install_prefix, executable)), *arguments],
                env=installed_env(install_prefix, domains[domain]), stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT, text=True))
        master, slave = (Side(domains[d]) for d in sorted(domains))
        sides = {'master': master, 'slave': slave}
        wrenches = Arrivals(master, WrenchStamped, 'wrench')
        slave_poses = Arrivals(slave, PoseStamped, 'slave_pose')
        # The slave moves once the driver's pose reached it; its wrench comes back delayed.
        wait_for(lambda: len(slave_poses.records) > 10 and len(wrenches.records) > 10,
                 timeout=90.0)
        assert wrenches.delays().min() > 0.05
        emulator = processes[-1]
        emulator.send_signal(signal.SIGINT)
        output = emulator.communicate(timeout=30)[0]
        assert emulator.returncode == 0, output
        assert re.search(r'to_slave: received [1-9]', output), output
        assert re.search(r'to_master: received [1-9]', output), output
    finally:
        for side in sides.values():
            side.close()
        for process in processes:
            dds_shm.end(process)
            process.communicate(timeout=10)
