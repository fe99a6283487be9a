# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Frame codecs of the host <-> KMC 9100 link.

The real KMC 9100 frame format is not public. A FrameCodec encodes and decodes the frames a
frame description gives (frame_description.py, a YAML file); get_codec() takes the name of a
built-in description or the path of a file. The default, 'kraft-default', is this project's own
framing, used by the driver and by the built-in simulator (all multi-byte fields little-endian,
CRC-16/CCITT-FALSE = binascii.crc_hqx(bytes, 0xFFFF) over every byte before it):

    command, host -> device, 15 bytes: 0xAA 0x43 ('C'), sequence (uint8),
        five int16 torque counts (axes 1..5), CRC (uint16)
    reply, device -> host, 18 bytes: 0xAA 0x50 ('P'), sequence echoed (uint8),
        six uint16 pot counts POT1..POT6 (0..4095), status bits (uint8), CRC (uint16)

A user with the real Kraft manual writes a description file, or for a frame no description can
express adds a Codec subclass to CODECS; nothing else in the driver sees bytes. Nothing here
raises on bad received bytes: the decoders count each kind of error and resynchronise.
"""
import abc
from collections.abc import Callable, Sequence
import operator
import os
import struct
from typing import Any, Generic, NamedTuple, Protocol, TypeVar

from kraft_master_driver.link.frame_description import (
    builtin_names, builtin_path, ByteOrder, Field, FrameDescription, FrameLayout,
    load_description)

AXIS_COUNT = 5
INT16_MAX = 32767

# The default description's torque scale and clamp (the real KMC scale is unknown).
DEFAULT_TORQUE_SCALE = (1000.0,) * AXIS_COUNT  # command counts per N*m, axes 1..5
DEFAULT_TORQUE_LIMIT = (3000,) * AXIS_COUNT  # counts, i.e. 3 N*m at the default scale

# Reply status bits, as every codec reports them whatever bits its frame uses.
STATUS_AMPLIFIERS_ENABLED = 0x01  # torques applied
STATUS_COMMAND_CLAMPED = 0x02  # a command was clamped
STATUS_CORRUPT_COMMAND = 0x04  # a corrupt command was received since the last reply
STATUS_COMMAND_TIMEOUT = 0x08  # the device zeroed its torques since the last reply

# Error kinds counted by every FrameDecoder.
BAD_CRC = 'bad_crc'
GARBAGE_BYTES = 'garbage_bytes'
TRUNCATED = 'truncated'
OUT_OF_RANGE = 'out_of_range'
ERROR_KINDS = (BAD_CRC, GARBAGE_BYTES, TRUNCATED, OUT_OF_RANGE)

BITS_PER_BYTE_8N1 = 10
DEFAULT_CODEC = 'kraft-default'


class PotFrame(NamedTuple):
    """A decoded reply: the echoed sequence number (None: the frame has none), pots, status."""

    sequence: int | None
    pots: tuple[int, ...]
    status: int


class TorqueCommand(NamedTuple):
    """A decoded command: sequence number (None: the frame has none), five torque counts."""

    sequence: int | None
    counts: tuple[int, ...]


# What a FrameDecoder yields: PotFrame on the host side, TorqueCommand on the device side.
Frame = TypeVar('Frame', PotFrame, TorqueCommand)
# parse(buffer, offset): the frame at buffer[offset:], or the error kind BAD_CRC or OUT_OF_RANGE.
FrameParser = Callable[[bytes | bytearray, int], Frame | str]


class FrameDecoder(Generic[Frame]):
    """
    Incremental decoder of fixed-length frames that start with a header byte sequence.

    feed() takes byte chunks of any size and returns the frames completed so far. On a frame
    that fails its check the decoder skips only the first header byte and searches again, so a
    real frame starting inside the bad one is recovered. Every byte fed ends up in exactly one
    of: a decoded frame, an out-of-range frame (frame_size bytes each), garbage_bytes, or
    pending (fewer than frame_size bytes kept for the next feed: the buffer is bounded).
    """

    def __init__(self, header: bytes, frame_size: int,
                 parse: FrameParser[Frame]) -> None:
        """
        Decode frames of frame_size bytes starting with header (bytes).

        parse(buffer, offset) returns the frame at buffer[offset:offset + frame_size], or
        BAD_CRC when its check fails, or OUT_OF_RANGE when it is intact but carries values
        outside their range (the frame is then dropped whole).
        """
        if not header or frame_size <= len(header):
            raise ValueError('header must be non-empty and shorter than frame_size')
        self._header = bytes(header)
        self._size = frame_size
        self._parse: FrameParser[Frame] = parse
        self._buffer = bytearray()
        self.frames_decoded = 0
        self.errors = dict.fromkeys(ERROR_KINDS, 0)

    @property
    def frame_size(self) -> int:
        """Return the length of one frame in bytes."""
        return self._size

    @property
    def pending(self) -> int:
        """Return the number of bytes held for the next feed (always less than frame_size)."""
        return len(self._buffer)

    def feed(self, data: bytes | bytearray) -> list[Frame]:
        """Append received bytes (bytes or bytearray); return the list of frames they complete."""
        size = self._size
        buffer = self._buffer
        if not buffer and len(data) == size and data.startswith(self._header):
            # Common case: exactly one frame arrived in one read.
            frame = self._parse(data, 0)
            if frame is not BAD_CRC and frame is not OUT_OF_RANGE:
                self.frames_decoded += 1
                return [frame]  # type: ignore[list-item]  # `is` cleared both error strings
        buffer += data
        header = self._header
        errors = self.errors
        end = len(buffer)
        frames: list[Frame] = []
        pos = 0
        while True:
            start = buffer.find(header, pos)
            if start < 0:
                keep = end - self._header_prefix_length(pos)
                errors[GARBAGE_BYTES] += keep - pos
                pos = keep
                break
            errors[GARBAGE_BYTES] += start - pos
            pos = start
            if end - start < size:
                break
            frame = self._parse(buffer, start)
            if frame is BAD_CRC:
                # A header inside the bad frame: most likely it was cut short by the next one.
                cut = buffer.find(header, start + 1, start + size) >= 0
                errors[TRUNCATED if cut else BAD_CRC] += 1
                errors[GARBAGE_BYTES] += 1
                pos = start + 1
            elif frame is OUT_OF_RANGE:
                errors[OUT_OF_RANGE] += 1
                pos = start + size
            else:
                frames.append(frame)  # type: ignore[arg-type]  # `is` cleared both error strings
                pos = start + size
        del buffer[:pos]
        self.frames_decoded += len(frames)
        return frames

    def _header_prefix_length(self, pos: int) -> int:
        """Return the length of the longest tail of buffer[pos:] that could begin a header."""
        buffer = self._buffer
        for length in range(min(len(self._header) - 1, len(buffer) - pos), 0, -1):
            if buffer.endswith(self._header[:length]):
                return length
        return 0

    def reset(self) -> None:
        """Drop the pending bytes (a partial frame counts as truncated); keep the counters."""
        if self._buffer.startswith(self._header):
            self.errors[TRUNCATED] += 1
        self.errors[GARBAGE_BYTES] += len(self._buffer)
        self._buffer.clear()


class Codec(abc.ABC):
    """The byte format of the link: encode commands and replies, make decoders for both."""

    name = ''
    command_size = 0
    reply_size = 0
    has_sequence = True  # False: replies carry no sequence number to match with commands
    status_mask = 0xFF  # the status bits (STATUS_*, and above) a reply can carry
    torque_scale = DEFAULT_TORQUE_SCALE  # the device's command counts per N*m, axes 1..5
    torque_limit = DEFAULT_TORQUE_LIMIT  # the device's clamp, counts
    count_limit = INT16_MAX  # the largest torque count the command frame holds
    pot_range = (0, 4095)  # the pot counts a reply can carry

    @abc.abstractmethod
    def encode_command(self, sequence: int, counts: Sequence[int]) -> bytes:
        """Return the command frame for sequence (0..255) and five int16 torque counts."""

    @abc.abstractmethod
    def encode_reply(self, sequence: int | None, pots: Sequence[int], status: int) -> bytes:
        """Return the reply frame for sequence (0..255), six pot counts and status bits."""

    @abc.abstractmethod
    def reply_decoder(self) -> FrameDecoder[PotFrame]:
        """Return a new FrameDecoder for the host side, yielding PotFrame."""

    @abc.abstractmethod
    def command_decoder(self) -> FrameDecoder[TorqueCommand]:
        """Return a new FrameDecoder for the device side, yielding TorqueCommand."""

    def wire_cycle_time(self, baud: float) -> float:
        """Return the seconds one command plus one reply take on the wire at 8N1."""
        if not baud > 0:
            raise ValueError(f'baud must be positive, got {baud!r}')
        return (self.command_size + self.reply_size) * BITS_PER_BYTE_8N1 / baud


_FORMATS = {(1, False): 'B', (1, True): 'b', (2, False): 'H', (2, True): 'h', (4, False): 'I',
            (4, True): 'i'}
_STATUS_BITS = {'amplifiers_on': STATUS_AMPLIFIERS_ENABLED,
                'amplifiers_off': STATUS_AMPLIFIERS_ENABLED,
                'command_clamped': STATUS_COMMAND_CLAMPED,
                'corrupt_command': STATUS_CORRUPT_COMMAND,
                'command_timeout': STATUS_COMMAND_TIMEOUT}
_DRIVER_STATUS_BITS = 4  # bits 0..3 of a decoded status are the STATUS_* meanings

_T = TypeVar('_T')
# What a frame's struct runs unpack, in offset order: the header's bytes, then the fields' ints.
# struct's own type: the format string, not the type system, decides each item's type.
_Fields = tuple[Any, ...]
# check(buffer, offset, fields): True if the frame's checksum and length byte hold.
_Check = Callable[[bytes | bytearray, int, _Fields], bool]


class _Picker(Protocol):
    """pick(items): the items at some fixed indices of a sequence, always as a tuple."""

    def __call__(self, items: Sequence[_T], /) -> tuple[_T, ...]:
        """Return the items at the indices, in the indices' order."""


def _picker(indices: Sequence[int]) -> _Picker:
    """Return a function that takes the items at indices of a sequence, always as a tuple."""
    if len(indices) == 1:
        index = indices[0]

        def pick_one(items: Sequence[_T], /) -> tuple[_T, ...]:
            return (items[index],)
        return pick_one
    return operator.itemgetter(*indices)


class _Packing:
    """
    A frame layout as struct runs, compiled once: all its fields in one or few struct calls.

    The fields are taken in slot order: header, sequence, length, the values, status,
    checksum (those the frame has). pack() takes their values in that order; unpack() returns
    the values in offset order and slot_index[slot] says where each slot's value is.
    """

    def __init__(self, layout: FrameLayout) -> None:
        header = Field('header', 0, len(layout.header), False, 'little')
        checksum = layout.checksum.field if layout.checksum else None
        slots = [field for field in (header, layout.sequence, layout.length, *layout.values,
                                     layout.status, checksum) if field is not None]
        by_offset = sorted(range(len(slots)), key=lambda slot: slots[slot].offset)
        self.slot_index = [by_offset.index(slot) for slot in range(len(slots))]
        runs: list[tuple[int, ByteOrder | None, list[int]]] = []  # (start, byte order, slots)
        for slot in by_offset:
            field = slots[slot]
            order = field.order if field.width > 1 and field is not header else None
            if runs and (order is None or runs[-1][1] in (None, order)):
                start, run_order, members = runs[-1]
                runs[-1] = (start, run_order or order, members + [slot])
            else:
                runs.append((field.offset, order, [slot]))
        self.runs: list[tuple[int, struct.Struct, _Picker]] = []  # (start, struct, pick)
        for number, (start, order, members) in enumerate(runs):
            codes, position = ['<' if order != 'big' else '>'], start
            for slot in members:
                field = slots[slot]
                codes.append('x' * (field.offset - position))
                codes.append(f'{field.width}s' if field is header
                             else _FORMATS[field.width, field.signed])
                position = field.end
            if number == len(runs) - 1:
                codes.append('x' * (layout.size - position))
            self.runs.append((start, struct.Struct(''.join(codes)), _picker(members)))
        self.unpack: Callable[[bytes | bytearray, int], _Fields]
        if len(self.runs) == 1:
            start, single, _ = self.runs[0]
            self.unpack = lambda buffer, offset: single.unpack_from(buffer, offset + start)
        else:
            self.unpack = self._unpack_runs
        self.size = layout.size

    def pack(self, values: Sequence[object]) -> bytearray:
        """Return the frame holding values (in slot order); struct.error if one does not fit."""
        if len(self.runs) == 1:  # it starts at the header, offset 0
            _, single, pick = self.runs[0]
            return bytearray(single.pack(*pick(values)))
        frame = bytearray(self.size)
        for start, run, pick in self.runs:
            run.pack_into(frame, start, *pick(values))
        return frame

    def _unpack_runs(self, buffer: bytes | bytearray, offset: int) -> _Fields:
        values: _Fields = ()
        for start, run, _ in self.runs:
            values += run.unpack_from(buffer, offset + start)
        return values


class FrameCodec(Codec):
    """The codec of a frame description (frame_description.py), compiled at construction."""

    def __init__(self, description: FrameDescription) -> None:
        """Compile the description's frames into struct runs and lookup tables."""
        self.description = description
        self.name = description.name
        command, reply = description.command, description.reply
        self.command_size, self.reply_size = command.size, reply.size
        self.has_sequence = reply.sequence is not None
        self.torque_scale = description.counts_per_nm
        self.torque_limit = description.torque_limit
        self.count_limit = min(field.high for field in command.values)
        self.pot_range = description.pot_range
        self._command = command
        self._reply = reply
        self._command_packing = _Packing(command)
        self._reply_packing = _Packing(reply)
        self._sign = None if set(description.torque_sign) == {1} else description.torque_sign
        self._status_to_driver, self._status_from_driver, self.status_mask = _status_tables(reply)

    def encode_command(self, sequence: int, counts: Sequence[int]) -> bytes:
        """Return the command frame; ValueError if a field is out of range."""
        try:
            if len(counts) != len(self._command.values):
                raise struct.error(f'{len(counts)} counts')
            wire_counts = tuple(map(operator.mul, counts, self._sign)) if self._sign else counts
            return self._encode(self._command, self._command_packing, sequence, wire_counts,
                                None)
        except (struct.error, TypeError) as exc:
            field = self._command.values[0]
            raise ValueError(f'bad torque command: sequence {sequence!r} (0..255), '
                             f'counts {counts!r} (5 ints in {field.low}..{field.high}): '
                             f'{exc}') from None

    def encode_reply(self, sequence: int | None, pots: Sequence[int], status: int) -> bytes:
        """Return the reply frame; ValueError if a field is out of range."""
        try:
            if len(pots) != len(self._reply.values):
                raise struct.error(f'{len(pots)} pots')
            if not 0 <= status < len(self._status_from_driver):
                raise struct.error(f'status {status} does not fit the frame')
            return self._encode(self._reply, self._reply_packing, sequence, pots,
                                self._status_from_driver[status])
        except (struct.error, TypeError) as exc:
            field = self._reply.values[0]
            raise ValueError(f'bad pot reply: sequence {sequence!r} (0..255), pots {pots!r} '
                             f'(6 ints in {field.low}..{field.high}), status {status!r} '
                             f'(0..{len(self._status_from_driver) - 1}): {exc}') from None

    def _encode(self, layout: FrameLayout, packing: _Packing, sequence: int | None,
                values: Sequence[int], status: int | None) -> bytes:
        slots: list[object] = [layout.header]
        if layout.sequence is not None:
            slots.append(sequence)
        if layout.length is not None:
            slots.append(layout.length_value)
        slots += values
        if layout.status is not None:
            slots.append(status)
        checksum = layout.checksum
        if checksum is None:
            return bytes(packing.pack(slots))
        slots.append(0)
        frame = packing.pack(slots)
        field = checksum.field
        value = checksum.function(frame[checksum.start:checksum.end])
        frame[field.offset:field.end] = value.to_bytes(field.width, field.order)
        return bytes(frame)

    def reply_decoder(self) -> FrameDecoder[PotFrame]:
        """Return a new FrameDecoder yielding PotFrame."""
        return FrameDecoder(self._reply.header, self.reply_size, self._reply_parser())

    def command_decoder(self) -> FrameDecoder[TorqueCommand]:
        """Return a new FrameDecoder yielding TorqueCommand."""
        return FrameDecoder(self._command.header, self.command_size, self._command_parser())

    def _checker(self, layout: FrameLayout, index: list[int]) -> _Check:
        """Return check(buffer, offset, fields): True if the frame's checksum and length hold."""
        checksum, length = layout.checksum, layout.length
        last = len(index) - 1
        length_index = index[1 + (layout.sequence is not None)] if length else 0
        length_value = layout.length_value
        if checksum is None:
            return lambda buffer, offset, fields: (
                length is None or fields[length_index] == length_value)
        function, start, end, checksum_index = (
            checksum.function, checksum.start, checksum.end, index[last])

        def check(buffer: bytes | bytearray, offset: int, fields: _Fields) -> bool:
            return function(buffer[offset + start:offset + end]) == fields[checksum_index] and (
                length is None or fields[length_index] == length_value)
        return check

    def _reply_parser(self) -> FrameParser[PotFrame]:
        """Return parse(buffer, offset): the PotFrame there, BAD_CRC or OUT_OF_RANGE."""
        layout, packing = self._reply, self._reply_packing
        index = packing.slot_index
        unpack, check = packing.unpack, self._checker(layout, index)
        first = 1 + (layout.sequence is not None) + (layout.length is not None)
        # The value fields' struct codes are integer codes: what they unpack is int.
        pots_of: Callable[[_Fields], tuple[int, ...]] = _picker(
            index[first:first + len(layout.values)])
        sequence_index = index[1] if layout.sequence is not None else None
        status_index = index[first + len(layout.values)] if layout.status is not None else None
        to_driver = self._status_to_driver
        low, high = self.pot_range

        def parse(buffer: bytes | bytearray, offset: int) -> PotFrame | str:
            fields = unpack(buffer, offset)
            if not check(buffer, offset, fields):
                return BAD_CRC
            pots = pots_of(fields)
            if max(pots) > high or min(pots) < low:
                return OUT_OF_RANGE
            return PotFrame(
                None if sequence_index is None else fields[sequence_index], pots,
                0 if status_index is None else to_driver[fields[status_index]])
        return parse

    def _command_parser(self) -> FrameParser[TorqueCommand]:
        """Return parse(buffer, offset): the TorqueCommand there or BAD_CRC."""
        layout, packing = self._command, self._command_packing
        index = packing.slot_index
        unpack, check = packing.unpack, self._checker(layout, index)
        first = 1 + (layout.sequence is not None) + (layout.length is not None)
        counts_of: Callable[[_Fields], tuple[int, ...]] = _picker(
            index[first:first + len(layout.values)])
        sequence_index = index[1] if layout.sequence is not None else None
        sign = self._sign

        def parse(buffer: bytes | bytearray, offset: int) -> TorqueCommand | str:
            fields = unpack(buffer, offset)
            if not check(buffer, offset, fields):
                return BAD_CRC
            counts = counts_of(fields)
            return TorqueCommand(
                None if sequence_index is None else fields[sequence_index],
                tuple(map(operator.mul, counts, sign)) if sign else counts)
        return parse


def _status_tables(layout: FrameLayout) -> tuple[tuple[int, ...], tuple[int, ...], int]:
    """
    Return (raw status -> driver status, driver status -> raw status, the driver bits carried).

    Bits 0..3 of the driver's status are its STATUS_* meanings; raw bits from 4 up that the
    description names no meaning for pass through unchanged both ways (the driver ignores them).
    """
    if layout.status is None:
        return (0,), (0,), 0
    bit_count = 8 * layout.status.width
    named = {bit for bit, _ in layout.status_bits}
    passed = sum(1 << bit for bit in range(_DRIVER_STATUS_BITS, bit_count) if bit not in named)
    carried = passed | sum(_STATUS_BITS[meaning] for _, meaning in layout.status_bits)

    def to_driver(raw: int) -> int:
        status = raw & passed
        for bit, meaning in layout.status_bits:
            if bool(raw >> bit & 1) != (meaning == 'amplifiers_off'):
                status |= _STATUS_BITS[meaning]
        return status

    def from_driver(status: int) -> int:
        raw = status & passed
        for bit, meaning in layout.status_bits:
            if bool(status & _STATUS_BITS[meaning]) != (meaning == 'amplifiers_off'):
                raw |= 1 << bit
        return raw
    driver_range = max(1 << bit_count, 1 << _DRIVER_STATUS_BITS)
    return (tuple(to_driver(raw) for raw in range(1 << bit_count)),
            tuple(from_driver(status) for status in range(driver_range)), carried)


class KraftDefaultCodec(FrameCodec):
    """This project's own framing, the built-in description 'kraft-default'; not Kraft's."""

    def __init__(self) -> None:
        """Load the built-in description."""
        super().__init__(load_description(builtin_path(DEFAULT_CODEC)))


def _builtin_codec(name: str) -> Callable[[], Codec]:
    """Return a function that makes a new FrameCodec of the built-in description called name."""
    def make() -> Codec:
        return FrameCodec(load_description(builtin_path(name)))
    return make


CODECS: dict[str, Callable[[], Codec]] = {
    name: KraftDefaultCodec if name == DEFAULT_CODEC else _builtin_codec(name)
    for name in builtin_names()}


def get_codec(name: 'str | Codec') -> Codec:
    """
    Return a new codec: a name in CODECS, or the path of a frame description file.

    A Codec given is returned as it is.

    ValueError if the name is unknown; FrameDescriptionError (a ValueError of one line naming
    the file, the key and the fault) if the file cannot be read or cannot work.
    """
    if isinstance(name, Codec):
        return name
    if isinstance(name, str) and name in CODECS:
        return CODECS[name]()
    if isinstance(name, str) and (name.endswith(('.yaml', '.yml')) or os.sep in name):
        return FrameCodec(load_description(name))
    raise ValueError(f'unknown codec {name!r}; known codecs: {", ".join(sorted(CODECS))}, '
                     'or the path of a frame description (.yaml)')
