# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The serial link to the KMC 9100: one cycle writes five torques and reads six pots.

The port is a device path or any pyserial URL (socket://host:port, loop://, ...). Link faults
never raise out of cycle(): an OSError/SerialException, or too many consecutive reply timeouts,
mark the link down and close the port (after an attempt to write zero torques); later cycles
reopen it with exponential backoff. Zero torques are written before every close.
"""
from collections.abc import Callable, Iterable, Sequence
import math
import os
import select
import threading
import time
from typing import NamedTuple, Self

from kraft_master_driver.link.protocol import (
    AXIS_COUNT, DEFAULT_CODEC, get_codec, PotFrame, STATUS_COMMAND_TIMEOUT,
    STATUS_CORRUPT_COMMAND)
import serial

SEQUENCE_MODULO = 256
# The port's read timeout: reads wake up at least this often to check the reply deadline.
READ_SLICE_S = 0.002
# The most bytes one read on a device file takes; the decoder keeps what follows a reply.
READ_CHUNK = 4096
# A write that cannot complete within this time is a link fault. Generous: pyserial also
# reports a timeout when the thread was merely descheduled that long during a write.
WRITE_TIMEOUT_S = 1.0
ZERO_COUNTS = (0,) * AXIS_COUNT
COUNTER_NAMES = (
    'cycles',  # commands sent by cycle()
    'replies',  # matching replies received
    'timeouts',  # cycles without a matching reply within reply_timeout
    'stale_replies',  # well-formed replies with the wrong sequence number (discarded)
    'link_faults',  # times the link was marked down
    'reconnects',  # successful reopens after a fault or a failed open
    'failed_opens',  # open attempts that failed
    'clamped_commands',  # commands with at least one axis clamped to its limit
    'nonfinite_commands',  # commands with a NaN or infinite torque (sent as zero on that axis)
    'zero_commands',  # zero-torque commands written before closing the port
    'device_corrupt_commands',  # replies reporting that the device received a corrupt command
    'device_command_timeouts',  # replies reporting that the device zeroed its torques
    'low_latency_failures',  # opens where ASYNC_LOW_LATENCY could not be set
)


class LinkError(Exception):
    """A misuse of the link that is not a link fault, such as cycling a closed device."""


class CycleResult(NamedTuple):
    """The outcome of one successful cycle."""

    frame: PotFrame
    receive_ns: int  # time.time_ns() when the reply completed
    round_trip_s: float  # from just before the write to the reply's last byte
    commanded_nm: tuple[float, ...]  # the five torques actually sent (after clamping), N*m


def torque_counts(torques_nm: Iterable[float], torque_scale: Sequence[float],
                  torque_limit: Sequence[int]) -> tuple[tuple[int, ...], bool, bool]:
    """
    Return (counts, clamped, nonfinite) for five torques in N*m (actuator axes 1..5).

    counts = round(scale * torque) clamped to +-limit, a NaN or infinite torque giving 0;
    clamped and nonfinite tell whether any axis was clamped or was not finite.
    """
    try:
        if isinstance(torques_nm, (str, bytes)):
            raise TypeError
        values = [float(value) for value in torques_nm]
    except (TypeError, ValueError):
        raise ValueError(f'torques_nm must be {AXIS_COUNT} numbers (N*m), '
                         f'got {torques_nm!r}') from None
    if len(values) != AXIS_COUNT:
        raise ValueError(f'torques_nm must be {AXIS_COUNT} numbers (N*m), got {len(values)}')
    counts = []
    clamped = nonfinite = False
    for value, scale, limit in zip(values, torque_scale, torque_limit):
        if not math.isfinite(value):
            nonfinite = True
            counts.append(0)
            continue
        count = round(value * scale)
        if count > limit or count < -limit:
            clamped = True
            count = limit if count > 0 else -limit
        counts.append(count)
    return tuple(counts), clamped, nonfinite


class KmcDevice:
    """The host side of the KMC 9100 link over pyserial."""

    def __init__(self, port: str, baudrate: float = 1_000_000, codec: str = DEFAULT_CODEC,
                 reply_timeout: float = 0.01,
                 torque_scale: Iterable[float] | None = None,
                 torque_limit: Iterable[float] | None = None,
                 torque_sign: Iterable[int] | None = None,
                 low_latency: bool = False, reconnect_min: float = 0.05,
                 reconnect_max: float = 2.0, timeouts_before_reconnect: int = 25) -> None:
        """
        Configure the link; nothing is opened until open().

        port: device path or pyserial URL. baudrate: bits/s. codec: a name in
        protocol.CODECS or the path of a frame description. reply_timeout: seconds to wait for
        each reply. torque_scale: five positive command counts per N*m (axes 1..5; None: the
        codec's). torque_limit: five limits in counts (1 to the largest count the frame holds;
        None: the codec's). torque_sign: five signs, 1 or -1 (None: all 1), multiplying each
        axis's counts on their way to the frame, after the clamp: the torque_signs of a
        calibration file (kraft_master_calibrate --check-torques); commanded_nm stays in the
        driver's sense. low_latency: set ASYNC_LOW_LATENCY on Linux serial ports (a failure is
        a warning in last_error, not an error). reconnect_min, reconnect_max: backoff bounds
        (seconds). timeouts_before_reconnect: consecutive timeouts after which the link is
        treated as dead and reopened.
        """
        if not isinstance(port, str) or not port:
            raise ValueError(f'port must be a device path or pyserial URL, got {port!r}')
        self.port = port
        self.baudrate = _positive('baudrate', baudrate)
        self.codec = get_codec(codec)
        self.reply_timeout = _positive('reply_timeout', reply_timeout)
        self.torque_scale = _axis_values(
            'torque_scale', self.codec.torque_scale if torque_scale is None else torque_scale,
            lambda v: math.isfinite(v) and v > 0, 'finite positive counts per N*m')
        count_limit = self.codec.count_limit
        limits = _axis_values(
            'torque_limit', self.codec.torque_limit if torque_limit is None else torque_limit,
            lambda v: 1 <= v <= count_limit and v == int(v),
            f'integer counts in 1..{count_limit}')
        self.torque_limit = tuple(int(v) for v in limits)
        signs = _axis_values('torque_sign', (1,) * AXIS_COUNT if torque_sign is None
                             else torque_sign, lambda v: v in (1.0, -1.0), '1 or -1')
        self.torque_sign = tuple(int(v) for v in signs)
        self._flip = None if set(self.torque_sign) == {1} else self.torque_sign
        self.low_latency = bool(low_latency)
        self.reconnect_min = _positive('reconnect_min', reconnect_min)
        self.reconnect_max = _positive('reconnect_max', reconnect_max)
        if self.reconnect_max < self.reconnect_min:
            raise ValueError(f'reconnect_max ({reconnect_max}) must not be less than '
                             f'reconnect_min ({reconnect_min})')
        if not (isinstance(timeouts_before_reconnect, int) and timeouts_before_reconnect >= 1):
            raise ValueError('timeouts_before_reconnect must be an integer >= 1, '
                             f'got {timeouts_before_reconnect!r}')
        self.timeouts_before_reconnect = timeouts_before_reconnect
        self.link_up = False
        self.last_error = ''
        self._counters = dict.fromkeys(COUNTER_NAMES, 0)
        self._decoder = self.codec.reply_decoder()
        self._serial: serial.SerialBase | None = None
        self._io: _PyserialIo | _DescriptorIo | None = None
        # (sequence, write time ns, counts) of the command sent last
        self._in_flight: tuple[int, int, tuple[int, ...]] | None = None
        self._lock = threading.Lock()
        self._opened = False
        self._ever_up = False
        self._sequence = 0
        self._consecutive_timeouts = 0
        self._backoff = self.reconnect_min
        self._next_attempt = 0.0

    @property
    def stats(self) -> dict[str, int]:
        """Counters of the link (see COUNTER_NAMES) and the decoder's error kinds."""
        return {**self._counters, **self._decoder.errors}

    def wire_limited_rate(self) -> float:
        """Return the cycles/s the wire allows at the configured baud (8N1)."""
        return 1.0 / self.codec.wire_cycle_time(self.baudrate)

    def open(self) -> bool:  # noqa: A003 - the name pyserial and file objects use
        """Open the port; return link_up. A failure leaves the link down, retried by cycle()."""
        with self._lock:
            self._opened = True
            self._backoff = self.reconnect_min
            return self._try_open()

    def close(self) -> None:
        """Write zero torques if the port is open, then close it. Safe to call repeatedly."""
        with self._lock:
            self._opened = False
            self._close_port()

    def __enter__(self) -> Self:
        """Open the device (a failed open is retried by cycle())."""
        self.open()
        return self

    def __exit__(self, *exc_info: object) -> None:
        """Zero the torques and close."""
        self.close()

    def cycle(self, torques_nm: Iterable[float]) -> CycleResult | None:
        """
        Write the torques (N*m, axes 1..5) and read the matching pot frame: send + receive.

        Returns a CycleResult, or None on a timeout or while the link is down (a reopen is
        attempted here when the backoff allows). Raises ValueError for bad torques and
        LinkError when the device is not open; never raises for link faults.
        """
        return self.receive() if self.send(torques_nm) else None

    def send(self, torques_nm: Iterable[float]) -> bool:
        """
        Write one torque command (N*m, axes 1..5); return True if it went out.

        False while the link is down (a reopen is attempted when the backoff allows) or when
        the write failed (a link fault). A command still waiting for its reply is forgotten:
        its reply, if it comes, is counted stale. Raises as cycle().
        """
        counts, clamped, nonfinite = torque_counts(torques_nm, self.torque_scale,
                                                   self.torque_limit)
        with self._lock:
            if not self._opened:
                raise LinkError(f'{self.port}: device is closed; call open() first')
            self._in_flight = None
            if not self.link_up and not self._reconnect_due():
                return False
            counters = self._counters
            counters['clamped_commands'] += clamped
            counters['nonfinite_commands'] += nonfinite
            sequence = self._next_sequence()
            wire_counts = counts if self._flip is None else tuple(
                count * sign for count, sign in zip(counts, self._flip))
            command = self.codec.encode_command(sequence, wire_counts)
            assert self._io is not None  # the link is up, so the port is open
            try:
                if not self.codec.has_sequence:
                    self._drop_late_replies()
                start_ns = time.perf_counter_ns()
                self._io.write(command)
            except (OSError, serial.SerialException) as exc:
                self._link_fault(f'{self.port}: {exc}')
                return False
            counters['cycles'] += 1
            self._in_flight = (sequence, start_ns, counts)
            return True

    def receive(self) -> CycleResult | None:
        """
        Wait for the reply to the command sent last; return its CycleResult.

        None on a timeout (reply_timeout after the write), a link fault, or when no command
        is waiting for its reply. Raises LinkError when the device is not open.
        """
        with self._lock:
            if not self._opened:
                raise LinkError(f'{self.port}: device is closed; call open() first')
            in_flight, self._in_flight = self._in_flight, None
            if in_flight is None or not self.link_up:
                return None
            sequence, start_ns, counts = in_flight
            counters = self._counters
            try:
                frame = self._read_reply(sequence, start_ns + int(self.reply_timeout * 1e9))
            except (OSError, serial.SerialException) as exc:
                self._link_fault(f'{self.port}: {exc}')
                return None
            if frame is None:
                counters['timeouts'] += 1
                self._consecutive_timeouts += 1
                if self._consecutive_timeouts >= self.timeouts_before_reconnect:
                    self._link_fault(f'{self.port}: no reply to {self._consecutive_timeouts} '
                                     'consecutive commands')
                return None
            receive_ns = time.time_ns()
            round_trip_s = (time.perf_counter_ns() - start_ns) * 1e-9
            self._consecutive_timeouts = 0
            counters['replies'] += 1
            commanded_nm = tuple(count / scale for count, scale in zip(counts, self.torque_scale))
            return CycleResult(frame, receive_ns, round_trip_s, commanded_nm)

    def _read_reply(self, sequence: int, deadline_ns: int) -> PotFrame | None:
        """
        Read until the reply with this sequence arrives (return it) or the deadline (None).

        A frame without sequence numbers has no stale replies to tell apart: the newest reply
        read is taken (those before it in the same read count as stale).
        """
        assert self._io is not None  # receive() reads only while the link is up
        read = self._io.read
        decoder = self._decoder
        reply_size = self.codec.reply_size
        while True:
            data = read(reply_size - decoder.pending, deadline_ns)
            if data:
                matching = None
                for frame in decoder.feed(data):
                    self._count_status(frame.status)
                    if matching is not None and frame.sequence is None:
                        self._counters['stale_replies'] += 1
                    if frame.sequence == sequence or frame.sequence is None:
                        matching = frame
                    else:
                        self._counters['stale_replies'] += 1
                if matching is not None:
                    return matching
            if time.perf_counter_ns() >= deadline_ns:
                return None

    def _drop_late_replies(self) -> None:
        """Before a command of a frame without sequence numbers: drop the replies come late."""
        assert self._io is not None
        data = self._io.read_waiting()
        if data:
            for frame in self._decoder.feed(data):
                self._count_status(frame.status)
                self._counters['stale_replies'] += 1

    def _count_status(self, status: int) -> None:
        """Count what a reply's status byte reports, stale replies included."""
        if status & STATUS_CORRUPT_COMMAND:
            self._counters['device_corrupt_commands'] += 1
        if status & STATUS_COMMAND_TIMEOUT:
            self._counters['device_command_timeouts'] += 1

    def _next_sequence(self) -> int:
        """Advance and return the command sequence number."""
        self._sequence = (self._sequence + 1) % SEQUENCE_MODULO
        return self._sequence

    def _reconnect_due(self) -> bool:
        """Reopen the port if the backoff allows; return link_up."""
        if time.monotonic() < self._next_attempt:
            return False
        self._backoff = min(self._backoff * 2, self.reconnect_max)
        return self._try_open()

    def _try_open(self) -> bool:
        """Open the port once; on failure schedule the next attempt. Return link_up."""
        self._close_port()
        try:
            # exclusive: a second driver on the same port fails to open instead of stealing
            # half of the replies (an advisory lock, honoured by pyserial users).
            port = serial.serial_for_url(
                self.port, baudrate=self.baudrate, timeout=min(self.reply_timeout, READ_SLICE_S),
                write_timeout=max(self.reply_timeout, WRITE_TIMEOUT_S), exclusive=True)
            port.reset_input_buffer()
        except (OSError, serial.SerialException) as exc:
            self._counters['failed_opens'] += 1
            self.last_error = f'{self.port}: cannot open: {_open_failure(exc)}'
            self._next_attempt = time.monotonic() + self._backoff
            return False
        self._serial = port
        self._io = _DescriptorIo(port) if isinstance(port, serial.Serial) else _PyserialIo(port)
        self._decoder.reset()
        self._consecutive_timeouts = 0
        self._backoff = self.reconnect_min
        if self._ever_up or self._counters['failed_opens']:
            self._counters['reconnects'] += 1
        self._ever_up = True
        self.link_up = True
        if self.low_latency:
            self._set_low_latency(port)
        return True

    def _set_low_latency(self, port: serial.SerialBase) -> None:
        """Ask the driver for ASYNC_LOW_LATENCY; a failure is recorded, not raised."""
        try:
            port.set_low_latency_mode(True)
        except (AttributeError, NotImplementedError, ValueError, OSError) as exc:
            self._counters['low_latency_failures'] += 1
            self.last_error = f'{self.port}: warning: low latency mode not set: {exc}'

    def _link_fault(self, reason: str) -> None:
        """Mark the link down, close the port, schedule a reopen."""
        self._counters['link_faults'] += 1
        self.last_error = reason
        self._close_port()
        self._next_attempt = time.monotonic() + self._backoff

    def _close_port(self) -> None:
        """Write zero torques (best effort) and close the port if it is open."""
        port, self._serial, self._io = self._serial, None, None
        self._in_flight = None
        self.link_up = False
        if port is None:
            return
        try:
            port.write(self.codec.encode_command(self._next_sequence(), ZERO_COUNTS))
            self._counters['zero_commands'] += 1
        except (OSError, serial.SerialException):
            pass  # the link is already broken; the device zeroes on its own command timeout
        try:
            port.close()
        except (OSError, serial.SerialException):
            pass


class _PyserialIo:
    """A URL port (socket://, loop://): pyserial's read and write."""

    def __init__(self, port: serial.SerialBase) -> None:
        self._port = port

    def write(self, data: bytes) -> None:
        self._port.write(data)

    def read(self, size: int, deadline_ns: int) -> bytes:
        """Return up to the bytes waiting (at least size if they come within READ_SLICE_S)."""
        port = self._port
        data: bytes = port.read(max(size, port.in_waiting))
        return data

    def read_waiting(self) -> bytes:
        """Return the bytes waiting, without waiting for more."""
        waiting = self._port.in_waiting
        return self._port.read(waiting) if waiting else b''


class _DescriptorIo:
    """
    A device file: os.read/os.write on its descriptor, waiting in poll().

    pyserial's own calls cost two extra select()s and its Timeout bookkeeping per cycle.
    """

    def __init__(self, port: serial.Serial) -> None:
        self._fd = port.fileno()
        self._readable = select.poll()
        self._readable.register(self._fd, select.POLLIN)
        self._writable = select.poll()
        self._writable.register(self._fd, select.POLLOUT)

    def write(self, data: bytes) -> None:
        """Write all of data; SerialTimeoutException after WRITE_TIMEOUT_S of a full buffer."""
        deadline = time.monotonic() + WRITE_TIMEOUT_S
        while data:
            try:
                data = data[os.write(self._fd, data):]
            except (BlockingIOError, InterruptedError):
                wait_ms = (deadline - time.monotonic()) * 1e3
                if wait_ms <= 0 or not self._writable.poll(wait_ms):
                    raise serial.SerialTimeoutException('Write timeout') from None

    def read_waiting(self) -> bytes:
        """Return the bytes waiting, without waiting for more."""
        return self.read(0, 0)

    def read(self, _size: int, deadline_ns: int) -> bytes:
        """Return all bytes waiting, or b'' if none came before deadline_ns (perf_counter_ns)."""
        wait_ms = max(0.0, (deadline_ns - time.perf_counter_ns()) / 1e6)
        if not self._readable.poll(wait_ms):
            return b''
        try:
            data = os.read(self._fd, READ_CHUNK)
        except (BlockingIOError, InterruptedError):
            return b''
        if not data:
            raise serial.SerialException('the port reports data but returns none '
                                         '(device disconnected?)')
        return data


def _open_failure(exc: Exception) -> str:
    """Say in a few words why a port did not open (pyserial repeats the path and errno)."""
    text = str(exc)
    if 'lock' in text.lower():
        return 'busy: another program holds its exclusive lock'
    errno = getattr(exc, 'errno', None)
    return os.strerror(errno) if isinstance(errno, int) else text


def _positive(name: str, value: float) -> float:
    """Return value if it is a finite positive number, else raise ValueError naming it."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (
            math.isfinite(value) and value > 0):
        raise ValueError(f'{name} must be a finite positive number, got {value!r}')
    return value


def _axis_values(name: str, values: Iterable[float], valid: Callable[[float], bool],
                 expected: str) -> tuple[float, ...]:
    """Return values as a tuple of AXIS_COUNT floats satisfying valid(); ValueError naming name."""
    try:
        result = tuple(float(value) for value in values)
    except (TypeError, ValueError):
        result = ()
    if len(result) != AXIS_COUNT or not all(valid(value) for value in result):
        raise ValueError(f'{name} must be {AXIS_COUNT} {expected}, got {values!r}')
    return result
