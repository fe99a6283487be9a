# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The MCAP file of a bag, as rosbag2 Jazzy's mcap plugin writes it.

The ros2 profile, plain (uncompressed) chunks with message indexes, channels with
offered_qos_profiles and topic_type_hash, messages with receive and send times, the bag's
metadata in a 'rosbag2' record, and a summary section with statistics.
"""
import collections
from collections.abc import Iterable
from importlib import metadata as package_metadata
from pathlib import Path
import struct
from typing import TYPE_CHECKING
import zlib

from kraft_master_driver.bag.common import INFINITE_NS, MCAP_MAGIC, MCAP_RECORD

if TYPE_CHECKING:
    from kraft_master_driver.bag.recorder import _Topic

_MCAP_CHUNK_BYTES = 768 * 1024  # the mcap C++ writer's default chunk size
_MESSAGE_HEADER_STRUCT = struct.Struct('<HIQQ')  # channel, sequence, log time, publish time
try:
    VERSION = package_metadata.version('kraft_master_driver')
except package_metadata.PackageNotFoundError:
    VERSION = 'from source'


def _record_header(opcode: int, length: int) -> bytes:
    return MCAP_RECORD.pack(opcode, length)


def _record(opcode: int, body: bytes) -> bytes:
    return MCAP_RECORD.pack(opcode, len(body)) + body


def _string(text: str) -> bytes:
    data = text.encode()
    return struct.pack('<I', len(data)) + data


def _string_map(pairs: Iterable[tuple[str, str]]) -> bytes:
    data = b''.join(_string(key) + _string(value) for key, value in pairs)
    return struct.pack('<I', len(data)) + data


class McapWriter:
    """An MCAP file as rosbag2 Jazzy's mcap plugin writes it: ros2 profile, plain chunks."""

    extension = '.mcap'

    def __init__(self, path: Path) -> None:
        """Create the file `path` (it must not exist) and write its header."""
        self.file = open(path, 'xb')
        self.file.write(MCAP_MAGIC + _record(0x01, _string('ros2') +
                                             _string(f'kraft_master_driver {VERSION}')))
        self.schemas: dict[str, bytes] = {}  # message type -> its Schema record
        self.channels: dict[int, bytes] = {}  # channel id -> its Channel record
        self.chunk_indexes: list[bytes] = []
        self.channel_counts: collections.Counter[int] = collections.Counter()
        self.time_span = [INFINITE_NS, 0]
        self._new_chunk()

    def _new_chunk(self) -> None:
        self.chunk = bytearray()
        self.chunk_span = [INFINITE_NS, 0]
        # channel id -> [log time, offset]
        self.chunk_index: collections.defaultdict[int, list[int]] = collections.defaultdict(list)

    def add_topic(self, topic_id: int, topic: '_Topic') -> None:
        """Write the channel of `topic` (a recorder's _Topic), and its type's schema if new."""
        if topic.msgtype not in self.schemas:
            self.schemas[topic.msgtype] = _record(0x03, struct.pack(
                '<H', len(self.schemas) + 1) + _string(topic.msgtype) + _string(
                topic.encoding) + _string(topic.definition))
            self.chunk += self.schemas[topic.msgtype]
        schema_id = list(self.schemas).index(topic.msgtype) + 1
        self.channels[topic_id] = _record(0x04, struct.pack('<HH', topic_id, schema_id) + (
            _string(topic.name) + _string('cdr') + _string_map(
                (('offered_qos_profiles', topic.qos_yaml),
                 ('topic_type_hash', topic.type_hash)))))
        self.chunk += self.channels[topic_id]

    def write(self, topic_id: int, log_time: int, publish_time: int, data: bytes,
              sequence: int = 0) -> None:
        """Add a message to the chunk (sequence: its publisher's count, 0 if not known)."""
        self.chunk_index[topic_id] += (log_time, len(self.chunk))
        self.chunk += _record_header(0x05, 22 + len(data))
        self.chunk += _MESSAGE_HEADER_STRUCT.pack(topic_id, sequence & 0xFFFFFFFF, log_time,
                                                  publish_time)
        self.chunk += data
        self.channel_counts[topic_id] += 1
        for span in (self.chunk_span, self.time_span):
            span[0], span[1] = min(span[0], log_time), max(span[1], log_time)
        if len(self.chunk) >= _MCAP_CHUNK_BYTES:
            self._write_chunk()

    def _write_chunk(self) -> None:
        if not self.chunk_index:
            return
        start = self.file.tell()
        self.file.write(_record_header(0x06, 8 * 3 + 4 + 4 + 8 + len(self.chunk)))
        self.file.write(struct.pack('<QQQI', *self.chunk_span, len(self.chunk), 0))
        self.file.write(_string('') + struct.pack('<Q', len(self.chunk)))
        self.file.write(self.chunk)
        end = self.file.tell()
        index_offsets = []
        for channel_id, entries in self.chunk_index.items():
            index_offsets.append(struct.pack('<HQ', channel_id, self.file.tell()))
            pairs = struct.pack(f'<{len(entries)}Q', *entries)
            self.file.write(_record(0x07, struct.pack('<HI', channel_id, len(pairs)) + pairs))
        offsets = b''.join(index_offsets)
        self.chunk_indexes.append(_record(0x08, struct.pack(
            '<QQQQI', *self.chunk_span, start, end - start, len(offsets)) + offsets + struct.pack(
            '<Q', self.file.tell() - end) + _string('') + struct.pack(
            '<QQ', len(self.chunk), len(self.chunk))))
        self._new_chunk()

    def close(self, metadata: str) -> None:
        """Write the last chunk, the bag's `metadata` (YAML), the summary and the footer."""
        self._write_chunk()
        metadata_start = self.file.tell()
        self.file.write(_record(0x0C, _string('rosbag2') + _string_map(
            (('serialized_metadata', metadata),))))
        metadata_index = _record(0x0D, struct.pack(
            '<QQ', metadata_start, self.file.tell() - metadata_start) + _string('rosbag2'))
        self.file.write(_record(0x0F, struct.pack('<I', 0)))
        summary_start = self.file.tell()
        span = self.time_span if self.channel_counts else [0, 0]
        counts = b''.join(struct.pack('<HQ', channel_id, self.channel_counts[channel_id])
                          for channel_id in self.channels)
        groups = [(0x03, list(self.schemas.values())), (0x04, list(self.channels.values())),
                  (0x08, self.chunk_indexes), (0x0D, [metadata_index]),
                  (0x0B, [_record(0x0B, struct.pack(
                      '<QHIIIIQQI', sum(self.channel_counts.values()), len(self.schemas),
                      len(self.channels), 0, 1, len(self.chunk_indexes), *span,
                      len(counts)) + counts)])]
        summary, offsets = bytearray(), bytearray()
        for opcode, records in groups:
            if records:
                group = b''.join(records)
                offsets += _record(0x0E, struct.pack('<BQQ', opcode,
                                                     summary_start + len(summary), len(group)))
                summary += group
        footer = _record_header(0x02, 20) + struct.pack(
            '<QQ', summary_start, summary_start + len(summary))
        crc = zlib.crc32(summary + offsets + footer)
        self.file.write(summary + offsets + footer + struct.pack('<I', crc) + MCAP_MAGIC)
        self.file.close()

    def abort(self) -> None:
        """Close the file as it is."""
        self.file.close()
