# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Raw CDR messages into a new rosbag2 directory, as `ros2 bag record` of ROS 2 Jazzy writes it.

BagRecorder takes the bytes as a subscription with raw=True receives them, and writes the
storage file through mcap_writer.py or sqlite3_writer.py, then metadata.yaml (version 9,
ros_distro jazzy). Message definitions and RIHS01 type hashes are rosbag2's.
"""
from collections.abc import Iterable, Sequence
import functools
import os
from pathlib import Path
import re
import sqlite3
import sys
import threading
from typing import NamedTuple, Self

from kraft_master_driver.bag.common import (
    BAG_VERSION, INFINITE_NS, ROS_DISTRO, SessionError, typestore)
from kraft_master_driver.bag.mcap_writer import McapWriter
from kraft_master_driver.bag.sqlite3_writer import Sqlite3Writer
from rosbags.interfaces import (
    Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime)
import yaml

STORAGES = ('mcap', 'sqlite3')
_STORAGE_WRITERS: dict[str, type[McapWriter] | type[Sqlite3Writer]] = {
    'mcap': McapWriter, 'sqlite3': Sqlite3Writer}
# How rosbag2 finds the types a .msg file uses.
_MSG_FIELD_TYPE = re.compile(r'(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+')
_PRIMITIVE_TYPES = {'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16',
                    'uint16', 'int32', 'uint32', 'int64', 'uint64', 'string'}


def _duration(nanoseconds: int) -> QosTime:
    return QosTime(*divmod(int(nanoseconds), 1_000_000_000))


def qos_profile(reliability: str = 'reliable', durability: str = 'volatile',
                history: str = 'unknown', depth: int = 0, deadline_ns: int = INFINITE_NS,
                lifespan_ns: int = INFINITE_NS, liveliness: str = 'automatic',
                liveliness_lease_duration_ns: int = INFINITE_NS,
                avoid_ros_namespace_conventions: bool = False) -> Qos:
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


def _qos_dicts(profiles: Iterable[Qos]) -> list[dict[str, object]]:
    """Return QoS profiles as rosbag2 (metadata version 9) writes them in YAML."""
    def duration(value: QosTime) -> dict[str, int]:
        return {'sec': value.sec, 'nsec': value.nsec}
    return [{'history': qos.history.name.lower(), 'depth': qos.depth,
             'reliability': qos.reliability.name.lower(),
             'durability': qos.durability.name.lower(), 'deadline': duration(qos.deadline),
             'lifespan': duration(qos.lifespan), 'liveliness': qos.liveliness.name.lower(),
             'liveliness_lease_duration': duration(qos.liveliness_lease_duration),
             'avoid_ros_namespace_conventions': qos.avoid_ros_namespace_conventions}
            for qos in profiles]


def _dump_yaml(value: object) -> str:
    text: str = yaml.safe_dump(value, sort_keys=False, default_flow_style=False)
    return text.rstrip('\n')


def _share_directory(package: str) -> Path:
    """Return the share directory of an installed ROS package, as the ament index finds it."""
    prefixes = os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) + [sys.prefix]
    for prefix in filter(None, prefixes):
        if (Path(prefix) / 'share/ament_index/resource_index/packages' / package).exists():
            return Path(prefix) / 'share' / package
    raise LookupError(package)


def _msg_text(name: str, seen: set[str]) -> str:
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
def message_definition(msgtype: str) -> tuple[str, str]:
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


class _Topic(NamedTuple):
    name: str
    msgtype: str
    offered_qos: list[Qos]
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

    def __init__(self, path: str | os.PathLike[str], storage: str = 'mcap') -> None:
        """Create the bag directory `path` (it must not exist) with storage mcap or sqlite3."""
        if storage not in STORAGES:
            raise ValueError(f'storage must be one of {", ".join(STORAGES)}, got {storage!r}')
        self.path = Path(path)
        self.storage = storage
        self.counts: dict[str, int] = {}
        self._topics: dict[str, tuple[int, _Topic]] = {}  # name -> (topic id, _Topic)
        self._lock = threading.Lock()
        self._time_span = [INFINITE_NS, 0]
        self.file_name = f'{self.path.name}_0{_STORAGE_WRITERS[storage].extension}'
        try:
            self.path.mkdir(parents=True)
        except OSError as error:
            raise SessionError(f'{self.path}: cannot create the bag: {error.strerror}') from None
        try:
            self._storage: McapWriter | Sqlite3Writer | None = _STORAGE_WRITERS[storage](
                self.path / self.file_name)
        except (OSError, sqlite3.Error) as error:
            raise SessionError(f'{self.path}: cannot create the bag: {error}') from None

    def add_topic(self, topic: str, msgtype: str, offered_qos: Sequence[Qos] = (),
                  type_hash: str | None = None) -> None:
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
            self._storage.add_topic(  # type: ignore[union-attr]  # closed: AttributeError
                len(self._topics), entry)
            self.counts[topic] = 0

    def write(self, topic: str, timestamp_ns: int, data: bytes | memoryview,
              publish_time_ns: int | None = None, sequence: int = 0) -> None:
        """
        Write one message's raw CDR bytes, received at `timestamp_ns` (ns since the epoch).

        publish_time_ns is when the publisher sent it (the source timestamp; MCAP stores it
        as the publish time); by default the receive time. sequence is the publisher's count
        of the message (DDS's publication sequence number; MCAP stores it, 0: not known), by
        which a reader tells the messages the recorder lost.
        """
        log_time = int(timestamp_ns)
        publish_time = log_time if publish_time_ns is None else int(publish_time_ns)
        with self._lock:
            entry = self._topics.get(topic)
            if entry is None:
                raise ValueError(f'{topic}: not added to the bag; call add_topic first')
            if self._storage is None:
                raise ValueError(f'{self.path}: the bag is closed')
            self._storage.write(entry[0], log_time, publish_time, bytes(data), sequence)
            self.counts[topic] += 1
            span = self._time_span
            span[0], span[1] = min(span[0], log_time), max(span[1], log_time)

    def metadata(self) -> dict[str, object]:
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

    def close(self) -> None:
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

    def __enter__(self) -> Self:
        """Return the recorder."""
        return self

    def __exit__(self, *_exc: object) -> None:
        """Close the bag."""
        self.close()
