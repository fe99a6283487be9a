# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""Synthetic sessions of the driver, for tests and benchmarks: simulate_samples, write_samples."""
from collections.abc import Sequence
from typing import NamedTuple, TYPE_CHECKING

from kraft_master_driver.bag.common import (
    DIAGNOSTIC_ARRAY, DRIVER_TOPICS, JOINT_STATE, POSE_STAMPED, typestore, WRENCH_STAMPED)
from kraft_master_driver.bag.recorder import BagRecorder, qos_profile
from kraft_master_driver.core import kinematics, rotations
from kraft_master_driver.core.calibration import ArmCalibration, POT_MAX
from kraft_master_driver.simulation.master.model import actuators_to_joints, Workspace
from kraft_master_driver.simulation.master.operators import RandomWalkOperator
import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from rosbags.typesys.store import MsgType


class Samples(NamedTuple):
    """The state of one arm, sample by sample, as the driver would publish it."""

    stamp: NDArray[np.int64]  # (N,) int64 ns
    position: NDArray[np.float64]  # (N, 6) rad
    velocity: NDArray[np.float64]  # (N, 6) rad/s
    effort: NDArray[np.float64]  # (N, 6) N*m
    pots: NDArray[np.float64]  # (N, 6) counts
    wrist: NDArray[np.float64]  # (N, 3) m
    orientation: NDArray[np.float64]  # (N, 4) qx qy qz qw
    wrench: NDArray[np.float64]  # (N, 6) N, N*m in the base frame


def simulate_samples(count: int, arm: str = 'right', calibration: ArmCalibration | None = None,
                     rate_hz: float = 1000.0, noise_counts: float = 1.0, seed: int = 0,
                     start_ns: int = 1_767_225_600_000_000_000) -> Samples:
    """
    Return the Samples of a simulated session of `count` samples.

    The simulator's random-walk operator hand moves the arm, the pots read it through
    `calibration` (default nominal) with Gaussian noise, and the joint angles, velocities,
    poses and J^T F torques of a smooth task wrench follow from the pots as in the driver.
    Stamps are `rate_hz` apart with a little jitter and an occasional late cycle.
    """
    calibration = calibration or ArmCalibration.nominal(arm)
    rng = np.random.default_rng(seed)
    period_ns = 1e9 / rate_hz
    jitter = rng.normal(0.0, 0.02 * period_ns, count)
    late = rng.random(count) < 0.001
    jitter[late] += rng.uniform(1.0, 3.0, int(late.sum())) * period_ns
    offsets = np.round(np.arange(count) * period_ns + np.maximum.accumulate(jitter))
    stamp = start_ns + offsets.astype(np.int64)
    t = (stamp - stamp[0]) / 1e9
    hand = RandomWalkOperator(Workspace(), 2.0, rng)
    theta = actuators_to_joints(np.array([hand.target(x) for x in t.tolist()]))
    pots = np.clip(np.rint(calibration.joints_to_pots(theta) +
                           rng.normal(0.0, noise_counts, theta.shape)), 0, POT_MAX)
    position = calibration.pots_to_joints(pots)
    velocity = np.gradient(position, t, axis=0) if count > 1 else np.zeros_like(position)
    poses = kinematics.forward(position, arm)
    orientation = np.array([rotations.rotation_to_quaternion(p) for p in poses]).reshape(-1, 4)
    phases = rng.uniform(0.0, 2.0 * np.pi, 6)
    wrench = np.array([5.0, 5.0, 5.0, 0.2, 0.2, 0.2]) * np.sin(
        2.0 * np.pi * 0.5 * t[:, None] + phases)
    effort = kinematics.joint_torques(position, wrench, arm)
    effort[:, 5] = 0.0
    return Samples(stamp, *(np.ascontiguousarray(values, dtype=float) for values in (
        position, velocity, effort, pots, poses[:, :3, 3], orientation, wrench)))


def write_samples(recorder: BagRecorder, namespace: str, samples: Samples,
                  joint_names: Sequence[str] | None = None,
                  frame_id: str = 'kraft_master_base', diagnostics_every: int = 1000,
                  receive_delay_ns: int = 200_000, diagnostics_topic: str | None = None) -> None:
    """
    Write `samples` into `recorder` as the driver's topics under `namespace`.

    Each message is serialised by rosbags: joint_states, pose, pots and wrench per sample
    (received receive_delay_ns after their stamp), and a diagnostics message every
    `diagnostics_every` samples: on `<namespace>/diagnostics`, the status named by the bare
    node name, or on `diagnostics_topic` (e.g. /diagnostics) by the node's full name. A late
    cycle and a link timeout are counted every 5000 samples. Topics not yet in the recorder
    are added.
    """
    store = typestore()
    types = store.types
    names = list(joint_names or kinematics.JOINT_NAMES)
    pot_names = [f'pot{i}' for i in range(1, 7)]
    topics = {name: f'{namespace}/{name}' for name in DRIVER_TOPICS}
    status_name = 'kraft_master_node: Kraft Master'
    if diagnostics_topic:
        topics['diagnostics'] = diagnostics_topic
        status_name = f'{namespace}/{status_name}'
    for name in ('joint_states', 'pose', 'pots', 'wrench', 'diagnostics'):
        if topics[name] not in recorder.counts:
            recorder.add_topic(topics[name], DRIVER_TOPICS[name], [qos_profile()])
    header_type, time_type = types['std_msgs/msg/Header'], types['builtin_interfaces/msg/Time']
    pose_type, point, quaternion = (types[f'geometry_msgs/msg/{name}']
                                    for name in ('Pose', 'Point', 'Quaternion'))
    wrench_type, vector = types['geometry_msgs/msg/Wrench'], types['geometry_msgs/msg/Vector3']
    status_type, key_value = (types[f'diagnostic_msgs/msg/{name}']
                              for name in ('DiagnosticStatus', 'KeyValue'))
    empty = np.empty(0)
    for i, stamp in enumerate(samples.stamp.tolist()):
        sec, nanosec = divmod(stamp, 1_000_000_000)
        header = header_type(stamp=time_type(sec=sec, nanosec=nanosec), frame_id=frame_id)
        received = stamp + receive_delay_ns
        x, y, z = samples.wrist[i].tolist()
        qx, qy, qz, qw = samples.orientation[i].tolist()
        fx, fy, fz, mx, my, mz = samples.wrench[i].tolist()
        messages: tuple[tuple[str, 'MsgType'], ...] = (
            ('joint_states', types[JOINT_STATE](
                header=header, name=names, position=samples.position[i],
                velocity=samples.velocity[i], effort=samples.effort[i])),
            ('pose', types[POSE_STAMPED](header=header, pose=pose_type(
                position=point(x=x, y=y, z=z),
                orientation=quaternion(x=qx, y=qy, z=qz, w=qw)))),
            ('pots', types[JOINT_STATE](header=header, name=pot_names,
                                        position=samples.pots[i], velocity=empty, effort=empty)),
            ('wrench', types[WRENCH_STAMPED](header=header, wrench=wrench_type(
                force=vector(x=fx, y=fy, z=fz), torque=vector(x=mx, y=my, z=mz)))),
        )
        if i % diagnostics_every == diagnostics_every - 1:
            values = [key_value(key=key, value=value) for key, value in (
                ('loop rate (Hz)', '1000.0'), ('late cycles', str(i // 5000)),
                ('missed cycles', '0'), ('link round trip median (ms)', '0.420'),
                ('link cycles', str(i + 1)), ('link timeouts', str(i // 5000)))]
            messages += (('diagnostics', types[DIAGNOSTIC_ARRAY](header=header, status=[
                status_type(level=0, name=status_name, message='running', hardware_id='sim',
                            values=values)])),)
        for name, message in messages:
            data = store.serialize_cdr(message, message.__msgtype__)
            recorder.write(topics[name], received, data)
