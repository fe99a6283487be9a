# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The loop's own CDR bytes against rclpy's serialisation and the bytes Fast DDS delivers."""
import math
import struct

from geometry_msgs.msg import PoseStamped, TwistStamped, WrenchStamped
from harness.driver import next_domain_id, wait_for
from hypothesis import given, settings, strategies as st
from kraft_master_driver.nodes import cdr
import pytest
import rclpy
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.typesys import get_typestore, Stores
from sensor_msgs.msg import JointState

# ROS strings end at their first NUL, so no generated frame_id holds one.
FRAME_IDS = st.text(st.characters(blacklist_characters='\x00', blacklist_categories=('Cs',)),
                    max_size=12)
FLOATS = st.floats(allow_nan=False, width=64)
SEC = st.integers(-2**31, 2**31 - 1)
NANOSEC = st.integers(0, 2**32 - 1)
JOINT_NAMES = ['kraft_joint1', 'j2', 'joint_three', 'j4', 'joint5', 'six']


def stamped(msg, frame_id, sec, nanosec):
    """Return msg with its header set."""
    msg.header.frame_id = frame_id
    msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
    return msg


def joint_state(frame_id, sec, nanosec, names, position, velocity, effort):
    return stamped(JointState(name=names, position=position, velocity=velocity, effort=effort),
                   frame_id, sec, nanosec)


def pose_stamped(frame_id, sec, nanosec, values):
    msg = stamped(PoseStamped(), frame_id, sec, nanosec)
    p, q = msg.pose.position, msg.pose.orientation
    p.x, p.y, p.z, q.x, q.y, q.z, q.w = values
    return msg


def with_vectors(msg, first, second, values):
    """Set two Vector3 fields of msg from six values; return msg."""
    first.x, first.y, first.z, second.x, second.y, second.z = values
    return msg


def twist_stamped(frame_id, sec, nanosec, values):
    msg = stamped(TwistStamped(), frame_id, sec, nanosec)
    return with_vectors(msg, msg.twist.linear, msg.twist.angular, values)


def wrench_stamped(frame_id, sec, nanosec, values):
    msg = stamped(WrenchStamped(), frame_id, sec, nanosec)
    return with_vectors(msg, msg.wrench.force, msg.wrench.torque, values)


@settings(max_examples=300, deadline=None, derandomize=True)
@given(FRAME_IDS, SEC, NANOSEC, st.sampled_from([(6, 6, 6), (6, 0, 0), (0, 0, 0), (6, 6, 0)]),
       st.data())
def test_joint_state_bytes_read_back_as_the_message(frame_id, sec, nanosec, lengths, data):
    values = [data.draw(st.lists(FLOATS, min_size=n, max_size=n)) for n in lengths]
    encoded = cdr.JointStateEncoder(frame_id, JOINT_NAMES, lengths).encode(sec, nanosec, *values)
    assert deserialize_message(encoded, JointState) == joint_state(
        frame_id, sec, nanosec, JOINT_NAMES, *values)


@settings(max_examples=300, deadline=None, derandomize=True)
@given(FRAME_IDS, SEC, NANOSEC, st.lists(FLOATS, min_size=7, max_size=7))
def test_pose_and_twist_bytes_read_back_as_the_messages(frame_id, sec, nanosec, values):
    pose = cdr.StampedDoublesEncoder(frame_id, 7).encode(sec, nanosec, values)
    assert deserialize_message(pose, PoseStamped) == pose_stamped(frame_id, sec, nanosec, values)
    twist = cdr.StampedDoublesEncoder(frame_id, 6).encode(sec, nanosec, values[:6])
    assert deserialize_message(twist, TwistStamped) == twist_stamped(
        frame_id, sec, nanosec, values[:6])


@settings(max_examples=500, deadline=None, derandomize=True)
@given(FRAME_IDS, SEC, NANOSEC, st.lists(st.floats(width=64), min_size=6, max_size=6))
def test_wrench_decoded_from_rclpy_serialisation(frame_id, sec, nanosec, values):
    data = serialize_message(wrench_stamped(frame_id, sec, nanosec, values))
    got_sec, got_nanosec, got_frame, got_values = cdr.decode_wrench_stamped(data)
    assert (got_sec, got_nanosec, got_frame) == (sec, nanosec, frame_id)
    assert [struct.pack('<d', v) for v in got_values] == [struct.pack('<d', v) for v in values]


@settings(max_examples=300, deadline=None, derandomize=True)
@given(FRAME_IDS, SEC, NANOSEC, st.lists(st.floats(width=64), min_size=7, max_size=7))
def test_pose_and_twist_decoded_from_rclpy_serialisation(frame_id, sec, nanosec, values):
    for message, decoder in ((pose_stamped(frame_id, sec, nanosec, values),
                              cdr.StampedDoublesDecoder('PoseStamped', 7)),
                             (twist_stamped(frame_id, sec, nanosec, values[:6]),
                              cdr.StampedDoublesDecoder('TwistStamped', 6))):
        got_sec, got_nanosec, got_frame, got_values = decoder.decode(serialize_message(message))
        assert (got_sec, got_nanosec, got_frame) == (sec, nanosec, frame_id)
        assert [struct.pack('<d', v) for v in got_values] == [
            struct.pack('<d', v) for v in values[:len(got_values)]]


@pytest.mark.slow
@settings(max_examples=2000, deadline=None, derandomize=True)
@given(st.binary(max_size=120) | st.builds(
    lambda data, cut, flips: bytes(
        b ^ flips.get(i, 0) for i, b in enumerate(data[:cut])),
    st.just(serialize_message(wrench_stamped('kraft_master_base', 1, 2, [1.0] * 6))),
    st.integers(0, 80), st.dictionaries(st.integers(0, 80), st.integers(1, 255), max_size=3)))
def test_bad_wrench_bytes_raise_value_error_only(data):
    try:
        sec, nanosec, frame_id, values = cdr.decode_wrench_stamped(data)
    except ValueError:
        return
    assert isinstance(frame_id, str) and len(values) == 6
    assert all(isinstance(v, float) for v in values)


@pytest.mark.parametrize('data, reason', [
    (b'', 'encapsulation'),
    (b'\x00\x00\x00\x00' + bytes(60), 'encapsulation'),  # big endian
    (b'\x00\x01\x00\x00' + bytes(8) + struct.pack('<I', 0), 'frame_id length'),
    (b'\x00\x01\x00\x00' + bytes(8) + struct.pack('<I', 400) + b'x\x00', 'frame_id length'),
    (b'\x00\x01\x00\x00' + bytes(8) + struct.pack('<I', 2) + b'xy', 'frame_id length'),
    (b'\x00\x01\x00\x00' + bytes(8) + struct.pack('<I', 2) + b'\xff\x00', 'WrenchStamped'),
    (b'\x00\x01\x00\x00' + bytes(8) + struct.pack('<I', 2) + b'x\x00' + bytes(20),
     'WrenchStamped'),
])
def test_bad_wrench_bytes_are_named(data, reason):
    with pytest.raises(ValueError, match=reason):
        cdr.decode_wrench_stamped(data)


def test_rosbags_reads_the_joint_state_bytes():
    typestore = get_typestore(Stores.ROS2_JAZZY)
    encoded = cdr.JointStateEncoder('kraft_master_base', JOINT_NAMES, (6, 0, 0)).encode(
        3, 4, [0.5] * 6, [], [])
    msg = typestore.deserialize_cdr(encoded, 'sensor_msgs/msg/JointState')
    assert msg.header.frame_id == 'kraft_master_base' and msg.name == JOINT_NAMES
    assert msg.position.tolist() == [0.5] * 6 and msg.velocity.size == msg.effort.size == 0


@pytest.fixture(scope='module')
def ros_node():
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=next_domain_id())
    node = rclpy.create_node('cdr_test', context=context)
    yield node
    node.destroy_node()
    rclpy.shutdown(context=context)


def delivered_bytes(node, msg_type, message):
    """Publish message with rclpy; return the bytes a raw subscription receives."""
    received = []
    topic = f'cdr_{msg_type.__name__}'
    publisher = node.create_publisher(msg_type, topic, 10)
    subscription = node.create_subscription(msg_type, topic, received.append, 10, raw=True)
    executor = rclpy.executors.SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    try:
        assert wait_for(lambda: publisher.get_subscription_count() > 0)
        publisher.publish(message)
        assert wait_for(lambda: received, spin=lambda: executor.spin_once(timeout_sec=0.01))
    finally:
        executor.remove_node(node)
        node.destroy_subscription(subscription)
        node.destroy_publisher(publisher)
    return received[0]


def test_bytes_equal_what_fast_dds_delivers_for_rclpy_messages(ros_node):
    position, velocity = [0.1, -2.0, math.pi, 0.0, 1e-9, 7.5], [1.0] * 6
    effort = [-0.25, 0.5, 0.0, 0.0, 1.25, 0.0]
    for frame_id in ('', 'kraft_master_base', 'left/kraft_master_base'):
        assert delivered_bytes(ros_node, JointState, joint_state(
            frame_id, 5, 6, JOINT_NAMES, position, velocity, effort)) == cdr.JointStateEncoder(
                frame_id, JOINT_NAMES, (6, 6, 6)).encode(5, 6, position, velocity, effort)
        assert delivered_bytes(ros_node, JointState, joint_state(
            frame_id, 5, 6, JOINT_NAMES, position, [], [])) == cdr.JointStateEncoder(
                frame_id, JOINT_NAMES, (6, 0, 0)).encode(5, 6, position, [], [])
        values = [0.25, -0.5, 0.125, 0.0, 0.0, 0.7071, 0.7071]
        assert delivered_bytes(ros_node, PoseStamped, pose_stamped(
            frame_id, 7, 8, values)) == cdr.StampedDoublesEncoder(frame_id, 7).encode(
                7, 8, values)
        assert delivered_bytes(ros_node, TwistStamped, twist_stamped(
            frame_id, 7, 8, values[:6])) == cdr.StampedDoublesEncoder(frame_id, 6).encode(
                7, 8, values[:6])
