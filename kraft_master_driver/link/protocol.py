# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Frame codecs of the host <-> KMC 9100 link.

The real KMC 9100 frame format is not public. The default codec, 'kraft-default', is this
project's own framing, used by the driver and by the built-in simulator (all multi-byte fields
little-endian, CRC-16/CCITT-FALSE = binascii.crc_hqx(bytes, 0xFFFF) over every byte before it):

    command, host -> device, 15 bytes: 0xAA 0x43 ('C'), sequence (uint8),
        five int16 torque counts (axes 1..5), CRC (uint16)
    reply, device -> host, 18 bytes: 0xAA 0x50 ('P'), sequence echoed (uint8),
        six uint16 pot counts POT1..POT6 (0..4095), status bits (uint8), CRC (uint16)

A user with the real Kraft manual adds a Codec subclass, registers it in CODECS and selects it
by name; nothing else in the driver sees bytes. Nothing here raises on bad received bytes:
the decoders count each kind of error and resynchronise.
"""
import abc
import binascii
from collections.abc import Callable, Sequence
import struct
from typing import Generic, NamedTuple, TypeVar

from kraft_master_driver.core.calibration import POT_COUNT, POT_MAX

AXIS_COUNT = 5
INT16_MAX = 32767

# Defaults shared by the device and the simulator. The real KMC scale is unknown: a parameter.
DEFAULT_TORQUE_SCALE = (1000.0,) * AXIS_COUNT  # command counts per N*m, axes 1..5
DEFAULT_TORQUE_LIMIT = (3000,) * AXIS_COUNT  # counts, i.e. 3 N*m at the default scale

# Reply status bits.
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
CRC_INIT = 0xFFFF


class PotFrame(NamedTuple):
    """A decoded reply: the echoed sequence number, pots POT1..POT6 (counts), status bits."""

    sequence: int
    pots: tuple[int, ...]
    status: int


class TorqueCommand(NamedTuple):
    """A decoded command: sequence number and five torque counts (axes 1..5)."""

    sequence: int
    counts: tuple[int, ...]


# What a FrameDecoder yields: PotFrame on the host side, TorqueCommand on the device side.
Frame = TypeVar('Frame', PotFrame, TorqueCommand)


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
                 parse: Callable[[bytes | bytearray, int], Frame | str]) -> None:
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
        self._parse: Callable[[bytes | bytearray, int], Frame | str] = parse
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

    @abc.abstractmethod
    def encode_command(self, sequence: int, counts: Sequence[int]) -> bytes:
        """Return the command frame for sequence (0..255) and five int16 torque counts."""

    @abc.abstractmethod
    def encode_reply(self, sequence: int, pots: Sequence[int], status: int) -> bytes:
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


class KraftDefaultCodec(Codec):
    """This project's own framing (see the module docstring); not Kraft's."""

    name = 'kraft-default'
    COMMAND_HEADER = b'\xaaC'
    REPLY_HEADER = b'\xaaP'
    _command_body = struct.Struct('<2sB5h')
    _reply_body = struct.Struct('<2sB6HB')
    _crc = struct.Struct('<H')
    _command = struct.Struct('<2sB5hH')
    _reply = struct.Struct('<2sB6HBH')
    command_size = _command.size
    reply_size = _reply.size

    def encode_command(self, sequence: int, counts: Sequence[int]) -> bytes:
        """Return the 15-byte command frame; ValueError if a field is out of range."""
        try:
            body = self._command_body.pack(self.COMMAND_HEADER, sequence, *counts)
        except struct.error as exc:
            raise ValueError(f'bad torque command: sequence {sequence!r} (0..255), '
                             f'counts {counts!r} (5 ints in -32768..32767): {exc}') from None
        return body + self._crc.pack(binascii.crc_hqx(body, CRC_INIT))

    def encode_reply(self, sequence: int, pots: Sequence[int], status: int) -> bytes:
        """Return the 18-byte reply frame; ValueError if a field is out of range."""
        try:
            body = self._reply_body.pack(self.REPLY_HEADER, sequence, *pots, status)
        except struct.error as exc:
            raise ValueError(f'bad pot reply: sequence {sequence!r} (0..255), pots {pots!r} '
                             f'(6 ints in 0..65535), status {status!r} (0..255): {exc}') from None
        return body + self._crc.pack(binascii.crc_hqx(body, CRC_INIT))

    def reply_decoder(self) -> FrameDecoder[PotFrame]:
        """Return a new FrameDecoder yielding PotFrame."""
        return FrameDecoder(self.REPLY_HEADER, self.reply_size, self._parse_reply)

    def command_decoder(self) -> FrameDecoder[TorqueCommand]:
        """Return a new FrameDecoder yielding TorqueCommand."""
        return FrameDecoder(self.COMMAND_HEADER, self.command_size, self._parse_command)

    def _parse_reply(self, buffer: bytes | bytearray, offset: int) -> PotFrame | str:
        """Return the PotFrame at offset, BAD_CRC or OUT_OF_RANGE."""
        fields = self._reply.unpack_from(buffer, offset)
        body_end = offset + self.reply_size - self._crc.size
        if binascii.crc_hqx(buffer[offset:body_end], CRC_INIT) != fields[-1]:
            return BAD_CRC
        pots = fields[2:2 + POT_COUNT]
        if max(pots) > POT_MAX:
            return OUT_OF_RANGE
        return PotFrame(fields[1], pots, fields[-2])

    def _parse_command(self, buffer: bytes | bytearray, offset: int) -> TorqueCommand | str:
        """Return the TorqueCommand at offset or BAD_CRC."""
        fields = self._command.unpack_from(buffer, offset)
        body_end = offset + self.command_size - self._crc.size
        if binascii.crc_hqx(buffer[offset:body_end], CRC_INIT) != fields[-1]:
            return BAD_CRC
        return TorqueCommand(fields[1], fields[2:2 + AXIS_COUNT])


CODECS: dict[str, type[Codec]] = {KraftDefaultCodec.name: KraftDefaultCodec}


def get_codec(name: str) -> Codec:
    """Return a new instance of the codec registered under name; ValueError if unknown."""
    try:
        return CODECS[name]()
    except (KeyError, TypeError):
        raise ValueError(f'unknown codec {name!r}; known codecs: '
                         f'{", ".join(sorted(CODECS))}') from None
