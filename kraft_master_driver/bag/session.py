# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Recorded sessions of the driver: rosbag2 directories (mcap or sqlite3 storage).

BagRecorder writes raw CDR bytes, as a subscription with raw=True receives them, into a
new rosbag2 directory laid out as `ros2 bag record` of ROS 2 Jazzy writes it: `NAME_0.mcap`
(ros2 profile, plain chunks, channels with offered_qos_profiles and topic_type_hash,
messages with receive and send times, the bag's metadata in a 'rosbag2' record) or
`NAME_0.db3` (the sqlite3 plugin's schema version 4), and metadata.yaml (version 9,
ros_distro jazzy). Message definitions and RIHS01 type hashes are rosbag2's.

read_topics reads topics back as numpy arrays, fast enough for millions of messages. The
raw bytes come straight from the storage: MCAP chunks located through their message
indexes (records scanned where there is none), sqlite3 rows concatenated by SQLite
itself. Equal-length messages are stacked into (N, length) byte arrays, and the
fixed-layout CDR of JointState, PoseStamped, WrenchStamped and TwistStamped is decoded with
numpy, equal to rosbags' deserialisation message by message. Other types (DiagnosticArray)
are deserialised one by one with rosbags; bags compressed by rosbag2 (file or message mode)
are read through rosbags' Reader. Malformed messages are counted and skipped, never raised.

simulate_samples and write_samples make synthetic sessions for tests and benchmarks.
"""
import collections
import functools
from importlib import metadata as package_metadata
import os
from pathlib import Path
import re
import sqlite3
import struct
import sys
import threading
from typing import NamedTuple
import zlib

from kraft_master_driver.core import kinematics
from lz4.frame import decompress as lz4_decompress
import numpy as np
from rosbags.interfaces import (
    Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime)
from rosbags.rosbag2 import Reader
from rosbags.rosbag2.errors import ReaderError
from rosbags.serde import SerdeError
from rosbags.typesys import get_typestore, Stores
import yaml

try:
    from compression import zstd  # Python 3.14
except ImportError:
    from backports import zstd

JOINT_STATE = 'sensor_msgs/msg/JointState'
POSE_STAMPED = 'geometry_msgs/msg/PoseStamped'
WRENCH_STAMPED = 'geometry_msgs/msg/WrenchStamped'
TWIST_STAMPED = 'geometry_msgs/msg/TwistStamped'
DIAGNOSTIC_ARRAY = 'diagnostic_msgs/msg/DiagnosticArray'
# The driver's topics, relative to its namespace, and their types.
DRIVER_TOPICS = {
    'joint_states': JOINT_STATE,
    'pose': POSE_STAMPED,
    'pots': JOINT_STATE,
    'wrench': WRENCH_STAMPED,
    'rate_command': TWIST_STAMPED,
    'diagnostics': DIAGNOSTIC_ARRAY,
}
STORAGES = ('mcap', 'sqlite3')
BAG_VERSION = 9  # the rosbag2 metadata version of ROS 2 Jazzy
ROS_DISTRO = 'jazzy'  # the message types and hashes written are Jazzy's
INFINITE_NS = 2 ** 63 - 1  # RMW_DURATION_INFINITE

# Fixed-layout message types: (field, kind) in CDR order. Kinds: 'time' (int32 sec, uint32
# nanosec), 'string', 'strings' (sequence of strings), 'doubles' (sequence of float64), or
# an int n for n consecutive float64 (nested structs of doubles only).
_HEADER = (('stamp', 'time'), ('frame_id', 'string'))
LAYOUTS = {
    JOINT_STATE: _HEADER + (('name', 'strings'), ('position', 'doubles'),
                            ('velocity', 'doubles'), ('effort', 'doubles')),
    POSE_STAMPED: _HEADER + (('position', 3), ('orientation', 4)),
    WRENCH_STAMPED: _HEADER + (('force', 3), ('torque', 3)),
    TWIST_STAMPED: _HEADER + (('linear', 3), ('angular', 3)),
}

_MCAP_MAGIC = b'\x89MCAP0\r\n'
_MCAP_CHUNK_BYTES = 768 * 1024  # the mcap C++ writer's default chunk size
_MESSAGE_HEADER_STRUCT = struct.Struct('<HIQQ')  # channel, sequence, log time, publish time
_MCAP_RECORD = struct.Struct('<BQ')  # opcode, content length
_MCAP_CHUNK = struct.Struct('<QQQII')  # start, end, uncompressed size, crc, compression length
_OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK, _OP_MESSAGE_INDEX = 0x04, 0x05, 0x06, 0x07
_SQLITE_BATCH_BYTES = 1 << 27  # message bytes per query (SQLite caps one value at 1e9 bytes)
_MESSAGE_HEADER = 22  # channel id u16, sequence u32, log time u64, publish time u64
_MESSAGE_RECORD = np.dtype({  # a Message record up to its data
    'names': ['opcode', 'length', 'channel', 'sequence', 'log_time', 'publish_time'],
    'formats': ['u1', '<u8', '<u2', '<u4', '<u8', '<u8'],
    'offsets': [0, 1, 9, 11, 15, 23], 'itemsize': 31})


# The tables of rosbag2 Jazzy's sqlite3 storage, in its words (sqlite_master keeps them).
_SQLITE3_SCHEMA = (
    'CREATE TABLE schema(schema_version INTEGER PRIMARY KEY,ros_distro TEXT NOT NULL);',
    'CREATE TABLE metadata(id INTEGER PRIMARY KEY,metadata_version INTEGER NOT NULL,'
    'metadata TEXT NOT NULL);',
    'CREATE TABLE topics(id INTEGER PRIMARY KEY,name TEXT NOT NULL,type TEXT NOT NULL,'
    'serialization_format TEXT NOT NULL,offered_qos_profiles TEXT NOT NULL,'
    'type_description_hash TEXT NOT NULL);',
    'CREATE TABLE message_definitions(id INTEGER PRIMARY KEY,topic_type TEXT NOT NULL,'
    'encoding TEXT NOT NULL,encoded_message_definition TEXT NOT NULL,'
    'type_description_hash TEXT NOT NULL);',
    'CREATE TABLE messages(id INTEGER PRIMARY KEY,topic_id INTEGER NOT NULL,'
    'timestamp INTEGER NOT NULL, data BLOB NOT NULL);',
    'CREATE INDEX timestamp_idx ON messages (timestamp ASC);',
)
# How rosbag2 finds the types a .msg file uses.
_MSG_FIELD_TYPE = re.compile(r'(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+')
_PRIMITIVE_TYPES = {'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16',
                    'uint16', 'int32', 'uint32', 'int64', 'uint64', 'string'}
try:
    VERSION = package_metadata.version('kraft_master_driver')
except package_metadata.PackageNotFoundError:
    VERSION = 'from source'


class SessionError(Exception):
    """A bag that cannot be read or written; the message names the bag and the fault."""


@functools.cache
def typestore():
    """Return the rosbags type store of ROS 2 Jazzy."""
    return get_typestore(Stores.ROS2_JAZZY)


def _duration(nanoseconds):
    return QosTime(*divmod(int(nanoseconds), 1_000_000_000))


def qos_profile(reliability='reliable', durability='volatile', history='unknown', depth=0,
                deadline_ns=INFINITE_NS, lifespan_ns=INFINITE_NS, liveliness='automatic',
                liveliness_lease_duration_ns=INFINITE_NS,
                avoid_ros_namespace_conventions=False):
    """
    Return an offered QoS profile as ros2 bag stores it, from policy names and nanoseconds.

    The names are those of rclpy's policy enums (case-insensitive, e.g. 'RELIABLE'); the
    defaults are what the ROS graph reports for a default publisher (history is not
    propagated, so 'unknown' with depth 0).
    """
    try:
        return Qos(
            history=QosHistory[history.upper()], depth=int(depth),
            reliability=QosReliability[reliability.upper()],
            durability=QosDurability[durability.upper()],
            deadline=_duration(deadline_ns), lifespan=_duration(lifespan_ns),
            liveliness=QosLiveliness[liveliness.upper()],
            liveliness_lease_duration=_duration(liveliness_lease_duration_ns),
            avoid_ros_namespace_conventions=bool(avoid_ros_namespace_conventions))
    except KeyError as error:
        raise ValueError(f'unknown QoS policy value {error}') from None


def _qos_dicts(profiles):
    """Return QoS profiles as rosbag2 (metadata version 9) writes them in YAML."""
    def duration(value):
        return {'sec': value.sec, 'nsec': value.nsec}
    return [{'history': qos.history.name.lower(), 'depth': qos.depth,
             'reliability': qos.reliability.name.lower(),
             'durability': qos.durability.name.lower(), 'deadline': duration(qos.deadline),
             'lifespan': duration(qos.lifespan), 'liveliness': qos.liveliness.name.lower(),
             'liveliness_lease_duration': duration(qos.liveliness_lease_duration),
             'avoid_ros_namespace_conventions': qos.avoid_ros_namespace_conventions}
            for qos in profiles]


def _dump_yaml(value):
    return yaml.safe_dump(value, sort_keys=False, default_flow_style=False).rstrip('\n')


def _share_directory(package):
    """Return the share directory of an installed ROS package, as the ament index finds it."""
    prefixes = os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) + [sys.prefix]
    for prefix in filter(None, prefixes):
        if (Path(prefix) / 'share/ament_index/resource_index/packages' / package).exists():
            return Path(prefix) / 'share' / package
    raise LookupError(package)


def _msg_text(name, seen):
    """Return the .msg text of `name` (pkg/Type) followed by those of the types it uses."""
    package, _, type_name = name.partition('/')
    text = (_share_directory(package) / 'msg' / f'{type_name.removeprefix("msg/")}.msg'
            ).read_text(encoding='utf-8')
    used = {used if '/' in used else f'{package}/{used}'
            for used in _MSG_FIELD_TYPE.findall(text) if used not in _PRIMITIVE_TYPES}
    for dependency in sorted(used - seen):
        seen.add(dependency)
        text += f'\n{"=" * 80}\nMSG: {dependency}\n{_msg_text(dependency, seen)}'
    return text


@functools.cache
def message_definition(msgtype):
    """
    Return (encoding, text) of a message type's full definition as rosbag2 Jazzy stores it.

    That is the type's .msg file from its package's share directory, then the .msg file of
    each type it uses, depth first, each after a line of '=' and 'MSG: pkg/Type'. Where the
    files are not installed, the definition the rosbags type store generates (no comments).
    """
    try:
        return 'ros2msg', _msg_text(msgtype.replace('/msg/', '/'), set())
    except (OSError, LookupError):
        return 'ros2msg', typestore().generate_msgdef(msgtype, ros_version=2)[0]


def _record_header(opcode, length):
    return _MCAP_RECORD.pack(opcode, length)


def _record(opcode, body):
    return _MCAP_RECORD.pack(opcode, len(body)) + body


def _string(text):
    data = text.encode()
    return struct.pack('<I', len(data)) + data


def _string_map(pairs):
    data = b''.join(_string(key) + _string(value) for key, value in pairs)
    return struct.pack('<I', len(data)) + data


class _McapStorage:
    """An MCAP file as rosbag2 Jazzy's mcap plugin writes it: ros2 profile, plain chunks."""

    extension = '.mcap'

    def __init__(self, path):
        self.file = open(path, 'xb')
        self.file.write(_MCAP_MAGIC + _record(0x01, _string('ros2') +
                                              _string(f'kraft_master_driver {VERSION}')))
        self.schemas, self.channels, self.chunk_indexes = {}, {}, []
        self.channel_counts = collections.Counter()
        self.time_span = [INFINITE_NS, 0]
        self._new_chunk()

    def _new_chunk(self):
        self.chunk = bytearray()
        self.chunk_span = [INFINITE_NS, 0]
        self.chunk_index = collections.defaultdict(list)  # channel id -> [log time, offset]

    def add_topic(self, topic_id, topic):
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

    def write(self, topic_id, log_time, publish_time, data):
        self.chunk_index[topic_id] += (log_time, len(self.chunk))
        self.chunk += _record_header(0x05, 22 + len(data))
        self.chunk += _MESSAGE_HEADER_STRUCT.pack(topic_id, 0, log_time, publish_time)
        self.chunk += data
        self.channel_counts[topic_id] += 1
        for span in (self.chunk_span, self.time_span):
            span[0], span[1] = min(span[0], log_time), max(span[1], log_time)
        if len(self.chunk) >= _MCAP_CHUNK_BYTES:
            self._write_chunk()

    def _write_chunk(self):
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

    def close(self, metadata):
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
        self.file.write(summary + offsets + footer + struct.pack('<I', crc) + _MCAP_MAGIC)
        self.file.close()

    def abort(self):
        self.file.close()


class _Sqlite3Storage:
    """A .db3 file with the schema (version 4) of rosbag2 Jazzy's sqlite3 plugin."""

    extension = '.db3'
    batch = 1000  # messages per transaction

    def __init__(self, path):
        if path.exists():
            raise FileExistsError(f'{path} exists')
        self.database = sqlite3.connect(path, check_same_thread=False, isolation_level=None)
        self.database.execute('PRAGMA journal_mode=MEMORY;')
        self.database.execute('PRAGMA synchronous=OFF;')
        self.database.execute('BEGIN')
        for statement in _SQLITE3_SCHEMA:
            self.database.execute(statement)
        self.database.execute('INSERT INTO schema (schema_version, ros_distro) VALUES (?, ?)',
                              (4, ROS_DISTRO))
        self.types = set()
        self.pending = []

    def add_topic(self, topic_id, topic):
        self.database.execute(
            'INSERT INTO topics(id, name, type, serialization_format, offered_qos_profiles, '
            'type_description_hash) VALUES (?, ?, ?, ?, ?, ?)',
            (topic_id, topic.name, topic.msgtype, 'cdr', topic.qos_yaml, topic.type_hash))
        if topic.msgtype not in self.types:
            self.types.add(topic.msgtype)
            self.database.execute(
                'INSERT INTO message_definitions (topic_type, encoding, '
                'encoded_message_definition, type_description_hash) VALUES (?, ?, ?, ?)',
                (topic.msgtype, topic.encoding, topic.definition, topic.type_hash))

    def write(self, topic_id, log_time, _publish_time, data):
        self.pending.append((log_time, topic_id, data))
        if len(self.pending) >= self.batch:
            self._flush()

    def _flush(self):
        self.database.executemany(
            'INSERT INTO messages (timestamp, topic_id, data) VALUES (?, ?, ?);', self.pending)
        self.database.execute('COMMIT')
        self.database.execute('BEGIN')
        self.pending = []

    def close(self, metadata):
        self._flush()
        self.database.execute('INSERT INTO metadata (metadata_version, metadata) VALUES (?, ?)',
                              (BAG_VERSION, metadata))
        self.database.execute('COMMIT')
        self.database.close()

    def abort(self):
        self.database.close()


_STORAGE_CLASSES = {'mcap': _McapStorage, 'sqlite3': _Sqlite3Storage}


class _Topic(NamedTuple):
    name: str
    msgtype: str
    offered_qos: list
    qos_yaml: str
    type_hash: str
    encoding: str
    definition: str


class BagRecorder:
    """
    Writes raw CDR messages into a new rosbag2 directory as rosbag2 Jazzy writes it.

    The bag `NAME/` holds `NAME_0.mcap` (or `NAME_0.db3`) and metadata.yaml. Thread-safe; a
    context manager.
    """

    def __init__(self, path, storage='mcap'):
        """Create the bag directory `path` (it must not exist) with storage mcap or sqlite3."""
        if storage not in STORAGES:
            raise ValueError(f'storage must be one of {", ".join(STORAGES)}, got {storage!r}')
        self.path = Path(path)
        self.storage = storage
        self.counts = {}
        self._topics = {}  # name -> (topic id, _Topic)
        self._lock = threading.Lock()
        self._time_span = [INFINITE_NS, 0]
        self.file_name = f'{self.path.name}_0{_STORAGE_CLASSES[storage].extension}'
        try:
            self.path.mkdir(parents=True)
        except OSError as error:
            raise SessionError(f'{self.path}: cannot create the bag: {error.strerror}') from None
        try:
            self._storage = _STORAGE_CLASSES[storage](self.path / self.file_name)
        except (OSError, sqlite3.Error) as error:
            raise SessionError(f'{self.path}: cannot create the bag: {error}') from None

    def add_topic(self, topic, msgtype, offered_qos=(), type_hash=None):
        """
        Declare `topic` (absolute name) of `msgtype` and the QoS profiles offered on it.

        type_hash is the RIHS01 type description hash the publishers report (rosbag2 stores
        that); by default the hash of msgtype in the Jazzy type store (the same, REP 2011).
        """
        if msgtype not in typestore().types:
            raise ValueError(f'{topic}: unknown message type {msgtype!r}')
        encoding, definition = message_definition(msgtype)
        entry = _Topic(topic, msgtype, list(offered_qos), _dump_yaml(_qos_dicts(offered_qos)),
                       typestore().hash_rihs01(msgtype) if type_hash is None else type_hash,
                       encoding, definition)
        with self._lock:
            if topic in self._topics:
                raise ValueError(f'{topic}: topic added twice')
            self._topics[topic] = (len(self._topics) + 1, entry)
            self._storage.add_topic(len(self._topics), entry)
            self.counts[topic] = 0

    def write(self, topic, timestamp_ns, data, publish_time_ns=None):
        """
        Write one message's raw CDR bytes, received at `timestamp_ns` (ns since the epoch).

        publish_time_ns is when the publisher sent it (the source timestamp; MCAP stores it
        as the publish time); by default the receive time.
        """
        log_time = int(timestamp_ns)
        publish_time = log_time if publish_time_ns is None else int(publish_time_ns)
        with self._lock:
            entry = self._topics.get(topic)
            if entry is None:
                raise ValueError(f'{topic}: not added to the bag; call add_topic first')
            if self._storage is None:
                raise ValueError(f'{self.path}: the bag is closed')
            self._storage.write(entry[0], log_time, publish_time, bytes(data))
            self.counts[topic] += 1
            span = self._time_span
            span[0], span[1] = min(span[0], log_time), max(span[1], log_time)

    def metadata(self):
        """Return the map rosbag2 writes under rosbag2_bagfile_information for this bag."""
        count = sum(self.counts.values())
        start = self._time_span[0] if count else 0
        duration = self._time_span[1] - start if count else 0
        return {
            'version': BAG_VERSION,
            'storage_identifier': self.storage,
            'duration': {'nanoseconds': duration},
            'starting_time': {'nanoseconds_since_epoch': start},
            'message_count': count,
            'topics_with_message_count': [
                {'topic_metadata': {
                    'name': topic.name, 'type': topic.msgtype, 'serialization_format': 'cdr',
                    'offered_qos_profiles': _qos_dicts(topic.offered_qos),
                    'type_description_hash': topic.type_hash},
                 'message_count': self.counts[topic.name]}
                for _, topic in self._topics.values()],
            'compression_format': '',
            'compression_mode': '',
            'relative_file_paths': [self.file_name],
            'files': [{'path': self.file_name,
                       'starting_time': {'nanoseconds_since_epoch': start},
                       'duration': {'nanoseconds': duration}, 'message_count': count}],
            'custom_data': None,
            'ros_distro': ROS_DISTRO,
        }

    def close(self):
        """Write the storage's index and metadata, then metadata.yaml; safe to call twice."""
        with self._lock:
            if self._storage is None:
                return
            storage, self._storage = self._storage, None
            metadata = self.metadata()
            try:
                storage.close(_dump_yaml(metadata))
                temporary = self.path / 'metadata.yaml.tmp'
                temporary.write_text(_dump_yaml({'rosbag2_bagfile_information': metadata}) +
                                     '\n', encoding='utf-8')
                temporary.replace(self.path / 'metadata.yaml')
            except (OSError, sqlite3.Error) as error:
                storage.abort()
                raise SessionError(f'{self.path}: cannot close the bag: {error}') from None

    def __enter__(self):
        """Return the recorder."""
        return self

    def __exit__(self, *_exc):
        """Close the bag."""
        self.close()


# -- decoding fixed-layout CDR ---------------------------------------------------------------


class _Malformed(Exception):
    """A message that does not parse as its type."""


class _Layout(NamedTuple):
    little: bool
    stamp: int  # offset of the stamp
    doubles: dict  # field -> (offset, count)
    strings: dict  # field -> the message's str or list of str
    structure: np.ndarray  # offsets of the bytes that fix the layout (header, lengths)


def _layout(data, fields):
    """Return the _Layout of one message `data` (bytes); raise _Malformed."""
    size = len(data)
    if size < 4 or data[0] != 0 or data[1] not in (0, 1):
        raise _Malformed('not a plain CDR encapsulation')
    little = data[1] == 1
    uint32 = struct.Struct('<I' if little else '>I').unpack_from
    structure = [0, 1, 2, 3]
    doubles, strings = {}, {}
    position = stamp = 4

    def align(position, alignment):
        # CDR aligns relative to the end of the 4-byte encapsulation header.
        return 4 + ((position - 4 + alignment - 1) & -alignment)

    def read_count(position):
        position = align(position, 4)
        if position + 4 > size:
            raise _Malformed('truncated')
        structure.extend(range(position, position + 4))
        return uint32(data, position)[0], position + 4

    def read_string(position):
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
            strings[name] = []
            for _ in range(count):
                value, position = read_string(position)
                strings[name].append(value)
        else:
            count, position = read_count(position) if kind == 'doubles' else (kind, position)
            if count:
                position = align(position, 8)
            doubles[name] = (position, count)
            position += 8 * count
        if position > size:
            raise _Malformed('truncated')
    return _Layout(little, stamp, doubles, strings, np.array(structure))


def _view(block, fields):
    """View the rows of `block` (N, length) uint8 as records: {name: (dtype, offset)}."""
    dtype = np.dtype({'names': list(fields), 'formats': [f for f, _ in fields.values()],
                      'offsets': [offset for _, offset in fields.values()],
                      'itemsize': block.shape[1]})
    return block.view(dtype)[:, 0]


def _same_structure(block, layout):
    """Return which rows of `block` have the first row's layout (header and lengths)."""
    words = _view(block, {f'w{i}': ('<u4', start)
                          for i, start in enumerate(layout.structure[::4].tolist())})
    same = np.ones(len(block), bool)
    for name in words.dtype.names:
        same &= words[name] == words[name][0]
    return same


def _decode_rows(block, layout):
    """Decode the rows of `block` (N, length) uint8 that all have `layout`."""
    order = '<' if layout.little else '>'
    fields = {'sec': (order + 'i4', layout.stamp), 'nanosec': (order + 'u4', layout.stamp + 4)}
    fields.update({name: ((order + 'f8', (count,)), offset)
                   for name, (offset, count) in layout.doubles.items() if count})
    records = _view(block, fields)
    decoded = {'stamp': records['sec'].astype(np.int64) * 1_000_000_000 + records['nanosec']}
    for name, (_, count) in layout.doubles.items():
        decoded[name] = (records[name].astype(np.float64) if count else
                         np.empty((len(block), 0)))
    return decoded


class TopicData(NamedTuple):
    """One topic read from a bag, in receive order."""

    topic: str
    msgtype: str
    log_time: np.ndarray  # (N,) int64 ns: when the recorder received each message
    fields: dict  # fixed layouts: 'stamp' (N,) int64 ns and each float64 field (N, count)
    strings: dict  # fixed layouts: frame_id and name of the first message
    messages: list  # other types: the messages deserialised by rosbags
    malformed: int  # messages skipped because they do not parse as msgtype

    def __len__(self):
        """Return the number of messages."""
        return len(self.log_time)


def _stack(arrays):
    """Stack (n_i, count_i) arrays into one, padding shorter rows with NaN."""
    width = max(array.shape[1] for array in arrays)
    if all(array.shape[1] == width for array in arrays):
        return np.concatenate(arrays)
    return np.concatenate([
        np.pad(array, ((0, 0), (0, width - array.shape[1])), constant_values=np.nan)
        for array in arrays])


class _TopicDecoder:
    """Decodes the raw messages of one topic batch by batch; result() gives its TopicData."""

    def __init__(self, topic, msgtype):
        self.topic, self.msgtype = topic, msgtype
        self._fields = LAYOUTS.get(msgtype)
        self._times, self._parts = [], []
        self._strings = None  # (receive time, strings) of the earliest message decoded
        self.malformed = 0

    def add(self, times, block):
        """Decode equal-length messages: block (N, length) uint8, log times (N,) int64."""
        if self._fields is None:
            self._deserialise(times, block)
            return
        while len(block):
            try:
                layout = _layout(block[0].tobytes(), self._fields)
            except _Malformed:
                self.malformed += 1
                times, block = times[1:], block[1:]
                continue
            same = _same_structure(block, layout)
            if self._strings is None or times[0] < self._strings[0]:
                self._strings = (times[0], layout.strings)
            if same.all():
                self._times.append(times)
                self._parts.append(_decode_rows(block, layout))
                return
            self._times.append(times[same])
            self._parts.append(_decode_rows(block[same], layout))
            times, block = times[~same], block[~same]

    def add_list(self, times, messages):
        """Decode messages given as a list of bytes, received at times (N,) int64."""
        lengths = np.fromiter(map(len, messages), np.int64, len(messages))
        for length in np.unique(lengths).tolist():
            rows = np.flatnonzero(lengths == length)
            data = b''.join(messages if len(rows) == len(messages) else
                            [messages[i] for i in rows])
            self.add(times[rows], np.frombuffer(data, np.uint8).reshape(len(rows), length))

    def _deserialise(self, times, block):
        store = typestore()
        for log_time, row in zip(times.tolist(), block):
            try:
                message = store.deserialize_cdr(row.tobytes(), self.msgtype)
            except (SerdeError, ValueError, IndexError, struct.error, UnicodeDecodeError):
                self.malformed += 1
                continue
            self._times.append(np.array([log_time], np.int64))
            self._parts.append(message)

    def result(self):
        """Return the TopicData of all messages added, sorted by log time (stable)."""
        if not self._parts:
            return TopicData(self.topic, self.msgtype, np.empty(0, np.int64), {}, {}, [],
                             self.malformed)
        log_time = np.concatenate(self._times)
        order = None if np.all(log_time[1:] >= log_time[:-1]) else np.argsort(
            log_time, kind='stable')
        if order is not None:
            log_time = log_time[order]
        if self._fields is None:
            messages = self._parts if order is None else [self._parts[i] for i in order]
            return TopicData(self.topic, self.msgtype, log_time, {}, {}, messages,
                             self.malformed)
        fields = {}
        for name in self._parts[0]:
            arrays = [part[name] for part in self._parts]
            values = np.concatenate(arrays) if name == 'stamp' else _stack(arrays)
            fields[name] = values if order is None else values[order]
        return TopicData(self.topic, self.msgtype, log_time, fields, self._strings[1], [],
                         self.malformed)


def decode_cdr(messages, msgtype, log_times=None, topic=''):
    """
    Decode raw CDR messages (a list of bytes) of `msgtype` into a TopicData.

    log_times (N,) orders the result; by default the messages keep their order.
    """
    times = np.arange(len(messages)) if log_times is None else np.asarray(log_times)
    decoder = _TopicDecoder(topic, msgtype)
    decoder.add_list(times.astype(np.int64), messages)
    return decoder.result()


# -- reading raw messages --------------------------------------------------------------------


def _add_packed(decoder, data, starts, lengths, times):
    """Decode the messages data[starts[i]:starts[i] + lengths[i]], received at times[i]."""
    for length in np.unique(lengths).tolist():
        rows = np.flatnonzero(lengths == length)
        if length <= 0:
            decoder.malformed += len(rows)
            continue
        # Each row is a window of `length` bytes: one copy, no index array per byte.
        windows = np.lib.stride_tricks.sliding_window_view(data, length)
        decoder.add(times[rows], windows[starts[rows]])


def _mcap_messages(data, offsets, channels, decoders):
    """Decode the message records at `offsets` of `data` (uint8) whose topic is decoded."""
    offsets = offsets[offsets + _MESSAGE_RECORD.itemsize <= len(data)]
    if not offsets.size:
        return
    windows = np.lib.stride_tricks.sliding_window_view(data, _MESSAGE_RECORD.itemsize)
    headers = windows[offsets].view(_MESSAGE_RECORD)[:, 0]
    lengths = headers['length'].astype(np.int64) - _MESSAGE_HEADER
    starts = offsets + _MESSAGE_RECORD.itemsize
    valid = (headers['opcode'] == _OP_MESSAGE) & (starts + lengths <= len(data))
    channel_ids = headers['channel']
    for channel_id in np.unique(channel_ids).tolist():
        decoder = decoders.get(channels.get(channel_id))
        if decoder is not None:
            of_channel = channel_ids == channel_id
            decoder.malformed += int(np.count_nonzero(of_channel & ~valid))
            rows = np.flatnonzero(of_channel & valid)
            _add_packed(decoder, data, starts[rows], lengths[rows],
                        headers['log_time'][rows].astype(np.int64))


def _decompress(data, compression):
    if compression == 'zstd':
        return zstd.decompress(data)
    if compression == 'lz4':
        return lz4_decompress(data)
    raise SessionError(f'unsupported MCAP chunk compression {compression!r}')


class _McapFile:
    """An MCAP file, mapped into memory, read for the topics of some decoders."""

    def __init__(self, path):
        self.path = path
        try:
            # A plain ndarray view of the map: slicing a memmap subclass costs more.
            self.data = np.memmap(path, np.uint8, mode='r').view(np.ndarray)
        except ValueError:
            raise SessionError(f'{path}: empty file, not MCAP') from None
        self.buffer = memoryview(self.data)  # for struct: cheaper than the array itself
        if len(self.data) < 16 or self.buffer[:8] != _MCAP_MAGIC:
            raise SessionError(f'{path}: not an MCAP file')
        self.channels = {}

    def records(self, buffer, start, end):
        """Yield (position, opcode, content length) of the records in buffer[start:end]."""
        position = start
        while position < end:
            if position + 9 > end:
                raise SessionError(f'{self.path}: MCAP record at byte {position} is cut short')
            opcode, length = _MCAP_RECORD.unpack_from(buffer, position)
            if position + 9 + length > end:
                raise SessionError(f'{self.path}: MCAP record at byte {position} runs past '
                                   'its end')
            if opcode == _OP_CHANNEL:
                channel_id, _schema, topic_length = struct.unpack_from('<HHI', buffer,
                                                                       position + 9)
                topic = bytes(buffer[position + 17:position + 17 + topic_length])
                self.channels[channel_id] = topic.decode()
            yield position, opcode, length
            position += 9 + length

    def read(self, decoders):
        """Decode the messages of the topics in `decoders`."""
        chunks, offsets = [], []  # offsets: message records in the file, not compressed
        for position, opcode, _ in self.records(self.buffer, 8, len(self.data) - 8):
            if opcode == _OP_CHUNK:
                chunks.append((position, []))
            elif opcode == _OP_MESSAGE_INDEX and chunks:
                chunks[-1][1].append(position)
            elif opcode == _OP_MESSAGE:
                offsets.append(np.array([position]))
        for position, indexes in chunks:
            offsets.append(self.chunk(position, indexes, decoders))
        if offsets:
            _mcap_messages(self.data, np.concatenate(offsets), self.channels, decoders)

    def chunk(self, position, indexes, decoders):
        """
        Find the wanted messages of the Chunk record at `position`.

        A compressed chunk is decoded here; for a plain one the file offsets of its message
        records are returned, to be decoded with all the others at once.
        """
        buffer = self.buffer
        header = position + 9
        *_, size, _crc, name_length = _MCAP_CHUNK.unpack_from(buffer, header)
        name_start = header + _MCAP_CHUNK.size
        compression = bytes(buffer[name_start:name_start + name_length]).decode()
        (records_length,) = struct.unpack_from('<Q', buffer, name_start + name_length)
        start = name_start + name_length + 8
        indexed = {struct.unpack_from('<H', buffer, index + 9)[0]: index for index in indexes}
        nothing = np.empty(0, np.int64)
        if indexed and indexed.keys() <= self.channels.keys():
            wanted = [index for channel_id, index in indexed.items()
                      if self.channels[channel_id] in decoders]
            if not wanted:
                return nothing
        else:
            wanted = None  # no usable message index: scan the records
        records = self.data[start:start + records_length]
        if compression:
            records = np.frombuffer(_decompress(records.tobytes(), compression), np.uint8)
        if len(records) != size:
            raise SessionError(f'{self.path}: MCAP chunk at byte {position} has the wrong size')
        if wanted is None:
            offsets = np.array([at for at, opcode, _ in self.records(memoryview(records), 0, size)
                                if opcode == _OP_MESSAGE], dtype=np.int64)
        else:
            # Message index records: channel id, then (log time, offset) pairs, u64 each.
            entries = []
            for index in wanted:
                (count,) = struct.unpack_from('<I', buffer, index + 11)
                entries.append(self.data[index + 15:index + 15 + count].view('<u8')[1::2])
            offsets = np.concatenate(entries).astype(np.int64)
        if not compression:
            return offsets + start
        _mcap_messages(records, offsets, self.channels, decoders)
        return nothing


def _read_mcap(path, decoders):
    """Decode the messages of the topics in `decoders` from an MCAP file."""
    _McapFile(path).read(decoders)


def _read_sqlite(path, decoders):
    """
    Decode the messages of the topics in `decoders` from a rosbag2 sqlite3 file.

    For each batch of rows SQLite concatenates the messages into one value, and their topic
    ids, receive times and lengths into comma-separated text: four Python objects per query
    instead of one per row. The aggregates of one query run over the same rows in the same
    order, so they stay paired.
    """
    connection = sqlite3.connect(f'{Path(path).resolve().as_uri()}?mode=ro', uri=True)
    try:
        topic_ids = {topic_id: topic for topic_id, topic
                     in connection.execute('SELECT id, name FROM topics') if topic in decoders}
        first, last = connection.execute('SELECT min(id), max(id) FROM messages').fetchone()
        if not topic_ids or first is None:
            return
        query = ("SELECT CAST(group_concat(data, '') AS BLOB), group_concat(topic_id), "
                 'group_concat(timestamp), group_concat(length(data)) FROM messages '
                 f'WHERE topic_id IN ({", ".join(map(str, topic_ids))}) AND id >= ? AND id < ?')
        batches = -(-Path(path).stat().st_size // _SQLITE_BATCH_BYTES)
        bounds = np.linspace(first, last + 1, batches + 1).astype(np.int64).tolist()
        for low, high in zip(bounds[:-1], bounds[1:]):
            data, *columns = connection.execute(query, (low, high)).fetchone()
            if data is None:
                continue
            topics, times, lengths = (np.fromstring(text, np.int64, sep=',') for text in columns)
            starts = np.cumsum(lengths) - lengths
            data = np.frombuffer(data, np.uint8)
            for topic_id, topic in topic_ids.items():
                rows = np.flatnonzero(topics == topic_id)
                _add_packed(decoders[topic], data, starts[rows], lengths[rows], times[rows])
    except sqlite3.Error as error:
        raise SessionError(f'{path}: {error}') from None
    finally:
        connection.close()


def _read_with_rosbags(reader, decoders):
    """Decode messages read through rosbags' Reader (any storage, any compression)."""
    connections = [c for c in reader.connections if c.topic in decoders]
    collected = collections.defaultdict(lambda: ([], []))
    for connection, log_time, data in reader.messages(connections=connections):
        times, messages = collected[connection.topic]
        times.append(log_time)
        messages.append(data)
    for topic, (times, messages) in collected.items():
        decoders[topic].add_list(np.array(times, dtype=np.int64), messages)


def _bag_info(path):
    """
    Return (storage, files, compressed, topics) from a bag's metadata.yaml.

    topics is {topic: (msgtype, message count)}. A bare storage file has no metadata:
    its storage comes from the file name, topics is None.
    """
    if path.is_file():
        return {'.mcap': 'mcap', '.db3': 'sqlite3'}.get(path.suffix), [path], False, None
    try:
        with open(path / 'metadata.yaml', encoding='utf-8') as stream:
            info = yaml.safe_load(stream)['rosbag2_bagfile_information']
        files = [path / Path(name).name for name in info['relative_file_paths']]
        topics = {entry['topic_metadata']['name']: (entry['topic_metadata']['type'],
                                                    entry['message_count'])
                  for entry in info['topics_with_message_count']}
        mode = (info.get('compression_mode') or '').lower()
        return info['storage_identifier'], files, mode not in ('', 'none'), topics
    except (yaml.YAMLError, TypeError, KeyError) as error:
        raise SessionError(f'{path}: metadata.yaml is not rosbag2 metadata: {error!r}') from None


def bag_topics(path):
    """Return {topic: (msgtype, message count)} of a bag; raise SessionError if unreadable."""
    path = Path(path)
    try:
        topics = _bag_info(path)[3]
        if topics is None:
            with Reader(path) as reader:
                topics = {name: (info.msgtype, info.msgcount)
                          for name, info in reader.topics.items()}
    except (ReaderError, OSError, KeyError, ValueError) as error:
        raise SessionError(f'{path}: cannot read the bag: {error}') from None
    return topics


def read_topics(path, topics):
    """
    Read `topics` (absolute names) of the bag at `path`; return {topic: TopicData}.

    Topics absent from the bag are absent from the result. Raises SessionError when the
    bag cannot be read at all.
    """
    path = Path(path)
    readers = {'mcap': _read_mcap, 'sqlite3': _read_sqlite}
    types = bag_topics(path)
    decoders = {topic: _TopicDecoder(topic, types[topic][0]) for topic in topics
                if topic in types}
    try:
        storage, files, compressed, _ = _bag_info(path)
        if compressed or storage not in readers:
            with Reader(path) as reader:
                _read_with_rosbags(reader, decoders)
        else:
            for storage_file in files:
                readers[storage](storage_file, decoders)
    except (ReaderError, OSError, KeyError, ValueError, struct.error) as error:
        raise SessionError(f'{path}: cannot read the bag: {error}') from None
    return {topic: decoders[topic].result() for topic in sorted(decoders)}


# -- synthetic sessions, for tests and benchmarks --------------------------------------------


class Samples(NamedTuple):
    """The state of one arm, sample by sample, as the driver would publish it."""

    stamp: np.ndarray  # (N,) int64 ns
    position: np.ndarray  # (N, 6) rad
    velocity: np.ndarray  # (N, 6) rad/s
    effort: np.ndarray  # (N, 6) N*m
    pots: np.ndarray  # (N, 6) counts
    wrist: np.ndarray  # (N, 3) m
    orientation: np.ndarray  # (N, 4) qx qy qz qw
    wrench: np.ndarray  # (N, 6) N, N*m in the base frame


def simulate_samples(count, arm='right', calibration=None, rate_hz=1000.0, noise_counts=1.0,
                     seed=0, start_ns=1_767_225_600_000_000_000):
    """
    Return the Samples of a simulated session of `count` samples.

    The simulator's random-walk operator hand moves the arm, the pots read it through
    `calibration` (default nominal) with Gaussian noise, and the joint angles, velocities,
    poses and J^T F torques of a smooth task wrench follow from the pots as in the driver.
    Stamps are `rate_hz` apart with a little jitter and an occasional late cycle.
    """
    from kraft_master_driver.core.calibration import ArmCalibration, POT_MAX
    from kraft_master_driver.simulation.model import actuators_to_joints, Workspace
    from kraft_master_driver.simulation.operators import RandomWalkOperator
    calibration = calibration or ArmCalibration.nominal(arm)
    rng = np.random.default_rng(seed)
    period_ns = 1e9 / rate_hz
    jitter = rng.normal(0.0, 0.02 * period_ns, count)
    late = rng.random(count) < 0.001
    jitter[late] += rng.uniform(1.0, 3.0, int(late.sum())) * period_ns
    offsets = np.round(np.arange(count) * period_ns + np.maximum.accumulate(jitter))
    stamp = start_ns + offsets.astype(np.int64)
    t = (stamp - stamp[0]) / 1e9
    hand = RandomWalkOperator(Workspace(), 2.0, rng)
    theta = actuators_to_joints(np.array([hand.target(x) for x in t.tolist()]))
    pots = np.clip(np.rint(calibration.joints_to_pots(theta) +
                           rng.normal(0.0, noise_counts, theta.shape)), 0, POT_MAX)
    position = calibration.pots_to_joints(pots)
    velocity = np.gradient(position, t, axis=0) if count > 1 else np.zeros_like(position)
    poses = kinematics.forward(position, arm)
    orientation = np.array([kinematics.rotation_to_quaternion(p) for p in poses]).reshape(-1, 4)
    phases = rng.uniform(0.0, 2.0 * np.pi, 6)
    wrench = np.array([5.0, 5.0, 5.0, 0.2, 0.2, 0.2]) * np.sin(
        2.0 * np.pi * 0.5 * t[:, None] + phases)
    effort = kinematics.joint_torques(position, wrench, arm)
    effort[:, 5] = 0.0
    return Samples(stamp, *(np.ascontiguousarray(values, dtype=float) for values in (
        position, velocity, effort, pots, poses[:, :3, 3], orientation, wrench)))


def write_samples(recorder, namespace, samples, joint_names=None, frame_id='kraft_master_base',
                  diagnostics_every=1000, receive_delay_ns=200_000, diagnostics_topic=None):
    """
    Write `samples` into `recorder` as the driver's topics under `namespace`.

    Each message is serialised by rosbags: joint_states, pose, pots and wrench per sample
    (received receive_delay_ns after their stamp), and a diagnostics message every
    `diagnostics_every` samples: on `<namespace>/diagnostics`, the status named by the bare
    node name, or on `diagnostics_topic` (e.g. /diagnostics) by the node's full name. A late
    cycle and a link timeout are counted every 5000 samples. Topics not yet in the recorder
    are added.
    """
    store = typestore()
    types = store.types
    names = list(joint_names or kinematics.JOINT_NAMES)
    pot_names = [f'pot{i}' for i in range(1, 7)]
    topics = {name: f'{namespace}/{name}' for name in DRIVER_TOPICS}
    status_name = 'kraft_master_node: Kraft Master'
    if diagnostics_topic:
        topics['diagnostics'] = diagnostics_topic
        status_name = f'{namespace}/{status_name}'
    for name in ('joint_states', 'pose', 'pots', 'wrench', 'diagnostics'):
        if topics[name] not in recorder.counts:
            recorder.add_topic(topics[name], DRIVER_TOPICS[name], [qos_profile()])
    header_type, time_type = types['std_msgs/msg/Header'], types['builtin_interfaces/msg/Time']
    pose_type, point, quaternion = (types[f'geometry_msgs/msg/{name}']
                                    for name in ('Pose', 'Point', 'Quaternion'))
    wrench_type, vector = types['geometry_msgs/msg/Wrench'], types['geometry_msgs/msg/Vector3']
    status_type, key_value = (types[f'diagnostic_msgs/msg/{name}']
                              for name in ('DiagnosticStatus', 'KeyValue'))
    empty = np.empty(0)
    for i, stamp in enumerate(samples.stamp.tolist()):
        sec, nanosec = divmod(stamp, 1_000_000_000)
        header = header_type(stamp=time_type(sec=sec, nanosec=nanosec), frame_id=frame_id)
        received = stamp + receive_delay_ns
        x, y, z = samples.wrist[i].tolist()
        qx, qy, qz, qw = samples.orientation[i].tolist()
        fx, fy, fz, mx, my, mz = samples.wrench[i].tolist()
        messages = (
            ('joint_states', types[JOINT_STATE](
                header=header, name=names, position=samples.position[i],
                velocity=samples.velocity[i], effort=samples.effort[i])),
            ('pose', types[POSE_STAMPED](header=header, pose=pose_type(
                position=point(x=x, y=y, z=z),
                orientation=quaternion(x=qx, y=qy, z=qz, w=qw)))),
            ('pots', types[JOINT_STATE](header=header, name=pot_names,
                                        position=samples.pots[i], velocity=empty, effort=empty)),
            ('wrench', types[WRENCH_STAMPED](header=header, wrench=wrench_type(
                force=vector(x=fx, y=fy, z=fz), torque=vector(x=mx, y=my, z=mz)))),
        )
        if i % diagnostics_every == diagnostics_every - 1:
            values = [key_value(key=key, value=value) for key, value in (
                ('loop rate (Hz)', '1000.0'), ('late cycles', str(i // 5000)),
                ('missed cycles', '0'), ('link round trip median (ms)', '0.420'),
                ('link cycles', str(i + 1)), ('link timeouts', str(i // 5000)))]
            messages += (('diagnostics', types[DIAGNOSTIC_ARRAY](header=header, status=[
                status_type(level=0, name=status_name, message='running', hardware_id='sim',
                            values=values)])),)
        for name, message in messages:
            data = store.serialize_cdr(message, message.__msgtype__)
            recorder.write(topics[name], received, data)
