# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
A delaying, lossy relay of the teleoperation topics between two DDS domains (tests only).

The master side (driver) lives on one domain, the slave on another; this process carries
`pose` and `master_energy` to the slave and `wrench` and `slave_energy` back, each message held
for a fixed one-way delay and dropped with a fixed probability, order kept. Messages are
relayed as serialized bytes. Run: python delay_relay.py MASTER_DOMAIN SLAVE_DOMAIN ONE_WAY_MS
LOSS SEED; it prints 'ready' once its endpoints exist and runs until SIGINT or SIGTERM.
"""
import collections
import random
import signal
import sys
import threading
import time

from geometry_msgs.msg import PoseStamped, Vector3Stamped, WrenchStamped
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy

TO_SLAVE = (('pose', PoseStamped), ('master_energy', Vector3Stamped))
TO_MASTER = (('wrench', WrenchStamped), ('slave_energy', Vector3Stamped))


class Side:
    """One DDS domain: its own context, node and executor thread."""

    def __init__(self, domain_id, name):
        """Join domain_id."""
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self._spin, daemon=True)

    def _spin(self):
        try:
            self.executor.spin()
        except Exception:  # noqa: B902 - shutdown while spinning ends the relay anyway
            pass

    def close(self):
        """Leave the domain."""
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def main(argv):
    """Relay until a signal; return 0."""
    master_domain, slave_domain = int(argv[0]), int(argv[1])
    delay, loss, rng = float(argv[2]) / 1e3, float(argv[3]), random.Random(int(argv[4]))
    master, slave = Side(master_domain, 'relay_master'), Side(slave_domain, 'relay_slave')
    queue = collections.deque()  # (due, publisher, bytes), in arrival order
    ready = threading.Condition()
    qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT)
    out_qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)

    def relay(publisher):
        def take(data):
            if rng.random() < loss:
                return
            with ready:
                queue.append((time.monotonic() + delay, publisher, data))
                ready.notify()
        return take

    for source, target, topics in ((master, slave, TO_SLAVE), (slave, master, TO_MASTER)):
        for topic, msg_type in topics:
            publisher = target.node.create_publisher(msg_type, topic, out_qos)
            source.node.create_subscription(msg_type, topic, relay(publisher), qos, raw=True)
    stop = threading.Event()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: stop.set())
    master.thread.start()
    slave.thread.start()
    print('ready', flush=True)
    while not stop.is_set():
        with ready:
            while not queue and not stop.is_set():
                ready.wait(0.1)
            if not queue:
                break
            due, publisher, data = queue[0]
            wait = due - time.monotonic()
            if wait <= 0:
                queue.popleft()
        if wait > 0:
            stop.wait(wait)
        else:
            publisher.publish(data)
    master.close()
    slave.close()
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
