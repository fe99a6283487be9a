# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
A teleoperation session written message by message into a bag, to break one invariant at a time.

The session (namespace /right, 200 Hz, from T0 s of the bag's clock): the bridge DISABLED,
then ENABLED at T0 + 0.5 s with the arm following the master at 0.1 m/s, 20 mm behind its
command, and the master feeling 0.2 N*m; a FAULT at FAULT_AT (the command steps 20 mm to where
the arm was measured and holds there, zero torque within 5 ms), enabled
again at ENABLE_AT (the torque ramped back in); the driver's and the bridge's diagnostics
every 0.5 s (passivity on, the pot frames counted), both ports' energies within credit.
Every invariant holds; each name in BREAKS breaks exactly one of them.
"""
from kraft_master_driver.bag.common import (
    DIAGNOSTIC_ARRAY, JOINT_STATE, POSE_STAMPED, typestore, VECTOR3_STAMPED, WRENCH_STAMPED)
from kraft_master_driver.bag.recorder import BagRecorder
import numpy as np

TYPES = typestore().types
NS = '/right'
T0 = 100.0  # s: the first message
RATE = 200.0  # Hz
DURATION = 4.0  # s
ENABLE_FIRST = T0 + 0.5
FAULT_AT = T0 + 1.5
ENABLE_AT = T0 + 2.5
JUMP_AT = T0 + 1.0  # 'jump': the command steps 30 mm here
LOST_AT = T0 + 3.0  # 'lost': five pot frames from here are not in the bag
FAULT_REASON = 'measured_cf older than ft_timeout 0.1 s'
BREAKS = ('jump', 'fault_move', 'torque_on', 'torque_kick', 'lost', 'energy')
STRING = 'std_msgs/msg/String'
LAG = np.array([0.02, 0.0, 0.0])  # m the arm lags its command while following


def _header(t, frame='base_link'):
    sec, nanosec = divmod(round(t * 1e9), 1_000_000_000)
    return TYPES['std_msgs/msg/Header'](
        stamp=TYPES['builtin_interfaces/msg/Time'](sec=sec, nanosec=nanosec), frame_id=frame)


def pose(t, position):
    """Return a PoseStamped at `position`, orientation identity."""
    x, y, z = (float(v) for v in position)
    return TYPES[POSE_STAMPED](header=_header(t), pose=TYPES['geometry_msgs/msg/Pose'](
        position=TYPES['geometry_msgs/msg/Point'](x=x, y=y, z=z),
        orientation=TYPES['geometry_msgs/msg/Quaternion'](x=0.0, y=0.0, z=0.0, w=1.0)))


def joints(t, names, position, effort=()):
    """Return a JointState."""
    return TYPES[JOINT_STATE](header=_header(t, 'kraft_master_base'), name=list(names),
                              position=np.array(position, float), velocity=np.zeros(0),
                              effort=np.array(effort, float))


def energy(t, values):
    """Return a Vector3Stamped of energies in, out, dissipated."""
    x, y, z = (float(v) for v in values)
    return TYPES[VECTOR3_STAMPED](header=_header(t), vector=TYPES['geometry_msgs/msg/Vector3'](
        x=x, y=y, z=z))


def wrench(t, force):
    """Return a WrenchStamped of `force` (N, base frame), no moment."""
    vector = TYPES['geometry_msgs/msg/Vector3']
    x, y, z = (float(v) for v in force)
    return TYPES[WRENCH_STAMPED](header=_header(t, 'kraft_master_base'), wrench=TYPES[
        'geometry_msgs/msg/Wrench'](force=vector(x=x, y=y, z=z), torque=vector(
            x=0.0, y=0.0, z=0.0)))


def diagnostics(t, name, values):
    """Return a DiagnosticArray of one status named `name` with `values` {key: text}."""
    status = TYPES['diagnostic_msgs/msg/DiagnosticStatus'](
        level=0, name=name, message='running', hardware_id='',
        values=[TYPES['diagnostic_msgs/msg/KeyValue'](key=k, value=v) for k, v in values.items()])
    return TYPES[DIAGNOSTIC_ARRAY](header=_header(t, ''), status=[status])


def state(text):
    """Return an operating_state message."""
    return TYPES[STRING](data=text)


def session_messages(breaks=()):
    """Return (topic, msgtype, receive time s, message) of the session, `breaks` broken."""
    unknown = set(breaks) - set(BREAKS)
    assert not unknown, unknown
    out = []
    states = [(T0, 'DISABLED: not enabled'), (ENABLE_FIRST, 'ENABLED'),
              (FAULT_AT, f'FAULT: {FAULT_REASON}'), (ENABLE_AT, 'ENABLED')]
    for at, text in states:
        out.append((f'{NS}/operating_state', STRING, at, state(text)))
    published, credit, sent = 0, 0.0, 0.0
    command = measured = np.zeros(3)
    held = None
    steps = np.arange(0, int(DURATION * RATE))
    for index in steps.tolist():
        t = T0 + index / RATE
        receive = t + 0.0004
        following = ENABLE_FIRST < t < FAULT_AT or t > ENABLE_AT
        effort = np.zeros(6)
        if following:
            since = t - (ENABLE_AT if t > ENABLE_AT else ENABLE_FIRST)
            effort[:3] = min(0.2, 0.2 * since / 0.25)  # ramped in over 0.25 s
            if 'torque_kick' in breaks and t > ENABLE_AT:
                effort[:3] = 1.0
        elif 'torque_on' in breaks and FAULT_AT + 0.2 < t < FAULT_AT + 0.3:
            effort[:3] = 0.2
        pots_lost = 'lost' in breaks and LOST_AT <= t < LOST_AT + 5 / RATE
        out.append((f'{NS}/joint_states', JOINT_STATE, receive,
                    joints(t, [f'j{i}' for i in range(6)], np.zeros(6), effort)))
        if not pots_lost:
            out.append((f'{NS}/pots', JOINT_STATE, receive,
                        joints(t, [f'pot{i}' for i in range(1, 7)], np.full(6, 2048.0))))
        published += 1
        credit += 0.001
        sent = min(sent + 0.0008, credit)
        if 'energy' in breaks and t > T0 + 3.5:
            sent = credit + 0.01
        out.append((f'{NS}/master_energy', VECTOR3_STAMPED, receive, energy(t, (credit, sent, 0))))
        out.append((f'{NS}/slave_energy', VECTOR3_STAMPED, receive + 0.0003,
                    energy(t, (credit, 0.5 * credit, 0))))
        if following:
            command = command + np.array([0.1 / RATE, 0.0, 0.0])
            measured = command - LAG
            held = None
            sent_command = command
            if 'jump' in breaks and abs(t - JUMP_AT) < 0.5 / RATE:
                sent_command = command + np.array([0.03, 0.0, 0.0])
        elif t >= ENABLE_FIRST:
            held = measured if held is None else held
            command = sent_command = held.copy()
            if 'fault_move' in breaks and t > FAULT_AT + 0.5:
                sent_command = held + np.array([0.0, 0.001, 0.0])
        if t >= ENABLE_FIRST:
            out.append((f'{NS}/servo_cp', POSE_STAMPED, receive + 0.0002,
                        pose(t, sent_command)))
        out.append((f'{NS}/measured_cp', POSE_STAMPED, receive + 0.0001, pose(t, measured)))
        if index % int(RATE / 2) == int(RATE / 4):
            out.append(('/diagnostics', DIAGNOSTIC_ARRAY, receive + 0.001, diagnostics(
                t + 0.0005, f'{NS}/kraft_master_node: right Kraft Master',
                {'pot frames published': str(published + 40), 'link replies': str(published),
                 'passivity': 'on'})))
            out.append(('/diagnostics', DIAGNOSTIC_ARRAY, receive + 0.001, diagnostics(
                t + 0.0005, f'{NS}/kraft_master_teleop: teleoperation bridge',
                {'state': 'ENABLED', 'passivity': 'on'})))
    return out


def write_session(path, breaks=(), storage='mcap', messages=None):
    """Write the session (or `messages`) into a new bag at `path`; return the messages."""
    messages = session_messages(breaks) if messages is None else messages
    store = typestore()
    with BagRecorder(path, storage) as bag:
        for topic, msgtype in dict.fromkeys((m[0], m[1]) for m in messages):
            bag.add_topic(topic, msgtype)
        for topic, msgtype, at, message in sorted(messages, key=lambda m: m[2]):
            bag.write(topic, round(at * 1e9), bytes(store.serialize_cdr(message, msgtype)))
    return messages
