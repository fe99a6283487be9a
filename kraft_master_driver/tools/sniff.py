# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
kraft_master_sniff: record a device's raw bytes and help find its reply frame.

It opens the port (a path or a pyserial URL), records every chunk of bytes read from it
('rx') and written to it ('tx') with its time in a JSON-lines file, and then analyses the
recording: the reply's length (from repeating byte patterns and the arrival bursts) and period,
the bytes that never change (header candidates), a length byte, a sequence byte, the checksum
among those a frame description can express, and, from segments in which the operator moved
one joint at a time, the pot fields that follow each joint. It writes a draft frame description
that link/frame_description.py loads. `--replay FILE` analyses a recording without a device.

A polled device answers nothing unprompted, and the sniffer cannot guess the command: give it
one with --poll (hex bytes sent every --period seconds), or record without --poll from a device
that sends by itself. doc/device-link.md ('Finding an unknown frame') says how to use it.

The recording, one JSON object a line:

    {"kraft_master_sniff": 1, "port": ..., "baud": ..., "poll": hex or null, "started": unix s}
    {"t": s since start, "dir": "rx" or "tx", "hex": "55aa0e..."}
    {"t": s since start, "mark": "joint 3"}   the operator moves joint 3 from here ...
    {"t": s since start, "mark": ""}          ... to here
"""
import argparse
import collections
from dataclasses import dataclass, field
import json
import sys
import threading
import time

from kraft_master_driver.link.checksums import make_crc, SUMS
from kraft_master_driver.link.frame_description import (
    FrameDescriptionError, load_description)
import numpy as np
import serial

FORMAT_VERSION = 1
JOINTS = 6
MAX_FRAME = 255  # the longest frame a description can give
MIN_FRAMES = 8  # fewer repeats than this and nothing can be said
CHECKSUM_SAMPLE = 64  # distinct frames the checksums are tried on
SEQUENCE_SHARE = 0.8  # the share of frame pairs in which a sequence byte steps by one
QUIET_END = 0.5  # s without a byte after the last poll (--count) that end the recording
READ_SIZE = 4096
# The checksums a description can express, wider ones first (a sum16 that fits also fits as
# sum8 in its low byte): (name, description keys).
CATALOGUE = (
    ('CRC-16/CCITT-FALSE', {'type': 'crc16', 'poly': 0x1021, 'init': 0xFFFF, 'refin': False,
                            'xorout': 0}),
    ('CRC-16/XMODEM', {'type': 'crc16', 'poly': 0x1021, 'init': 0, 'refin': False, 'xorout': 0}),
    ('CRC-16/KERMIT', {'type': 'crc16', 'poly': 0x1021, 'init': 0, 'refin': True, 'xorout': 0}),
    ('CRC-16/MODBUS', {'type': 'crc16', 'poly': 0x8005, 'init': 0xFFFF, 'refin': True,
                       'xorout': 0}),
    ('CRC-16/ARC', {'type': 'crc16', 'poly': 0x8005, 'init': 0, 'refin': True, 'xorout': 0}),
    ('CRC-16/GENIBUS', {'type': 'crc16', 'poly': 0x1021, 'init': 0xFFFF, 'refin': False,
                        'xorout': 0xFFFF}),
    ('sum16', {'type': 'sum16'}),
    ('CRC-8/SMBUS', {'type': 'crc8', 'poly': 0x07, 'init': 0, 'refin': False, 'xorout': 0}),
    ('CRC-8/MAXIM-DOW', {'type': 'crc8', 'poly': 0x31, 'init': 0, 'refin': True, 'xorout': 0}),
    ('CRC-8/SAE-J1850', {'type': 'crc8', 'poly': 0x1D, 'init': 0xFF, 'refin': False,
                         'xorout': 0xFF}),
    ('sum8', {'type': 'sum8'}),
    ('xor8', {'type': 'xor8'}),
)


def checksum_function(keys):
    """Return the function of a catalogue entry's description keys."""
    kind = keys['type']
    if kind in SUMS:
        return SUMS[kind]
    width = 16 if kind == 'crc16' else 8
    return make_crc(width, keys['poly'], keys['init'], keys['refin'], keys['refin'],
                    keys['xorout'])


# Reading and writing recordings.

@dataclass
class Recording:
    """A recording: its header, the chunks (time, direction, bytes) and the marks (time, label)."""

    header: dict = field(default_factory=dict)
    chunks: list = field(default_factory=list)
    marks: list = field(default_factory=list)

    def stream(self, direction):
        """Return the bytes of one direction, and the time of each byte's chunk (numpy)."""
        data = bytearray()
        times = []
        for t, chunk_direction, chunk in self.chunks:
            if chunk_direction == direction:
                data += chunk
                times.extend([t] * len(chunk))
        return bytes(data), np.asarray(times, dtype=float)

    def bursts(self, direction):
        """Return (time, offset in the stream) of each chunk of one direction."""
        offset, bursts = 0, []
        for t, chunk_direction, chunk in self.chunks:
            if chunk_direction == direction:
                bursts.append((t, offset))
                offset += len(chunk)
        return bursts

    def segments(self):
        """Return (label, start, end) of each marked segment, in seconds."""
        segments, open_mark = [], None
        for t, label in self.marks:
            if open_mark is not None:
                segments.append((open_mark[1], open_mark[0], t))
            open_mark = (t, label) if label else None
        return segments


def read_recording(path):
    """Read a recording file; ValueError naming the line if it is not one."""
    recording = Recording()
    with open(path, encoding='utf-8') as stream:
        for number, line in enumerate(stream, 1):
            if not line.strip():
                continue
            try:
                item = json.loads(line)
                if number == 1:
                    if item.get('kraft_master_sniff') != FORMAT_VERSION:
                        raise ValueError('not a kraft_master_sniff recording')
                    recording.header = item
                elif 'mark' in item:
                    recording.marks.append((float(item['t']), str(item['mark'])))
                else:
                    if item['dir'] not in ('rx', 'tx'):
                        raise ValueError(f'dir must be rx or tx, got {item["dir"]!r}')
                    recording.chunks.append((float(item['t']), item['dir'],
                                             bytes.fromhex(item['hex'])))
            except (ValueError, KeyError, TypeError, AttributeError) as error:
                raise ValueError(f'{path}:{number}: {error}') from None
    if not recording.header:
        raise ValueError(f'{path}: empty')
    return recording


class RecordingWriter:
    """Writes a recording as it happens; thread-safe enough for one reader and one prompter."""

    def __init__(self, stream, header):
        """Write to the text stream, starting with header (a dict); times from now."""
        self._stream = stream
        self._start = time.monotonic()
        stream.write(json.dumps({'kraft_master_sniff': FORMAT_VERSION, **header}) + '\n')

    def now(self):
        """Return the seconds since the recording started."""
        return round(time.monotonic() - self._start, 6)

    def chunk(self, direction, data):
        """Record bytes read ('rx') or written ('tx')."""
        self._stream.write(json.dumps({'t': self.now(), 'dir': direction,
                                       'hex': bytes(data).hex()}) + '\n')

    def mark(self, label):
        """Start a segment called label, or end the open one (label '')."""
        self._stream.write(json.dumps({'t': self.now(), 'mark': label}) + '\n')
        self._stream.flush()


def prompt_moves(writer, ask, say, joints=JOINTS):
    """Ask the operator to move each joint alone in turn; mark each move in the recording."""
    for joint in range(1, joints + 1):
        ask(f'Hold the handle still. Press Enter, then move joint {joint} alone through as much '
            'of its range as you can. ')
        writer.mark(f'joint {joint}')
        ask(f'Moving joint {joint}; press Enter when done. ')
        writer.mark('')
    say('All joints done.')


# Analysis.

@dataclass
class FrameFinding:
    """What the analysis found out about one direction's frames."""

    direction: str
    length: int = 0
    phase: int = 0
    period: float | None = None
    frames: list = field(default_factory=list)
    frame_times: list = field(default_factory=list)
    distinct: int = 0
    constant: dict = field(default_factory=dict)  # offset -> byte that never changes
    header: bytes = b''
    length_field: tuple | None = None  # (offset, 'frame' or 'following')
    sequence: int | None = None
    checksums: list = field(default_factory=list)  # (name, keys, offset, order, covers)
    notes: list = field(default_factory=list)


def frame_length(data, max_length=MAX_FRAME):
    """Return the repeat length of a byte stream: the shortest lag at which it best repeats."""
    array = np.frombuffer(data, dtype=np.uint8)
    longest = min(max_length, len(array) // MIN_FRAMES)
    if longest < 2:
        return 0
    scores = np.array([np.mean(array[lag:] == array[:-lag]) for lag in range(1, longest + 1)])
    best = scores.max()
    if best < 0.1:
        return 0
    return int(np.argmax(scores >= 0.9 * best)) + 1


def _phase(data, length, bursts):
    """Return where the first whole frame starts: most chunks start a frame."""
    starts = collections.Counter(offset % length for _, offset in bursts)
    if len(bursts) >= MIN_FRAMES and starts:
        return starts.most_common(1)[0][0]
    # One long chunk: the frame starts at the longest run of never-changing bytes.
    frames = [data[start:start + length] for start in range(0, len(data) - length + 1, length)]
    fixed = [len({frame[offset] for frame in frames}) == 1 for offset in range(length)]
    best, best_run = 0, -1
    for offset in range(length):
        run = 0
        while run < length and fixed[(offset + run) % length]:
            run += 1
        if run > best_run and (not fixed[offset - 1] or run == length):
            best, best_run = offset, run
    return best


def find_frames(recording, direction):
    """Analyse one direction's bytes; return a FrameFinding."""
    finding = FrameFinding(direction)
    data, times = recording.stream(direction)
    bursts = recording.bursts(direction)
    if not data:
        finding.notes.append(f'no {direction} bytes recorded')
        return finding
    length = frame_length(data)
    sizes = collections.Counter(len(chunk) for _, d, chunk in recording.chunks if d == direction)
    if length == 0 and len(sizes) == 1 and len(bursts) >= 2:
        length = next(iter(sizes))  # the same frame every time: the chunk is the frame
    if length == 0:
        finding.notes.append(f'{direction}: no repeating pattern in {len(data)} bytes')
        return finding
    finding.length = length
    finding.phase = phase = _phase(data, length, bursts)
    frames = [data[start:start + length]
              for start in range(phase, len(data) - length + 1, length)]
    starts = collections.Counter(frame[:1] for frame in frames).most_common(1)[0][0]
    kept = [(bytes(frame), float(times[phase + index * length]))
            for index, frame in enumerate(frames) if frame[:1] == starts]
    finding.frames = [frame for frame, _ in kept]
    finding.frame_times = [t for _, t in kept]
    if len(kept) < len(frames):
        finding.notes.append(f'{direction}: {len(frames) - len(kept)} frame(s) out of step '
                             'dropped (lost or garbled bytes)')
    if len(finding.frame_times) >= 2:
        finding.period = float(np.median(np.diff(finding.frame_times)))
    distinct = sorted(set(finding.frames))
    finding.distinct = len(distinct)
    finding.constant = {offset: distinct[0][offset] for offset in range(length)
                        if len({frame[offset] for frame in distinct}) == 1}
    _header_and_length(finding)
    _sequence(finding)
    _checksums(finding)
    return finding


def _header_and_length(finding):
    """Set the header (the fixed bytes from offset 0) and a length byte if one ends it."""
    run = 0
    while run in finding.constant:
        run += 1
    for offset in range(1, run):
        value = finding.constant[offset]
        if value == finding.length:
            finding.length_field = (offset, 'frame')
        elif value == finding.length - offset - 1:
            finding.length_field = (offset, 'following')
        if finding.length_field:
            run = offset
            break
    finding.header = bytes(finding.constant[offset] for offset in range(max(run, 1)))
    if not run:
        finding.notes.append(f'{finding.direction}: the first byte changes: no header found')


def _sequence(finding):
    """Set the sequence byte: one that steps by one, modulo 256, from frame to frame."""
    frames = finding.frames
    if len(frames) < MIN_FRAMES:
        return
    for offset in range(finding.length):
        steps = sum((later[offset] - earlier[offset]) % 256 == 1
                    for earlier, later in zip(frames, frames[1:]))
        if steps >= SEQUENCE_SHARE * (len(frames) - 1):
            finding.sequence = offset
            return


def _placements(length, header_length, width):
    """Yield (offset, covers) for a check value after the header over bytes just before it."""
    for offset in range(max(header_length, 1), length - width + 1):
        for start in range(0, min(offset, header_length + 2)):
            yield offset, (start, offset)


def _checksums(finding, catalogue=CATALOGUE):
    """Try each catalogue checksum at each plausible place on the distinct frames."""
    frames = sorted(set(finding.frames))[:CHECKSUM_SAMPLE]
    if len(frames) < 2:
        finding.notes.append(f'{finding.direction}: the frame never changed: a checksum '
                             'cannot be told from data')
        return
    taken = len(finding.header) + (finding.length_field is not None)
    for name, keys in catalogue:
        function = checksum_function(keys)
        width = 2 if keys['type'] in ('crc16', 'sum16') else 1
        orders = ('little', 'big') if width == 2 else ('little',)
        for offset, (start, end) in _placements(finding.length, taken, width):
            values = {frame[offset:offset + width] for frame in frames}
            if len(values) < 2:
                continue
            for order in orders:
                if all(function(frame[start:end]) == int.from_bytes(
                        frame[offset:offset + width], order) for frame in frames):
                    finding.checksums.append((name, keys, offset, order, [start, end]))


def check_single_frame(finding, checksums):
    """For a frame that never changed, keep the given checksums that fit it (a weak proof)."""
    if finding.distinct != 1 or not finding.frames:
        return
    frame = finding.frames[0]
    taken = len(finding.header) + (finding.length_field is not None)
    for name, keys, _offset, order, covers in checksums:
        width = 2 if keys['type'] in ('crc16', 'sum16') else 1
        offset = finding.length - width  # at the end, as a checksum most often is
        function = checksum_function(keys)
        for start in range(0, min(offset, taken + 2)):
            if function(frame[start:offset]) == int.from_bytes(frame[offset:], order):
                finding.checksums.append((name, keys, offset, order, [start, offset]))
                finding.notes.append(f'{finding.direction}: {name} fits the one frame seen '
                                     '(one frame is a weak proof)')
                return


@dataclass
class PotField:
    """A two-byte field that followed a joint: its offset and byte order."""

    joint: int
    offset: int
    order: str
    low: int
    high: int
    sure: bool


def find_pots(finding, segments, excluded):
    """Return the PotField of each joint moved in a segment ('joint N'), and notes."""
    notes, moved = [], {}
    for label, start, end in segments:
        try:
            joint = int(label.split()[-1])
        except (ValueError, IndexError):
            notes.append(f'segment {label!r}: not "joint N", ignored')
            continue
        frames = [frame for frame, t in zip(finding.frames, finding.frame_times)
                  if start <= t <= end]
        if len(frames) < 2:
            notes.append(f'joint {joint}: {len(frames)} frame(s) while it moved: move it longer')
            continue
        counts = {offset: len({frame[offset] for frame in frames})
                  for offset in range(finding.length) if offset not in excluded}
        changing = {offset for offset, count in counts.items() if count > 1}
        if not changing:
            notes.append(f'joint {joint}: no byte changed while it moved')
            continue
        lsb = max(sorted(changing), key=lambda offset: counts[offset])
        moved[joint] = (lsb, frames, changing)
    # One byte order for all pots (a description gives one): where the byte beside the busiest
    # one also changed, it is the high byte.
    votes = collections.Counter()
    for lsb, _, changing in moved.values():
        if lsb + 1 in changing and lsb - 1 not in changing:
            votes['little'] += 1
        elif lsb - 1 in changing and lsb + 1 not in changing:
            votes['big'] += 1
    order = votes.most_common(1)[0][0] if votes else 'little'
    sure = bool(votes) and len(votes) == 1
    if not sure:
        notes.append(f'pot byte order: {dict(votes) or "no joint crossed a high byte"}; '
                     f'{order} assumed: move each joint through more of its range')
    pots = []
    for joint, (lsb, frames, _) in sorted(moved.items()):
        offset = lsb if order == 'little' else lsb - 1
        if offset < 0 or offset + 2 > finding.length:
            notes.append(f'joint {joint}: its byte {lsb} has no neighbour for a {order}-endian '
                         'pair')
            continue
        values = [int.from_bytes(frame[offset:offset + 2], order) for frame in frames]
        earlier = [pot.joint for pot in pots if abs(pot.offset - offset) < 2]
        if earlier:
            notes.append(f'joint {joint}: bytes {offset}..{offset + 1} also followed joint '
                         f'{earlier[0]}: was each joint moved alone? the draft guesses one')
        pots.append(PotField(joint, offset, order, min(values), max(values), sure))
    return pots, notes


# The draft description.

def _checksum_yaml(entry, indent='  '):
    name, keys, offset, order, covers = entry
    lines = [f'{indent}checksum:  # {name}, found by the sniffer',
             f'{indent}  type: {keys["type"]}']
    if keys['type'] in ('crc8', 'crc16'):
        digits = 4 if keys['type'] == 'crc16' else 2
        lines += [f'{indent}  poly: 0x{keys["poly"]:0{digits}X}',
                  f'{indent}  init: 0x{keys["init"]:0{digits}X}',
                  f'{indent}  refin: {str(keys["refin"]).lower()}',
                  f'{indent}  refout: {str(keys["refin"]).lower()}',
                  f'{indent}  xorout: 0x{keys["xorout"]:0{digits}X}']
    lines += [f'{indent}  offset: {offset}']
    if keys['type'] in ('crc16', 'sum16'):
        lines += [f'{indent}  order: {order}']
    lines += [f'{indent}  covers: [{covers[0]}, {covers[1]}]']
    return lines


def _common_lines(finding):
    lines = [f'  size: {finding.length}', f"  header: '{finding.header.hex(' ').upper()}'"]
    if finding.sequence is not None:
        lines.append(f'  sequence: {{offset: {finding.sequence}, width: 1}}')
    if finding.length_field is not None:
        offset, counts = finding.length_field
        lines.append(f'  length: {{offset: {offset}, counts: {counts}}}')
    return lines


def _used(finding):
    used = set(range(len(finding.header)))
    if finding.sequence is not None:
        used.add(finding.sequence)
    if finding.length_field is not None:
        used.add(finding.length_field[0])
    if finding.checksums:
        _, keys, offset, _, _ = finding.checksums[0]
        used.update(range(offset, offset + (2 if keys['type'] in ('crc16', 'sum16') else 1)))
    return used


def _free_pairs(length, used, count, width=2):
    """Return count offsets of width free bytes each, in order, or None."""
    offsets, offset = [], 0
    while len(offsets) < count and offset + width <= length:
        if not used & set(range(offset, offset + width)):
            offsets.append(offset)
            used = used | set(range(offset, offset + width))
            offset += width
        else:
            offset += 1
    return offsets if len(offsets) == count else None


def draft_yaml(name, reply, command, pots):
    """Return the text of a draft frame description; ValueError if no frame can be written."""
    if not reply.length:
        raise ValueError('no reply frame found: nothing to draft')
    used = _used(reply)
    by_joint = {pot.joint: pot for pot in pots}
    order = pots[0].order if pots else 'little'
    offsets, guessed = [], []
    for joint in range(1, JOINTS + 1):
        if joint in by_joint and not used & {by_joint[joint].offset, by_joint[joint].offset + 1}:
            offsets.append(by_joint[joint].offset)
            used = used | {by_joint[joint].offset, by_joint[joint].offset + 1}
        else:
            offsets.append(None)
            guessed.append(joint)
    for index, joint in enumerate(guessed):
        free = _free_pairs(reply.length, used, 1)
        if free is None:
            raise ValueError(f'no room left in the {reply.length}-byte reply for POT{joint}')
        offsets[joint - 1] = free[0]
        used = used | {free[0], free[0] + 1}
    lines = [
        '# A DRAFT written by kraft_master_sniff from a recording. Check every line against the',
        "# device's manual before use: the sniffer found what the bytes show, not what they mean.",
        f'name: {name}',
        'note: a draft from kraft_master_sniff',
        'reply:']
    lines += _common_lines(reply)
    guess_note = (f'  # POT{", POT".join(map(str, guessed))} not found on their own: placed '
                  'in free bytes, a guess') if guessed else ''
    lines.append(f'  pots: {{offset: {offsets}, width: 2, signed: false, order: {order}}}'
                 + guess_note)
    lines.append('  # status: not found by the sniffer; add it from the manual')
    if reply.checksums:
        lines += _checksum_yaml(reply.checksums[0])
    command_lines, limit = _command_lines(command)
    lines += command_lines
    seen = max((pot.high for pot in pots), default=0)
    lines += [
        f'pots: {{bits: 16, range: [0, 65535]}}  # the highest count seen: {seen}; set 10 or 12 '
        'bits from the manual',
        'torque:  # NOT from the sniffer: placeholders, to be set from the manual',
        '  counts_per_nm: [1000.0, 1000.0, 1000.0, 1000.0, 1000.0]',
        '  sign: [1, 1, 1, 1, 1]',
        f'  limit: [{limit}, {limit}, {limit}, {limit}, {limit}]']
    return '\n'.join(lines) + '\n'


def _command_lines(command):
    """Return the command's lines (what the poll showed, torques where there is room), clamp."""
    if command is None or not command.length:
        return ['command:  # NOT OBSERVED (no --poll): a placeholder to be replaced',
                '  size: 13', "  header: 'FF'",
                '  torques: {offset: 1, width: 2, signed: true, order: little}'], 3000
    used = _used(command)
    lines = ['command:  # the poll sent; the torque fields are placed in free bytes, a guess']
    lines += _common_lines(command)
    for width in (2, 1):
        offsets = _free_pairs(command.length, used, 5, width)
        if offsets is not None:
            break
    else:
        raise ValueError(f'the {command.length}-byte poll has no room for five torque fields')
    if offsets == list(range(offsets[0], offsets[0] + 5 * width, width)):
        where = str(offsets[0])
    else:
        where = str(offsets)
    lines.append(f'  torques: {{offset: {where}, width: {width}, signed: true, order: little}}')
    if command.checksums:
        lines += _checksum_yaml(command.checksums[0])
    return lines, 127 if width == 1 else 3000


# Reporting.

def describe(finding):
    """Return lines telling what was found about one direction."""
    if not finding.length:
        return finding.notes or [f'{finding.direction}: nothing found']
    name = 'reply (device -> host)' if finding.direction == 'rx' else 'command (host -> device)'
    lines = [f'{name}: {finding.length} bytes a frame, {len(finding.frames)} frames, '
             f'{finding.distinct} distinct']
    if finding.period:
        lines.append(f'  period: {finding.period * 1e3:.2f} ms (median between frames)')
    fixed = ' '.join(f'{offset}:{value:02X}' for offset, value in sorted(finding.constant.items()))
    lines.append(f'  bytes that never changed (offset:value): {fixed or "none"}')
    lines.append(f"  header: '{finding.header.hex(' ').upper()}'")
    if finding.length_field:
        lines.append(f'  length byte at {finding.length_field[0]} '
                     f'(counts {finding.length_field[1]})')
    if finding.sequence is not None:
        lines.append(f'  sequence byte at {finding.sequence}')
    for name_, _keys, offset, order, covers in finding.checksums:
        where = f'{offset} ({order}-endian)' if _keys['type'] in ('crc16', 'sum16') else offset
        lines.append(f'  checksum: {name_} at {where}, covering bytes '
                     f'{covers[0]}..{covers[1] - 1}')
    if not finding.checksums and finding.distinct > 1:
        lines.append('  checksum: none of the catalogue fits (none, or one a description '
                     'cannot express)')
    return lines + [f'  note: {note}' for note in finding.notes]


def analyse(recording, name='sniffed', out=print):
    """Analyse a recording, print what was found; return the draft YAML text (or None)."""
    reply = find_frames(recording, 'rx')
    command = find_frames(recording, 'tx') if recording.header.get('poll') else None
    if command is not None:
        check_single_frame(command, reply.checksums)
    for line in describe(reply) + (describe(command) if command else []):
        out(line)
    segments = recording.segments()
    pots = []
    if reply.length and segments:
        pots, notes = find_pots(reply, segments, _used(reply))
        for pot in pots:
            out(f'joint {pot.joint}: bytes {pot.offset}..{pot.offset + 1} ({pot.order}-endian) '
                f'followed it, {pot.low}..{pot.high}')
        for note in notes:
            out(f'note: {note}')
    elif reply.length:
        out('no joint moves in the recording (record with --moves): pot fields not found')
    if not reply.length:
        return None
    return draft_yaml(name, reply, command, pots)


# Recording from a port.

def record(port, baud, path, poll=None, period=0.01, duration=10.0, count=None, moves=False,
           ask=input, say=print, min_bytes=0):
    """
    Record the port to path, sending poll (bytes or None) every period s.

    Without moves, stop after duration s, or once count polls are sent, min_bytes received and
    the port quiet for QUIET_END s; with moves, once the operator has moved every joint.
    """
    connection = serial.serial_for_url(port, baudrate=baud, timeout=0)
    try:
        with open(path, 'w', encoding='utf-8') as stream:
            writer = RecordingWriter(stream, {'port': port, 'baud': baud,
                                              'poll': poll.hex() if poll else None,
                                              'started': time.time()})
            _record_loop(connection, writer, poll, period, (duration, count, min_bytes), moves,
                         ask, say)
    finally:
        connection.close()


def _record_loop(connection, writer, poll, period, ends, moves, ask, say):
    duration, count, min_bytes = ends
    done = threading.Event()
    prompter = None
    if moves:
        def prompt():
            try:
                prompt_moves(writer, ask, say)
            except EOFError:
                say('no more input: the moves end here')
            finally:
                done.set()
        prompter = threading.Thread(target=prompt, daemon=True)
        prompter.start()
    start = time.monotonic()
    next_poll, sent, last_data, received = start, 0, start, 0
    while not done.is_set():
        now = time.monotonic()
        if not moves and now - start >= duration:
            break
        if poll and (count is None or sent < count) and now >= next_poll:
            connection.write(poll)
            writer.chunk('tx', poll)
            sent += 1
            next_poll = max(next_poll + period, now)
        elif not moves and count is not None and sent >= count and received >= min_bytes \
                and now - max(last_data, next_poll) >= QUIET_END:
            break  # every poll sent, and the port has been quiet since
        data = connection.read(READ_SIZE)
        if data:
            writer.chunk('rx', data)
            last_data = time.monotonic()
            received += len(data)
        else:
            time.sleep(min(0.001, period / 4))
    if prompter is not None:
        prompter.join(timeout=0.1)


# The command line.

def _parser():
    parser = argparse.ArgumentParser(
        prog='kraft_master_sniff',
        description="Record a device's raw bytes and find its reply frame: length, period, "
                    'header, checksum, the pot fields; write a draft frame description.')
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument('--port', help='serial port path or pyserial URL of the device')
    source.add_argument('--replay', metavar='FILE', help='analyse a recording, no device')
    parser.add_argument('--baud', type=int, default=115200, help='baud rate (default 115200)')
    parser.add_argument('--record', metavar='FILE', default='sniff.jsonl',
                        help='where to write the recording (default sniff.jsonl)')
    parser.add_argument('--poll', metavar='HEX',
                        help="bytes to send every --period s, e.g. '55 0C 00 ...': a polled "
                             'device answers nothing unprompted')
    parser.add_argument('--period', type=float, default=0.01, help='s between polls (0.01)')
    parser.add_argument('--duration', type=float, default=5.0,
                        help='s to record when not prompting for moves (5)')
    parser.add_argument('--count', type=int,
                        help=f'polls to send; then stop once the port is quiet {QUIET_END} s')
    parser.add_argument('--min-bytes', type=int, default=0,
                        help='with --count: record until at least this many bytes came '
                             '(within --duration)')
    parser.add_argument('--moves', action='store_true',
                        help='ask the operator to move each joint alone in turn (Enter to go on)')
    parser.add_argument('--draft', metavar='FILE', help='write the draft description here')
    parser.add_argument('--name', default='sniffed', help="the draft description's name")
    return parser


def main(argv=None, ask=input):
    """Run kraft_master_sniff; return the exit code."""
    parser = _parser()
    args = parser.parse_args(argv)
    poll = None
    if args.poll:
        try:
            poll = bytes.fromhex(args.poll)
        except ValueError:
            parser.error(f'--poll: not hex bytes: {args.poll!r}')
    if not args.period > 0:
        parser.error(f'--period must be positive, got {args.period}')
    try:
        if args.port:
            record(args.port, args.baud, args.record, poll, args.period, args.duration,
                   args.count, args.moves, ask=ask, min_bytes=args.min_bytes)
            print(f'recorded to {args.record}')
            path = args.record
        else:
            path = args.replay
        recording = read_recording(path)
    except (OSError, ValueError) as error:
        print(f'kraft_master_sniff: {error}', file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130
    try:
        text = analyse(recording, args.name)
    except ValueError as error:
        print(f'kraft_master_sniff: {error}', file=sys.stderr)
        return 1
    if text is None:
        print('kraft_master_sniff: no frame found: no draft written', file=sys.stderr)
        return 1
    if args.draft:
        with open(args.draft, 'w', encoding='utf-8') as stream:
            stream.write(text)
        try:
            load_description(args.draft)
        except FrameDescriptionError as error:
            print(f'kraft_master_sniff: the draft does not load: {error}', file=sys.stderr)
            return 1
        print(f'draft written to {args.draft}; it loads')
    else:
        print(text, end='')
    return 0


if __name__ == '__main__':
    sys.exit(main())
