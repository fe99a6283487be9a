# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The simulated device's serving thread: the only thread that touches its port.

It waits on the port (transport.py) and on a wake-up pipe, hands what the host sends to the
device, ticks the device every few milliseconds when nothing comes, sends the replies and
carries out what other threads ask of the port (unplug, replug, garbage). With a wire time,
each reply leaves when a serial line at the baud rate would have carried it.
"""
import collections
import os
import queue
import select
import threading
import time

from kraft_master_driver.core import realtime
from kraft_master_driver.simulation.master.transport import READ_SIZE

IDLE_TICK = 0.005  # s between ticks when nothing arrives
WIRE_WAKE_EARLY = 0.0003  # s before a reply is due: select() oversleeps by ~0.1 ms
REQUEST_TIMEOUT = 5.0  # s to wait for the thread to carry out a request
# Its name, in ps -L and top as in Python (benchmarks/loop.py --sched-trace finds it by it).
SERVING_THREAD = 'kraft_sim'


class ServingThread(threading.Thread):
    """Serves a started transport until stop(); replies go out through send()."""

    def __init__(self, transport, wire_time, counters, on_data, on_tick):
        """
        Serve `transport`: hand each read to on_data(data, now) and tick on_tick(now).

        wire_time (s) is a reply's time on the wire (0: none); counters (a dict) counts the
        'replies' sent and the writes 'unsent'. Times are time.monotonic().
        """
        super().__init__(name=SERVING_THREAD, daemon=True)
        self._transport = transport
        self._wire_time = wire_time
        self._counters = counters
        self._on_data, self._on_tick = on_data, on_tick
        self._wake = os.pipe()
        os.set_blocking(self._wake[0], False)
        self._requests = queue.SimpleQueue()
        self.serving = True
        self._pending = collections.deque()  # (send time, reply bytes) under wire timing
        self._last_send = 0.0

    def stop(self):
        """Stop serving, wait for the thread to end, close the wake-up pipe."""
        self.serving = False
        os.write(self._wake[1], b'x')
        self.join()
        for fd in self._wake:
            os.close(fd)

    def call(self, function):
        """Have the thread call function(); return once it has, or raise RuntimeError."""
        done = threading.Event()

        def request():
            function()
            done.set()

        self._requests.put(request)
        os.write(self._wake[1], b'r')
        if not done.wait(REQUEST_TIMEOUT):
            raise RuntimeError('the simulator thread did not respond')

    def send(self, reply, now):
        """Send a reply now, or under wire timing when the wire is free for it."""
        if self._wire_time:
            self._last_send = max(now, self._last_send) + self._wire_time
            self._pending.append((self._last_send, reply))
        else:
            self._write_reply(reply)

    def drop_pending(self):
        """Forget the replies not yet sent (the host that was to have them has gone)."""
        self._pending.clear()

    def write(self, data):
        """Write to the host; False (counted as unsent) when unplugged or its buffer is full."""
        if self._transport.write(data):
            return True
        self._counters['unsent'] += 1
        return False

    def run(self):
        """Serve until stop()."""
        realtime.name_this_thread(self.name)
        wake = self._wake[0]
        transport = self._transport
        while self.serving:
            timeout = IDLE_TICK
            if self._pending:
                due = self._pending[0][0]
                due_in = due - time.monotonic()
                if due_in <= WIRE_WAKE_EARLY:
                    # select() oversleeps by about 0.1 ms here: watch the clock alone until
                    # the reply is due, so that it leaves on time.
                    while time.monotonic() < due:
                        pass
                    self._send_due(time.monotonic())
                    continue
                timeout = min(timeout, due_in - WIRE_WAKE_EARLY)
            host, listener = transport.host, transport.listener
            waits = [fd for fd in (wake, host, listener) if fd is not None]
            readable = select.select(waits, (), (), timeout)[0]
            now = time.monotonic()
            if self._pending:
                self._send_due(now)
            self._on_tick(now)
            if host is not None and host in readable:
                data = transport.read()
                if data:
                    self._on_data(data, now)
            if listener is not None and listener in readable:
                transport.accept()
            if wake in readable:
                self._run_requests()

    def _send_due(self, now):
        pending = self._pending
        while pending and pending[0][0] <= now:
            self._write_reply(pending.popleft()[1])

    def _write_reply(self, reply):
        if self.write(reply):
            self._counters['replies'] += 1

    def _run_requests(self):
        try:
            os.read(self._wake[0], READ_SIZE)
        except BlockingIOError:
            pass
        while not self._requests.empty():
            self._requests.get()()
