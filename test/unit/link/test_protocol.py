# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""Tests of the frame codec and the incremental frame decoder, with property-based fuzzing."""
import itertools
import struct

from hypothesis import given, HealthCheck, settings, strategies as st
from kraft_master_driver.link.protocol import (
    CODECS, DEFAULT_TORQUE_LIMIT, DEFAULT_TORQUE_SCALE, ERROR_KINDS, get_codec, KraftDefaultCodec,
    PotFrame, TorqueCommand)
import pytest

CODEC = KraftDefaultCodec()
REPLY_HEADER = b'\xaaP'
COMMAND_HEADER = b'\xaaC'
# The fuzz tests below run 3000 + 3000 + 3000 + 1000 = 10,000 generated cases.
FUZZ = settings(deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def reference_crc(data):
    """Return CRC-16/CCITT-FALSE of data, computed bit by bit (independent of binascii)."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else crc << 1
            crc &= 0xFFFF
    return crc


def crc_is_valid(frame):
    """Return whether the last two bytes of frame are the little-endian CRC of the rest."""
    return reference_crc(frame[:-2]) == int.from_bytes(frame[-2:], 'little')


def feed_in_chunks(decoder, stream, chunk_sizes):
    """Feed stream to decoder in chunks of the given sizes (cycled); return all frames."""
    frames = []
    position = 0
    for size in itertools.cycle(chunk_sizes or [len(stream) or 1]):
        if position >= len(stream):
            return frames
        frames += decoder.feed(stream[position:position + size])
        position += size


def assert_accounting(decoder, fed_bytes):
    """Every byte fed is in a frame, an out-of-range frame, garbage or pending."""
    errors = decoder.errors
    assert set(ERROR_KINDS) <= set(errors)
    assert all(count >= 0 for count in errors.values())
    assert 0 <= decoder.pending < decoder.frame_size
    accounted = ((decoder.frames_decoded + errors['out_of_range']) * decoder.frame_size
                 + errors['garbage_bytes'] + decoder.pending)
    assert accounted == fed_bytes
    assert errors['bad_crc'] + errors['truncated'] <= errors['garbage_bytes']


def encode(frame):
    """Encode a PotFrame or TorqueCommand with the default codec."""
    if isinstance(frame, PotFrame):
        return CODEC.encode_reply(*frame)
    return CODEC.encode_command(*frame)


# Field values are drawn as raw bytes: far cheaper to generate than one integer each.
def reply_fields(raw):
    """Return pots (12 bits each) and status bits made of 13 raw bytes."""
    return tuple(value & 0xFFF for value in struct.unpack_from('<6H', raw)), raw[12]


def reply_lists(min_size, max_size):
    """Return a strategy for lists of (pots, status), drawn as one run of raw bytes."""
    return st.binary(min_size=13 * min_size, max_size=13 * max_size).map(
        lambda raw: [reply_fields(raw[i:i + 13]) for i in range(0, len(raw) - 12, 13)])


def count_lists(max_size):
    """Return a strategy for lists of five torque counts, drawn as one run of raw bytes."""
    return st.binary(max_size=10 * max_size).map(
        lambda raw: [struct.unpack_from('<5h', raw, i) for i in range(0, len(raw) - 9, 10)])


def interleave(gaps, frames):
    """Return the encoded frames with gaps[i] before frame i and the last gap after them."""
    gaps = gaps + [b''] * (len(frames) + 1 - len(gaps))
    return b''.join(gap + encode(frame) for gap, frame in zip(gaps, frames)) + gaps[-1]


replies = st.binary(min_size=13, max_size=13).map(reply_fields)
counts = st.binary(min_size=10, max_size=10).map(lambda raw: struct.unpack('<5h', raw))
chunk_sizes = st.binary(max_size=8).map(lambda raw: [byte % 40 + 1 for byte in raw])
# Garbage ending in a header fragment half of the time, so resynchronisation is exercised.
HEADER_FRAGMENTS = (b'\xaa', REPLY_HEADER, COMMAND_HEADER, REPLY_HEADER + b'\x01\x02\x03',
                    b'\xaa\xaa', REPLY_HEADER + b'\x00' * 12)
garbage = st.tuples(st.binary(max_size=24), st.sampled_from((b'',) * 6 + HEADER_FRAGMENTS)).map(
    b''.join)


def test_reference_crc_matches_published_check_value():
    assert reference_crc(b'123456789') == 0x29B1


def test_command_golden_bytes():
    frame = CODEC.encode_command(7, (1, -2, 3, -32768, 32767))
    assert frame == bytes.fromhex('aa4307' '0100' 'feff' '0300' '0080' 'ff7f' 'afa0')
    assert crc_is_valid(frame)


def test_reply_layout():
    frame = CODEC.encode_reply(200, (0, 4095, 1, 2, 3, 4), 0x05)
    assert len(frame) == CODEC.reply_size == 18
    assert frame[:3] == b'\xaaP\xc8'
    assert frame[3:15] == bytes.fromhex('0000' 'ff0f' '0100' '0200' '0300' '0400')
    assert frame[15] == 0x05
    assert crc_is_valid(frame)


@given(sequence=st.integers(0, 255), reply=replies)
@settings(deadline=None)
def test_reply_round_trip(sequence, reply):
    pots, status = reply
    frame = CODEC.encode_reply(sequence, pots, status)
    assert crc_is_valid(frame)
    assert CODEC.reply_decoder().feed(frame) == [PotFrame(sequence, pots, status)]


@given(sequence=st.integers(0, 255), counts=counts)
@settings(deadline=None)
def test_command_round_trip(sequence, counts):
    frame = CODEC.encode_command(sequence, counts)
    assert len(frame) == CODEC.command_size == 15
    assert crc_is_valid(frame)
    assert CODEC.command_decoder().feed(frame) == [TorqueCommand(sequence, counts)]


@pytest.mark.parametrize('sequence, values', [
    (256, (0,) * 5), (-1, (0,) * 5), (0, (32768, 0, 0, 0, 0)), (0, (0,) * 4), (0, (0.5,) * 5)])
def test_encode_command_rejects_bad_fields(sequence, values):
    with pytest.raises(ValueError, match='bad torque command'):
        CODEC.encode_command(sequence, values)


def test_encode_reply_rejects_bad_fields():
    with pytest.raises(ValueError, match='bad pot reply'):
        CODEC.encode_reply(0, (0,) * 6, 256)
    with pytest.raises(ValueError, match='bad pot reply'):
        CODEC.encode_reply(0, (-1,) * 6, 0)


def test_codec_registry():
    assert isinstance(get_codec('kraft-default'), KraftDefaultCodec)
    assert CODECS['kraft-default'] is KraftDefaultCodec
    with pytest.raises(ValueError, match='kraft-default'):
        get_codec('kmc-9100-real')


def test_wire_cycle_time():
    assert CODEC.wire_cycle_time(115200) == pytest.approx(33 * 10 / 115200)
    assert 1 / CODEC.wire_cycle_time(1_000_000) == pytest.approx(3030.3, abs=0.1)
    with pytest.raises(ValueError, match='baud'):
        CODEC.wire_cycle_time(0)


def test_shared_defaults():
    assert DEFAULT_TORQUE_SCALE == (1000.0,) * 5
    assert DEFAULT_TORQUE_LIMIT == (3000,) * 5


def test_out_of_range_pots_are_dropped_and_counted():
    decoder = CODEC.reply_decoder()
    bad = CODEC.encode_reply(1, (0, 0, 4096, 0, 0, 0), 0)
    good = CODEC.encode_reply(2, (4095,) * 6, 0)
    assert decoder.feed(bad + good) == [PotFrame(2, (4095,) * 6, 0)]
    assert decoder.errors['out_of_range'] == 1
    assert_accounting(decoder, len(bad) + len(good))


def test_truncated_frame_followed_by_a_good_one():
    decoder = CODEC.reply_decoder()
    cut = CODEC.encode_reply(1, (1,) * 6, 0)[:10]
    good = CODEC.encode_reply(2, (2,) * 6, 0)
    assert decoder.feed(cut + good) == [PotFrame(2, (2,) * 6, 0)]
    assert decoder.errors['truncated'] == 1
    assert decoder.errors['bad_crc'] == 0
    assert decoder.errors['garbage_bytes'] == 10


def test_corrupt_byte_is_a_crc_error_and_the_next_frame_survives():
    decoder = CODEC.reply_decoder()
    corrupt = bytearray(CODEC.encode_reply(1, (100,) * 6, 0))
    corrupt[7] ^= 0x10
    good = CODEC.encode_reply(2, (200,) * 6, 1)
    assert decoder.feed(bytes(corrupt) + good) == [PotFrame(2, (200,) * 6, 1)]
    assert decoder.errors['bad_crc'] == 1
    assert decoder.errors['garbage_bytes'] == len(corrupt)


def test_frame_starting_inside_a_bad_one_is_recovered():
    decoder = CODEC.reply_decoder()
    good = CODEC.encode_reply(9, (9,) * 6, 0)
    # A fake header 5 bytes before the real frame: the fake frame swallows its first 13 bytes.
    assert decoder.feed(REPLY_HEADER + b'\x01\x02\x03' + good) == [PotFrame(9, (9,) * 6, 0)]
    assert_accounting(decoder, 5 + len(good))


def test_one_byte_at_a_time_and_pending_bytes():
    decoder = CODEC.reply_decoder()
    frame = CODEC.encode_reply(3, (3,) * 6, 3)
    results = [decoder.feed(frame[i:i + 1]) for i in range(len(frame))]
    assert results[:-1] == [[]] * (len(frame) - 1)
    assert results[-1] == [PotFrame(3, (3,) * 6, 3)]
    assert decoder.feed(frame[:11]) == []
    assert decoder.pending == 11


def test_reset_drops_a_partial_frame_and_keeps_counters():
    decoder = CODEC.reply_decoder()
    frame = CODEC.encode_reply(4, (4,) * 6, 0)
    decoder.feed(b'junk' + frame[:12])
    decoder.reset()
    assert decoder.pending == 0
    assert decoder.errors['truncated'] == 1
    assert decoder.errors['garbage_bytes'] == 16
    assert decoder.feed(frame[12:] + frame) == [PotFrame(4, (4,) * 6, 0)]
    assert_accounting(decoder, 16 + 6 + len(frame))


def test_buffer_stays_bounded_under_a_flood():
    decoder = CODEC.reply_decoder()
    flood = (REPLY_HEADER + b'\xff' * 30) * 3000
    assert decoder.feed(flood) == []
    assert decoder.pending < decoder.frame_size
    assert_accounting(decoder, len(flood))


@pytest.mark.slow
@given(stream=st.binary(max_size=600), chunks=chunk_sizes,
       side=st.sampled_from(['reply', 'command']))
@settings(FUZZ, max_examples=3000)
def test_fuzz_random_bytes_never_raise(stream, chunks, side):
    decoder = CODEC.reply_decoder() if side == 'reply' else CODEC.command_decoder()
    for frame in feed_in_chunks(decoder, stream, chunks):
        assert encode(frame) in stream
        assert crc_is_valid(encode(frame))
    assert_accounting(decoder, len(stream))


@pytest.mark.slow
@given(items=reply_lists(0, 12), gaps=st.lists(garbage, max_size=13), chunks=chunk_sizes)
@settings(FUZZ, max_examples=3000)
def test_fuzz_every_reply_in_garbage_is_recovered(items, gaps, chunks):
    frames = [PotFrame(index, *reply) for index, reply in enumerate(items)]
    stream = interleave(gaps, frames)
    decoder = CODEC.reply_decoder()
    assert feed_in_chunks(decoder, stream, chunks) == frames
    assert_accounting(decoder, len(stream))
    garbage_fed = len(stream) - len(frames) * CODEC.reply_size
    assert decoder.errors['garbage_bytes'] + decoder.pending == garbage_fed
    if b'\xaa' not in b''.join(gaps):
        assert decoder.errors['bad_crc'] == decoder.errors['truncated'] == 0


@pytest.mark.slow
@given(items=count_lists(12), gaps=st.lists(garbage, max_size=13), chunks=chunk_sizes)
@settings(FUZZ, max_examples=1000)
def test_fuzz_every_command_in_garbage_is_recovered(items, gaps, chunks):
    commands = [TorqueCommand(index, counts) for index, counts in enumerate(items)]
    stream = interleave(gaps, commands)
    decoder = CODEC.command_decoder()
    assert feed_in_chunks(decoder, stream, chunks) == commands
    assert_accounting(decoder, len(stream))


EDIT_KINDS = ('flip', 'delete', 'insert', 'cut')
# Up to six edits (position, kind, value 1..255), four raw bytes each.
mutations = st.binary(max_size=24).map(lambda raw: [
    (int.from_bytes(raw[i:i + 2], 'little'), EDIT_KINDS[raw[i + 2] % 4], raw[i + 3] % 255 + 1)
    for i in range(0, len(raw) - 3, 4)])


def mutate(stream, edits, frame_size):
    """Apply edits to stream; return the new stream and the indices of frames they touched."""
    stream = bytearray(stream)
    origin = list(range(len(stream)))  # original position of each byte, None if inserted
    touched = set()
    for position, kind, value in edits:
        if not stream:
            break
        position %= len(stream)
        if kind == 'insert':
            left, right = origin[position - 1:position + 1] if position else (None, None)
            if None not in (left, right) and left // frame_size == right // frame_size:
                touched.add(left // frame_size)
            stream.insert(position, value)
            origin.insert(position, None)
            continue
        end = position + (value % frame_size if kind == 'cut' else 1)
        touched.update(o // frame_size for o in origin[position:end] if o is not None)
        if kind == 'flip':
            stream[position] ^= value
        else:
            del stream[position:end], origin[position:end]
    return bytes(stream), touched


@pytest.mark.slow
@given(items=reply_lists(1, 15), edits=mutations, chunks=chunk_sizes)
@settings(FUZZ, max_examples=3000)
def test_fuzz_mutated_stream(items, edits, chunks):
    frames = [PotFrame(index, *reply) for index, reply in enumerate(items)]
    stream, touched = mutate(b''.join(encode(frame) for frame in frames), edits,
                             CODEC.reply_size)
    decoder = CODEC.reply_decoder()
    decoded = feed_in_chunks(decoder, stream, chunks)
    # Nothing altered is accepted: sequences are unique, so each frame is an original one.
    assert all(frame.sequence < len(frames) and frame == frames[frame.sequence]
               for frame in decoded)
    sequences = [frame.sequence for frame in decoded]
    assert sequences == sorted(set(sequences))
    assert set(sequences) >= set(range(len(frames))) - touched
    assert_accounting(decoder, len(stream))
