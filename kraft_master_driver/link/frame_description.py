# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
A frame description: the command and reply frames of the link, read from a YAML file.

load_description() reads and checks a file (doc/device-link.md describes its keys); a file that
cannot work is refused with a FrameDescriptionError of one line naming the file, the key and
the fault. The built-in descriptions live in the frames/ directory beside this module.
"""
from dataclasses import dataclass
import os
from pathlib import Path
from typing import Any, Literal

from kraft_master_driver.core.calibration import POT_COUNT, yaml_fault
from kraft_master_driver.link.checksums import (
    Checksum, CHECKSUM_TYPES, CRC_TYPES, make_crc, SUM_TYPES, SUMS)
import yaml

AXIS_COUNT = 5
FRAMES_DIRECTORY = Path(__file__).parent / 'frames'
ByteOrder = Literal['little', 'big']  # what int.to_bytes and int.from_bytes take
BYTE_ORDERS: tuple[ByteOrder, ...] = ('little', 'big')
FIELD_WIDTHS = (1, 2, 4)
POT_BITS = (10, 12, 16)
LENGTH_COUNTS = ('frame', 'following')
# What a status bit can mean to the driver.
STATUS_MEANINGS = ('amplifiers_on', 'amplifiers_off', 'command_clamped', 'corrupt_command',
                   'command_timeout')

_TOP_KEYS = ('name', 'note', 'command', 'reply', 'pots', 'torque')
_FRAME_KEYS = {'command': ('size', 'header', 'sequence', 'length', 'torques', 'checksum'),
               'reply': ('size', 'header', 'sequence', 'length', 'pots', 'status', 'checksum')}
_FIELD_KEYS = ('offset', 'width', 'signed', 'order')
_CHECKSUM_KEYS = ('type', 'offset', 'order', 'covers', 'poly', 'init', 'refin', 'refout',
                  'xorout')


class FrameDescriptionError(ValueError):
    """A frame description that cannot work; the message is one line naming file and key."""


@dataclass(frozen=True)
class Field:
    """An integer field: offset and width in bytes, signedness, byte order."""

    name: str
    offset: int
    width: int
    signed: bool
    order: ByteOrder

    @property
    def end(self) -> int:
        """Return the offset just past the field."""
        return self.offset + self.width

    @property
    def low(self) -> int:
        """Return the smallest value the field holds."""
        return -(1 << (8 * self.width - 1)) if self.signed else 0

    @property
    def high(self) -> int:
        """Return the largest value the field holds."""
        return (1 << (8 * self.width - self.signed)) - 1


@dataclass(frozen=True)
class ChecksumField:
    """The check value: its field, its function and the bytes [start, end) it covers."""

    type: str  # noqa: A003 - the key's name in the file
    field: Field
    function: Checksum
    start: int
    end: int


@dataclass(frozen=True)
class FrameLayout:
    """One frame, command or reply: fixed length, header at offset 0, integer fields."""

    size: int
    header: bytes
    sequence: Field | None
    length: Field | None
    length_value: int  # what the length byte holds
    values: tuple[Field, ...]  # five torques or six pots
    status: Field | None
    status_bits: tuple[tuple[int, str], ...]  # (bit, meaning)
    checksum: ChecksumField | None


@dataclass(frozen=True)
class FrameDescription:
    """Both frames, the pot counts' width and range, the torque scale, sign and clamp."""

    name: str
    source: str
    command: FrameLayout
    reply: FrameLayout
    pot_bits: int
    pot_range: tuple[int, int]
    counts_per_nm: tuple[float, ...]
    torque_sign: tuple[int, ...]
    torque_limit: tuple[int, ...]


def builtin_names() -> list[str]:
    """Return the names of the built-in descriptions (the files in frames/)."""
    return sorted(path.stem for path in FRAMES_DIRECTORY.glob('*.yaml'))


def builtin_path(name: str) -> Path:
    """Return the file of the built-in description called name."""
    return FRAMES_DIRECTORY / f'{name}.yaml'


def load_description(path: str | os.PathLike[str]) -> FrameDescription:
    """Read and check the description in the YAML file at path; FrameDescriptionError if bad."""
    try:
        with open(path, encoding='utf-8') as stream:
            document = yaml.safe_load(stream)
    except OSError as error:
        raise FrameDescriptionError(
            f'frame description {path}: cannot read: {error.strerror}') from None
    except yaml.YAMLError as error:
        raise FrameDescriptionError(
            f'frame description {yaml_fault(path, error)}') from None
    return _Reader(str(path)).description(document)


class _Reader:
    """Checks a parsed document; every fault raises with the file and the key's path."""

    def __init__(self, source: str) -> None:
        self.source = source

    def fail(self, key: str, fault: str) -> FrameDescriptionError:
        return FrameDescriptionError(f'frame description {self.source}: {key}: {fault}')

    def mapping(self, value: Any, key: str, known: tuple[str, ...],
                required: tuple[str, ...] = ()) -> dict[str, Any]:
        if not isinstance(value, dict):
            raise self.fail(key or 'top level', f'must be a mapping, got {value!r}')
        prefix = f'{key}.' if key else ''
        for name in value:
            if name not in known:
                raise self.fail(f'{prefix}{name}', f'unknown key; known: {", ".join(known)}')
        for name in required:
            if name not in value:
                raise self.fail(f'{prefix}{name}', 'missing')
        return value

    def integer(self, value: Any, key: str, low: int, high: int) -> int:
        if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
            raise self.fail(key, f'must be an integer in {low}..{high}, got {value!r}')
        return value

    def choice(self, value: Any, key: str, choices: tuple[Any, ...], what: str) -> Any:
        if value not in choices or isinstance(value, bool) != isinstance(choices[0], bool):
            raise self.fail(key, f'unknown {what} {value!r}; known: '
                                 f'{", ".join(str(choice) for choice in choices)}')
        return value

    def flag(self, value: Any, key: str) -> bool:
        if not isinstance(value, bool):
            raise self.fail(key, f'must be true or false, got {value!r}')
        return value

    def numbers(self, value: Any, key: str, count: int) -> list[Any]:
        if not isinstance(value, list) or len(value) != count:
            raise self.fail(key, f'must be a list of {count} values, got {value!r}')
        return value

    def description(self, document: Any) -> FrameDescription:
        top = self.mapping(document, '', _TOP_KEYS, _TOP_KEYS[:1] + _TOP_KEYS[2:])
        if not isinstance(top['name'], str) or not top['name']:
            raise self.fail('name', f'must be a non-empty string, got {top["name"]!r}')
        pots = self.mapping(top['pots'], 'pots', ('bits', 'range'), ('bits',))
        pot_bits = self.choice(pots['bits'], 'pots.bits', POT_BITS, 'pot count width')
        pot_max = (1 << pot_bits) - 1
        low, high = self.numbers(pots.get('range', [0, pot_max]), 'pots.range', 2)
        pot_range = (self.integer(low, 'pots.range', 0, pot_max),
                     self.integer(high, 'pots.range', 0, pot_max))
        if pot_range[0] >= pot_range[1]:
            raise self.fail('pots.range', f'must rise, got {list(pot_range)}')
        command = self.frame(top['command'], 'command', 'torques', AXIS_COUNT)
        reply = self.frame(top['reply'], 'reply', 'pots', POT_COUNT)
        for field in command.values:
            if not field.signed:
                raise self.fail(field.name, 'torque counts must be signed')
        for field in reply.values:
            if field.high < pot_range[1] or field.low > pot_range[0]:
                raise self.fail(field.name, f'{field.width} byte(s) cannot hold the pot range '
                                            f'{pot_range[0]}..{pot_range[1]}')
        torque = self.mapping(top['torque'], 'torque', ('counts_per_nm', 'sign', 'limit'),
                              ('counts_per_nm', 'sign', 'limit'))
        scale = []
        for axis, value in enumerate(self.numbers(torque['counts_per_nm'],
                                                  'torque.counts_per_nm', AXIS_COUNT)):
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not (
                    0 < value < float('inf')):
                raise self.fail(f'torque.counts_per_nm[{axis}]',
                                f'must be a finite positive number, got {value!r}')
            scale.append(float(value))
        sign = tuple(self.choice(value, f'torque.sign[{axis}]', (1, -1), 'sign')
                     for axis, value in enumerate(
                         self.numbers(torque['sign'], 'torque.sign', AXIS_COUNT)))
        limit = tuple(self.integer(value, f'torque.limit[{axis}]', 1, field.high)
                      for axis, (value, field) in enumerate(zip(
                          self.numbers(torque['limit'], 'torque.limit', AXIS_COUNT),
                          command.values)))
        return FrameDescription(top['name'], self.source, command, reply, pot_bits, pot_range,
                                tuple(scale), sign, limit)

    def frame(self, value: Any, key: str, values_key: str, count: int) -> FrameLayout:
        known = _FRAME_KEYS[key]
        frame = self.mapping(value, key, known, ('size', 'header', values_key))
        size = self.integer(frame['size'], f'{key}.size', 2, 255)
        header = self.header(frame['header'], f'{key}.header')
        sequence = self.optional_field(frame, 'sequence', key, (1, 2))
        length = self.optional_field(frame, 'length', key, (1,), ('counts',))
        length_value = 0
        if length is not None:
            counts = self.choice(frame['length'].get('counts', 'frame'), f'{key}.length.counts',
                                 LENGTH_COUNTS, 'length kind')
            length_value = size if counts == 'frame' else size - length.end
        values = self.value_fields(frame[values_key], f'{key}.{values_key}', count)
        status: Field | None = None
        status_bits: tuple[tuple[int, str], ...] = ()
        if 'status' in frame:
            status = self.field(frame['status'], f'{key}.status', (1, 2), ('bits',))
            status_bits = self.status_bits(frame['status'].get('bits', {}), f'{key}.status.bits',
                                           8 * status.width)
        checksum = self.checksum(frame['checksum'], f'{key}.checksum', size) \
            if 'checksum' in frame else None
        spans = [(0, len(header), f'{key}.header')] + [
            (field.offset, field.end, field.name)
            for field in (sequence, length, *values, status,
                          checksum.field if checksum is not None else None)
            if field is not None]
        for start, end, name in spans:
            if end > size:
                raise self.fail(name, f"bytes {start}..{end - 1} past the frame's end "
                                      f'({key}.size {size})')
        spans.sort()
        for (_, end, name), (start, _, next_name) in zip(spans, spans[1:]):
            if start < end:
                raise self.fail(next_name, f'overlaps {name} at byte {start}')
        if checksum is not None and checksum.start < checksum.field.end and \
                checksum.field.offset < checksum.end:
            raise self.fail(f'{key}.checksum.covers', 'covers the checksum itself')
        return FrameLayout(size, header, sequence, length, length_value, values, status,
                           status_bits, checksum)

    def header(self, value: Any, key: str) -> bytes:
        try:
            header = bytes.fromhex(value)
        except (TypeError, ValueError):
            raise self.fail(key, f"must be hex bytes such as 'AA 43', got {value!r}") from None
        if not header:
            raise self.fail(key, 'must have at least one byte')
        return header

    def field(self, value: Any, key: str, widths: tuple[int, ...],
              extra: tuple[str, ...] = ()) -> Field:
        field = self.mapping(value, key, _FIELD_KEYS + extra, ('offset',))
        return Field(key, self.integer(field['offset'], f'{key}.offset', 0, 254),
                     self.choice(field.get('width', 1), f'{key}.width', widths, 'width'),
                     self.flag(field.get('signed', False), f'{key}.signed'),
                     self.choice(field.get('order', 'little'), f'{key}.order', BYTE_ORDERS,
                                 'byte order'))

    def optional_field(self, frame: dict[str, Any], name: str, key: str,
                       widths: tuple[int, ...], extra: tuple[str, ...] = ()) -> Field | None:
        return self.field(frame[name], f'{key}.{name}', widths, extra) if name in frame else None

    def value_fields(self, value: Any, key: str, count: int) -> tuple[Field, ...]:
        """Return count fields: at offset, offset + width, ... or at each of a list of offsets."""
        mapping = self.mapping(value, key, _FIELD_KEYS, ('offset', 'width'))
        offsets = mapping['offset']
        if isinstance(offsets, list):
            self.numbers(offsets, f'{key}.offset', count)
        else:
            template = self.field(mapping, key, FIELD_WIDTHS)
            offsets = [template.offset + index * template.width for index in range(count)]
        return tuple(self.field({**mapping, 'offset': offset}, f'{key}[{index}]', FIELD_WIDTHS)
                     for index, offset in enumerate(offsets))

    def status_bits(self, value: Any, key: str, bit_count: int) -> tuple[tuple[int, str], ...]:
        if not isinstance(value, dict):
            raise self.fail(key, f'must map bit numbers to meanings, got {value!r}')
        bits = []
        for bit, meaning in value.items():
            self.integer(bit, f'{key}.{bit}', 0, bit_count - 1)
            self.choice(meaning, f'{key}.{bit}', STATUS_MEANINGS, 'status meaning')
            bits.append((bit, meaning))
        meanings = [meaning for _, meaning in bits]
        for meaning in set(meanings):
            if meanings.count(meaning) > 1:
                raise self.fail(key, f'{meaning} is given to more than one bit')
        if {'amplifiers_on', 'amplifiers_off'} <= set(meanings):
            raise self.fail(key, 'amplifiers_on and amplifiers_off exclude each other')
        return tuple(sorted(bits))

    def checksum(self, value: Any, key: str, size: int) -> ChecksumField | None:
        mapping = self.mapping(value, key, _CHECKSUM_KEYS, ('type',))
        kind = self.choice(mapping['type'], f'{key}.type', CHECKSUM_TYPES, 'checksum')
        if kind == 'none':
            return None
        width_bits = CRC_TYPES.get(kind) or SUM_TYPES[kind]
        if 'offset' not in mapping:
            raise self.fail(f'{key}.offset', 'missing')
        field = Field(key, self.integer(mapping['offset'], f'{key}.offset', 1, 254),
                      width_bits // 8, False,
                      self.choice(mapping.get('order', 'little'), f'{key}.order', BYTE_ORDERS,
                                  'byte order'))
        start, end = self.numbers(mapping.get('covers', [0, field.offset]), f'{key}.covers', 2)
        start = self.integer(start, f'{key}.covers', 0, size - 1)
        end = self.integer(end, f'{key}.covers', start + 1, size)
        crc_keys = _CHECKSUM_KEYS[4:]
        if kind in CRC_TYPES:
            mask = (1 << width_bits) - 1
            if 'poly' not in mapping:
                raise self.fail(f'{key}.poly', 'missing')
            poly = self.integer(mapping['poly'], f'{key}.poly', 1, mask)
            init = self.integer(mapping.get('init', 0), f'{key}.init', 0, mask)
            refin = self.flag(mapping.get('refin', False), f'{key}.refin')
            refout = self.flag(mapping.get('refout', refin), f'{key}.refout')
            xorout = self.integer(mapping.get('xorout', 0), f'{key}.xorout', 0, mask)
            function = make_crc(width_bits, poly, init, refin, refout, xorout)
        else:
            for name in crc_keys:
                if name in mapping:
                    raise self.fail(f'{key}.{name}', f'a parameter of a CRC, not of {kind}')
            function = SUMS[kind]
        return ChecksumField(kind, field, function, start, end)
