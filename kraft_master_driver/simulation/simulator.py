# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
A simulated Kraft Master hand controller on a real pseudo-terminal, or on TCP.

The device answers each torque command with one pot reply in the link's frame format
(protocol.py). Behind the link:

- Six joints with inertia, viscous damping and Coulomb friction, integrated in the actuator
  coordinates q = (th1, th2, th2 + th3, th4, th5, th6) that the pots read, with the joint
  limits of Table II as rigid, inelastic end stops (the elbow's range coupled to th2).
- The received torque counts / torque_scale (N*m) drive actuator axes 1..5 directly
  (coupling 'actuator') or are joint torques mapped onto the actuators (coupling 'joint');
  the wrist roll has no motor.
- A scripted operator hand: a spring-damper per axis pulling the device toward a target that
  is held ('hold'), sweeps each joint in turn ('sweep') or wanders smoothly inside the
  workspace ('random_walk'). The motors act against the hand: the device follows the hand
  when no torque resists, and deflects when one is applied.
- Pots read the device's true calibration (with optional Gaussian noise), 12-bit.
- Time is wall time: the model is integrated in substeps of at most 0.5 ms up to the moment
  each command arrives, and every few milliseconds when no command comes.
- A watchdog zeroes the torques when no command arrives for command_timeout, as amplifier
  electronics with a watchdog would.
- Fault switches for tests: dropped replies, corrupted bytes, stalls, unplug and replug of the
  pty (behind a stable symlink), garbage bytes; optional wire timing for a baud rate.
- Transport 'tcp' in place of the pty: a TCP server on 127.0.0.1, reached as socket://, the way
  a serial device server carries a serial line over a network. A pty passes every byte through
  a kernel worker thread, which a busy machine can leave waiting for seconds; loopback TCP has
  none.
"""
import argparse
import collections
import gc
import math
import operator
import os
import queue
import random
import select
import shutil
import signal
import socket
import sys
import tempfile
import threading
import time
import tty
from typing import NamedTuple

from kraft_master_driver.core import kinematics
from kraft_master_driver.core.calibration import ArmCalibration, CalibrationError, POT_MAX
from kraft_master_driver.link.protocol import (
    AXIS_COUNT, DEFAULT_TORQUE_LIMIT, DEFAULT_TORQUE_SCALE, get_codec, INT16_MAX,
    STATUS_AMPLIFIERS_ENABLED, STATUS_COMMAND_CLAMPED, STATUS_COMMAND_TIMEOUT,
    STATUS_CORRUPT_COMMAND)
import numpy as np

OPERATORS = ('hold', 'sweep', 'random_walk', 'push')
COUPLINGS = ('actuator', 'joint')
TRANSPORTS = ('pty', 'tcp')
JOINT_COUNT = 6
MAX_SUBSTEP = 0.5e-3  # s
MAX_CATCH_UP = 0.05  # s of model time per step; a longer idle gap is skipped, not replayed
IDLE_TICK = 0.005  # s between model steps when no command arrives
WIRE_WAKE_EARLY = 0.0003  # s before a reply is due: select() oversleeps by ~0.1 ms
OPERATOR_MARGIN = 0.1  # fraction of each joint's range the operator's targets keep clear of
READ_SIZE = 4096
PROC_FD = '/proc/{pid}/fd/{fd}'
REQUEST_TIMEOUT = 5.0  # s to wait for the serving thread to carry out unplug/replug/garbage


class AxisDynamics(NamedTuple):
    """Model parameters per actuator axis q1..q6: the device and the operator's hand."""

    inertia: tuple  # kg*m^2
    damping: tuple  # viscous, N*m*s/rad
    friction: tuple  # Coulomb, N*m
    hand_stiffness: tuple  # N*m/rad
    hand_damping: tuple  # N*m*s/rad


# Made-up but plausible values: the paper gives no dynamics. Every axis of the hand and device
# together has a natural frequency of about 3.5 Hz, damped at about 0.8 of critical.
DEFAULT_DYNAMICS = AxisDynamics(
    inertia=(0.04, 0.04, 0.03, 0.005, 0.005, 0.002),
    damping=(0.05, 0.05, 0.04, 0.005, 0.005, 0.002),
    friction=(0.03, 0.03, 0.02, 0.005, 0.005, 0.002),
    hand_stiffness=(20.0, 20.0, 15.0, 3.0, 3.0, 1.0),
    hand_damping=(1.4, 1.4, 1.05, 0.19, 0.19, 0.07),
)


def joints_to_actuators(theta):
    """Return the actuator coordinates q (th3 replaced by th2 + th3) of joint angles th1..th6."""
    q = np.array(theta, dtype=float)
    q[..., 2] += q[..., 1]
    return q


def actuators_to_joints(q):
    """Return joint angles th1..th6 of actuator coordinates q (inverse of joints_to_actuators)."""
    theta = np.array(q, dtype=float)
    theta[..., 2] -= theta[..., 1]
    return theta


def elbow_upper_slope():
    """Return d(upper limit of th3)/d(th2): the elbow's range shrinks as th2 grows."""
    th2_max = kinematics.JOINT_LIMITS[1, 1]
    upper_at_max = kinematics.joint_limits(th2_max)[1][2]
    return (upper_at_max - kinematics.joint_limits(0.0)[1][2]) / th2_max


class Workspace:
    """Table II joint ranges shrunk by OPERATOR_MARGIN at each end: where the hand goes."""

    def __init__(self):
        """Compute the ranges; the elbow's upper bound is given at th2 = 0."""
        lower, upper = kinematics.joint_limits(0.0)
        margin = OPERATOR_MARGIN * (upper - lower)
        self.lower, self.upper = lower + margin, upper - margin
        self._elbow_slope = elbow_upper_slope()

    def elbow_upper(self, th2):
        """Return the upper bound of th3 at th2."""
        return self.upper[2] + self._elbow_slope * th2

    def clip(self, theta):
        """Clip joint angles (6,) in place into the workspace; return them."""
        np.clip(theta, self.lower, self.upper, out=theta)
        theta[2] = min(theta[2], self.elbow_upper(theta[1]))
        return theta

    def home(self):
        """Return the joint angles th1..th6 in the middle of the workspace."""
        home = (self.lower + self.upper) / 2.0
        home[2] = (self.lower[2] + self.elbow_upper(home[1])) / 2.0
        return home


class HoldOperator:
    """An operator hand that holds the device at one pose."""

    def __init__(self, workspace):
        """Hold the workspace's home pose."""
        self._target = joints_to_actuators(workspace.home()).tolist()

    def target(self, _t):
        """Return the actuator coordinates (6 floats) the hand pulls toward at time t (s)."""
        return self._target

    def hold_at(self, actuator_target):
        """Hold actuator coordinates (6 values, rad) from now on."""
        self._target = [float(x) for x in actuator_target]


class SweepOperator:
    """An operator hand that sweeps each joint in turn, one sine period each, inside limits."""

    def __init__(self, workspace, period):
        """Sweep about the workspace's home, `period` seconds per joint."""
        self._home = workspace.home()
        upper = workspace.upper.copy()
        upper[2] = workspace.elbow_upper(self._home[1])
        self._amplitude = np.minimum(upper - self._home, self._home - workspace.lower)
        self._period = period
        self._theta = self._home.copy()

    def target(self, t):
        """Return the actuator coordinates (6 floats) the hand pulls toward at time t (s)."""
        cycle, phase = divmod(t / self._period, 1.0)
        joint = int(cycle) % JOINT_COUNT
        theta = self._theta
        theta[:] = self._home
        theta[joint] += self._amplitude[joint] * math.sin(2.0 * math.pi * phase)
        return joints_to_actuators(theta).tolist()


class RandomWalkOperator:
    """An operator hand that moves smoothly between random waypoints inside the workspace."""

    STEP_FRACTION = 0.25  # standard deviation of one step, as a fraction of each joint's range

    def __init__(self, workspace, period, rng):
        """Start at the workspace's home; segments last 0.5..1.5 `period` s; draw from `rng`."""
        self._workspace = workspace
        self._step_sigma = self.STEP_FRACTION * (workspace.upper - workspace.lower)
        self._period = period
        self._rng = rng
        self._start = workspace.home()
        self._end = self._start.copy()
        self._t_start = 0.0
        self._t_end = 0.0

    def target(self, t):
        """Return the actuator coordinates (6 floats) the hand pulls toward at time t (s)."""
        while t >= self._t_end:
            self._start = self._end
            self._end = self._workspace.clip(
                self._start + self._rng.normal(0.0, self._step_sigma))
            self._t_start = max(self._t_end, t - self._period)
            self._t_end = self._t_start + self._period * self._rng.uniform(0.5, 1.5)
        fraction = (t - self._t_start) / (self._t_end - self._t_start)
        blend = 0.5 - 0.5 * math.cos(math.pi * fraction)
        return joints_to_actuators(self._start + blend * (self._end - self._start)).tolist()


class PushOperator:
    """
    An operator hand that pushes the wrist straight down and back, `period` s each way.

    It takes hold when the host first commands: the first stroke starts at rest from home,
    whenever the driver starts (the simulator holds t at 0 until then).
    """

    DEPTH = 0.08  # m below the home pose at the bottom of the stroke

    def __init__(self, workspace, period):
        """Push from the workspace's home to DEPTH below it (shoulder and elbow only)."""
        self._home = workspace.home()
        self._bottom = self._home.copy()
        goal = kinematics.forward(self._home)[:3, 3] - (0.0, 0.0, self.DEPTH)
        for _ in range(20):
            pose, jac = kinematics.forward_and_jacobian(self._bottom)
            self._bottom[:3] += np.linalg.lstsq(jac[:3, :3], goal - pose[:3, 3], rcond=None)[0]
        workspace.clip(self._bottom)
        self._period = period

    def target(self, t):
        """Return the actuator coordinates (6 floats) the hand pulls toward at time t (s)."""
        blend = 0.5 - 0.5 * math.cos(math.pi * t / self._period)
        return joints_to_actuators(self._home + blend * (self._bottom - self._home)).tolist()


def make_operator(name, workspace, period, rng):
    """Return the operator hand called `name` (one of OPERATORS)."""
    if name == 'hold':
        return HoldOperator(workspace)
    if name == 'sweep':
        return SweepOperator(workspace, period)
    if name == 'push':
        return PushOperator(workspace, period)
    return RandomWalkOperator(workspace, period, rng)


class DeviceModel:
    """
    Six actuator axes with inertia, damping, Coulomb friction, end stops and the hand.

    The state is plain Python floats: for six axes that is several times faster than numpy.
    """

    def __init__(self, dynamics, start):
        """Start at rest at joint angles `start` (6,) with the parameters `dynamics`."""
        self.q = joints_to_actuators(start).tolist()
        self.qd = [0.0] * JOINT_COUNT
        self.motor = [0.0] * JOINT_COUNT  # actuator torques, N*m; the roll stays zero
        self._inverse_inertia = [1.0 / m for m in dynamics.inertia]
        self._friction_per_inertia = [f / m for f, m in zip(dynamics.friction, dynamics.inertia)]
        self._stiffness = [float(k) for k in dynamics.hand_stiffness]
        self._damping = [b + h for b, h in zip(dynamics.damping, dynamics.hand_damping)]
        lower, upper = kinematics.joint_limits(0.0)
        self._lower, self._upper = lower.tolist(), upper.tolist()
        self._elbow_lower, self._elbow_upper = self._lower[2], self._upper[2]
        self._elbow_upper_slope = elbow_upper_slope()

    def step(self, elapsed, target):
        """Advance `elapsed` seconds, the hand pulling toward actuator coordinates `target`."""
        substeps = max(1, math.ceil(elapsed / MAX_SUBSTEP))
        dt = elapsed / substeps
        q, qd, lower, upper = self.q, self.qd, self._lower, self._upper
        axes = [(axis, dt * inverse_inertia, dt * friction, motor + stiffness * goal,
                 stiffness, damping)
                for axis, (inverse_inertia, friction, motor, stiffness, goal, damping)
                in enumerate(zip(self._inverse_inertia, self._friction_per_inertia,
                                 self.motor, self._stiffness, target, self._damping))]
        for _ in range(substeps):
            for axis, velocity_per_torque, stiction, drive, stiffness, damping in axes:
                # Semi-implicit Euler; Coulomb friction as an impulse that can stop the axis.
                velocity = qd[axis] + velocity_per_torque * (
                    drive - stiffness * q[axis] - damping * qd[axis])
                if velocity > stiction:
                    velocity -= stiction
                elif velocity < -stiction:
                    velocity += stiction
                else:
                    velocity = 0.0
                position = q[axis] + dt * velocity
                # Rigid, inelastic end stops.
                if position < lower[axis]:
                    position, velocity = lower[axis], 0.0
                elif position > upper[axis]:
                    position, velocity = upper[axis], 0.0
                q[axis], qd[axis] = position, velocity
                if axis == 1:
                    # The elbow's range is in th3 = q3 - q2; its upper bound falls as th2 grows.
                    lower[2] = position + self._elbow_lower
                    upper[2] = position + self._elbow_upper + self._elbow_upper_slope * position

    def joint_angles(self):
        """Return the joint angles th1..th6 (rad)."""
        return actuators_to_joints(self.q)

    def joint_angle_list(self):
        """Return joint_angles() as a list of floats, without numpy."""
        theta = list(self.q)
        theta[2] -= theta[1]
        return theta


def _rate(value, name):
    """Return `value` as a probability, or raise ValueError naming `name`."""
    rate = float(value)
    if not 0.0 <= rate <= 1.0:
        raise ValueError(f'{name} must be within 0..1, got {value!r}')
    return rate


def _axis_values(values, name, valid, requirement):
    """Return `values` as AXIS_COUNT floats that all pass `valid`, or raise ValueError."""
    try:
        array = np.asarray(values, dtype=float)
    except (TypeError, ValueError):
        array = None
    if array is None or array.shape != (AXIS_COUNT,) or not np.all(valid(array)):
        raise ValueError(f'{name} must be {AXIS_COUNT} {requirement}, got {values!r}')
    return array


class SimulatedKraftMaster:
    """A simulated Kraft Master on a pseudo-terminal or TCP; start() returns the port."""

    def __init__(self, arm='right', calibration=None, codec='kraft-default',
                 torque_scale=DEFAULT_TORQUE_SCALE, coupling='actuator', operator='hold',
                 pot_noise_counts=0.0, baudrate=None, seed=0, *,
                 torque_limit=DEFAULT_TORQUE_LIMIT, command_timeout=0.1,
                 operator_period=2.0, drop_reply_rate=0.0, corrupt_byte_rate=0.0,
                 dynamics=DEFAULT_DYNAMICS, record=10000, priority=0, transport='pty'):
        """
        Configure the device; nothing runs until start().

        calibration is the device's true calibration (default: the arm's nominal one);
        torque_scale is in command counts per N*m, torque_limit in counts (larger commands
        are clamped, status bit1); baudrate None means no wire timing; command_timeout (s)
        is the watchdog; operator_period (s) is the sweep time per joint or the mean
        segment of the random walk; `record` is the length of the `received` deque;
        priority (1-99) runs the serving thread SCHED_FIFO, answering as promptly as the
        device's own electronics would (0: the normal scheduler; if the OS refuses,
        priority_error says why and the thread runs normally). transport 'pty': the port is
        a pseudo-terminal behind a symlink; 'tcp': a TCP server on 127.0.0.1 that serves one
        host at a time, its port a pyserial URL socket://127.0.0.1:N.
        """
        if transport not in TRANSPORTS:
            raise ValueError(f'transport must be one of {", ".join(TRANSPORTS)}, '
                             f'got {transport!r}')
        self.transport = transport
        if not (isinstance(priority, int) and 0 <= priority <= 99):
            raise ValueError(f'priority must be an integer in 0..99, got {priority!r}')
        self.priority = priority
        self.priority_error = None
        self.arm = kinematics.check_arm(arm)
        self.calibration = ArmCalibration.nominal(arm) if calibration is None else calibration
        if self.calibration.arm != arm:
            raise ValueError(f'calibration is for the {self.calibration.arm} arm, not {arm}')
        self._codec = get_codec(codec)
        scale = _axis_values(torque_scale, 'torque_scale',
                             lambda x: np.isfinite(x) & (x != 0.0), 'finite non-zero numbers')
        self._inverse_scale = tuple(1.0 / scale)
        limits = _axis_values(torque_limit, 'torque_limit', lambda x: (x >= 0) & (x <= INT16_MAX),
                              f'counts within 0..{INT16_MAX}')
        self._limits = tuple(int(x) for x in limits)
        if coupling not in COUPLINGS:
            raise ValueError(f'coupling must be one of {", ".join(COUPLINGS)}, got {coupling!r}')
        self.coupling = coupling
        if operator not in OPERATORS:
            raise ValueError(f'operator must be one of {", ".join(OPERATORS)}, got {operator!r}')
        self.operator = operator
        if not 0.0 <= pot_noise_counts < math.inf:
            raise ValueError(f'pot_noise_counts must be >= 0, got {pot_noise_counts!r}')
        self._noise = float(pot_noise_counts)
        self._wire_time = 0.0 if baudrate is None else self._codec.wire_cycle_time(baudrate)
        self.baudrate = baudrate
        if not command_timeout > 0.0 or not operator_period > 0.0:
            raise ValueError('command_timeout and operator_period must be positive, got '
                             f'{command_timeout!r} and {operator_period!r}')
        self._command_timeout = command_timeout
        self.drop_reply_rate = drop_reply_rate
        self.corrupt_byte_rate = corrupt_byte_rate

        operator_seed, noise_seed, fault_seed = np.random.SeedSequence(seed).spawn(3)
        self._noise_rng = np.random.default_rng(noise_seed)
        self._fault_random = random.Random(int(fault_seed.generate_state(1)[0]))
        workspace = Workspace()
        self._operator = make_operator(operator, workspace, operator_period,
                                       np.random.default_rng(operator_seed))
        self._model = DeviceModel(dynamics, workspace.home())
        self._model_lock = threading.Lock()
        self._decoder = self._codec.command_decoder()

        self.received = collections.deque(maxlen=record)
        self._stats = dict.fromkeys(
            ('commands', 'replies', 'dropped', 'corrupted_bytes', 'stalled', 'clamped',
             'timeouts', 'garbage_sent', 'unsent'), 0)
        self._directory = None
        self._link = None
        self._master = None  # the host's end: the pty master or the accepted connection
        self._slave = None
        self._listener = None
        self._tcp_port = 0
        self._wake = None
        self._requests = queue.SimpleQueue()
        self._thread = None
        self._running = False
        self._pending = collections.deque()  # (send time, reply bytes) under wire timing
        self._last_send = 0.0
        self._stall_until = 0.0
        self._model_time = 0.0
        self._start_time = 0.0
        self._waits_for_host = False  # the operator's time stands at 0 until the first command
        self._last_command = 0.0
        self._amplifiers = False
        self._timed_out = False
        self._errors_reported = 0

    # Fault switches.

    @property
    def drop_reply_rate(self):
        """Probability (0..1) that a reply is lost after the command was applied."""
        return self._drop_rate

    @drop_reply_rate.setter
    def drop_reply_rate(self, rate):
        self._drop_rate = _rate(rate, 'drop_reply_rate')

    @property
    def corrupt_byte_rate(self):
        """Probability (0..1) per outgoing byte that random bits of it are flipped."""
        return self._corrupt_rate

    @corrupt_byte_rate.setter
    def corrupt_byte_rate(self, rate):
        self._corrupt_rate = _rate(rate, 'corrupt_byte_rate')

    def hold_at(self, actuator_target):
        """Make the 'hold' operator hand pull toward actuator coordinates (6 values, rad)."""
        if not isinstance(self._operator, HoldOperator):
            raise ValueError("only the 'hold' operator hand can be held at a pose")
        self._operator.hold_at(actuator_target)

    def stall(self, ms):
        """Answer nothing for `ms` milliseconds; commands meanwhile are consumed, not applied."""
        if not ms >= 0:
            raise ValueError(f'stall needs a duration >= 0 ms, got {ms!r}')
        self._stall_until = time.monotonic() + ms / 1000.0

    def unplug(self):
        """Close the pty master and remove the port symlink (tcp: close the server)."""
        self._call_in_loop(self._close_port)

    def replug(self):
        """Open a new pty behind the port symlink (tcp: serve the same port again)."""
        self._call_in_loop(self._open_port)

    def send_garbage(self, n_bytes):
        """Write `n_bytes` random bytes to the host, between replies."""
        if not n_bytes >= 0:
            raise ValueError(f'send_garbage needs a byte count >= 0, got {n_bytes!r}')
        self._call_in_loop(lambda: self._write_garbage(int(n_bytes)))

    # Observation.

    @property
    def port(self):
        """Return the stable port to open, a symlink to the pty slave or a URL; None if stopped."""
        return self._link

    @property
    def stats(self):
        """Counters of the device, with the command decoder's error counts as decode_errors."""
        return dict(self._stats, decode_errors=dict(self._decoder.errors))

    def joint_angles(self):
        """Return the true joint angles th1..th6 (rad) of the simulated device."""
        with self._model_lock:
            return self._model.joint_angles()

    # Life cycle.

    def start(self):
        """Open the port (pty and symlink, or TCP server), start serving; return the port."""
        if self._running:
            return self._link
        if self.transport == 'pty':
            self._directory = tempfile.mkdtemp(prefix='kraft_master_sim_')
            self._link = os.path.join(self._directory, 'tty')
        self._wake = os.pipe()
        os.set_blocking(self._wake[0], False)
        self._open_port()
        if self.transport == 'tcp':
            self._link = f'socket://127.0.0.1:{self._tcp_port}'
        self._start_time = self._model_time = self._last_command = time.monotonic()
        self._waits_for_host = isinstance(self._operator, PushOperator)
        self._running = True
        self._thread = threading.Thread(target=self._serve, name='kraft_master_sim',
                                        daemon=True)
        self._thread.start()
        if self.priority:
            try:  # Linux: a thread id in place of a process id sets that thread alone
                os.sched_setscheduler(self._thread.native_id, os.SCHED_FIFO,
                                      os.sched_param(self.priority))
            except OSError as error:
                self.priority_error = f'SCHED_FIFO {self.priority} refused: {error}'
        return self._link

    def stop(self):
        """Stop serving, close every descriptor, remove the temporary directory."""
        if self._thread is not None:
            self._running = False
            os.write(self._wake[1], b'x')
            self._thread.join()
            self._thread = None
        self._close_port()
        if self._wake is not None:
            for fd in self._wake:
                os.close(fd)
            self._wake = None
        if self._directory is not None:
            shutil.rmtree(self._directory, ignore_errors=True)
            self._directory = None
        self._link = None

    def __enter__(self):
        """Start serving and return the simulator."""
        self.start()
        return self

    def __exit__(self, *_exc):
        """Stop serving."""
        self.stop()

    # The serving thread.

    def _serve(self):
        wake = self._wake[0]
        while self._running:
            timeout = IDLE_TICK
            if self._pending:
                due = self._pending[0][0]
                due_in = due - time.monotonic()
                if due_in <= WIRE_WAKE_EARLY:
                    # select() oversleeps by about 0.1 ms here: watch the clock alone until
                    # the reply is due, so that it leaves on time.
                    while time.monotonic() < due:
                        pass
                    self._send_due(time.monotonic())
                    continue
                timeout = min(timeout, due_in - WIRE_WAKE_EARLY)
            master, listener = self._master, self._listener
            waits = [fd for fd in (wake, master, listener) if fd is not None]
            readable = select.select(waits, (), (), timeout)[0]
            now = time.monotonic()
            if self._pending:
                self._send_due(now)
            self._advance(now)
            if master is not None and master in readable:
                self._receive(now)
            if listener is not None and listener in readable:
                self._accept()
            if wake in readable:
                self._run_requests()

    def _advance(self, now):
        """Run the watchdog, then integrate the model up to `now`."""
        if self._amplifiers and now - self._last_command > self._command_timeout:
            self._model.motor[:] = [0.0] * JOINT_COUNT
            self._amplifiers = False
            self._timed_out = True
            self._stats['timeouts'] += 1
        elapsed = now - self._model_time
        if elapsed <= 0.0:
            return
        self._model_time = now
        target = self._operator.target(0.0 if self._waits_for_host else now - self._start_time)
        with self._model_lock:
            self._model.step(min(elapsed, MAX_CATCH_UP), target)

    def _receive(self, now):
        try:
            data = os.read(self._master, READ_SIZE)
        except OSError:
            data = None  # pty: no host has the slave open
        if not data:
            if self.transport == 'tcp':
                self._drop_host()  # the host closed or reset its connection
            return
        for command in self._decoder.feed(data):
            self._handle(command, now)

    def _handle(self, command, now):
        self.received.append((time.time_ns(), command))  # before the reply: a host can count on it
        stats = self._stats
        stats['commands'] += 1
        if now < self._stall_until:
            stats['stalled'] += 1
            return
        clamped = self._clamped(command.counts)
        if clamped:
            stats['clamped'] += 1  # before the reply: a host that has it can count on it
        # The pots were read when the command arrived: answer first, then drive the motors.
        self._answer(command.sequence, clamped, now)
        self._apply(command.counts)
        self._last_command = now
        self._amplifiers = True
        if self._waits_for_host:
            self._waits_for_host = False
            self._start_time = now

    def _clamped(self, counts):
        """Return True if any command count is beyond its axis limit."""
        return any(not -limit <= count <= limit for count, limit in zip(counts, self._limits))

    def _answer(self, sequence, clamped, now):
        """Send (or, under wire timing, schedule) the reply to command `sequence`."""
        stats = self._stats
        status = STATUS_AMPLIFIERS_ENABLED
        if clamped:
            status |= STATUS_COMMAND_CLAMPED
        errors = sum(self._decoder.errors.values())
        if errors != self._errors_reported:
            self._errors_reported = errors
            status |= STATUS_CORRUPT_COMMAND
        if self._timed_out:
            self._timed_out = False
            status |= STATUS_COMMAND_TIMEOUT
        if self._drop_rate and self._fault_random.random() < self._drop_rate:
            stats['dropped'] += 1
            return
        reply = self._codec.encode_reply(sequence, self._read_pots(), status)
        if self._corrupt_rate:
            reply = self._corrupt(reply)
        if self._wire_time:
            self._last_send = max(now, self._last_send) + self._wire_time
            self._pending.append((self._last_send, reply))
        else:
            self._write_reply(reply)

    def _apply(self, counts):
        """Set the motor torques from command counts, each clamped to its axis limit."""
        torques = [min(max(count, -limit), limit) * inverse_scale for count, limit, inverse_scale
                   in zip(counts, self._limits, self._inverse_scale)]
        if self.coupling == 'joint':
            torques = kinematics.actuator_torques(torques).tolist()
        self._model.motor[:AXIS_COUNT] = torques

    def _read_pots(self):
        """Return the six pot counts the device reads now (true calibration, noise, 12 bits)."""
        pots = self.calibration.joints_to_frame(self._model.joint_angle_list())
        if self._noise:
            pots = map(operator.add, pots,
                       self._noise_rng.normal(0.0, self._noise, JOINT_COUNT).tolist())
        return [min(max(round(count), 0), POT_MAX) for count in pots]

    def _corrupt(self, reply):
        """Flip random bits of each byte of `reply` with probability corrupt_byte_rate."""
        data = bytearray(reply)
        chance = self._fault_random.random
        for index in range(len(data)):
            if chance() < self._corrupt_rate:
                data[index] ^= self._fault_random.randrange(1, 256)
                self._stats['corrupted_bytes'] += 1
        return bytes(data)

    def _send_due(self, now):
        pending = self._pending
        while pending and pending[0][0] <= now:
            self._write_reply(pending.popleft()[1])

    def _write_reply(self, reply):
        if self._write(reply):
            self._stats['replies'] += 1

    def _write_garbage(self, n_bytes):
        if self._write(self._fault_random.randbytes(n_bytes)):
            self._stats['garbage_sent'] += n_bytes

    def _write(self, data):
        """Write to the host; False (counted as unsent) when unplugged or its buffer is full."""
        if self._master is None:
            self._stats['unsent'] += 1
            return False
        try:
            written = os.write(self._master, data)
        except OSError:
            written = 0
        if written != len(data):
            self._stats['unsent'] += 1
            return False
        return True

    # Work the serving thread does on request, so that only it touches the pty.

    def _call_in_loop(self, function):
        if not self._running:
            raise RuntimeError('the simulator is not running: call start() first')
        done = threading.Event()

        def request():
            function()
            done.set()

        self._requests.put(request)
        os.write(self._wake[1], b'r')
        if not done.wait(REQUEST_TIMEOUT):
            raise RuntimeError('the simulator thread did not respond')

    def _run_requests(self):
        try:
            os.read(self._wake[0], READ_SIZE)
        except BlockingIOError:
            pass
        while not self._requests.empty():
            self._requests.get()()

    def _open_port(self):
        if self.transport == 'tcp':
            self._open_listener()
        else:
            self._open_pty()

    def _close_port(self):
        if self.transport == 'tcp':
            self._close_listener()
        else:
            self._close_pty()

    def _open_listener(self):
        """Serve TCP on 127.0.0.1, on the port served before if any (unplugs first)."""
        self._close_listener()
        listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        listener.bind(('127.0.0.1', self._tcp_port))
        listener.listen(1)
        listener.setblocking(False)
        self._tcp_port = listener.getsockname()[1]
        self._listener = listener

    def _accept(self):
        """Take a host that connects; refuse a second one while the first is served."""
        try:
            connection, _address = self._listener.accept()
        except OSError:
            return
        if self._master is not None:
            connection.close()
            return
        connection.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        connection.setblocking(False)
        self._master = connection.detach()

    def _drop_host(self):
        """Close the connection to the host; drop what was in flight."""
        if self._master is not None:
            os.close(self._master)
            self._master = None
        self._pending.clear()
        self._decoder.reset()

    def _close_listener(self):
        """Stop serving TCP (a connected host sees the connection closed)."""
        self._drop_host()
        if self._listener is not None:
            self._listener.close()
            self._listener = None

    def _open_pty(self):
        """Open a new pty in raw mode and point the port symlink at its slave."""
        self._close_pty()
        master, slave = os.openpty()
        tty.setraw(slave)
        os.set_blocking(master, False)
        # Our own slave descriptor keeps the pty (and its raw mode) alive between host opens.
        self._master, self._slave = master, slave
        # Link through /proc where there is one: a link left behind by a killed simulator then
        # dangles, instead of leading a reconnecting driver to whichever pty gets the same
        # /dev/pts number next.
        target = PROC_FD.format(pid=os.getpid(), fd=slave)
        if not os.path.exists(target):
            target = os.ttyname(slave)
        staging = self._link + '.new'
        os.symlink(target, staging)
        os.replace(staging, self._link)

    def _close_pty(self):
        """Close the pty (the host sees a hangup), drop what was in flight, remove the link."""
        for fd in (self._master, self._slave):
            if fd is not None:
                os.close(fd)
        self._master = self._slave = None
        self._pending.clear()
        self._decoder.reset()
        if self._link is not None and os.path.lexists(self._link):
            os.unlink(self._link)


RECORD_ALL = None  # an unbounded deque


def main(argv=None):
    """Run the simulator from the command line until Ctrl-C or SIGTERM; return 0."""
    parser = argparse.ArgumentParser(
        prog='kraft_master_sim',
        description='Simulated Kraft Master hand controller on a pseudo-terminal (or TCP). '
                    'Prints the port for the driver, then serves until Ctrl-C or SIGTERM.')
    parser.add_argument('--arm', choices=kinematics.ARMS,
                        help="arm (default: the calibration's, else right)")
    parser.add_argument('--operator', choices=OPERATORS, default='hold',
                        help='what the simulated operator hand does (default: hold)')
    parser.add_argument('--baud', type=int, default=None,
                        help='delay replies by the wire time at this baud rate (default: none)')
    parser.add_argument('--noise', type=float, default=0.0,
                        help='pot noise, counts (1 sigma, default 0)')
    parser.add_argument('--coupling', choices=COUPLINGS, default='actuator',
                        help='torque channels 2 and 3 are actuator (default) or joint torques')
    parser.add_argument('--drop-rate', type=float, default=0.0,
                        help='probability that a reply is lost (default 0)')
    parser.add_argument('--corrupt-rate', type=float, default=0.0,
                        help='probability per reply byte of flipped bits (default 0)')
    parser.add_argument('--calibration', metavar='YAML',
                        help="the device's true calibration, a parameter file such as "
                             'config/right_arm.yaml (default: nominal)')
    parser.add_argument('--seed', type=int, default=0, help='random seed (default 0)')
    parser.add_argument('--priority', type=int, default=0,
                        help='SCHED_FIFO priority 1-99 of the thread that answers commands, '
                             'as prompt as the real electronics (default 0: normal)')
    parser.add_argument('--tcp', action='store_true',
                        help='serve on TCP, 127.0.0.1, instead of a pty: the port is a '
                             'socket:// URL, as of a serial device server')
    parser.add_argument('--record', metavar='NPY',
                        help='on exit, save every received command as rows (time_ns, '
                             'counts axis 1..5, sequence) in this .npy file')
    args = parser.parse_args(argv)

    calibration = None
    if args.calibration:
        try:
            calibration = ArmCalibration.from_yaml(args.calibration)
        except CalibrationError as error:
            parser.error(str(error))
    arm = args.arm or (calibration.arm if calibration else 'right')
    try:
        simulator = SimulatedKraftMaster(
            arm=arm, calibration=calibration, coupling=args.coupling, operator=args.operator,
            pot_noise_counts=args.noise, baudrate=args.baud, seed=args.seed,
            drop_reply_rate=args.drop_rate, corrupt_byte_rate=args.corrupt_rate,
            record=RECORD_ALL if args.record else 10000, priority=args.priority,
            transport='tcp' if args.tcp else 'pty')
    except ValueError as error:
        parser.error(str(error))

    # A plain list, not an Event: Event.set() in a handler deadlocks if the signal comes while
    # this thread holds the Event's lock inside wait() (a full test run once hung so).
    stop = []
    handlers = {signum: signal.signal(signum, lambda signum, _frame: stop.append(signum))
                for signum in (signal.SIGINT, signal.SIGTERM)}
    try:
        with simulator:
            print(f'port: {simulator.port}', flush=True)
            if simulator.priority_error:
                print(f'kraft_master_sim: warning: {simulator.priority_error}', file=sys.stderr)
            gc.freeze()  # no full garbage collection passes over the set-up (parameters.run_node)
            while not stop:
                time.sleep(0.5)
            print(f'kraft_master_sim: stopped, {simulator.stats}', file=sys.stderr)
        if args.record:
            np.save(args.record, np.array(
                [(t, *command.counts, command.sequence) for t, command in simulator.received],
                dtype=np.int64).reshape(-1, 7))
    finally:
        for signum, handler in handlers.items():
            signal.signal(signum, handler)
    return 0


if __name__ == '__main__':
    sys.exit(main())
