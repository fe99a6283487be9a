# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""What the machine did during a benchmark run: CPU time stolen by the hypervisor."""
import pathlib


def cpu_times():
    """Return the machine's CPU time counters (ticks) from the first line of /proc/stat."""
    names = ('user', 'nice', 'system', 'idle', 'iowait', 'irq', 'softirq', 'steal')
    values = pathlib.Path('/proc/stat').read_text().split('\n', 1)[0].split()[1:9]
    return dict(zip(names, map(int, values)))


def steal_fraction(start, end):
    """Share of all CPU time between two cpu_times() readings that the hypervisor took."""
    total = sum(end.values()) - sum(start.values())
    return (end['steal'] - start['steal']) / total if total else 0.0
