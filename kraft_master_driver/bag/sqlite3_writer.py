# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The .db3 file of a bag, as rosbag2 Jazzy's sqlite3 plugin (schema version 4) writes it."""
from pathlib import Path
import sqlite3
from typing import TYPE_CHECKING

from kraft_master_driver.bag.common import BAG_VERSION, ROS_DISTRO

if TYPE_CHECKING:
    from kraft_master_driver.bag.recorder import _Topic

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


class Sqlite3Writer:
    """A .db3 file with the schema (version 4) of rosbag2 Jazzy's sqlite3 plugin."""

    extension = '.db3'
    batch = 1000  # messages per transaction

    def __init__(self, path: Path) -> None:
        """Create the database `path` (it must not exist) with rosbag2's tables."""
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
        self.types: set[str] = set()
        self.pending: list[tuple[int, int, bytes]] = []  # (log time, topic id, data)

    def add_topic(self, topic_id: int, topic: '_Topic') -> None:
        """Insert `topic` (a recorder's _Topic), and its type's definition if new."""
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

    def write(self, topic_id: int, log_time: int, _publish_time: int, data: bytes,
              _sequence: int = 0) -> None:
        """Add a message (no publish time, no sequence); commit every `batch` messages."""
        self.pending.append((log_time, topic_id, data))
        if len(self.pending) >= self.batch:
            self._flush()

    def _flush(self) -> None:
        self.database.executemany(
            'INSERT INTO messages (timestamp, topic_id, data) VALUES (?, ?, ?);', self.pending)
        self.database.execute('COMMIT')
        self.database.execute('BEGIN')
        self.pending = []

    def close(self, metadata: str) -> None:
        """Commit the last messages and the bag's `metadata` (YAML); close the database."""
        self._flush()
        self.database.execute('INSERT INTO metadata (metadata_version, metadata) VALUES (?, ?)',
                              (BAG_VERSION, metadata))
        self.database.execute('COMMIT')
        self.database.close()

    def abort(self) -> None:
        """Close the database as it is."""
        self.database.close()
