# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Tests of kraft_master_sniff: the frame found in recordings of frames it was not told.

Recordings are made two ways: written here from a codec's own encoder, with labelled joint
moves and chosen times; and recorded live from the simulator speaking the made-up example
frame, polled with a command the project's own codec encodes. Nothing asserted depends on how
fast the machine runs: the live test checks what the bytes show, not when they came.
"""
import json
import math

from kraft_master_driver.link.frame_description import load_description
from kraft_master_driver.link.protocol import FrameCodec, get_codec
from kraft_master_driver.simulation.master.simulator import SimulatedKraftMaster
from kraft_master_driver.tools import sniff
import pytest

# A third frame, made up here and told to no one: a three-byte header, a sequence byte, pots
# little-endian in a scattered order, a status byte between them, a big-endian sum16.
MADE_UP = """
name: made-up-test
command:
  size: 16
  header: 'A5 5A 01'
  sequence: {offset: 3, width: 1}
  torques: {offset: 4, width: 2, signed: true, order: little}
  checksum: {type: sum16, offset: 14, order: big}
reply:
  size: 20
  header: 'A5 5A 02'
  sequence: {offset: 3, width: 1}
  pots: {offset: [6, 4, 8, 10, 12, 14], width: 2, order: little}
  status: {offset: 16, width: 1, bits: {0: amplifiers_on}}
  checksum: {type: sum16, offset: 18, order: big}
pots: {bits: 12}
torque:
  counts_per_nm: [1000, 1000, 1000, 1000, 1000]
  sign: [1, 1, 1, 1, 1]
  limit: [3000, 3000, 3000, 3000, 3000]
"""
PERIOD = 0.004  # s between the frames of a written recording


@pytest.fixture(params=['kraft-default', 'example-be-crc8', 'made-up'])
def codec(request, tmp_path):
    """Return each built-in codec and the made-up one."""
    if request.param == 'made-up':
        path = tmp_path / 'made_up.yaml'
        path.write_text(MADE_UP, encoding='utf-8')
        return get_codec(str(path))
    return get_codec(request.param)


def write_recording(path, codec, moves=True):
    """Write a polled session of codec: still, then each joint swept alone, labelled."""
    pots = [2000, 1500, 2500, 1000, 3000, 2048]
    lines = [{'kraft_master_sniff': 1, 'port': 'written', 'baud': 115200,
              'poll': codec.encode_command(0, [0] * 5).hex(), 'started': 0.0}]
    clock = {'t': 0.0, 'sequence': 0}

    def frames(count, joint=None):
        for index in range(count):
            if joint is not None:
                pots[joint] = int(2048 + 1500 * math.sin(index / 10))
            sequence = clock['sequence'] if codec.has_sequence else None
            lines.append({'t': clock['t'], 'dir': 'tx',
                          'hex': codec.encode_command(sequence or 0, [0] * 5).hex()})
            lines.append({'t': clock['t'] + 0.0003, 'dir': 'rx',
                          'hex': codec.encode_reply(sequence, pots, 1).hex()})
            clock['t'] += PERIOD
            clock['sequence'] = (clock['sequence'] + 1) % 256
    frames(20)
    for joint in range(6 if moves else 0):
        lines.append({'t': clock['t'], 'mark': f'joint {joint + 1}'})
        frames(60, joint)
        lines.append({'t': clock['t'], 'mark': ''})
        frames(5)
    path.write_text(''.join(json.dumps(line) + '\n' for line in lines), encoding='utf-8')


def test_replay_finds_the_frame_it_was_not_told(codec, tmp_path, capsys):
    recording = tmp_path / 'session.jsonl'
    draft = tmp_path / 'draft.yaml'
    write_recording(recording, codec)
    assert sniff.main(['--replay', str(recording), '--draft', str(draft)]) == 0
    out = capsys.readouterr().out
    reply = codec.description.reply
    found = sniff.find_frames(sniff.read_recording(recording), 'rx')
    assert found.length == codec.reply_size
    assert found.period == pytest.approx(PERIOD)
    assert found.header.startswith(reply.header)
    assert (found.sequence is not None) == codec.has_sequence
    name, keys, offset, order, covers = found.checksums[0]
    assert keys['type'] == reply.checksum.type
    assert offset == reply.checksum.field.offset
    assert covers == [reply.checksum.start, reply.checksum.end]
    assert f'{codec.reply_size} bytes a frame' in out
    # The draft loads with the project's own loader and reads the pots the device sent.
    drafted = load_description(draft)
    assert [field.offset for field in drafted.reply.values] == \
        [field.offset for field in reply.values]
    assert {field.order for field in drafted.reply.values} == {reply.values[0].order}
    decoder = FrameCodec(drafted).reply_decoder()
    stream, _ = sniff.read_recording(recording).stream('rx')
    original = codec.reply_decoder().feed(stream)
    assert [frame.pots for frame in decoder.feed(stream)] == [frame.pots for frame in original]
    # The poll's frame too: its size and header, and the torques where the poll had room.
    assert drafted.command.size == codec.command_size
    assert drafted.command.header == codec.description.command.header


def test_a_recording_without_moves_still_drafts(tmp_path, capsys):
    recording = tmp_path / 'session.jsonl'
    codec = get_codec('example-be-crc8')
    write_recording(recording, codec, moves=False)
    # Still pots: one distinct reply, so no checksum can be claimed; the draft still loads.
    assert sniff.main(['--replay', str(recording), '--draft', str(tmp_path / 'd.yaml')]) == 0
    out = capsys.readouterr().out
    assert 'pot fields not found' in out
    assert 'a checksum cannot be told from data' in out
    load_description(tmp_path / 'd.yaml')


def test_prompts_mark_one_segment_per_joint(tmp_path):
    path = tmp_path / 'marks.jsonl'
    asked, said = [], []
    with open(path, 'w', encoding='utf-8') as stream:
        writer = sniff.RecordingWriter(stream, {'port': 'none'})
        sniff.prompt_moves(writer, asked.append, said.append, joints=3)
    segments = sniff.read_recording(path).segments()
    assert [label for label, _, _ in segments] == ['joint 1', 'joint 2', 'joint 3']
    assert all(start <= end for _, start, end in segments)
    assert len(asked) == 6 and 'joint 3' in asked[-1]


def test_bad_recording_and_options_are_refused(tmp_path, capsys):
    bad = tmp_path / 'bad.jsonl'
    bad.write_text('{"kraft_master_sniff": 1}\n{"t": 0, "dir": "up", "hex": "00"}\n')
    assert sniff.main(['--replay', str(bad)]) == 1
    assert 'bad.jsonl:2' in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_info:
        sniff.main(['--replay', str(bad), '--poll', 'zz'])
    assert exit_info.value.code == 2


def test_the_simulator_sends_nothing_unprompted(tmp_path, capsys):
    recording = tmp_path / 'quiet.jsonl'
    with SimulatedKraftMaster(codec='example-be-crc8') as simulator:
        assert sniff.main(['--port', simulator.port, '--record', str(recording),
                           '--duration', '0.2']) == 1
    assert 'no rx bytes recorded' in capsys.readouterr().out


def test_live_session_with_the_simulator(tmp_path, capsys):
    # The simulator speaks the made-up example; the sniffer is only given a poll, encoded by
    # the project's codec as a host that knows the command would send it.
    recording = tmp_path / 'live.jsonl'
    draft = tmp_path / 'draft.yaml'
    codec = get_codec('example-be-crc8')
    poll = codec.encode_command(0, [0] * 5).hex()
    with SimulatedKraftMaster(codec='example-be-crc8', pot_noise_counts=3.0,
                              operator='sweep') as simulator:
        assert sniff.main(['--port', simulator.port, '--record', str(recording),
                           '--poll', poll, '--count', '120', '--period', '0.002',
                           '--min-bytes', str(17 * 100), '--duration', '60',
                           '--draft', str(draft)]) == 0
    out = capsys.readouterr().out
    assert 'reply (device -> host): 17 bytes a frame' in out
    assert "header: '55 AA'" in out
    assert 'length byte at 2 (counts following)' in out
    assert 'checksum: CRC-8/SMBUS at 16, covering bytes 2..15' in out
    drafted = load_description(draft)
    assert drafted.reply.size == 17 and drafted.command.size == 14
    # The recording replays to the same findings, without a device.
    assert sniff.main(['--replay', str(recording)]) == 0
    assert 'checksum: CRC-8/SMBUS at 16' in capsys.readouterr().out
