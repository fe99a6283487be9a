# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
What the bag writers, the reader and the sample generator share.

The driver's message types and topics, the ROS 2 Jazzy type store of rosbags, the rosbag2
metadata version, the framing of MCAP records, and the error every bag function raises.
"""
import functools
import struct

from rosbags.typesys import get_typestore, Stores
from rosbags.typesys.store import Typestore

JOINT_STATE = 'sensor_msgs/msg/JointState'
POSE_STAMPED = 'geometry_msgs/msg/PoseStamped'
WRENCH_STAMPED = 'geometry_msgs/msg/WrenchStamped'
TWIST_STAMPED = 'geometry_msgs/msg/TwistStamped'
VECTOR3_STAMPED = 'geometry_msgs/msg/Vector3Stamped'
DIAGNOSTIC_ARRAY = 'diagnostic_msgs/msg/DiagnosticArray'
# The driver's topics, relative to its namespace, and their types.
DRIVER_TOPICS = {
    'joint_states': JOINT_STATE,
    'pose': POSE_STAMPED,
    'pots': JOINT_STATE,
    'wrench': WRENCH_STAMPED,
    'rate_command': TWIST_STAMPED,
    'diagnostics': DIAGNOSTIC_ARRAY,
}
BAG_VERSION = 9  # the rosbag2 metadata version of ROS 2 Jazzy
ROS_DISTRO = 'jazzy'  # the message types and hashes written are Jazzy's
INFINITE_NS = 2 ** 63 - 1  # RMW_DURATION_INFINITE
MCAP_MAGIC = b'\x89MCAP0\r\n'
MCAP_RECORD = struct.Struct('<BQ')  # opcode, content length


class SessionError(Exception):
    """A bag that cannot be read or written; the message names the bag and the fault."""


@functools.cache
def typestore() -> Typestore:
    """Return the rosbags type store of ROS 2 Jazzy."""
    return get_typestore(Stores.ROS2_JAZZY)
