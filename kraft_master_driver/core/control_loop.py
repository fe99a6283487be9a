# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The driver's control loop, without ROS: one device cycle per period.

Each cycle reads the pot frame that answers the last command, estimates the arm's state from
it (joint angles, velocity, wrist pose, Jacobian), takes the inputs that came (wrenches), works
out the torques and sends them at the cycle's deadline, and hands every publish_decimation-th
frame to `publish`. A cycle that ends after its deadline sends at once and skips the whole
periods it cannot catch up (core.pacing's rule). On every doubt the torques are zero: no reply,
or an exception in a cycle.

The hot path works in plain floats with its work inlined: at 1 kHz a chain of small numpy
operations costs more than it saves (benchmarks/loop.py measures the loop).
"""
from collections.abc import Callable, Iterable, Mapping, Sequence
import operator
import time
from typing import Any, NamedTuple, Protocol

from kraft_master_driver.core import kinematics, realtime
from kraft_master_driver.core.calibration import ArmCalibration
from kraft_master_driver.core.force_mode import ModelFeedback
from kraft_master_driver.core.force_reflection import (
    ACTIVE, ForceReflection, STALE, TorqueOutput)
from kraft_master_driver.core.loop_statistics import LoopStatistics
from kraft_master_driver.core.pacing import MonotonicClock, Pacer
from kraft_master_driver.core.passivity import MasterPort
from kraft_master_driver.core.velocity_filter import VelocityFilter
import numpy as np
from numpy.typing import NDArray

ZERO_TORQUES = (0.0,) * kinematics.DRIVEN_JOINTS
# The name of the thread the driver runs the loop in, in ps -L and top as in Python
# (benchmarks/loop.py --sched-trace finds it by it).
LOOP_THREAD = 'kraft_loop'


class Estimate(NamedTuple):
    """
    What one pot frame tells, in plain floats.

    theta and velocity (6 each), pose (0T6 row by row, 16), its rotation (3 rows of 3) and
    the Jacobian (6 rows of 6).
    """

    theta: list[float]
    velocity: list[float]
    pose: tuple[float, ...]
    rotation: tuple[tuple[float, ...], ...]
    jacobian: list[tuple[float, ...]]


class PotFrame(Protocol):
    """The part of a device's pot frame the loop reads."""

    @property
    def pots(self) -> Sequence[int]:
        """Return the six pot counts."""


class Reply(Protocol):
    """The part of a device cycle's result the loop reads (link.device.CycleResult)."""

    @property
    def frame(self) -> PotFrame:
        """Return the pot frame that answered the command."""

    @property
    def round_trip_s(self) -> float:
        """Seconds from the command's send to its reply."""

    @property
    def receive_ns(self) -> int:
        """When the reply came (monotonic ns)."""


class Device(Protocol):
    """What the loop asks of a device (link.device.KmcDevice)."""

    link_up: bool
    last_error: str
    port: str
    reply_timeout: float

    @property
    def stats(self) -> Mapping[str, int]:
        """Return the link's counters."""

    def send(self, torques_nm: Iterable[float]) -> bool:
        """Send five torques (N*m); return whether they went out."""

    def receive(self) -> Any:
        """Return the reply to the last command (a Reply), or None."""

    def close(self) -> None:
        """Send zero torque and close the port."""


class Log(Protocol):
    """The loop's logger: rclpy's, or a stand-in."""

    def info(self, message: str, throttle_duration_sec: float = ...) -> object:
        """Log at info level."""

    def warning(self, message: str, throttle_duration_sec: float = ...) -> object:
        """Log at warning level."""

    def error(self, message: str, throttle_duration_sec: float = ...) -> object:
        """Log at error level."""


class SystemClock(MonotonicClock):
    """The clocks the loop runs on: monotonic time, the thread's CPU time, and sleep."""

    thread_time_ns = staticmethod(time.thread_time_ns)


class ControlLoop:
    """
    Paces a device's cycles: command out at each deadline, reply in, state handed on.

    device: a link.device.KmcDevice (send, receive, close, link_up, stats, last_error, port,
    reply_timeout). force: the core.force_reflection.ForceReflection that turns wrenches into
    torques. publish(result, estimate): called with a device CycleResult and its Estimate.
    take_inputs(): called before each send, to hand the wrenches that came to `force`.
    log: a logger with info, warning and error(message, throttle_duration_sec=...), as an
    rclpy logger. clock: SystemClock, or a stand-in with the same three functions.
    priority: the loop thread's SCHED_FIFO priority (0: normal). executor_thread: the native id
    of the thread that spins the node's executor; granted FIFO, the loop runs it one below.

    model: the contact model's side (core.force_mode.ModelFeedback), or None: direct only.

    run() cycles in the calling thread until stop() is called or keep_running() is false.
    centre (a 4x4 0T6 array, or None), holding and publish_decimation may be set from other
    threads.
    """

    def __init__(self, device: Device, force: ForceReflection,
                 publish: Callable[[Any, Estimate], None], *, calibration: ArmCalibration,
                 arm: str, lengths: kinematics.LinkLengths | None, velocity: VelocityFilter,
                 master_port: MasterPort, log: Log, rate_hz: float,
                 take_inputs: Callable[[], None] = lambda: None, publish_decimation: int = 1,
                 priority: int = 0, executor_thread: int | None = None,
                 clock: type[SystemClock] = SystemClock,
                 keep_running: Callable[[], bool] = lambda: True,
                 model: ModelFeedback | None = None) -> None:
        """Wire the parts together; nothing runs until run()."""
        self.device = device
        self.force = force
        self.publish = publish
        self.calibration = calibration
        self.arm = arm
        self.lengths = lengths
        self.velocity = velocity
        self.master_port = master_port
        self.log = log
        self.pacer = Pacer(int(1e9 / rate_hz), clock)
        self.take_inputs = take_inputs
        self.publish_decimation = publish_decimation
        self.priority = priority
        self.executor_thread = executor_thread
        self.statistics = LoopStatistics()
        self.clock = clock
        self.keep_running = keep_running
        self.model = model
        self.scheduler = 'normal'
        self.executor_scheduler = 'normal'
        self.memory_lock = 'not locked (loop_priority 0)'
        self.centre: NDArray[np.float64] | None = None
        # holding(theta): the motor torques that hold the arm up (core/gravity.py), or None.
        self.holding: Callable[[Sequence[float]], Sequence[float]] | None = None
        # The TorqueOutput of the last send, None without an estimate.
        self.output: TorqueOutput | None = None
        self.pose_entries: tuple[float, ...] | None = None  # 0T6 of the newest frame, by row
        self.cartesian_velocity: list[float] | None = None
        # Joint angles of the last frame, for the master port's work.
        self._theta: list[float] | None = None
        self._running = True
        self._last_force_state: str | None = None
        self._replies_missing = 0
        # Failed opens at which a down link is reported next; a link down from the start is
        # reported by the owner as it starts the loop.
        self._link_report_at = 0 if device.link_up else 2
        self._failed_opens_when_up = 0

    def stop(self) -> None:
        """Make run() return after the cycle under way."""
        self._running = False

    def pose(self) -> NDArray[np.float64] | None:
        """Return the newest wrist pose 0T6 as a new 4x4 array, None before the first frame."""
        entries = self.pose_entries
        return None if entries is None else np.array(entries).reshape(4, 4)

    def link_state(self) -> str:
        """Return what the loop waits for and why while the link is down."""
        reason = self.device.last_error.removeprefix(f'{self.device.port}: ')
        if self.statistics.frames:
            return f'link down: {reason}; reconnecting'
        return f'waiting for the device: {reason}'

    def run(self) -> None:
        """Run the loop at its priority; however it ends, zero the torques and close."""
        self._raise_priority()
        try:
            self._cycle_until_stopped()
        finally:
            self.device.close()

    def _raise_priority(self) -> None:
        """Give this thread real-time priority and lock memory if asked and allowed; say so."""
        if not self.priority:
            return
        granted = realtime.make_real_time(self.priority, self.executor_thread, self.log.warning,
                                          'loop_priority', 'the loop')
        self.scheduler, self.executor_scheduler, self.memory_lock = granted

    def _cycle_until_stopped(self) -> None:
        """
        Pace the device cycles: command out at each deadline, reply in, state published.

        A late cycle sends its next command as soon as the reply is estimated and publishes
        while that command is on the wire, so a wire-limited link is never idle for the
        publishing.
        """
        clock = self.clock
        cpu = clock.thread_time_ns
        statistics = self.statistics
        device = self.device
        pacer = self.pacer
        statistics.record_start(pacer.restart())
        sent = self._send_torques(None)
        while self._running and self.keep_running():
            try:
                c0 = cpu()
                result = device.receive() if sent else None
                c1 = cpu()
                estimate = None
                if result is None:
                    self.velocity.reset()
                    self._theta = None
                    self._warn_no_reply()
                else:
                    if self._replies_missing:
                        self._replies_missing = 0
                        self._link_report_at = 0
                        self._failed_opens_when_up = device.stats['failed_opens']
                        self.log.info('the device answers again', throttle_duration_sec=1.0)
                    statistics.round_trips.add(int(result.round_trip_s * 1e9))
                    estimate = self._estimate(result)
                statistics.add_cpu(link=c1 - c0, kinematics=cpu() - c1)
                missed = pacer.advance()
                if missed is not None:  # late: run at once, the missed periods skipped
                    statistics.late += 1
                    statistics.missed += missed
                    statistics.record_start(pacer.now_ns)
                    sent = self._send_torques(estimate)
                if estimate is not None and statistics.frames % self.publish_decimation == 0:
                    c2 = cpu()
                    self.publish(result, estimate)
                    statistics.published += 1
                    statistics.add_cpu(publish=cpu() - c2)
                if missed is None:
                    statistics.record_start(pacer.sleep())
                    sent = self._send_torques(estimate)
            except Exception as error:  # noqa: B902 - any fault must end in zero torque
                if not self._running or not self.keep_running():
                    break
                sent = device.send(ZERO_TORQUES)
                self.force.interrupt()
                statistics.internal_errors += 1
                self.log.error(f'cycle failed, torques zeroed: {error!r}',
                               throttle_duration_sec=1.0)
                # No busy loop at real-time priority if it recurs.
                clock.sleep(pacer.period_ns / 1e9)
                pacer.restart()

    def _send_torques(self, estimate: Estimate | None) -> bool:
        """Take the inputs that came, work out the torques and send them; True if sent."""
        cpu = self.clock.thread_time_ns
        c0 = cpu()
        self.take_inputs()
        output = None
        model = self.model
        now_ns = self.clock.monotonic_ns()
        if estimate is None:
            self.force.interrupt()
            self.master_port.idle(now_ns)
            if model is not None:
                model.idle()
        else:
            centre = self.centre
            velocity = self.cartesian_velocity
            model_force = None
            if model is not None and velocity is not None:
                pose = estimate.pose
                model_force = model.force((pose[3], pose[7], pose[11]), velocity[:3], now_ns)
            holding = self.holding
            output = self.force.compute(
                estimate.rotation, estimate.jacobian, now_ns,
                pose=None if centre is None else self.pose(), centre=centre,
                cartesian_velocity=velocity, port=self.master_port, model=model_force,
                holding=None if holding is None else holding(estimate.theta))
            if model is not None:
                model.applied(output.model_share if output.state == ACTIVE else 0.0)
            if output.state == STALE and self._last_force_state != STALE:
                self.log.warning(
                    f'no wrench for {self.force.wrench_timeout:g} s (wrench_timeout): '
                    'torques zeroed', throttle_duration_sec=1.0)
            self._last_force_state = output.state
        self.output = output
        c1 = cpu()
        sent = self.device.send(ZERO_TORQUES if output is None else output.actuator)
        self.statistics.add_cpu(kinematics=c1 - c0, link=cpu() - c1)
        return sent

    def _estimate(self, result: Reply) -> Estimate:
        """Joint angles, velocity, wrist pose and Jacobian of one pot frame, in floats."""
        theta = self.calibration.frame_to_joints(result.frame.pots)
        pose, entries = kinematics.forward_and_jacobian_entries(theta, self.arm, self.lengths)
        previous, self._theta = self._theta, theta
        velocity = self.velocity.update(theta, result.receive_ns)
        jacobian = [entries[row:row + 6] for row in range(0, 36, 6)]
        self.cartesian_velocity = [sum(map(operator.mul, row, velocity)) for row in jacobian]
        if previous is not None:
            step = [now - before for now, before in zip(theta, previous)]
            self.master_port.moved([sum(map(operator.mul, row, step)) for row in jacobian])
        self.pose_entries = pose
        self.statistics.frames += 1
        return Estimate(theta, velocity, pose, (pose[0:3], pose[4:7], pose[8:11]), jacobian)

    def _warn_no_reply(self) -> None:
        """Say why this cycle got no pot frame; its torques, and the next cycle's, are zero."""
        self._replies_missing += 1
        device = self.device
        if device.link_up:
            self.log.warning(
                f'no reply within reply_timeout {device.reply_timeout:g} s '
                f'({self._replies_missing} in a row): torques zeroed', throttle_duration_sec=1.0)
            return
        # Reported at the fault, then after 1, 2, 4, 8... failed reopens: less often as the
        # backoff grows.
        attempts = device.stats['failed_opens'] - self._failed_opens_when_up
        if attempts >= self._link_report_at:
            self._link_report_at = max(2 * attempts, 1)
            tried = f' ({attempts} attempts)' if attempts else ''
            self.log.warning(f'{self.link_state()}{tried}: torques zero')
