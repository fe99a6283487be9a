# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""Tests of frame descriptions: checksums, the built-ins, refused files, fuzzing of each frame."""
import copy
import random

from hypothesis import given, HealthCheck, settings, strategies as st
from kraft_master_driver.link.checksums import make_crc, SUMS
from kraft_master_driver.link.frame_description import (
    builtin_path, FrameDescriptionError, load_description)
from kraft_master_driver.link.protocol import (
    CODECS, DEFAULT_TORQUE_LIMIT, DEFAULT_TORQUE_SCALE, ERROR_KINDS, FrameCodec, get_codec,
    PotFrame, STATUS_AMPLIFIERS_ENABLED, STATUS_COMMAND_CLAMPED, STATUS_COMMAND_TIMEOUT,
    TorqueCommand)
import pytest
import yaml

BUILTINS = sorted(CODECS)
FUZZ = settings(deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                       HealthCheck.function_scoped_fixture])


def reference_crc(data, width, poly, init, refin, refout, xorout):
    """Return a CRC computed bit by bit from its catalogue parameters (no tables)."""
    top, mask = 1 << (width - 1), (1 << width) - 1
    crc = init
    for byte in data:
        if refin:
            byte = int(f'{byte:08b}'[::-1], 2)
        crc ^= byte << (width - 8)
        for _ in range(8):
            crc = ((crc << 1) ^ poly) & mask if crc & top else (crc << 1) & mask
    if refout:
        crc = int(f'{crc:0{width}b}'[::-1], 2)
    return crc ^ xorout


# (name, width, poly, init, refin, refout, xorout, check value of b'123456789'), as the
# catalogues of CRC parameters give them.
CATALOGUE = [
    ('CRC-16/CCITT-FALSE', 16, 0x1021, 0xFFFF, False, False, 0x0000, 0x29B1),
    ('CRC-16/XMODEM', 16, 0x1021, 0x0000, False, False, 0x0000, 0x31C3),
    ('CRC-16/KERMIT', 16, 0x1021, 0x0000, True, True, 0x0000, 0x2189),
    ('CRC-16/MODBUS', 16, 0x8005, 0xFFFF, True, True, 0x0000, 0x4B37),
    ('CRC-16/ARC', 16, 0x8005, 0x0000, True, True, 0x0000, 0xBB3D),
    ('CRC-16/GENIBUS', 16, 0x1021, 0xFFFF, False, False, 0xFFFF, 0xD64E),
    ('CRC-8/SMBUS', 8, 0x07, 0x00, False, False, 0x00, 0xF4),
    ('CRC-8/MAXIM-DOW', 8, 0x31, 0x00, True, True, 0x00, 0xA1),
    ('CRC-8/SAE-J1850', 8, 0x1D, 0xFF, False, False, 0xFF, 0x4B),
]


@pytest.mark.parametrize('name, width, poly, init, refin, refout, xorout, check', CATALOGUE)
def test_crc_catalogue_check_values(name, width, poly, init, refin, refout, xorout, check):
    crc = make_crc(width, poly, init, refin, refout, xorout)
    assert crc(b'123456789') == check, name
    rng = random.Random(width * poly)
    for _ in range(50):
        data = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 40)))
        assert crc(data) == reference_crc(data, width, poly, init, refin, refout, xorout)


def test_crc_with_refin_unlike_refout_matches_the_bitwise_model():
    for refin, refout in ((True, False), (False, True)):
        crc = make_crc(16, 0x8005, 0x1234, refin, refout, 0x00FF)
        for data in (b'', b'\x00', b'123456789', bytes(range(256))):
            assert crc(data) == reference_crc(data, 16, 0x8005, 0x1234, refin, refout, 0x00FF)


def test_sums_and_xor():
    data = bytes(range(1, 200))
    assert SUMS['sum8'](data) == sum(data) % 256
    assert SUMS['sum16'](data) == sum(data) % 65536
    assert SUMS['xor8'](b'\x0f\xf0\x01') == 0xFE


def test_kraft_default_file_is_the_shared_defaults():
    codec = get_codec('kraft-default')
    assert (codec.torque_scale, codec.torque_limit) == (DEFAULT_TORQUE_SCALE, DEFAULT_TORQUE_LIMIT)
    assert (codec.command_size, codec.reply_size, codec.has_sequence) == (15, 18, True)


def test_example_frame_golden_bytes():
    codec = get_codec('example-be-crc8')
    assert not codec.has_sequence
    command = codec.encode_command(99, (1, -2, 3, -4, 5))
    # header, length (the 12 bytes after it), big-endian torques with axes 2 and 5 negated,
    # a reserved 0, CRC-8/SMBUS of bytes 1..12.
    assert command[:12] == bytes.fromhex('55 0c 0001 0002 0003 fffc fffb')
    assert command[12] == 0
    assert command[13] == reference_crc(command[1:13], 8, 0x07, 0, False, False, 0)
    assert codec.command_decoder().feed(command) == [TorqueCommand(None, (1, -2, 3, -4, 5))]
    reply = codec.encode_reply(None, (1, 2, 3, 4, 5, 4095),
                               STATUS_AMPLIFIERS_ENABLED | STATUS_COMMAND_TIMEOUT)
    # POT4 and POT5 trade places on the wire; amplifiers on is bit 0 clear; timeout is bit 5.
    assert reply[:15] == bytes.fromhex('55aa 0e 0001 0002 0003 0005 0004 0fff')
    assert reply[15] == 0x20
    assert reply[16] == reference_crc(reply[2:16], 8, 0x07, 0, False, False, 0)
    assert codec.reply_decoder().feed(reply) == [
        PotFrame(None, (1, 2, 3, 4, 5, 4095), STATUS_AMPLIFIERS_ENABLED | STATUS_COMMAND_TIMEOUT)]
    off = codec.encode_reply(None, (0,) * 6, STATUS_COMMAND_CLAMPED)
    assert off[15] == 0x03
    assert codec.reply_decoder().feed(off)[0].status == STATUS_COMMAND_CLAMPED


def test_a_wrong_length_byte_fails_the_frame():
    codec = get_codec('example-be-crc8')
    frame = bytearray(codec.encode_reply(None, (7,) * 6, 1))
    frame[2] = 13
    frame[16] = reference_crc(frame[2:16], 8, 0x07, 0, False, False, 0)
    decoder = codec.reply_decoder()
    assert decoder.feed(bytes(frame)) == []
    assert decoder.errors['bad_crc'] == 1


def description_dict(name='kraft-default'):
    """Return a built-in description as a mapping to alter."""
    return yaml.safe_load(builtin_path(name).read_text())


def write(tmp_path, document, name='frame.yaml'):
    """Write a description; return its path as a string."""
    path = tmp_path / name
    path.write_text(yaml.safe_dump(document))
    return str(path)


def test_a_description_file_is_a_codec(tmp_path):
    document = description_dict()
    document['name'] = 'mine'
    codec = get_codec(write(tmp_path, document))
    assert isinstance(codec, FrameCodec) and codec.name == 'mine'
    assert codec.encode_command(7, (1, -2, 3, -32768, 32767)) == get_codec(
        'kraft-default').encode_command(7, (1, -2, 3, -32768, 32767))
    with pytest.raises(ValueError, match='unknown codec .*example-be-crc8, kraft-default'):
        get_codec('kmc-9100-real')


def test_mixed_byte_orders_and_no_checksum_round_trip(tmp_path):
    document = description_dict()
    document['reply']['pots']['order'] = 'big'
    document['reply']['status']['width'] = 2
    document['reply']['status']['order'] = 'big'
    document['reply']['size'] = 19
    document['reply']['checksum'] = {'type': 'sum16', 'offset': 17, 'order': 'little'}
    document['command']['checksum'] = {'type': 'none'}
    codec = get_codec(write(tmp_path, document))
    reply = codec.encode_reply(3, (1, 2, 3, 4, 5, 4095), 0x0105)
    assert reply[3:5] == b'\x00\x01' and reply[15:17] == b'\x01\x05'
    assert reply[17:19] == (sum(reply[:17]) % 65536).to_bytes(2, 'little')
    assert codec.reply_decoder().feed(reply) == [PotFrame(3, (1, 2, 3, 4, 5, 4095), 0x0105)]
    command = codec.encode_command(4, (5, 4, 3, 2, 1))
    assert codec.command_decoder().feed(command) == [TorqueCommand(4, (5, 4, 3, 2, 1))]


def alter(path, value):
    """Return a function that sets the key at path (a dotted string) of a description."""
    def change(document):
        *parents, last = (int(key) if key.isdigit() else key for key in path.split('.'))
        for key in parents:
            document = document[key]
        if value is DELETE:
            del document[last]
        else:
            document[last] = value
    return change


DELETE = object()
REFUSALS = [
    (alter('reply.pots.offset', 10), 'reply.pots[4]', "past the frame's end"),
    (alter('reply.status.offset', 14), 'reply.status', 'overlaps reply.pots[5] at byte 14'),
    (alter('command.sequence.offset', 1), 'command.sequence', 'overlaps command.header'),
    (alter('reply.checksum.type', 'crc32'), 'reply.checksum.type', "unknown checksum 'crc32'"),
    (alter('reply.pots.width', 3), 'reply.pots.width', 'unknown width 3'),
    (alter('command.torques.order', 'middle'), 'command.torques.order', 'unknown byte order'),
    (alter('pots.bits', 14), 'pots.bits', 'unknown pot count width 14'),
    (alter('pots.range', [0, 5000]), 'pots.range', 'must be an integer in 0..4095'),
    (alter('torque.limit.2', 40000), 'torque.limit[2]', 'must be an integer in 1..32767'),
    (alter('torque.sign', [1, 1, 1, 1, 2]), 'torque.sign[4]', 'unknown sign 2'),
    (alter('reply.status.bits.4', 'on_fire'), 'reply.status.bits.4', 'unknown status meaning'),
    (alter('reply.checksum.covers', [0, 18]), 'reply.checksum.covers', 'the checksum itself'),
    (alter('reply.checksum.poly', DELETE), 'reply.checksum.poly', 'missing'),
    (alter('reply.checksum.refin', 'yes'), 'reply.checksum.refin', 'true or false'),
    (alter('command.torques.signed', False), 'command.torques[0]', 'must be signed'),
    (alter('reply.header', 'AZ'), 'reply.header', 'hex bytes'),
    (alter('reply.ofset', 2), 'reply.ofset', 'unknown key'),
    (alter('torque', DELETE), 'torque', 'missing'),
]


@pytest.mark.parametrize('change, key, fault', REFUSALS)
def test_a_description_that_cannot_work_is_refused_in_one_line(tmp_path, change, key, fault):
    document = description_dict()
    change(document)
    path = write(tmp_path, document, 'bad_frame.yaml')
    with pytest.raises(FrameDescriptionError) as refusal:
        load_description(path)
    message = str(refusal.value)
    assert '\n' not in message
    assert message.startswith(f'frame description {path}: {key}: ')
    assert fault in message


def test_unreadable_and_invalid_files_are_refused_in_one_line(tmp_path):
    with pytest.raises(FrameDescriptionError, match='missing.yaml: cannot read'):
        get_codec(str(tmp_path / 'missing.yaml'))
    path = tmp_path / 'broken.yaml'
    path.write_text('command: [\n')
    with pytest.raises(FrameDescriptionError, match='broken.yaml line 2: not valid YAML'):
        get_codec(str(path))


# Fuzzing of every built-in frame, and of one without checksum or sequence.

def no_checksum_codec(tmp_path_factory):
    """Return the example frame without its checksums (a header and a length byte alone)."""
    document = description_dict('example-be-crc8')
    for side in ('command', 'reply'):
        document[side]['checksum'] = {'type': 'none'}
    return get_codec(write(tmp_path_factory.mktemp('frames'), document))


@pytest.fixture(scope='module', params=BUILTINS + ['example-without-checksum'])
def codec(request, tmp_path_factory):
    """Each built-in codec, and the example without checksums."""
    if request.param == 'example-without-checksum':
        return no_checksum_codec(tmp_path_factory)
    return get_codec(request.param)


def feed_in_chunks(decoder, stream, chunk_sizes):
    """Feed stream in chunks of the given sizes (cycled); return all frames."""
    frames, position, index = [], 0, 0
    sizes = chunk_sizes or [len(stream) or 1]
    while position < len(stream):
        size = sizes[index % len(sizes)]
        frames += decoder.feed(stream[position:position + size])
        position, index = position + size, index + 1
    return frames


def assert_accounting(decoder, fed_bytes):
    """Every byte fed is in a frame, an out-of-range frame, garbage or pending."""
    errors = decoder.errors
    assert set(ERROR_KINDS) <= set(errors)
    assert 0 <= decoder.pending < decoder.frame_size
    assert ((decoder.frames_decoded + errors['out_of_range']) * decoder.frame_size
            + errors['garbage_bytes'] + decoder.pending) == fed_bytes


def reply_of(codec, index, raw):
    """Return a PotFrame the codec can carry, made of 7 raw bytes."""
    low, high = codec.pot_range
    pots = tuple(low + byte * 16 % (high - low + 1) for byte in raw[:6])
    return PotFrame(index % 256 if codec.has_sequence else None, pots, raw[6] & codec.status_mask)


chunk_sizes = st.lists(st.integers(1, 40), max_size=8)
garbage = st.lists(st.binary(max_size=24), max_size=13)


@pytest.mark.slow
@given(stream=st.binary(max_size=600), chunks=chunk_sizes, side=st.sampled_from(['r', 'c']))
@settings(FUZZ, max_examples=1000)
def test_fuzz_random_bytes_never_raise(codec, stream, chunks, side):
    decoder = codec.reply_decoder() if side == 'r' else codec.command_decoder()
    for frame in feed_in_chunks(decoder, stream, chunks):
        encoded = (codec.encode_reply(*frame) if side == 'r'
                   else codec.encode_command(frame.sequence or 0, frame.counts))
        assert encoded in stream
    assert_accounting(decoder, len(stream))


@pytest.mark.slow
@given(raw=st.lists(st.binary(min_size=7, max_size=7), max_size=12), gaps=garbage,
       chunks=chunk_sizes)
@settings(FUZZ, max_examples=1000)
def test_fuzz_replies_in_garbage(codec, raw, gaps, chunks):
    frames = [reply_of(codec, index, item) for index, item in enumerate(raw)]
    gaps = gaps + [b''] * (len(frames) + 1 - len(gaps))
    stream = b''.join(gap + codec.encode_reply(*frame) for gap, frame in zip(gaps, frames))
    stream += gaps[len(frames)]
    decoder = codec.reply_decoder()
    decoded = feed_in_chunks(decoder, stream, chunks)
    assert_accounting(decoder, len(stream))
    if not any(gaps):
        assert decoded == frames
    else:  # every frame is found; a header in the garbage may add a false one (CRC-8: 1/256)
        remaining = iter(decoded)
        assert all(any(found == frame for found in remaining) for frame in frames)


@pytest.mark.slow
@given(counts=st.lists(st.tuples(*[st.integers(-1200, 1200)] * 5), max_size=12),
       chunks=chunk_sizes)
@settings(FUZZ, max_examples=500)
def test_fuzz_commands_back_to_back(codec, counts, chunks):
    commands = [TorqueCommand(index % 256 if codec.has_sequence else None, tuple(values))
                for index, values in enumerate(counts)]
    stream = b''.join(codec.encode_command(index % 256, command.counts)
                      for index, command in enumerate(commands))
    decoder = codec.command_decoder()
    assert feed_in_chunks(decoder, stream, chunks) == commands
    assert_accounting(decoder, len(stream))


@pytest.mark.slow
@given(raw=st.lists(st.binary(min_size=7, max_size=7), min_size=1, max_size=15),
       flips=st.lists(st.tuples(st.integers(0, 10_000), st.integers(1, 255)), max_size=6),
       chunks=chunk_sizes)
@settings(FUZZ, max_examples=1000)
def test_fuzz_corrupted_replies(codec, raw, flips, chunks):
    frames = [reply_of(codec, index, item) for index, item in enumerate(raw)]
    stream = bytearray(b''.join(codec.encode_reply(*frame) for frame in frames))
    touched = set()
    for position, mask in flips:
        stream[position % len(stream)] ^= mask
        touched.add(position % len(stream) // codec.reply_size)
    decoder = codec.reply_decoder()
    decoded = feed_in_chunks(decoder, bytes(stream), chunks)
    assert_accounting(decoder, len(stream))
    # Every untouched frame is recovered, in order.
    remaining = iter(decoded)
    assert all(any(found == frame for found in remaining)
               for index, frame in enumerate(frames) if index not in touched)


def test_every_builtin_is_labelled_honestly():
    for name in BUILTINS:
        text = builtin_path(name).read_text()
        assert "not Kraft's" in text or 'NOT the frame of Kraft' in text, name
    assert 'made-up example' in copy.deepcopy(description_dict('example-be-crc8'))['note']
