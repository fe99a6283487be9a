# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
kraft_master_link_emulator: relay chosen topics between master and slave through a bad link.

The master side (the driver) and the slave side live in two DDS domains: the node joins the
master's domain (ROS_DOMAIN_ID) and the slave's (parameter slave_domain_id), so the two sides
can only hear each other through it, with the topic names they already use. Each relay takes
one topic of any message type as serialized bytes (no deserialisation), lets the direction's
DelayLine (delay_line.py) decide its fate, and publishes the bytes on the other side when due:
at once from the subscription when nothing is queued and no delay is set, else from one release
thread that sleeps until the earliest due time. Subscriptions are best effort (they accept any
publisher; losing a sample is the emulated link's job) and keep queue_depth messages, so that a
busy emulator loses what it cannot take instead of adding a queue's wait to every message; the
publishers are reliable, depth 10 (a reliable publisher reaches reliable and best-effort
subscribers alike).

Both directions report counts and the delay they added (received to published) on
`diagnostics` every second and in the log every 10 s and at exit. A direction's delay, jitter,
loss and loss_burst can be set at run time (a delay step), and so can its blackout (every
message lost) and its stamp_offset (the stamps of its messages moved: a skewed clock).
"""
import heapq
import importlib
import itertools
import re
import struct
import sys
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from kraft_master_driver.core.delay_line import DelayLine, LinkModel
from kraft_master_driver.nodes.node_process import run_node, try_shutdown
from kraft_master_driver.nodes.parameters import (
    declare_parameters, ParameterError, run_time_changes, Spec)
from kraft_master_driver.nodes.ros_io import GIL_SWITCH_INTERVAL_S, steady_timer
from rcl_interfaces.msg import SetParametersResult
import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy

DIRECTIONS = ('to_slave', 'to_master')
TYPE_PATTERN = re.compile(r'^(\w+)/msg/(\w+)$')
LOG_PERIOD_S = 10.0
RECHECK_S = 0.1  # s: the release thread looks at `running` at least this often
STAMP = {0: struct.Struct('>iI'), 1: struct.Struct('<iI')}  # by the CDR header's endianness
STAMP_AT = 4  # a message that starts with a Header: its stamp follows the 4-byte CDR header

PARAMETERS = {
    'slave_domain_id': Spec(-1, 'DDS domain of the slave side; -1: the domain of the master '
                            '(then relays must rename their topics).', low=-1, high=232),
    'seed': Spec(-1, 'Seed of the loss and jitter draws; -1: a different one each run.'),
    'queue_depth': Spec(10, 'Messages each relay keeps while the emulator is busy; older ones '
                        'are lost, not delayed.', low=1, high=10000),
    'to_slave.topics': Spec(['pose'], 'Topics relayed master -> slave: "name", '
                            '"source:destination" or "source:destination:pkg/msg/Type".'),
    'to_master.topics': Spec(['wrench'], 'Topics relayed slave -> master, as to_slave.topics.'),
}
for _direction in DIRECTIONS:
    PARAMETERS.update({
        f'{_direction}.delay': Spec(0.0, 'One-way delay (s) added to every message.',
                                    read_only=False),
        f'{_direction}.jitter': Spec(0.0, 'Extra delay (s) drawn uniformly in [0, jitter]; '
                                     'order is kept, so a draw that would overtake waits.',
                                     read_only=False),
        f'{_direction}.loss': Spec(0.0, 'Long-run fraction of messages lost, in [0, 1).',
                                   read_only=False),
        f'{_direction}.loss_burst': Spec(0.0, 'Mean length of a run of lost messages (Gilbert '
                                         'chain), >= 1; 0: independent losses.',
                                         read_only=False),
        f'{_direction}.blackout': Spec(False, 'Lose every message while true (a link that is '
                                       'down).', read_only=False),
        f'{_direction}.stamp_offset': Spec(0.0, 'Seconds added to the header stamp of each '
                                           'message relayed (a skewed clock on the sending '
                                           'side); types without a header pass unchanged.',
                                           low=-1e6, high=1e6, read_only=False),
    })


def parse_relay(spec):
    """Return (source, destination, type name or None) from "src[:dst[:pkg/msg/Type]]"."""
    parts = spec.split(':') if isinstance(spec, str) else []
    if not 1 <= len(parts) <= 3 or not all(parts):
        raise ValueError(f'topics: relay "{spec}" must be "name", "source:destination" or '
                         f'"source:destination:pkg/msg/Type"')
    type_name = parts[2] if len(parts) == 3 else None
    if type_name is not None and not TYPE_PATTERN.match(type_name):
        raise ValueError(f'topics: relay "{spec}": message type must look like pkg/msg/Type')
    return parts[0], parts[1] if len(parts) > 1 else parts[0], type_name


def shift_stamp(data, offset_ns):
    """Return CDR bytes of a message that starts with a Header, its stamp moved by offset_ns."""
    layout = STAMP[data[1] & 1]
    sec, nanosec = layout.unpack_from(data, STAMP_AT)
    shifted = bytearray(data)
    total = sec * 1_000_000_000 + nanosec + offset_ns
    layout.pack_into(shifted, STAMP_AT, *divmod(total, 1_000_000_000))
    return bytes(shifted)


class StampShift:
    """The offset (ns) added to the stamps of one direction's messages; 0: none."""

    def __init__(self, seconds=0.0):
        """Shift by `seconds`."""
        self.offset_ns = round(seconds * 1e9)

    def wrap(self, send, msg_class):
        """Return `send` preceded by the shift, if messages of `msg_class` have a header."""
        fields = list(msg_class.get_fields_and_field_types())
        if fields[:1] != ['header']:
            return send

        def shifted_send(data):
            offset_ns = self.offset_ns
            send(shift_stamp(data, offset_ns) if offset_ns else data)
        return shifted_send


def message_class(type_name):
    """Return the Python class of a message type "pkg/msg/Type", or raise ValueError."""
    package, name = TYPE_PATTERN.match(type_name).groups()
    try:
        return getattr(importlib.import_module(f'{package}.msg'), name)
    except (ImportError, AttributeError):
        raise ValueError(f'message type {type_name} is not installed') from None


class Releaser(threading.Thread):
    """Publishes queued messages at their due times (time.monotonic seconds), in due order."""

    def __init__(self):
        """Start with nothing queued; call start()."""
        super().__init__(name='link_emulator_release', daemon=True)
        self.queue = []
        self.sequence = itertools.count()
        self.wake = threading.Condition()
        self.running = True

    def put(self, due, sender, data, admitted):
        """Queue `data` for `sender` to publish at `due`."""
        with self.wake:
            heapq.heappush(self.queue, (due, next(self.sequence), sender, data, admitted))
            if self.queue[0][0] == due:
                self.wake.notify()

    def run(self):
        """Sleep to the earliest due time, publish what is due, repeat until stop()."""
        while self.running:
            with self.wake:
                now = time.monotonic()
                if not self.queue or self.queue[0][0] > now:
                    # Bounded: Ctrl-C raises KeyboardInterrupt anywhere in the main thread,
                    # even inside notify(), and a lost wake-up must not keep stop() waiting.
                    self.wake.wait(min(self.queue[0][0] - now, RECHECK_S) if self.queue
                                   else RECHECK_S)
                    continue
                _, _, sender, data, admitted = heapq.heappop(self.queue)
            try:
                sender.release(data, admitted)
            except RuntimeError:
                # Ctrl-C shut a context down before stop(): nothing more can be published.
                return

    def stop(self):
        """End the thread; whatever is still queued is not published."""
        with self.wake:
            self.running = False
            self.wake.notify()
        self.join()


class DelayedSender:
    """Hands messages to `publish` through a DelayLine: at once if due now, else at their time."""

    def __init__(self, line, releaser, publish):
        """Send through `line`; `releaser` publishes what must wait, by calling release()."""
        self.line = line
        self.releaser = releaser
        self.publish = publish
        self.queued = 0
        self.lock = threading.Lock()

    def send(self, data):
        """Lose `data`, publish it now, or queue it for its due time, as the line decides."""
        now = time.monotonic()
        with self.lock:
            due = self.line.admit(now)
            if due is None:
                return
            if due <= now and not self.queued:
                self.publish(data)
                self.line.record(time.monotonic(), now)
                return
            self.queued += 1
        self.releaser.put(due, self, data, now)

    def release(self, data, admitted):
        """Publish `data` (called by the release thread at its due time)."""
        self.publish(data)
        with self.lock:
            self.line.record(time.monotonic(), admitted)
            self.queued -= 1


class Relay:
    """One topic carried in one direction: a raw subscription and a publisher of bytes."""

    def __init__(self, spec, source_node, destination_node, line, releaser, queue_depth,
                 shift=None):
        """Parse `spec`; the subscription, `queue_depth` deep, starts once the type is known."""
        self.spec = spec
        self.shift = StampShift() if shift is None else shift
        self.queue_depth = queue_depth
        self.source, self.destination, self.type_name = parse_relay(spec)
        self.source_node = source_node
        self.destination_node = destination_node
        self.line = line
        self.releaser = releaser
        self.publisher = None
        if self.type_name is not None:
            self._connect(message_class(self.type_name))

    def discover(self):
        """Take the type from the source side's graph if it is known yet; return True if so."""
        name = self.source_node.resolve_topic_name(self.source)
        types = dict(self.source_node.get_topic_names_and_types()).get(name)
        if not types:
            return False
        if len(types) > 1:
            raise ValueError(f'topic {name} has several types ({", ".join(types)}): '
                             f'name one in the relay')
        self.type_name = types[0]
        self._connect(message_class(self.type_name))
        return True

    def _connect(self, msg_class):
        self.publisher = self.destination_node.create_publisher(
            msg_class, self.destination, QoSProfile(depth=10,
                                                    reliability=ReliabilityPolicy.RELIABLE))
        sender = DelayedSender(self.line, self.releaser, self.publisher.publish)
        self.source_node.create_subscription(
            msg_class, self.source, self.shift.wrap(sender.send, msg_class),
            QoSProfile(depth=self.queue_depth, reliability=ReliabilityPolicy.BEST_EFFORT),
            raw=True)


class LinkEmulatorNode(Node):
    """Joins both sides, relays the configured topics through one DelayLine per direction."""

    def __init__(self, params_files=(), **kwargs):
        """Check parameters, join the slave's domain, start relays and the release thread."""
        super().__init__('kraft_master_link_emulator', **kwargs)
        config = declare_parameters(self, PARAMETERS, params_files)
        try:
            models = {}
            for direction in DIRECTIONS:
                models[direction] = LinkModel(*(config[f'{direction}.{field}']
                                                for field in LinkModel._fields)).checked()
                for spec in config[f'{direction}.topics']:
                    parse_relay(spec)
        except ValueError as error:
            raise ParameterError(f'parameter {direction}.{error}') from None
        specs = {d: config[f'{d}.topics'] for d in DIRECTIONS}
        seed = None if config['seed'] < 0 else config['seed']
        self.master_domain = self.context.get_domain_id()
        slave_domain = config['slave_domain_id']
        self.slave_context = self.slave_executor = self.slave_thread = None
        slave_node = self
        if slave_domain >= 0 and slave_domain != self.master_domain:
            self.slave_context = rclpy.Context()
            rclpy.init(context=self.slave_context, domain_id=slave_domain)
            # Without rosout: the log goes through this node, and rcl keeps one rosout
            # publisher per node name in a process (a second one is refused with a warning).
            slave_node = rclpy.create_node(self.get_name(), namespace=self.get_namespace(),
                                           context=self.slave_context, enable_rosout=False)
            self.slave_executor = SingleThreadedExecutor(context=self.slave_context)
            self.slave_executor.add_node(slave_node)
        else:
            slave_domain = self.master_domain
            for spec in specs['to_slave'] + specs['to_master']:
                source, destination, _ = parse_relay(spec)
                if self.resolve_topic_name(source) == self.resolve_topic_name(destination):
                    raise ParameterError(
                        f'relay "{spec}" in one domain would feed itself: set '
                        f'slave_domain_id or rename the destination')
        self.slave_node = slave_node
        self.slave_domain = slave_domain
        self.releaser = Releaser()
        ends = {'to_slave': (self, slave_node), 'to_master': (slave_node, self)}
        self.lines = {d: DelayLine(models[d], seed=None if seed is None else seed + i)
                      for i, d in enumerate(DIRECTIONS)}
        self.shifts = {d: StampShift(config[f'{d}.stamp_offset']) for d in DIRECTIONS}
        for direction in DIRECTIONS:
            self.lines[direction].blackout = config[f'{direction}.blackout']
        try:
            self.relays = {d: [Relay(spec, *ends[d], self.lines[d], self.releaser,
                                     config['queue_depth'], self.shifts[d])
                               for spec in specs[d]] for d in DIRECTIONS}
        except ValueError as error:
            raise ParameterError(str(error)) from None
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.releaser.start()
        if self.slave_executor is not None:
            self.slave_thread = threading.Thread(
                target=self._spin_slave_side, name='link_emulator_slave_side', daemon=True)
            self.slave_thread.start()
        self.diag_pub = self.create_publisher(
            DiagnosticArray, 'diagnostics',
            QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
        steady_timer(self, 0.5, self._discover)
        steady_timer(self, 1.0, self._publish_diagnostics)
        steady_timer(self, LOG_PERIOD_S, self._log_summary)
        self.get_logger().info(
            f'relaying domain {self.master_domain} (master) <-> {slave_domain} (slave); '
            + '; '.join(f'{d}: {", ".join(config[f"{d}.topics"])} with {models[d]}'
                        for d in DIRECTIONS))

    def _on_set_parameters(self, parameters):
        """Apply a run-time set of a direction's link model, blackout or stamp offset."""
        try:
            changes = run_time_changes(PARAMETERS, parameters)
            models = {}
            for direction in DIRECTIONS:
                fields = {field: changes[f'{direction}.{field}'] for field in LinkModel._fields
                          if f'{direction}.{field}' in changes}
                if fields:
                    models[direction] = self.lines[direction].model._replace(**fields)
                    try:
                        models[direction].checked()
                    except ValueError as error:
                        raise ParameterError(f'parameter {direction}.{error}') from None
        except ParameterError as error:
            return SetParametersResult(successful=False, reason=str(error))
        for direction, model in models.items():
            self.lines[direction].change(model)
        for direction in DIRECTIONS:
            if f'{direction}.blackout' in changes:
                self.lines[direction].blackout = changes[f'{direction}.blackout']
            if f'{direction}.stamp_offset' in changes:
                self.shifts[direction].offset_ns = round(
                    changes[f'{direction}.stamp_offset'] * 1e9)
        if changes:
            self.get_logger().info('set ' + ', '.join(
                f'{name} {value}' for name, value in changes.items()))
        return SetParametersResult(successful=True)

    def _spin_slave_side(self):
        try:
            self.slave_executor.spin()
        except ExternalShutdownException:
            pass
        except RuntimeError:
            # Ctrl-C shut a context down while a message was relayed.
            if self.slave_context.ok() and self.context.ok():
                raise

    def _discover(self):
        for relay in itertools.chain.from_iterable(self.relays.values()):
            if relay.publisher is not None:
                continue
            try:
                if relay.discover():
                    self.get_logger().info(
                        f'relay {relay.source} -> {relay.destination} ({relay.type_name}) up')
            except ValueError as error:
                self.get_logger().error(str(error), throttle_duration_sec=10.0)

    def _summary(self, direction):
        values = {'domains': (f'{self.master_domain} -> {self.slave_domain}'
                              if direction == 'to_slave'
                              else f'{self.slave_domain} -> {self.master_domain}'),
                  'model': str(self.lines[direction].model)}
        values.update({k: str(v) for k, v in self.lines[direction].stats.summary().items()})
        values['topics'] = ', '.join(
            f'{r.source} -> {r.destination}' + ('' if r.publisher else ' (waiting for type)')
            for r in self.relays[direction])
        return values

    def _publish_diagnostics(self):
        array = DiagnosticArray()
        array.header.stamp = self.get_clock().now().to_msg()
        for direction in DIRECTIONS:
            waiting = any(r.publisher is None for r in self.relays[direction])
            array.status.append(DiagnosticStatus(
                name=f'{self.get_name()}: {direction.replace("_", " ")}',
                level=DiagnosticStatus.WARN if waiting else DiagnosticStatus.OK,
                message='waiting for a topic type' if waiting else 'relaying',
                values=[KeyValue(key=k, value=v) for k, v in self._summary(direction).items()]))
        self.diag_pub.publish(array)

    def _log_summary(self, logger=None):
        for direction in DIRECTIONS:
            stats = self.lines[direction].stats.summary()
            (logger or self.get_logger()).info(f'{direction}: ' + ', '.join(
                f'{k} {v}' for k, v in stats.items()))

    def destroy_node(self):
        """Stop both threads that publish, leave the slave's domain, log what was done."""
        # Both threads must have ended before any publisher they use is destroyed.
        self.releaser.stop()
        if self.slave_executor is not None:
            # The slave side's spin ends once its context is shut down and it is woken; its
            # executor goes after it (Executor.shutdown does not wait for the spinning thread,
            # and destroys the guard conditions that thread waits on).
            try_shutdown(self.slave_context)
            self.slave_executor.wake()
            self.slave_thread.join()
            self.slave_executor.shutdown()
            self.slave_node.destroy_node()
        exit_logger = rclpy.logging.get_logger(f'{self.get_name()}.exit')
        super().destroy_node()
        # A Ctrl-C has shut the context down already, and rosout would refuse the lines with an
        # error each: logged by a logger of another name, which no rosout publisher serves (the
        # node's own was seen to outlive destroy_node once, in a full run).
        self._log_summary(exit_logger)


def main(args=None):
    """Run the emulator until Ctrl-C or SIGTERM; exit 1 on a bad parameter."""
    # The release thread must get the interpreter lock soon after its due time.
    sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
    return run_node(LinkEmulatorNode, 'kraft_master_link_emulator',
                    __doc__.strip().splitlines()[0], PARAMETERS, args)


if __name__ == '__main__':
    sys.exit(main())
