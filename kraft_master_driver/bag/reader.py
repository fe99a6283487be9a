# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Topics of a recorded bag read back as numpy arrays, fast enough for millions of messages.

The raw bytes come straight from the storage: MCAP chunks located through their message
indexes (records scanned where there is none), sqlite3 rows concatenated by SQLite itself;
decoding.py turns them into TopicData. Bags compressed by rosbag2 (file or message mode)
are read through rosbags' Reader.
"""
import collections
from collections.abc import Iterable, Iterator
import os
from pathlib import Path
import sqlite3
import struct

from kraft_master_driver.bag.common import MCAP_MAGIC, MCAP_RECORD, SessionError
from kraft_master_driver.bag.decoding import TopicData, TopicDecoder
from lz4.frame import decompress as lz4_decompress
import numpy as np
from numpy.typing import NDArray
from rosbags.rosbag2 import Reader
from rosbags.rosbag2.errors import ReaderError
import yaml

try:
    from compression import zstd  # type: ignore[import-not-found]  # Python 3.14
except ImportError:
    from backports import zstd

_MCAP_CHUNK = struct.Struct('<QQQII')  # start, end, uncompressed size, crc, compression length
_OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK, _OP_MESSAGE_INDEX = 0x04, 0x05, 0x06, 0x07
_SQLITE_BATCH_BYTES = 1 << 27  # message bytes per query (SQLite caps one value at 1e9 bytes)
_MESSAGE_HEADER = 22  # channel id u16, sequence u32, log time u64, publish time u64
_MESSAGE_RECORD = np.dtype({  # a Message record up to its data
    'names': ['opcode', 'length', 'channel', 'sequence', 'log_time', 'publish_time'],
    'formats': ['u1', '<u8', '<u2', '<u4', '<u8', '<u8'],
    'offsets': [0, 1, 9, 11, 15, 23], 'itemsize': 31})


def _add_packed(decoder: TopicDecoder, data: NDArray[np.uint8], starts: NDArray[np.int64],
                lengths: NDArray[np.int64], times: NDArray[np.int64],
                sequences: NDArray[np.int64] | None = None) -> None:
    """Decode the messages data[starts[i]:starts[i] + lengths[i]], received at times[i]."""
    for length in np.unique(lengths).tolist():
        rows = np.flatnonzero(lengths == length)
        if length <= 0:
            decoder.malformed += len(rows)
            continue
        # Each row is a window of `length` bytes: one copy, no index array per byte.
        windows = np.lib.stride_tricks.sliding_window_view(data, length)
        decoder.add(times[rows], windows[starts[rows]],
                    None if sequences is None else sequences[rows])


def _mcap_messages(data: NDArray[np.uint8], offsets: NDArray[np.int64], channels: dict[int, str],
                   decoders: dict[str, TopicDecoder]) -> None:
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
        decoder = decoders.get(channels.get(channel_id))  # type: ignore[arg-type]  # unknown: None
        if decoder is not None:
            of_channel = channel_ids == channel_id
            decoder.malformed += int(np.count_nonzero(of_channel & ~valid))
            rows = np.flatnonzero(of_channel & valid)
            _add_packed(decoder, data, starts[rows], lengths[rows],
                        headers['log_time'][rows].astype(np.int64),
                        headers['sequence'][rows].astype(np.int64))


def _decompress(data: bytes, compression: str) -> bytes:
    decompressed: bytes  # untyped to mypy: lz4, and zstd (its first import is Python 3.14's)
    if compression == 'zstd':
        decompressed = zstd.decompress(data)
        return decompressed
    if compression == 'lz4':
        decompressed = lz4_decompress(data)
        return decompressed
    raise SessionError(f'unsupported MCAP chunk compression {compression!r}')


class _McapFile:
    """An MCAP file, mapped into memory, read for the topics of some decoders."""

    def __init__(self, path: Path) -> None:
        self.path = path
        try:
            # A plain ndarray view of the map: slicing a memmap subclass costs more.
            self.data = np.memmap(path, np.uint8, mode='r').view(np.ndarray)
        except ValueError:
            raise SessionError(f'{path}: empty file, not MCAP') from None
        # For struct: cheaper than the array itself. numpy types an array a Buffer from
        # Python 3.12 on, and the check is for 3.11.
        self.buffer = memoryview(self.data)  # type: ignore[arg-type]  # an array is a buffer
        if len(self.data) < 16 or self.buffer[:8] != MCAP_MAGIC:
            raise SessionError(f'{path}: not an MCAP file')
        self.channels: dict[int, str] = {}

    def records(self, buffer: memoryview, start: int,
                end: int) -> Iterator[tuple[int, int, int]]:
        """Yield (position, opcode, content length) of the records in buffer[start:end]."""
        position = start
        while position < end:
            if position + 9 > end:
                raise SessionError(f'{self.path}: MCAP record at byte {position} is cut short')
            opcode, length = MCAP_RECORD.unpack_from(buffer, position)
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

    def read(self, decoders: dict[str, TopicDecoder]) -> None:
        """Decode the messages of the topics in `decoders`."""
        chunks: list[tuple[int, list[int]]] = []  # (position, its message indexes' positions)
        offsets: list[NDArray[np.int64]] = []  # message records in the file, not compressed
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

    def chunk(self, position: int, indexes: list[int],
              decoders: dict[str, TopicDecoder]) -> NDArray[np.int64]:
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
        start: int = name_start + name_length + 8
        indexed = {struct.unpack_from('<H', buffer, index + 9)[0]: index for index in indexes}
        nothing = np.empty(0, np.int64)
        if indexed and indexed.keys() <= self.channels.keys():
            wanted: list[int] | None = [index for channel_id, index in indexed.items()
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
            view = memoryview(records)  # type: ignore[arg-type]  # an array is a buffer
            offsets = np.array([at for at, opcode, _ in self.records(view, 0, size)
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


def _read_mcap(path: Path, decoders: dict[str, TopicDecoder]) -> None:
    """Decode the messages of the topics in `decoders` from an MCAP file."""
    _McapFile(path).read(decoders)


def _read_sqlite(path: Path, decoders: dict[str, TopicDecoder]) -> None:
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


def _read_with_rosbags(reader: Reader, decoders: dict[str, TopicDecoder]) -> None:
    """Decode messages read through rosbags' Reader (any storage, any compression)."""
    connections = [c for c in reader.connections if c.topic in decoders]
    # topic -> (receive times, messages)
    collected: collections.defaultdict[str, tuple[list[int], list[bytes]]] = (
        collections.defaultdict(lambda: ([], [])))
    for connection, log_time, data in reader.messages(connections=connections):
        times, messages = collected[connection.topic]
        times.append(log_time)
        messages.append(data)
    for topic, (times, messages) in collected.items():
        decoders[topic].add_list(np.array(times, dtype=np.int64), messages)


def _bag_info(
        path: Path,
) -> tuple[str | None, list[Path], bool, dict[str, tuple[str, int]] | None]:
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


def bag_topics(path: str | os.PathLike[str]) -> dict[str, tuple[str, int]]:
    """Return {topic: (msgtype, message count)} of a bag; raise SessionError if unreadable."""
    path = Path(path)
    try:
        topics = _bag_info(path)[3]
        if topics is None:
            with Reader(path) as reader:
                topics = {
                    name: (info.msgtype, info.msgcount)  # type: ignore[misc]  # one type each
                    for name, info in reader.topics.items()}
    except (ReaderError, OSError, KeyError, ValueError) as error:
        raise SessionError(f'{path}: cannot read the bag: {error}') from None
    return topics


def read_topics(path: str | os.PathLike[str], topics: Iterable[str]) -> dict[str, TopicData]:
    """
    Read `topics` (absolute names) of the bag at `path`; return {topic: TopicData}.

    Topics absent from the bag are absent from the result. Raises SessionError when the
    bag cannot be read at all.
    """
    path = Path(path)
    readers = {'mcap': _read_mcap, 'sqlite3': _read_sqlite}
    types = bag_topics(path)
    decoders = {topic: TopicDecoder(topic, types[topic][0]) for topic in topics
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
