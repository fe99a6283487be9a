# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The CDR bytes (XCDR1, as rmw_fastrtps sends them) of the messages the loops handle.

rclpy converts a message object field by field on every publish and builds a tree of Python
objects on every take: about 40 us more per JointState published and 70 us more per
WrenchStamped taken than packing and unpacking the bytes here (measured on the 2-core test
machine). The driver's loop therefore publishes bytes (Publisher.publish accepts them) and
takes the wrench raw; the simulated slave's loop does the same with its pose and wrench. No
rclpy here; the tests check every encoding against rclpy and Fast DDS.

Layout: a 4-byte encapsulation header (0x00 0x01: little endian, all this module reads or
writes), then the fields in order, each aligned to its own size counted from the end of that
header; a string is a uint32 length (with its NUL), the bytes and a NUL; a sequence a uint32
count and the elements.
"""
import struct

LITTLE_ENDIAN_HEADER = b'\x00\x01\x00\x00'
_STAMP = struct.Struct('<iI')
_HEADER = struct.Struct('<iII')  # stamp, then the frame_id's length


def _string(text):
    """Return the CDR bytes of a string (to be placed at a 4-aligned offset)."""
    data = text.encode() + b'\x00'
    return struct.pack('<I', len(data)) + data


def _padding(offset, alignment):
    return -offset % alignment


class _StampedLayout:
    """The fixed bytes after a Header's stamp (frame_id and any constant fields) and the offset."""

    def __init__(self, frame_id):
        self.fixed = _string(frame_id)
        self.offset = 8 + len(self.fixed)

    def append_fixed(self, data):
        self.fixed += data
        self.offset += len(data)

    def align(self, alignment):
        """Pad the fixed bytes so the next field starts at a multiple of alignment."""
        self.append_fixed(b'\x00' * _padding(self.offset, alignment))

    def tail(self, fields):
        """Return the struct format of variable fields after the fixed bytes: (code, size)."""
        layout = ['<']
        for code, size in fields:
            pad = _padding(self.offset, size)
            if pad:
                layout.append(f'{pad}x')
            layout.append(code)
            self.offset += pad + size
        return struct.Struct(''.join(layout))


class JointStateEncoder:
    """sensor_msgs/JointState with fixed frame_id and names, and sequences of fixed lengths."""

    def __init__(self, frame_id, names, lengths):
        """Lengths: the element counts of position, velocity and effort (0 or len(names))."""
        layout = _StampedLayout(frame_id)
        layout.align(4)
        layout.append_fixed(struct.pack('<I', len(names)))
        for name in names:
            layout.align(4)
            layout.append_fixed(_string(name))
        fields = []
        for length in lengths:
            fields.append(('I', 4))
            fields.extend(('d', 8) for _ in range(length))
        self._fixed = layout.fixed
        self._tail = layout.tail(fields)
        self._counts = lengths

    def encode(self, sec, nanosec, *sequences):
        """Return the message's bytes; one sequence of floats per length given."""
        values = []
        for count, sequence in zip(self._counts, sequences):
            values.append(count)
            values.extend(sequence)
        return b''.join((LITTLE_ENDIAN_HEADER, _STAMP.pack(sec, nanosec), self._fixed,
                         self._tail.pack(*values)))


class StampedDoublesEncoder:
    """A message of a Header and then only float64 fields (PoseStamped, TwistStamped)."""

    def __init__(self, frame_id, count):
        """Count: the number of float64 fields after the header (7 for a pose, 6 for a twist)."""
        layout = _StampedLayout(frame_id)
        self._fixed = layout.fixed
        self._tail = layout.tail([('d', 8)] * count)

    def encode(self, sec, nanosec, values):
        """Return the message's bytes with these float64 values in field order."""
        return b''.join((LITTLE_ENDIAN_HEADER, _STAMP.pack(sec, nanosec), self._fixed,
                         self._tail.pack(*values)))


class StampedDoublesDecoder:
    """Reads a message of a Header and then only float64 fields (see StampedDoublesEncoder)."""

    def __init__(self, name, count):
        """Name: the message type, for errors; count: its float64 fields after the header."""
        self._name = name
        self._values = struct.Struct(f'<{count}d')

    def decode(self, data):
        """
        Return (sec, nanosec, frame_id, values) of the message's CDR bytes.

        Raise ValueError on bytes that are not such a message: another encapsulation (big
        endian or XCDR2), truncated, a frame_id without its NUL or not UTF-8.
        """
        if data[:2] != LITTLE_ENDIAN_HEADER[:2]:
            raise ValueError(f'unsupported CDR encapsulation {bytes(data[:4]).hex()}')
        body = memoryview(data)[4:]
        try:
            sec, nanosec, length = _HEADER.unpack_from(body, 0)
            end = 12 + length
            if length == 0 or end > len(body) or body[end - 1] != 0:
                raise ValueError(f'bad frame_id length {length}')
            frame_id = bytes(body[12:end - 1]).decode()
            values = self._values.unpack_from(body, end + _padding(end, 8))
        except (struct.error, UnicodeDecodeError) as error:
            raise ValueError(f'not a {self._name}: {error}') from None
        return sec, nanosec, frame_id, values


# (sec, nanosec, frame_id, (fx, fy, fz, mx, my, mz)) of geometry_msgs/WrenchStamped bytes.
decode_wrench_stamped = StampedDoublesDecoder('WrenchStamped', 6).decode
