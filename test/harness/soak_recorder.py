# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The session soak's recorder: kraft_master_record's Recorder on both sites' domains, one bag.

The link emulator keeps the master's site and the arm's in two DDS domains; one recorder node
joins each, and both write into one BagRecorder (receive time, system clock, as
kraft_master_record writes). Each topic is taken from one site: MASTER_TOPICS from the master's
(the driver's output, and what reached it over the link), ARM_TOPICS from the arm's. It prints
`recording` once every topic is subscribed, and closes the bag at SIGINT or SIGTERM.
"""
import argparse
import signal
import sys
import threading
import time

from kraft_master_driver.bag.recorder import BagRecorder
from kraft_master_driver.core.process import STOP_SIGNALS, stop_with_parent
from kraft_master_driver.tools.record import DISCOVERY_PERIOD_S, Recorder
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.signals import SignalHandlerOptions

# What the checker and the figure read, and the wrench that reached the driver: a Python
# recorder that takes more falls behind on a loaded machine and loses messages.
MASTER_TOPICS = ('/joint_states', '/pots', '/master_energy', '/wrench', '/slave_energy',
                 '/contact_model', '/diagnostics')
ARM_TOPICS = ('/servo_cp', '/measured_cp', '/operating_state')


def main():
    """Record both domains into --bag until a stop signal; return 0."""
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('--bag', required=True)
    parser.add_argument('--master-domain', type=int, required=True)
    parser.add_argument('--arm-domain', type=int, required=True)
    args = parser.parse_args()
    stop = threading.Event()
    for signum in STOP_SIGNALS:
        signal.signal(signum, lambda _signum, _frame: stop.set())
    stop_with_parent()
    bag = BagRecorder(args.bag, 'mcap')
    lock = threading.Lock()  # the two executors' threads write into one bag
    write = bag.write

    def locked_write(*arguments):
        with lock:
            write(*arguments)
    bag.write = locked_write
    sites = []
    for domain, topics in ((args.master_domain, MASTER_TOPICS),
                           (args.arm_domain, ARM_TOPICS)):
        context = rclpy.Context()
        rclpy.init(context=context, domain_id=domain,
                   signal_handler_options=SignalHandlerOptions.NO)
        recorder = Recorder(context, bag, list(topics))
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(recorder.node)
        sites.append((context, recorder, executor))
    threads = [threading.Thread(target=spin, args=(recorder, executor, stop, lock),
                                daemon=True) for _, recorder, executor in sites]
    for thread in threads:
        thread.start()
    announced = False
    while not stop.wait(DISCOVERY_PERIOD_S):
        if not announced and all(len(r.subscriptions) == len(r.wanted) for _, r, _ in sites):
            print('recording', flush=True)
            announced = True
    for thread in threads:
        thread.join()
    with lock:
        bag.close()
    for context, recorder, executor in sites:
        executor.shutdown()
        recorder.close()
        rclpy.try_shutdown(context=context)
    print('closed ' + ', '.join(f'{t} {n}' for t, n in bag.counts.items()), flush=True)
    return 0


def spin(recorder, executor, stop, lock):
    """Subscribe to the site's topics as they appear and write what comes, until `stop`."""
    next_discovery = 0.0
    while not stop.is_set():
        now = time.monotonic()
        if now >= next_discovery and len(recorder.subscriptions) < len(recorder.wanted):
            with lock:
                recorder.discover()
            next_discovery = now + DISCOVERY_PERIOD_S
        executor.spin_once(timeout_sec=DISCOVERY_PERIOD_S)


if __name__ == '__main__':
    sys.exit(main())
