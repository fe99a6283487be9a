# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The session soak's simulated master, a process of its own, its fault switches on stdin.

It runs a SimulatedKraftMaster (the 'task' operator hand by default) at the loop's priority,
prints `port: <port>`, then takes one JSON line at a time on stdin, {"fault": name, "on": bool},
switches that fault on or off and answers `ok <time.time()>` (or `error <reason>`). Faults:
'unplugged' (the port goes away), 'replies dropped' (1 in 10), 'corrupt bytes 1e-3' and
'corrupt bytes 1e-2', 'stall' (no answer until switched off), 'garbage' (512 random bytes every
10 ms). It ends at stdin's end, SIGINT or SIGTERM, and prints its counters on stderr.
"""
import argparse
import json
import select
import signal
import sys
import time

from kraft_master_driver.core import realtime
from kraft_master_driver.core.process import STOP_SIGNALS, stop_with_parent
from kraft_master_driver.nodes.driver_parameters import PARAMETERS
from kraft_master_driver.simulation.master.simulator import SimulatedKraftMaster

GARBAGE_BYTES = 512
GARBAGE_PERIOD_S = 0.01
STALL_MS = 1e9  # a stall lasts until it is switched off
RATES = {'replies dropped': ('drop_reply_rate', 0.1), 'corrupt bytes 1e-3':
         ('corrupt_byte_rate', 1e-3), 'corrupt bytes 1e-2': ('corrupt_byte_rate', 1e-2)}
FAULTS = ('unplugged', 'stall', 'garbage', *RATES)


def switch(simulator, fault, on):
    """Switch `fault` (one of FAULTS) on or off."""
    if fault == 'unplugged':
        (simulator.unplug if on else simulator.replug)()
    elif fault == 'stall':
        simulator.stall(STALL_MS if on else 0)
    elif fault in RATES:
        name, rate = RATES[fault]
        setattr(simulator, name, rate if on else 0.0)
    elif fault != 'garbage':
        raise ValueError(f'unknown fault {fault!r}; known: {", ".join(FAULTS)}')


def serve(simulator, stop):
    """Take the switches on stdin until it ends or `stop` fills; keep the garbage flowing."""
    garbage = False
    while not stop:
        ready, _, _ = select.select([sys.stdin], [], [], GARBAGE_PERIOD_S if garbage else 0.2)
        if garbage:
            simulator.send_garbage(GARBAGE_BYTES)
        if not ready:
            continue
        line = sys.stdin.readline()
        if not line:
            return
        try:
            request = json.loads(line)
            switch(simulator, request['fault'], bool(request['on']))
        except (ValueError, KeyError, TypeError) as error:
            print(f'error {error}', flush=True)
            continue
        if request['fault'] == 'garbage':
            garbage = bool(request['on'])
        print(f'ok {time.time():.6f}', flush=True)


def main():
    """Run the simulated master until stdin ends or a stop signal; return 0."""
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('--operator', default='task')
    parser.add_argument('--operator-period', type=float, default=2.0)
    parser.add_argument('--seed', type=int, default=0)
    args = parser.parse_args()
    stop = []
    for signum in STOP_SIGNALS:
        signal.signal(signum, lambda signum, _frame: stop.append(signum))
    stop_with_parent()
    priority = PARAMETERS['loop_priority'].default
    with SimulatedKraftMaster(operator=args.operator, operator_period=args.operator_period,
                              seed=args.seed, priority=priority) as simulator:
        if simulator.priority_error:
            print(f'soak_master: warning: {simulator.priority_error}', file=sys.stderr)
        else:
            realtime.set_fifo_priority(max(1, priority - 1))
        print(f'port: {simulator.port}', flush=True)
        serve(simulator, stop)
        print(f'soak_master: stopped, {simulator.stats}', file=sys.stderr, flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
