# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Raw CDR messages decoded into numpy arrays, a topic at a time (TopicData).

Equal-length messages are stacked into (N, length) byte arrays, and the fixed-layout CDR of
JointState, PoseStamped, WrenchStamped, TwistStamped and Vector3Stamped is decoded with numpy,
equal to rosbags' deserialisation message by message. Other types (DiagnosticArray) are
deserialised one by one with rosbags. Malformed messages are counted and skipped, never raised.
"""
from collections.abc import Sequence
import struct
from typing import Any, Literal, NamedTuple

from kraft_master_driver.bag.common import (
    JOINT_STATE, POSE_STAMPED, TWIST_STAMPED, typestore, VECTOR3_STAMPED, WRENCH_STAMPED)
import numpy as np
from numpy.typing import ArrayLike, DTypeLike, NDArray
from rosbags.serde import SerdeError

# Fixed-layout message types: (field, kind) in CDR order. Kinds: 'time' (int32 sec, uint32
# nanosec), 'string', 'strings' (sequence of strings), 'doubles' (sequence of float64), or
# an int n for n consecutive float64 (nested structs of doubles only).
_Kind = Literal['time', 'string', 'strings', 'doubles'] | int
_Fields = tuple[tuple[str, _Kind], ...]
# The decoded arrays of a fixed-layout topic: 'stamp' in int64 ns, the rest float64.
_Arrays = dict[str, NDArray[np.int64] | NDArray[np.float64]]
# The strings of a fixed-layout message: frame_id, and name (a sequence of strings).
_Strings = dict[str, str | list[str]]
_HEADER: _Fields = (('stamp', 'time'), ('frame_id', 'string'))
LAYOUTS: dict[str, _Fields] = {
    JOINT_STATE: _HEADER + (('name', 'strings'), ('position', 'doubles'),
                            ('velocity', 'doubles'), ('effort', 'doubles')),
    POSE_STAMPED: _HEADER + (('position', 3), ('orientation', 4)),
    WRENCH_STAMPED: _HEADER + (('force', 3), ('torque', 3)),
    TWIST_STAMPED: _HEADER + (('linear', 3), ('angular', 3)),
    VECTOR3_STAMPED: _HEADER + (('vector', 3),),
}


class _Malformed(Exception):
    """A message that does not parse as its type."""


class _Layout(NamedTuple):
    little: bool
    stamp: int  # offset of the stamp
    doubles: dict[str, tuple[int, int]]  # field -> (offset, count)
    strings: _Strings  # field -> the message's str or list of str
    structure: NDArray[np.int64]  # offsets of the bytes that fix the layout (header, lengths)


def _layout(data: bytes, fields: _Fields) -> _Layout:
    """Return the _Layout of one message `data` (bytes); raise _Malformed."""
    size = len(data)
    if size < 4 or data[0] != 0 or data[1] not in (0, 1):
        raise _Malformed('not a plain CDR encapsulation')
    little = data[1] == 1
    uint32 = struct.Struct('<I' if little else '>I').unpack_from
    structure = [0, 1, 2, 3]
    doubles: dict[str, tuple[int, int]] = {}
    strings: _Strings = {}
    position = stamp = 4

    def align(position: int, alignment: int) -> int:
        # CDR aligns relative to the end of the 4-byte encapsulation header.
        return 4 + ((position - 4 + alignment - 1) & -alignment)

    def read_count(position: int) -> tuple[int, int]:
        position = align(position, 4)
        if position + 4 > size:
            raise _Malformed('truncated')
        structure.extend(range(position, position + 4))
        return uint32(data, position)[0], position + 4

    def read_string(position: int) -> tuple[str, int]:
        length, position = read_count(position)
        end = position + length
        if length < 1 or end > size or data[end - 1] != 0:
            raise _Malformed('bad string')
        try:
            return data[position:end - 1].decode(), end
        except UnicodeDecodeError:
            raise _Malformed('string not UTF-8') from None

    for name, kind in fields:
        if kind == 'time':
            stamp = position = align(position, 4)
            position += 8
        elif kind == 'string':
            strings[name], position = read_string(position)
        elif kind == 'strings':
            count, position = read_count(position)
            if count > size:
                raise _Malformed('bad sequence length')
            names: list[str] = []
            strings[name] = names
            for _ in range(count):
                value, position = read_string(position)
                names.append(value)
        else:
            count, position = read_count(position) if kind == 'doubles' else (kind, position)
            if count:
                position = align(position, 8)
            doubles[name] = (position, count)
            position += 8 * count
        if position > size:
            raise _Malformed('truncated')
    return _Layout(little, stamp, doubles, strings, np.array(structure))


def _view(block: NDArray[np.uint8], fields: dict[str, tuple[DTypeLike, int]]) -> NDArray[Any]:
    """View the rows of `block` (N, length) uint8 as records: {name: (dtype, offset)}."""
    dtype = np.dtype({'names': list(fields), 'formats': [f for f, _ in fields.values()],
                      'offsets': [offset for _, offset in fields.values()],
                      'itemsize': block.shape[1]})
    return block.view(dtype)[:, 0]


def _same_structure(block: NDArray[np.uint8], layout: _Layout) -> NDArray[np.bool_]:
    """Return which rows of `block` have the first row's layout (header and lengths)."""
    words = _view(block, {f'w{i}': ('<u4', start)
                          for i, start in enumerate(layout.structure[::4].tolist())})
    same = np.ones(len(block), bool)
    for name in words.dtype.names:  # type: ignore[union-attr]  # a record dtype has names
        same &= words[name] == words[name][0]
    return same


def _decode_rows(block: NDArray[np.uint8], layout: _Layout) -> _Arrays:
    """Decode the rows of `block` (N, length) uint8 that all have `layout`."""
    order = '<' if layout.little else '>'
    fields: dict[str, tuple[DTypeLike, int]] = {
        'sec': (order + 'i4', layout.stamp), 'nanosec': (order + 'u4', layout.stamp + 4)}
    fields.update({name: ((order + 'f8', (count,)), offset)
                   for name, (offset, count) in layout.doubles.items() if count})
    records = _view(block, fields)
    decoded: _Arrays = {
        'stamp': records['sec'].astype(np.int64) * 1_000_000_000 + records['nanosec']}
    for name, (_, count) in layout.doubles.items():
        decoded[name] = (records[name].astype(np.float64) if count else
                         np.empty((len(block), 0)))
    return decoded


class TopicData(NamedTuple):
    """One topic read from a bag, in receive order."""

    topic: str
    msgtype: str
    log_time: NDArray[np.int64]  # (N,) int64 ns: when the recorder received each message
    fields: _Arrays  # fixed layouts: 'stamp' (N,) int64 ns and each float64 field (N, count)
    strings: _Strings  # fixed layouts: frame_id and name of the first message
    messages: list[object]  # other types: the messages deserialised by rosbags
    malformed: int  # messages skipped because they do not parse as msgtype
    # (N,) int64: each message's count by its publisher, where an MCAP bag has it; 0: not known
    sequence: NDArray[np.int64] | None = None

    def __len__(self) -> int:
        """Return the number of messages."""
        return len(self.log_time)


def _stack(arrays: Sequence[NDArray[np.float64]]) -> NDArray[np.float64]:
    """Stack (n_i, count_i) arrays into one, padding shorter rows with NaN."""
    width = max(array.shape[1] for array in arrays)
    if all(array.shape[1] == width for array in arrays):
        return np.concatenate(arrays)
    return np.concatenate([
        np.pad(array, ((0, 0), (0, width - array.shape[1])), constant_values=np.nan)
        for array in arrays])


class TopicDecoder:
    """Decodes the raw messages of one topic batch by batch; result() gives its TopicData."""

    def __init__(self, topic: str, msgtype: str) -> None:
        self.topic, self.msgtype = topic, msgtype
        self._fields = LAYOUTS.get(msgtype)
        self._times: list[NDArray[np.int64]] = []
        self._sequences: list[NDArray[np.int64]] = []
        # Decoded rows (_Arrays) of a fixed layout, or the messages rosbags deserialised.
        self._parts: list[Any] = []
        # (receive time, strings) of the earliest message decoded
        self._strings: tuple[int, _Strings] | None = None
        self.malformed = 0

    def add(self, times: NDArray[np.int64], block: NDArray[np.uint8],
            sequences: NDArray[np.int64] | None = None) -> None:
        """
        Decode equal-length messages: block (N, length) uint8, log times (N,) int64.

        sequences (N,): each message's count by its publisher, as an MCAP bag keeps it (0: not
        known, as without them).
        """
        if self._fields is None:
            self._deserialise(times, block)
            return
        if sequences is None:
            sequences = np.zeros(len(times), np.int64)
        while len(block):
            try:
                layout = _layout(block[0].tobytes(), self._fields)
            except _Malformed:
                self.malformed += 1
                times, block = times[1:], block[1:]
                sequences = sequences[1:]
                continue
            same = _same_structure(block, layout)
            if self._strings is None or times[0] < self._strings[0]:
                self._strings = (times[0], layout.strings)
            every = bool(same.all())  # then no copy of the block
            self._parts.append(_decode_rows(block if every else block[same], layout))
            self._times.append(times if every else times[same])
            self._sequences.append(sequences if every else sequences[same])
            if every:
                return
            times, block = times[~same], block[~same]
            sequences = sequences[~same]

    def add_list(self, times: NDArray[np.int64], messages: list[bytes]) -> None:
        """Decode messages given as a list of bytes, received at times (N,) int64."""
        lengths = np.fromiter(map(len, messages), np.int64, len(messages))
        for length in np.unique(lengths).tolist():
            rows = np.flatnonzero(lengths == length)
            data = b''.join(messages if len(rows) == len(messages) else
                            [messages[i] for i in rows])
            self.add(times[rows], np.frombuffer(data, np.uint8).reshape(len(rows), length))

    def _deserialise(self, times: NDArray[np.int64], block: NDArray[np.uint8]) -> None:
        store = typestore()
        for log_time, row in zip(times.tolist(), block):
            try:
                message = store.deserialize_cdr(row.tobytes(), self.msgtype)
            except (SerdeError, ValueError, IndexError, struct.error, UnicodeDecodeError):
                self.malformed += 1
                continue
            self._times.append(np.array([log_time], np.int64))
            self._sequences.append(np.zeros(1, np.int64))
            self._parts.append(message)

    def result(self) -> TopicData:
        """Return the TopicData of all messages added, sorted by log time (stable)."""
        if not self._parts:
            return TopicData(self.topic, self.msgtype, np.empty(0, np.int64), {}, {}, [],
                             self.malformed)
        log_time = np.concatenate(self._times)
        order = None if np.all(log_time[1:] >= log_time[:-1]) else np.argsort(
            log_time, kind='stable')
        sequence = np.concatenate(self._sequences)
        if order is not None:
            log_time, sequence = log_time[order], sequence[order]
        if self._fields is None:
            messages = self._parts if order is None else [self._parts[i] for i in order]
            return TopicData(self.topic, self.msgtype, log_time, {}, {}, messages,
                             self.malformed, sequence)
        fields = {}
        for name in self._parts[0]:
            arrays = [part[name] for part in self._parts]
            values = np.concatenate(arrays) if name == 'stamp' else _stack(arrays)
            fields[name] = values if order is None else values[order]
        assert self._strings is not None  # set with the first rows decoded
        return TopicData(self.topic, self.msgtype, log_time, fields, self._strings[1], [],
                         self.malformed, sequence)


def decode_cdr(messages: list[bytes], msgtype: str, log_times: ArrayLike | None = None,
               topic: str = '') -> TopicData:
    """
    Decode raw CDR messages (a list of bytes) of `msgtype` into a TopicData.

    log_times (N,) orders the result; by default the messages keep their order.
    """
    times = np.arange(len(messages)) if log_times is None else np.asarray(log_times)
    decoder = TopicDecoder(topic, msgtype)
    decoder.add_list(times.astype(np.int64), messages)
    return decoder.result()
