# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""Reading recorded sessions back (bag/reader.py) and kraft_master_report on synthetic bags."""
import csv
import math

from harness.session_bags import SAMPLES, write_bag
from kraft_master_driver.bag.common import (
    DIAGNOSTIC_ARRAY, JOINT_STATE, POSE_STAMPED, SessionError, typestore, VECTOR3_STAMPED,
    WRENCH_STAMPED)
from kraft_master_driver.bag.decoding import decode_cdr, LAYOUTS
from kraft_master_driver.bag.reader import read_topics
from kraft_master_driver.bag.recorder import BagRecorder, qos_profile
from kraft_master_driver.bag.samples import simulate_samples, write_samples
from kraft_master_driver.core import kinematics
from kraft_master_driver.core.calibration import ArmCalibration
from kraft_master_driver.core.rotations import rotation_to_quaternion
from kraft_master_driver.tools import report, report_data, report_plots
from matplotlib.image import imread
import numpy as np
import pytest
from rosbags.rosbag2 import Reader
from rosbags.rosbag2.enums import CompressionMode

STORE = typestore()
TYPES = STORE.types


def header(rng):
    """Return a Header with a random stamp and frame id (any length, not only ASCII)."""
    frame = ''.join(rng.choice(list('abc_/0é'), rng.integers(0, 14)))
    return TYPES['std_msgs/msg/Header'](
        stamp=TYPES['builtin_interfaces/msg/Time'](sec=int(rng.integers(-2**31, 2**31)),
                                                   nanosec=int(rng.integers(0, 10**9))),
        frame_id=frame)


def random_message(msgtype, rng):
    """Return a random message of a fixed-layout type, arrays of any length."""
    def vector(name):
        x, y, z = rng.normal(size=3).tolist()
        return TYPES[f'geometry_msgs/msg/{name}'](x=x, y=y, z=z)

    if msgtype == JOINT_STATE:
        names = [''.join(rng.choice(list('xyz_1'), rng.integers(0, 12)))
                 for _ in range(rng.integers(0, 7))]
        return TYPES[msgtype](header=header(rng), name=names,
                              **{field: rng.normal(size=rng.integers(0, 8))
                                 for field in ('position', 'velocity', 'effort')})
    if msgtype == POSE_STAMPED:
        qx, qy, qz, qw = rng.normal(size=4).tolist()
        return TYPES[msgtype](header=header(rng), pose=TYPES['geometry_msgs/msg/Pose'](
            position=vector('Point'),
            orientation=TYPES['geometry_msgs/msg/Quaternion'](x=qx, y=qy, z=qz, w=qw)))
    if msgtype == VECTOR3_STAMPED:
        return TYPES[msgtype](header=header(rng), vector=vector('Vector3'))
    if msgtype == WRENCH_STAMPED:
        return TYPES[msgtype](header=header(rng), wrench=TYPES['geometry_msgs/msg/Wrench'](
            force=vector('Vector3'), torque=vector('Vector3')))
    return TYPES[msgtype](header=header(rng), twist=TYPES['geometry_msgs/msg/Twist'](
        linear=vector('Vector3'), angular=vector('Vector3')))


def expected_fields(message):
    """Return the fields session's decoder gives for a message deserialised by rosbags."""
    stamp = message.header.stamp
    fields = {'stamp': stamp.sec * 1_000_000_000 + stamp.nanosec}
    if message.__msgtype__ == JOINT_STATE:
        fields.update(position=message.position, velocity=message.velocity,
                      effort=message.effort)
    elif message.__msgtype__ == POSE_STAMPED:
        p, q = message.pose.position, message.pose.orientation
        fields.update(position=[p.x, p.y, p.z], orientation=[q.x, q.y, q.z, q.w])
    elif message.__msgtype__ == VECTOR3_STAMPED:
        fields.update(vector=[message.vector.x, message.vector.y, message.vector.z])
    else:
        wrench = getattr(message, 'wrench', None)
        pairs = ((wrench.force, wrench.torque) if wrench else
                 (message.twist.linear, message.twist.angular))
        names = ('force', 'torque') if wrench else ('linear', 'angular')
        fields.update({name: [v.x, v.y, v.z] for name, v in zip(names, pairs)})
    return fields


def assert_row_equals(data, row, message):
    """Assert that row `row` of a TopicData decodes `message` (NaN padding past its arrays)."""
    for name, value in expected_fields(message).items():
        decoded = data.fields[name][row]
        if name == 'stamp':
            assert decoded == value
            continue
        value = np.asarray(value, dtype=float)
        np.testing.assert_array_equal(decoded[:len(value)], value)
        assert np.isnan(decoded[len(value):]).all()


@pytest.mark.parametrize('msgtype', sorted(LAYOUTS))
@pytest.mark.parametrize('little_endian', [True, False])
def test_numpy_decoding_equals_rosbags_deserialisation(msgtype, little_endian):
    rng = np.random.default_rng(len(msgtype) + little_endian)
    messages = [random_message(msgtype, rng) for _ in range(300)]
    raw = [bytes(STORE.serialize_cdr(m, msgtype, little_endian=little_endian))
           for m in messages]
    # ROS middlewares may pad a message to 4 bytes; rosbags reads such padding too.
    raw = [data + b'\0' * (i % 4) for i, data in enumerate(raw)]
    data = decode_cdr(raw, msgtype)
    assert len(data) == len(raw) and data.malformed == 0
    for row, data_bytes in enumerate(raw):
        reference = STORE.deserialize_cdr(data_bytes, msgtype)
        assert_row_equals(data, row, reference)
    assert data.strings['frame_id'] == messages[0].header.frame_id
    if msgtype == JOINT_STATE:
        assert data.strings['name'] == messages[0].name


def test_malformed_messages_are_counted_not_raised():
    rng = np.random.default_rng(2)
    good = [bytes(STORE.serialize_cdr(random_message(JOINT_STATE, rng),
                                      JOINT_STATE)) for _ in range(20)]
    bad = [b'', b'\x00', good[0][:-9], b'\x00\x02\x00\x00' + good[0][4:], rng.bytes(64),
           good[1][:12] + b'\xff\xff\xff\x7f' + good[1][16:]]
    data = decode_cdr(bad[:3] + good + bad[3:], JOINT_STATE)
    assert data.malformed == len(bad)
    assert len(data) == len(good)
    for row, data_bytes in enumerate(good):
        assert_row_equals(data, row, STORE.deserialize_cdr(data_bytes, JOINT_STATE))
    diagnostics = decode_cdr([good[0], b'\x00\x01\x00\x00'], DIAGNOSTIC_ARRAY)
    assert len(diagnostics) == 0 and diagnostics.malformed == 2


@pytest.mark.parametrize('storage, compression', [
    ('mcap', None), ('sqlite3', None), ('mcap', CompressionMode.STORAGE),
    ('mcap', CompressionMode.MESSAGE), ('sqlite3', CompressionMode.FILE)])
def test_read_topics_equals_rosbags_reader(tmp_path, storage, compression):
    bag = tmp_path / 'bag'
    write_bag(bag, storage, {'/left': ('left', 1), '': ('right', 2)}, compression, samples=400)
    topics = [f'{ns}/{name}' for ns in ('/left', '') for name in report_data.ARM_TOPICS]
    data = read_topics(bag, topics + ['/absent'])
    assert sorted(data) == sorted(topics)
    received = {topic: ([], []) for topic in topics}
    with Reader(bag) as reader:
        for connection, log_time, raw in reader.messages():
            times, messages = received[connection.topic]
            times.append(log_time)
            messages.append(STORE.deserialize_cdr(raw, connection.msgtype))
    for topic, (times, messages) in received.items():
        np.testing.assert_array_equal(data[topic].log_time, times)
        if data[topic].msgtype == DIAGNOSTIC_ARRAY:
            assert data[topic].messages == messages
            continue
        expected = [expected_fields(message) for message in messages]
        for name, values in data[topic].fields.items():
            np.testing.assert_array_equal(values, np.array([e[name] for e in expected]))
    assert data['/left/joint_states'].strings['name'] == list(kinematics.JOINT_NAMES)
    assert data['/pots'].fields['velocity'].shape == (400, 0)
    assert data['/pots'].strings['name'] == [f'pot{i}' for i in range(1, 7)]


def read_csv(path):
    """Return the header, the stamps (int) and the rows of a report CSV, empty fields NaN."""
    with open(path, newline='') as stream:
        reader = csv.reader(stream)
        names = next(reader)
        lines = list(reader)
    stamps = np.array([int(line[0]) for line in lines])
    rows = np.array([[float(x) if x else math.nan for x in line] for line in lines])
    return names, stamps, rows


def columns(names, rows, prefix='', suffix=''):
    """Return the CSV columns whose names start and end so, in order."""
    return rows[:, [i for i, n in enumerate(names) if n.startswith(prefix) and
                    n.endswith(suffix)]]


@pytest.mark.slow
def test_report_of_two_arms_writes_figures_and_the_samples(tmp_path, capsys):
    bag = tmp_path / 'session'
    samples = write_bag(bag, 'mcap', {'/left': ('left', 3), '/right': ('right', 4)})
    out = tmp_path / 'out'
    assert report.main([str(bag), '--out', str(out)]) == 0
    printed = capsys.readouterr().out
    for namespace, arm in (('/left', 'left'), ('/right', 'right')):
        assert f'{namespace} ({arm} arm): {SAMPLES} samples' in printed
        stem = out / f'session_{arm}'
        image = imread(stem.with_name(stem.name + '_report.png'))
        assert image.shape[0] > 1000 and image.shape[1] > 1000
        names, stamps, rows = read_csv(stem.with_name(stem.name + '_samples.csv'))
        expected = samples[namespace]
        np.testing.assert_array_equal(stamps, expected.stamp)
        for suffix, values, decimals in (('_position', expected.position, 9),
                                         ('_velocity', expected.velocity, 6),
                                         ('_effort', expected.effort, 6)):
            np.testing.assert_allclose(columns(names, rows, suffix=suffix), values,
                                       rtol=0, atol=0.51 * 10.0 ** -decimals)
        np.testing.assert_array_equal(columns(names, rows, 'pot'), expected.pots)
        np.testing.assert_allclose(rows[:, -7:-4], expected.wrist, rtol=0, atol=1e-9)
        np.testing.assert_allclose(rows[:, -4:], expected.orientation, rtol=0, atol=1e-9)
    assert 'missing' not in printed


@pytest.mark.slow
def test_missing_topics_are_named_and_the_rest_reported(tmp_path, capsys):
    bag = tmp_path / 'partial'
    expected = simulate_samples(200, 'right', seed=5)
    with BagRecorder(bag, 'sqlite3') as recorder:
        recorder.add_topic('/joint_states', JOINT_STATE)
        recorder.add_topic('/pose', JOINT_STATE)  # the wrong type
        state = TYPES[JOINT_STATE]
        for i, stamp in enumerate(expected.stamp.tolist()):
            message = state(
                header=TYPES['std_msgs/msg/Header'](
                    stamp=TYPES['builtin_interfaces/msg/Time'](sec=stamp // 10**9,
                                                               nanosec=stamp % 10**9),
                    frame_id='kraft_master_base'),
                name=list(kinematics.JOINT_NAMES), position=expected.position[i],
                velocity=expected.velocity[i], effort=expected.effort[i])
            data = STORE.serialize_cdr(message, JOINT_STATE)
            recorder.write('/joint_states', stamp, data)
        recorder.write('/joint_states', 0, b'\x00\x01\x00\x00garbage')
    out = tmp_path / 'out'
    assert report.main([str(bag), '--out', str(out)]) == 0
    printed = capsys.readouterr().out
    assert 'missing topics: /pots, /wrench, /diagnostics' in printed
    assert '/pose has type sensor_msgs/msg/JointState' in printed
    assert '/joint_states: 1 malformed messages skipped' in printed
    names, _, rows = read_csv(out / 'partial_samples.csv')
    np.testing.assert_allclose(columns(names, rows, suffix='_position'), expected.position,
                               atol=1e-9)
    assert np.isnan(rows[:, names.index('pot1'):]).all()
    assert imread(out / 'partial_report.png').size


@pytest.mark.slow
def test_recalibration_from_the_recorded_pots(tmp_path, capsys):
    bag = tmp_path / 'session'
    samples = write_bag(bag, 'sqlite3', {'/right': ('right', 6)})['/right']
    nominal = ArmCalibration.nominal('right')
    other = ArmCalibration('right', nominal.pot_a + 30.0, nominal.pot_b - 20.0,
                           nominal.angle_a, nominal.angle_b, source='other')
    other_file = tmp_path / 'other.yaml'
    other.to_yaml(other_file)
    out = tmp_path / 'out'
    assert report.main([str(bag), '--out', str(out), '--calibration', str(other_file),
                        '--arm-namespace', 'right']) == 0
    printed = capsys.readouterr().out
    assert f'recalibrated with {other_file}' in printed
    assert 'largest wrist position change' in printed
    names, _, rows = read_csv(out / 'session_right_samples.csv')
    position = other.pots_to_joints(samples.pots)
    np.testing.assert_allclose(columns(names, rows, 'recal_', '_position'), position,
                               atol=1e-9)
    poses = kinematics.forward(position, 'right')
    recal = [names.index(n) for n in ('recal_x', 'recal_y', 'recal_z')]
    np.testing.assert_allclose(rows[:, recal], poses[:, :3, 3], atol=1e-9)
    quaternions = np.array([rotation_to_quaternion(p) for p in poses])
    np.testing.assert_allclose(rows[:, -4:], quaternions, atol=1e-9)


@pytest.mark.parametrize('argv, fragment', [
    (['--arm-namespace', '/middle'], 'no driver topics under /middle'),
    (['--calibration', 'no_such_file.yaml'], 'no_such_file.yaml'),
])
def test_unusable_input_exits_1_naming_it(tmp_path, capsys, argv, fragment):
    bag = tmp_path / 'bag'
    write_bag(bag, 'mcap', {'/left': ('left', 1)}, samples=200)
    assert report.main([str(bag), '--out', str(tmp_path)] + argv) == 1
    assert fragment in capsys.readouterr().err


def test_not_a_bag_exits_1(tmp_path, capsys):
    (tmp_path / 'empty').mkdir()
    assert report.main([str(tmp_path / 'empty')]) == 1
    assert 'cannot read the bag' in capsys.readouterr().err


def test_recorder_rejects_unknown_topics_and_existing_paths(tmp_path):
    with BagRecorder(tmp_path / 'bag', 'sqlite3') as recorder:
        recorder.add_topic('/a', POSE_STAMPED, [qos_profile('best_effort')])
        with pytest.raises(ValueError, match='/b'):
            recorder.write('/b', 0, b'')
        with pytest.raises(ValueError, match='added twice'):
            recorder.add_topic('/a', POSE_STAMPED)
        with pytest.raises(ValueError, match='unknown message type'):
            recorder.add_topic('/c', 'no_pkg/msg/Nothing')
    with pytest.raises(SessionError, match='exists'):
        BagRecorder(tmp_path / 'bag', 'mcap')
    with pytest.raises(ValueError, match='storage'):
        BagRecorder(tmp_path / 'other', 'rosbag1')
    with pytest.raises(ValueError, match='QoS'):
        qos_profile('sometimes')
    with Reader(tmp_path / 'bag') as reader:
        (connection,) = reader.connections
        assert connection.ext.offered_qos_profiles == [qos_profile('best_effort')]
        assert reader.connections[0].msgcount == 0


def test_storage_file_of_a_bag_reads_as_the_bag(tmp_path, capsys):
    bag = tmp_path / 'bag'
    write_bag(bag, 'mcap', {'': ('right', 7)}, samples=300)
    (arm_from_directory,) = report_data.read_arms(bag)
    (arm_from_file,) = report_data.read_arms(bag / 'bag_0.mcap', [''])
    for field in ('stamp', 'position', 'pots', 'wrist', 'wrench'):
        np.testing.assert_array_equal(getattr(arm_from_file, field),
                                      getattr(arm_from_directory, field))
    blocked = tmp_path / 'a_file'
    blocked.write_text('not a directory')
    assert report.main([str(bag), '--out', str(blocked), '--arm-namespace', '/']) == 1
    assert 'cannot write the report' in capsys.readouterr().err


@pytest.mark.slow
@pytest.mark.filterwarnings('error')
def test_session_without_samples_still_reports(tmp_path, capsys):
    bag = tmp_path / 'empty'
    with BagRecorder(bag, 'mcap') as recorder:
        recorder.add_topic('/left/joint_states', JOINT_STATE)
    calibration = tmp_path / 'left.yaml'
    ArmCalibration.nominal('left').to_yaml(calibration)
    assert report.main([str(bag), '--out', str(tmp_path), '--calibration',
                        str(calibration)]) == 0
    assert '/left (left arm): 0 samples' in capsys.readouterr().out
    names, stamps, rows = read_csv(tmp_path / 'empty_left_samples.csv')
    assert names[0] == 'stamp_ns' and names[-1] == 'recal_qw' and len(stamps) == 0


def status(name, **values):
    """Return a DiagnosticStatus named `name` with `values` (keys with _ for spaces)."""
    return TYPES['diagnostic_msgs/msg/DiagnosticStatus'](
        level=0, name=name, message='running', hardware_id='sim',
        values=[TYPES['diagnostic_msgs/msg/KeyValue'](key=key, value=value)
                for key, value in values.items()])


def diagnostics_message(*statuses):
    """Return the CDR bytes of a DiagnosticArray of `statuses`."""
    message = TYPES[DIAGNOSTIC_ARRAY](
        header=TYPES['std_msgs/msg/Header'](
            stamp=TYPES['builtin_interfaces/msg/Time'](sec=0, nanosec=0), frame_id=''),
        status=list(statuses))
    return STORE.serialize_cdr(message, DIAGNOSTIC_ARRAY)


def driver_values(errors, late, round_trip_ms):
    """Return diagnostics values as the driver publishes them (a subset)."""
    return {'late cycles': str(late), 'missed cycles': '0', 'link cycles': '5000',
            'link replies': '4990', 'link clamped_commands': '7',
            'link round trip median (ms)': f'{round_trip_ms:.3f}',
            'link round trip max (ms)': f'{3 * round_trip_ms:.3f}',
            'link timeouts': str(errors), 'link bad_crc': '0'}


@pytest.mark.slow
def test_diagnostics_on_slash_diagnostics_are_told_apart_by_node_name(tmp_path, capsys):
    bag = tmp_path / 'two_arms'
    with BagRecorder(bag, 'mcap') as recorder:
        for namespace, arm, seed in (('/left', 'left', 1), ('/right', 'right', 2)):
            write_samples(recorder, namespace,
                          simulate_samples(300, arm, seed=seed),
                          diagnostics_every=10_000)
        recorder.add_topic('/diagnostics', DIAGNOSTIC_ARRAY)
        for second in range(1, 6):
            recorder.write('/diagnostics', 1_767_225_600_000_000_000 + second * 10**8,
                           diagnostics_message(
                               status('/left/kraft_master_node: left Kraft Master',
                                      **driver_values(0, 0, 0.4)),
                               status('/right/kraft_master_node: right Kraft Master',
                                      **driver_values(second, 2 * second, 0.5)),
                               status('/other_node: something', **{'link timeouts': '99'})))
    left, right = report_data.read_arms(bag)
    assert [len(arm.diagnostics) for arm in (left, right)] == [5, 5]
    times, errors = report_data.link_errors(right.diagnostics)
    # Error counts only: not progress, not what was done to commands, not milliseconds.
    assert list(errors) == ['timeouts'] and errors['timeouts'].tolist() == [1, 2, 3, 4, 5]
    assert report_data.link_errors(left.diagnostics)[1] == {}
    assert report.main([str(bag), '--out', str(tmp_path / 'out')]) == 0
    printed = capsys.readouterr().out
    assert ('5 diagnostics messages: late cycles 0, missed cycles 0, link errors: none'
            in printed)
    assert ('5 diagnostics messages: late cycles 10, missed cycles 0, link errors: '
            'timeouts 5' in printed)
    assert 'missing' not in printed

    def panel(figure, title):
        return next(ax for ax in figure.axes if ax.get_title().startswith(title))

    figure = report_plots.draw(left)
    assert [t.get_text() for t in panel(figure, 'link errors').texts] == [
        'no link errors in 5 diagnostics messages']
    assert [t.get_text() for t in panel(figure, 'late and missed').texts] == [
        'no late or missed cycles in 5 diagnostics messages']
    figure = report_plots.draw(right)
    errors_panel = panel(figure, 'link errors')
    assert [t.get_text() for t in errors_panel.get_legend().get_texts()] == ['timeouts (5)']
    assert max(line.get_ydata().max() for line in errors_panel.lines) == 5
    assert [t.get_text() for t in panel(figure, 'late and missed').get_legend().get_texts()] == [
        'late cycles (10)', 'missed cycles (0)']
    round_trip = panel(figure, 'link round trip')
    assert [t.get_text() for t in round_trip.get_legend().get_texts()] == [
        'median', 'p99', 'max']
    np.testing.assert_allclose(round_trip.lines[2].get_ydata(), 1.5)
    elbow = panel(figure, 'elbow_pitch')
    assert 'upper stop, moves with th2' in [t.get_text() for t in elbow.get_legend().get_texts()]
