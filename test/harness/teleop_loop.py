# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The whole teleoperation chain on the MuJoCo Panda in simulated time: no DDS, no machine.

The same classes as the live chain, stepped together every millisecond: the simulated hand
controller and the operator's hand (DeviceModel), the driver's VelocityFilter, WrenchAdmission,
ForceReflection and MasterPort at 1 kHz; the bridge's Teleoperation (its motion, slave port and
force path) on each message as it arrives and its tick at 500 Hz; the Panda (PandaArm, 1 ms
steps) giving its pose and F/T reading at 500 Hz, as its node publishes them. Between the two
sides each message waits exactly its one-way delay (half the round trip plus `latency_ms`, the
hops' own time, plus a draw of `jitter_ms` if any) and is lost with the given probability. The
operator's hand pushes the master down through the table, holds, and lets go. What it shows is
the physics of the loop, the same on a busy machine as on an idle one.
"""
import collections
import math
import random
from typing import NamedTuple

from kraft_master_driver.core import kinematics
from kraft_master_driver.core.calibration import ArmCalibration
from kraft_master_driver.core.contact_rendering import ContactRenderer, RendererSettings
from kraft_master_driver.core.force_mode import (
    ForceMode, ModelFeedback, ModeSelector, ModeSettings)
from kraft_master_driver.core.force_reflection import ACTIVE, ForceReflection
from kraft_master_driver.core.passivity import MasterPort
from kraft_master_driver.core.teleoperation import Teleoperation
from kraft_master_driver.core.teleoperation_settings import Settings
from kraft_master_driver.core.velocity_filter import VelocityFilter
from kraft_master_driver.core.wrench_admission import BASE_FRAME, WrenchAdmission
from kraft_master_driver.nodes.driver_parameters import PARAMETERS as DRIVER_PARAMETERS
from kraft_master_driver.simulation.arms.panda import Gains, PandaArm, Table
from kraft_master_driver.simulation.master.model import (
    DEFAULT_DYNAMICS, DeviceModel, joints_to_actuators, Workspace)
from kraft_master_driver.tools.demo import MUJOCO_BRIDGE, MUJOCO_DRIVER
import numpy as np

ARM = 'right'
DT = 0.001  # s: the device's cycle and the Panda's step
ARM_PERIOD = 2  # ms between the arm's measured_cp and measured_cf (its publish_rate_hz, 500)
TICK_PERIOD = 2  # ms between the bridge's ticks (its rate_hz, 500)
REST, PUSH, HOLD, WINDOW, RELEASE = 0.2, 1.0, 4.0, 2.0, 1.0  # s
NORMAL = np.array([0.0, 0.0, 1.0])
FREE_SPACE = 0.002  # m: the hand's tip at least this far above the table is in free space
FIRST_FORCE = 1.0  # N: a wrench at least this strong is the contact's first news to the master
# The bridge as the demo runs it on the Panda, its force limit raised so that the deepest
# press is reflected whole (the bridge's default 10 N would clip it).
BRIDGE_SETTINGS = {name: value for name, value in MUJOCO_BRIDGE.items()
                   if name in Settings._fields}
MAX_FORCE = 60.0  # N
# Passivity as doc/design/passivity-experiments.md (Booking the force sent) has it feel the
# contact at 0 ms: the slave port books the force sent, the master port a 5 N*s/m damper (0.5 N
# of drag at 100 mm/s).
SENT_BOOKS = {'passivity': True, 'slave_port_force': 'sent', 'passivity_damping': 5.0}


class Session(NamedTuple):
    """One run: the link, passivity, the arm's stiffness and the operator's push."""

    round_trip_ms: float = 0.0
    loss: float = 0.0
    passivity: bool = False
    stiffness: float = 1000.0  # N/m: the Panda's translational stiffness
    past: float = 0.025  # m the operator's hand aims past the table top
    latency_ms: float = 1.0  # ms each way beyond the emulated delay: DDS and the ticks
    jitter_ms: float = 0.0  # ms each way drawn uniformly on top, order kept
    pot_counts: bool = False  # the driver reads the angles through whole pot counts, as live
    contact_damping: float = MUJOCO_DRIVER['contact_damping']  # s/m, the driver's
    passivity_damping: float = DRIVER_PARAMETERS['passivity_damping'].default  # N*s/m
    slave_port_force: str = Settings().slave_port_force  # what the bridge's slave port books
    limits_pull: bool = True  # the bridge's arm_stiffness set to the arm's (False: 0, no limit)
    seed: int = 0  # of the losses
    hold: float = HOLD  # s
    push: float = PUSH  # s the hand takes from above the table to `past` (up to 97 mm/s in 1 s)
    force_mode: str = 'direct'  # the driver's force_mode: direct, model or auto
    round_trip_changes: tuple = ()  # (s, ms): from then on the link's round trip is this
    table_stiffness: float = Table().stiffness  # N/m


class _Link:
    """One direction of the network: each message waits its delay and jitter; some are lost."""

    def __init__(self, delay, loss, rng, jitter=0.0):
        self.delay, self.loss, self.rng, self.jitter = delay, loss, rng, jitter
        self.queue = collections.deque()

    def send(self, now, message):
        if self.rng.random() >= self.loss:
            due = now + self.delay
            if self.jitter:
                # As the link emulator's jitter: a draw that would overtake waits.
                due += self.rng.random() * self.jitter
                if self.queue:
                    due = max(due, self.queue[-1][0])
            self.queue.append((due, message))

    def due(self, now):
        while self.queue and self.queue[0][0] <= now + 1e-9:
            yield self.queue.popleft()[1]


def _actuator_target(home_theta, depth):
    """Return the actuator coordinates with the wrist `depth` m below home."""
    theta = home_theta.copy()
    goal = kinematics.forward(home_theta, ARM)[:3, 3] - depth * NORMAL
    for _ in range(20):
        pose, jacobian = kinematics.forward_and_jacobian(theta, ARM)
        theta[:3] += np.linalg.lstsq(jacobian[:3, :3], goal - pose[:3, 3], rcond=None)[0]
    return joints_to_actuators(theta)


class _Master:
    """The driver's side: the device and the hand, the force path and the master port."""

    def __init__(self, session, home_theta):
        self.model = DeviceModel(DEFAULT_DYNAMICS, home_theta)
        ramp = DRIVER_PARAMETERS['force_ramp_time'].default  # the driver's, as it runs
        self.reflection = ForceReflection(contact_damping=session.contact_damping, enabled=True,
                                          force_ramp_time=ramp)
        self.admission = WrenchAdmission()
        self.velocity_filter = VelocityFilter(50.0)
        self.port = MasterPort(session.passivity_damping, rise_time=ramp)
        self.port.enabled = session.passivity
        self.feedback = ModelFeedback(
            ModeSelector(ModeSettings(ForceMode(session.force_mode)), session.passivity),
            ContactRenderer(RendererSettings(rate_hz=1.0 / DT)))
        self.calibration = ArmCalibration.nominal(ARM) if session.pot_counts else None
        self.previous = None
        self.felt = 0.0
        self.first_force = None  # (s, J): when the contact's force first came, energy in then

    def cycle(self, t, hand, to_arm, to_master):
        """Read, book, send the pose and energy, take the wrenches, apply torques, step."""
        now_ns = round(t * 1e9)
        port = self.port
        theta = self.model.joint_angle_list()
        if self.calibration is not None:
            theta = self.calibration.frame_to_joints(
                [round(count) for count in self.calibration.joints_to_frame(theta)])
        pose, entries = kinematics.forward_and_jacobian_entries(theta, ARM)
        jacobian = [entries[row:row + 6] for row in range(0, 36, 6)]
        velocity = self.velocity_filter.update(theta, now_ns)
        twist = [sum(a * b for a, b in zip(row, velocity)) for row in jacobian]
        if self.previous is not None:
            step = [a - b for a, b in zip(theta, self.previous)]
            port.moved([sum(a * b for a, b in zip(row, step)) for row in jacobian])
        self.previous = theta
        position = (pose[3], pose[7], pose[11])
        to_arm.send(t, (position, port.energy_in))
        for wrench, energy, model, sent in to_master.due(t):
            self.feedback.delay(t - sent, now_ns)
            if wrench is not None:
                self.reflection.hold(self.admission.admit(wrench, BASE_FRAME, 0, now_ns, 0))
                if self.first_force is None and math.hypot(*wrench[:3]) >= FIRST_FORCE:
                    self.first_force = (t, port.energy_in)
            if model is not None:
                self.feedback.take(model, now_ns)
            port.credit(energy)
        out = self.reflection.compute((pose[0:3], pose[4:7], pose[8:11]), jacobian, now_ns,
                                      cartesian_velocity=twist, port=port,
                                      model=self.feedback.force(position, twist[:3], now_ns))
        self.feedback.applied(out.model_share if out.state == ACTIVE else 0.0)
        self.felt = _felt(theta, out.actuator)
        self.model.motor[:5] = list(out.actuator)
        self.model.step(DT, hand)
        return np.array((pose[3], pose[7], pose[11]))


def _felt(theta, actuator):
    """Return the force along the normal that the torques sent amount to at the wrist (N)."""
    t1, t2, t3, t4, t5 = actuator
    joint = np.array([t1, t2 + t3, t3, t4, t5])
    jacobian = kinematics.jacobian(np.array(theta), ARM)
    return float(np.linalg.lstsq(jacobian[:3, :5].T, joint, rcond=None)[0] @ NORMAL)


def _arm_millisecond(k, t, arm, bridge, to_arm, to_master):
    """One millisecond on the arm's side: messages in, the Panda's step, its outputs."""
    settings = bridge.settings
    for position, energy in to_arm.due(t):
        bridge.master_energy(energy)
        out = bridge.master_pose(settings.master_frame, position, (0.0, 0.0, 0.0, 1.0), t)
        if out.command is not None:
            arm.command_pose(out.command[:3], out.command[3:], t)
    arm.step(t)
    if k % ARM_PERIOD == 0:
        bridge.arm_pose(settings.arm_frame, arm.tool_position(), arm.tool_quaternion(), t)
        out = bridge.ft_reading(settings.ft_frame, arm.wrench(), t)
        if out.wrench is not None:
            to_master.send(t, (tuple(out.wrench), bridge.port.energy_in, None, t))
        if bridge.master is not None and not bridge.following:
            bridge.enable(t)  # at the master's first pose, where the demo enables it
    if k % TICK_PERIOD == 1:
        out = bridge.tick(t)
        if out.command is not None:
            arm.command_pose(out.command[:3], out.command[3:], t)
        to_master.send(t, (None if out.wrench is None else tuple(out.wrench),
                           bridge.port.energy_in, out.contact_model, t))


def run(session=Session()):
    """
    Run one push, hold and release; return (log, master, slave port).

    The log has one row per millisecond: time (s); how far past the table top (m, > 0 below
    it) the master's wrist is, mapped onto the arm, the arm's command and the hand's tip; the
    table's force on the hand along the normal (N); the force felt along the normal (N, from
    the torques sent); the model's share of the force.
    """
    depth = session.past
    phases = ((None, None, REST, 0.0), (None, depth, session.push, 0.0),
              (depth, depth, session.hold, 0.0), (depth, None, RELEASE, 0.0))
    return _simulate(session, phases)


def _simulate(session, phases):
    """
    Run the hand through `phases`; return (log, master, slave port).

    Each phase: where the hand aims at its start and at its end (m past the table top as
    built, None: the top of the stroke, home), its seconds, and how far the table's rest is
    moved down from then on (m).
    """
    rng = random.Random(session.seed)
    home_theta = Workspace().home()
    home = kinematics.forward(home_theta, ARM)[:3, 3]
    table = Table(stiffness=session.table_stiffness)
    arm = PandaArm(table=table, gains=Gains(translational_stiffness=session.stiffness))
    start = arm.tool_position()
    settings = Settings(**{**BRIDGE_SETTINGS, 'max_force': MAX_FORCE,
                           'passivity': session.passivity,
                           'slave_port_force': session.slave_port_force,
                           'arm_stiffness': session.stiffness if session.limits_pull else 0.0})
    bridge = Teleoperation(settings)
    master = _Master(session, home_theta)
    one_way = (session.round_trip_ms / 2.0 + session.latency_ms) / 1e3
    jitter = session.jitter_ms / 1e3
    to_arm, to_master = (_Link(one_way, session.loss, rng, jitter),
                         _Link(one_way, session.loss, rng, jitter))
    targets = {}

    def aim(depth):
        if depth not in targets:
            targets[depth] = (joints_to_actuators(home_theta) if depth is None else
                              _actuator_target(home_theta, start[2] - table.height + depth))
        return targets[depth]

    log = []
    k = 0
    for begin_depth, end_depth, seconds, drop in phases:
        arm.move_table(drop)
        begin, end = aim(begin_depth), aim(end_depth)
        top = table.height - drop
        steps = round(seconds / DT)
        for step in range(steps):
            t = k * DT
            for at, round_trip_ms in session.round_trip_changes:
                if abs(t - at) < DT / 2:
                    to_arm.delay = to_master.delay = (
                        round_trip_ms / 2.0 + session.latency_ms) / 1e3
            blend = 0.5 - 0.5 * math.cos(math.pi * step / steps)
            wrist = master.cycle(t, (begin + blend * (end - begin)).tolist(), to_arm, to_master)
            _arm_millisecond(k, t, arm, bridge, to_arm, to_master)
            command = bridge.motion.command
            command_z = start[2] if command is None else command.position[2]
            log.append((t, top - (start[2] + wrist[2] - home[2]), top - command_z,
                        top - arm.tool_position()[2], arm.table_contact_force() @ NORMAL,
                        master.felt, master.feedback.share))
            k += 1
    return np.array(log), master, bridge.port


def figures(session=Session()):
    """
    Return what one session measured, in SI units, as a dict.

    Over the last WINDOW s of the hold: the master's peak-to-peak along the normal, how far
    past the table it is, the table's force and the force felt (means), their ratio, the
    stiffness felt (force felt over how far the master is past the table), the drift (the
    mapped master less the arm's command along the normal), the 99th percentile of the force
    felt's change from one millisecond to the next (chatter). Over the push while the hand is
    in free space: the largest force felt (drag). Over the run: the energy the channel
    generated by the ports' books (out at both ports less in at both), and what the slave
    port's controller took off the command (J). When the first wrench of FIRST_FORCE N reached
    the master: how far past the table the master was, and the energy its port had sent as
    credit by then (NaN without one).
    """
    log, master, slave_port = run(session)
    master_port = master.port
    first_past, first_energy = math.nan, math.nan
    if master.first_force is not None:
        first_past = float(log[round(master.first_force[0] / DT), 1])
        first_energy = master.first_force[1]
    t = log[:, 0]
    hold_end = REST + session.push + session.hold
    hold = (t >= hold_end - WINDOW) & (t < hold_end)
    push = (t >= REST) & (t < REST + session.push) & (log[:, 3] < -FREE_SPACE)
    master_past, table_force, felt = (log[hold, 1].mean(), log[hold, 4].mean(),
                                      log[hold, 5].mean())
    return {
        'master_pp': float(np.ptp(log[hold, 1])),
        'master_past': float(master_past),
        'table_force': float(table_force),
        'felt_force': float(felt),
        'felt_ratio': float(felt / table_force) if table_force > 0.0 else math.nan,
        'felt_stiffness': float(felt / master_past) if master_past > 0.0 else math.nan,
        'drift': float((log[hold, 1] - log[hold, 2]).mean()),
        'felt_chatter': float(np.percentile(np.abs(np.diff(log[hold, 5])), 99)),
        'free_space_drag': float(np.abs(log[push, 5]).max()) if push.any() else math.nan,
        'energy_generated': (master_port.energy_out + slave_port.energy_out
                             - master_port.energy_in - slave_port.energy_in),
        'slave_dissipated': slave_port.dissipated,
        'first_force_past': first_past,
        'first_force_energy_in': first_energy,
    }


class Tapping(NamedTuple):
    """Touches of the table: each aims `past` m past its top, then `back` m back up."""

    touches: int = 5
    past: float = 0.015
    back: float = 0.020
    down: float = 0.5  # s from above the table to past it
    hold: float = 2.0  # s
    up: float = 0.5  # s
    moved_before: int = 0  # the table moves before this touch (1-based; 0: never)
    drop: float = 0.010  # m it moves down then


def tap(session=Session(), tapping=Tapping()):
    """
    Run the touches; return (log, master, touches), touches a list of (start, end) log rows.

    The log's rows are run()'s, past the table where it stands at the time.
    """
    phases, bounds, drop = [(None, None, REST, 0.0)], [], 0.0
    above = tapping.past - tapping.back
    for touch in range(1, tapping.touches + 1):
        if touch == tapping.moved_before:
            drop = tapping.drop
        start = None if touch == 1 else above + drop
        first = sum(round(phase[2] / DT) for phase in phases)
        phases += [(start, tapping.past + drop, tapping.down, drop),
                   (tapping.past + drop, tapping.past + drop, tapping.hold, drop),
                   (tapping.past + drop, above + drop, tapping.up, drop)]
        bounds.append((first, first + round((tapping.down + tapping.hold + tapping.up) / DT)))
    log, master, _ = _simulate(session, phases)
    return log, master, bounds


def tapping_figures(session=Session(), tapping=Tapping(), window=1.0):
    """
    Return the figures of each touch (a list of dicts, SI units) and of the run (a dict).

    Per touch, over the last `window` s of its hold: the master's mean past the table and its
    peak-to-peak, the table's force and the force felt (means), the stiffness felt (felt over
    past); over the touch: the largest step of the force felt from one millisecond to the next,
    and the largest force felt while the master is above the table (drag, or a contact that is
    not there any more), and the table's largest force. The run: the stiffness possible (the
    arm's in series with the table's, clipped to the master's renderable wall), and when the
    arm and then the master first felt 1 N.
    """
    log, master, bounds = tap(session, tapping)
    touches = []
    window_rows = round(window / DT)
    hold_end = round((tapping.down + tapping.hold) / DT)
    for first, last in bounds:
        rows = log[first:last]
        hold = rows[hold_end - window_rows:hold_end]
        free = rows[:, 1] < -FREE_SPACE
        past, felt = hold[:, 1].mean(), hold[:, 5].mean()
        touches.append({
            'master_past': float(past), 'master_pp': float(np.ptp(hold[:, 1])),
            'table_force': float(hold[:, 4].mean()), 'felt_force': float(felt),
            'felt_stiffness': float(felt / past) if past > 0.0 else math.nan,
            'force_step': float(np.abs(np.diff(rows[:, 5])).max()),
            'max_table_force': float(rows[:, 4].max()),
            'drag': float(np.abs(rows[free, 5]).max()) if free.any() else math.nan})
    series = session.stiffness * session.table_stiffness / (
        session.stiffness + session.table_stiffness)
    arm_felt = np.flatnonzero(log[:, 4] >= FIRST_FORCE)
    master_felt = np.flatnonzero(log[:, 5] >= FIRST_FORCE)
    return touches, {
        'possible_stiffness': min(series, master.feedback.renderer.max_stiffness),
        'arm_first_force': float(log[arm_felt[0], 0]) if arm_felt.size else math.nan,
        'master_first_force': float(log[master_felt[0], 0]) if master_felt.size else math.nan,
        'wall_balance': master.feedback.renderer.balance,
        'max_table_force': float(log[:, 4].max()),
    }
