# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The session soak's run (scripts/teleop_soak.py, and its 60 s test): schedule, operator, checks.

Soak starts the Site (soak_site.py), enables the bridge once it can, and runs the schedule
(soak_faults.py): between faults the operator keeps the bridge enabled and clutches now and
then; while a fault lasts the operator does nothing; after it, the operator enables again if the
bridge is not following, and the next fault waits until it follows. The faults are written as
JSON lines (kind, side, start, end, force_untrue; time.time() seconds, the recorder's clock).
At the end every process is stopped, what was left behind is listed, and the recorded session
is checked with kraft_master_driver.tools.session_check.
"""
import collections
import json
import signal
import time

from harness.driver import wait_for
from harness.faults import WrenchSource
from harness.soak_faults import schedule
from harness.soak_site import Operator, Site, START_S
import numpy as np

RSS_PERIOD_S = 10.0
WARM_UP_S = 60.0  # a process's RSS samples in its first minute are left out of its slope
MIN_SAMPLES = 10  # a slope of fewer samples (after the warm-up) is not given
CLUTCH_EVERY_S = 30.0  # the operator clutches this often, between faults
CLUTCH_S = 1.5
ENABLE_EVERY_S = 0.5
RECOVERY_S = 60.0  # a fault the bridge does not follow again after, within this, is reported
SETTLE_S = 1.0  # following again this long before the next fault may come


def _interrupt(_signum, _frame):
    raise KeyboardInterrupt


def _take_stop_signals():
    """Have SIGINT and SIGTERM end the run through its `finally`, which stops every process."""
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, _interrupt)


class Soak:
    """One run: the site, the operator, the schedule's faults and what was measured."""

    def __init__(self, work, seed, duration, longest=float('inf'), link='emulator'):
        """Draw the schedule for `link` between the sites; nothing starts until run()."""
        self.work, self.seed, self.duration, self.link = work, seed, duration, link
        self.schedule, self.rng = schedule(seed, duration, longest, link)
        self.site = self.operator = self._source = None
        self.faults = []  # dicts, as written to faults.jsonl
        self.notes = []  # what went wrong in the run itself
        self.rss = collections.defaultdict(list)  # (name, pid) -> [(s, KiB)]
        self.started = None
        self._next_rss = self._next_clutch = self._last_enable = 0.0

    def wrench_source(self):
        """Return the second wrench source on the driver's site, started on first use."""
        if self._source is None:
            self._source = WrenchSource(self.site.env['master'], '/',
                                        lambda condition: wait_for(condition, START_S))
            self._source.wait_ready()
        return self._source

    def run_for(self, seconds, operating=False):
        """Let `seconds` pass; `operating`: enable and clutch as the operator does."""
        deadline = time.monotonic() + seconds
        while True:
            now = time.monotonic()
            self._sample_rss(now)
            if operating:
                self._operate(now)
            if now >= deadline:
                return
            time.sleep(min(0.05, deadline - now))

    def _operate(self, now):
        operator = self.operator
        # The master is registered where the hand is at enable and at the clutch's release: as
        # the demo does, at the top of the stroke, so that the arm keeps its height.
        if operator.state.startswith('CLUTCHED'):
            if (now >= self._next_clutch - CLUTCH_EVERY_S + CLUTCH_S
                    and operator.at_top_of_stroke()):
                operator.clutch(False)
        elif not operator.following():
            if now - self._last_enable >= ENABLE_EVERY_S and operator.at_top_of_stroke():
                operator.enable()
                self._last_enable = now
        elif now >= self._next_clutch:
            operator.clutch(True)
            self._next_clutch = now + CLUTCH_EVERY_S

    def _sample_rss(self, now):
        if now < self._next_rss:
            return
        self._next_rss = now + RSS_PERIOD_S
        for name, (pid, kib) in self.site.rss().items():
            if kib is not None:
                self.rss[(name, pid)].append((now - self.started, kib))

    def follow(self, timeout):
        """Operate until the bridge has followed for SETTLE_S; return the seconds it took."""
        began = time.monotonic()
        since = None
        while time.monotonic() - began < timeout:
            self.run_for(0.05, operating=True)
            if self.operator.following() and not self.site.dead():
                since = since or time.monotonic()
                if time.monotonic() - since >= SETTLE_S:
                    return time.monotonic() - began
            else:
                since = None
        return None

    def run(self):
        """Run the session and the schedule; return the seconds run. Always stops everything."""
        print(f'seed {self.seed}, {self.duration:g} s, link {self.link}, '
              f'{len(self.schedule)} faults:')
        for fault in self.schedule:
            print(f'  {fault.at:8.2f} s  {fault.kind.name} ({fault.duration:g} s)')
        try:
            _take_stop_signals()  # a Site that fails to start stops what it started
            self.site = Site(self.work, self.seed, link=self.link)
            self.started = time.monotonic()
            self.site.wait_recording()
            self.operator = Operator(self.site)
            _take_stop_signals()  # rclpy.init took them for its contexts
            assert self.follow(START_S) is not None, (
                f'the bridge never followed: {self.operator.state!r}; see {self.work}')
            self.started = time.monotonic()
            for fault in self.schedule:
                self.run_for(self.started + fault.at - time.monotonic(), operating=True)
                if self.site.dead():
                    self.notes.append(f'{", ".join(self.site.dead())} ended by itself')
                    break
                try:
                    self.inject(fault)
                except AssertionError as error:  # a request no process of the site answered
                    self.notes.append(f'{fault.kind.name} at {time.monotonic() - self.started:.0f}'
                                      f' s: {error}; the soak stopped there (operator spinning: '
                                      f'{self.operator.spin_error or "yes"})')
                    return time.monotonic() - self.started
            self.run_for(self.started + self.duration - time.monotonic(), operating=True)
            return time.monotonic() - self.started
        finally:
            self.stop()

    def inject(self, fault):
        """Inject one scheduled fault, then wait for the bridge to follow again."""
        if self.operator.state.startswith('CLUTCHED'):
            self.operator.clutch(False)
            self.follow(RECOVERY_S)
        start, end = fault.kind.inject(self, fault.duration, self.rng)
        entry = {'kind': fault.kind.name, 'side': fault.kind.side, 'start': start, 'end': end,
                 'force_untrue': fault.kind.force_untrue, 'scheduled_s': fault.duration}
        took = self.follow(RECOVERY_S)
        entry['following_again_s'] = None if took is None else round(took, 2)
        if took is None:
            self.notes.append(f'{fault.kind.name} at {start:.3f}: the bridge did not follow '
                              f'again within {RECOVERY_S:g} s ({self.operator.state!r}; '
                              f'operator spinning: {self.operator.spin_error or "yes"})')
        self.faults.append(entry)
        print(f'{time.strftime("%H:%M:%S")} {fault.kind.name}: {end - start:.3f} s, following '
              f'again after {entry["following_again_s"]} s', flush=True)

    def stop(self):
        """Stop every process; note exit codes that are not 0 and what was left behind."""
        if self.operator is not None:
            self.operator.close()
        if self._source is not None:
            self._source.close()
        if self.site is None:
            return
        self.exit_codes = self.site.stop()
        self.notes += [f'{name} exited with {code} at SIGINT'
                       for name, code in self.exit_codes.items() if code != 0]
        self.leftovers = self.site.leftovers()
        if self._source is not None and self._source.process.poll() is None:
            self.leftovers.append('the wrench source still runs')

    def write_faults(self, path):
        """Write the faults as JSON lines."""
        with open(path, 'w') as stream:
            for entry in self.faults:
                stream.write(json.dumps(entry) + '\n')

    def rss_slopes(self):
        """Return {name: {first, last, max KiB, slope KiB/min after warm-up}} per incarnation."""
        found = {}
        for (name, pid), samples in sorted(self.rss.items()):
            times, kib = np.array(samples, dtype=float).T
            settled = times >= times[0] + WARM_UP_S  # each incarnation from its own start
            slope = (float(np.polyfit(times[settled] / 60.0, kib[settled], 1)[0])
                     if settled.sum() >= MIN_SAMPLES else None)
            found.setdefault(name, []).append({
                'pid': pid, 'samples': len(kib), 'first_kib': int(kib[0]),
                'last_kib': int(kib[-1]), 'max_kib': int(kib.max()),
                'slope_kib_per_min': None if slope is None else round(slope, 1)})
        return found
