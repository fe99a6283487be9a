# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The invariants of a teleoperation session, each a function of the recorded series.

No bag here: session_check.py reads the bag into Series (receive times in seconds and values)
and hands them on. Each check returns the Violations it finds, each naming its time (the
receive time of the message at fault, seconds of the bag's clock) and its topic.
"""
from typing import Callable, NamedTuple, Optional

from kraft_master_driver.core import kinematics
from kraft_master_driver.core.passivity import PortEnergy
import numpy as np

HOLD_EXACT = 1e-9  # m: a held command is re-sent unchanged; farther is a move
# s: a command stamped before a hold began and received up to this much later was sent before
# it (the soak's recorder took one 2.6 s late on a loaded machine); a stamp older than this, or
# unset, may be another clock's, and the receive time counts.
LATE_RECEIPT_S = 10.0


class Series(NamedTuple):
    """
    One topic's messages: receive times (N,) in s, values (N, k), header stamps (N,) in s.

    sequence (N,): each message's count by its publisher (0: not known), where the bag has it.
    """

    topic: str
    t: np.ndarray
    values: np.ndarray
    stamp: Optional[np.ndarray] = None
    sequence: Optional[np.ndarray] = None

    def __len__(self) -> int:
        """Return the number of messages."""
        return len(self.t)


class Violation(NamedTuple):
    """An invariant broken at `time` (s) on `topic`; `text` says how."""

    time: float
    topic: str
    text: str

    @property
    def line(self) -> str:
        """Return it as one line: time, topic, what."""
        return f'{self.time:.3f} s {self.topic}: {self.text}'


class Fault(NamedTuple):
    """A fault, injected (from a faults file) or found in the recording."""

    kind: str
    side: str  # master, arm, link or clock
    start: float  # s, the bag's clock
    end: float
    force_untrue: bool  # whether the master's torque must go to zero


class Period(NamedTuple):
    """An operating state of the bridge, from its message until the next one."""

    state: str  # DISABLED, ENABLED, CLUTCHED, FAULT
    reason: str
    start: float
    end: float


class Limits(NamedTuple):
    """The bounds the checks hold the session to (SI units); session_check.py fills them."""

    max_linear_speed: float  # m/s: the bridge's limit on its target
    max_angular_speed: float  # rad/s
    max_step_s: float  # s: the longest step the bridge takes between two master poses
    hold_tolerance: float  # m: a command this close to the measured arm holds it where it is
    state_grace: float  # s: messages of two topics may be received this far out of order
    torque_zero_within: float  # s after a fault that makes the force untrue
    max_wrench_age: float  # s: the driver refuses older wrenches (the news of the arm's side)
    torque_zero: float  # N*m: an effort this small is zero
    max_torque_step: float  # N*m per message when the force comes back
    come_back_window: float  # s from the first torque after a fault in which its rise counts
    frame_tolerance: int  # pot frames a diagnostics count may differ from the bag at its stamp
    energy_tolerance: float  # J a port may hand out beyond its credit
    energy_grace: float  # s: credit received this much after a port's message still counts
    wrench_timeout: float = 0.05  # s: the driver's; a longer gap in the wrenches made it stale
    force_scale: float = 1.0  # the driver's, from wrench to reflected wrench
    contact_damping: float = 0.0  # s/m: the driver's, damping per newton of the force reflected


def _first(series: Series, rows: np.ndarray, text: Callable[[int], str]) -> list[Violation]:
    """Return the Violation at the first of `rows` of `series`, told by text(row); or none."""
    if not rows.size:
        return []
    row = int(rows[0])
    return [Violation(float(series.t[row]), series.topic, text(row))]


def state_periods(t: np.ndarray, texts: list[str], end: float) -> list[Period]:
    """Return the periods of operating_state messages ('STATE' or 'STATE: why') until `end`."""
    periods = []
    for index, (start, text) in enumerate(zip(t.tolist(), texts)):
        state, _, reason = text.partition(':')
        stop = t[index + 1] if index + 1 < len(t) else max(end, start)
        periods.append(Period(state.strip(), reason.strip(), start, float(stop)))
    return periods


def _near_measured(position: np.ndarray, time: float, measured: Optional[Series],
                   limits: Limits) -> bool:
    """Return whether the arm was measured within hold_tolerance of `position` near `time`."""
    if measured is None or not len(measured):
        return False
    low, high = np.searchsorted(measured.t, [time - limits.state_grace,
                                             time + limits.state_grace])
    near = measured.values[max(low - 1, 0):max(high, 1), :3]
    return float(np.min(np.linalg.norm(near - position, axis=1))) <= limits.hold_tolerance


def _measured_next(command: Series, index: int, measured: Optional[Series],
                   limits: Limits) -> bool:
    """
    Return whether the arm, not recorded near the step to command[index], was there after it.

    A restarted arm may reach the recorder later than the bridge, which registered where the
    arm is: the arm's first pose recorded after the step must be within hold_tolerance of the
    step's target, less the path the command took since. An arm recorded just before the step
    is judged by _near_measured alone.
    """
    if measured is None or not len(measured):
        return False
    time = float(command.t[index])
    after = int(np.searchsorted(measured.t, time))
    if after == len(measured) or (after and time - measured.t[after - 1] <= limits.state_grace):
        return False
    until = int(np.searchsorted(command.t, measured.t[after], side='right'))
    path = float(np.sum(np.linalg.norm(np.diff(command.values[index:until, :3], axis=0),
                                       axis=1)))
    target = command.values[index, :3]
    return float(np.linalg.norm(measured.values[after, :3] - target)) <= (
        limits.hold_tolerance + path)


def _angles(quaternions: np.ndarray) -> np.ndarray:
    """Return the angle (rad) between consecutive unit quaternions (N, 4) x y z w."""
    unit = quaternions / np.linalg.norm(quaternions, axis=1, keepdims=True)
    dots = np.abs(np.sum(unit[1:] * unit[:-1], axis=1))
    return 2.0 * np.arccos(np.minimum(dots, 1.0))


def _messages_apart(series: Series) -> np.ndarray:
    """Return (N-1,) how many messages the publisher sent from each to the next: 1 if unknown."""
    apart = np.ones(max(len(series) - 1, 0))
    if series.sequence is not None:
        sequence = series.sequence.astype(np.int64)
        counted = np.diff(sequence)
        known = (sequence[:-1] > 0) & (sequence[1:] > 0) & (counted > 1)
        apart[known] = counted[known]
    return apart


def command_steps(command: Series, measured: Optional[Series], limits: Limits
                  ) -> list[Violation]:
    """
    Check servo_cp: no step beyond the bridge's per-pose limit, unless to the arm's own pose.

    The limit is max_linear_speed (max_angular_speed) times max_step_s, the largest step the
    bridge lets its target take between two master poses. A hold where the arm is measured
    (a fault, an enable, a restarted arm recorded late) is no motion of the arm and passes.
    Two messages their publisher counted n apart (the recorder lost those between) may be n
    limits apart.
    """
    linear = limits.max_linear_speed * limits.max_step_s
    angular = limits.max_angular_speed * limits.max_step_s
    position, orientation = command.values[:, :3], command.values[:, 3:7]
    steps = np.linalg.norm(np.diff(position, axis=0), axis=1)
    turns = _angles(orientation)
    apart = _messages_apart(command)
    found = []
    for index in np.flatnonzero((steps > linear * apart * (1 + 1e-9)) |
                                (turns > angular * apart * (1 + 1e-9))).tolist():
        time = float(command.t[index + 1])
        if (_near_measured(position[index + 1], time, measured, limits)
                or _measured_next(command, index + 1, measured, limits)):
            continue
        found.append(Violation(
            time, command.topic,
            f'the command stepped {1e3 * steps[index]:.2f} mm and {turns[index]:.4f} rad in one '
            f'message (limit {1e3 * linear:.2f} mm and {angular:.4f} rad: max_linear_speed '
            f'{limits.max_linear_speed:g} m/s, max_angular_speed {limits.max_angular_speed:g} '
            f'rad/s, times {limits.max_step_s:g} s), and not to where the arm was measured'))
    return found


def twist_limits(twist: Series, limits: Limits) -> list[Violation]:
    """Check servo_cv: no twist faster than the bridge's speed limits."""
    linear = np.linalg.norm(twist.values[:, :3], axis=1)
    angular = np.linalg.norm(twist.values[:, 3:6], axis=1)
    over = np.flatnonzero((linear > limits.max_linear_speed * (1 + 1e-9)) |
                          (angular > limits.max_angular_speed * (1 + 1e-9)))
    return [Violation(float(twist.t[i]), twist.topic,
                      f'twist {linear[i]:.4f} m/s, {angular[i]:.4f} rad/s beyond the limits '
                      f'{limits.max_linear_speed:g} m/s, {limits.max_angular_speed:g} rad/s')
            for i in over.tolist()]


def _sent_before(series: Series, time: float) -> np.ndarray:
    """
    Return which messages were stamped before `time` and received at most LATE_RECEIPT_S after.

    A message the recorder received late (a reliable topic's repair, a recorder behind) was
    sent when its stamp says, on the sender's clock, where that clock is the recorder's.
    """
    if series.stamp is None:
        return np.zeros(len(series), bool)
    return (series.stamp < time) & (series.t - series.stamp <= LATE_RECEIPT_S)


def holds(periods: list[Period], command: Series, twist: bool, limits: Limits
          ) -> list[Violation]:
    """
    Check that the arm holds while the bridge says it must, until the operator enables.

    In FAULT every command (from state_grace after its start to state_grace before its end)
    is the same position, or a zero twist; in DISABLED nothing is sent. The first offending
    message of each period is named.
    """
    found = []
    for period in periods:
        if period.state not in ('FAULT', 'DISABLED'):
            continue
        rows = np.flatnonzero((command.t >= period.start + limits.state_grace) &
                              (command.t < period.end - limits.state_grace) &
                              ~_sent_before(command, period.start))
        if not rows.size:
            continue
        why = f'{period.state}' + (f' ({period.reason})' if period.reason else '')
        if period.state == 'DISABLED':
            found.append(Violation(float(command.t[rows[0]]), command.topic,
                                   f'a command sent while {why} since {period.start:.3f} s'))
            continue
        values = command.values[rows]
        moved = (np.linalg.norm(values[:, :6], axis=1) if twist else
                 np.linalg.norm(values[:, :3] - values[0, :3], axis=1))
        bad = np.flatnonzero(moved > HOLD_EXACT)
        if bad.size:
            what = (f'a twist of {moved[bad[0]]:.4f} m/s' if twist else
                    f'a move of {1e3 * moved[bad[0]]:.3f} mm')
            found.append(Violation(float(command.t[rows[bad[0]]]), command.topic,
                                   f'{what} commanded in {why} since {period.start:.3f} s, '
                                   'before the operator enabled again'))
    return found


def torque_zero(faults: list[Fault], effort: Series, limits: Limits,
                wrench: Optional[Series] = None) -> list[Violation]:
    """
    Check that the master's torque is zero from torque_zero_within after each such fault.

    Up to its end less state_grace: the message that ends a fault (an ENABLED, say) and the
    first torque after it may be received in either order. A torque stamped before
    torque_zero_within had passed was applied then, however late the recorder received it.
    A fault on the arm's side reaches the master with the wrench (as the master's side
    received it): from the first one stamped after the fault began, if it came within
    max_wrench_age (an older one the driver refuses; none, as when the bridge died, and the
    driver's own timeouts zero the torque).
    """
    found = []
    size = np.max(np.abs(np.nan_to_num(effort.values, nan=np.inf)), axis=1, initial=0.0)
    for fault in faults:
        if not fault.force_untrue:
            continue
        start = fault.start + limits.torque_zero_within
        if fault.side == 'arm' and wrench is not None and wrench.stamp is not None:
            news = wrench.t[(wrench.stamp >= fault.start) & (wrench.t >= fault.start) &
                            (wrench.t <= fault.start + limits.max_wrench_age)]
            start += float(news.min()) - fault.start if news.size else 0.0
        rows = np.flatnonzero((effort.t >= start) &
                              (effort.t <= fault.end - limits.state_grace) &
                              (size > limits.torque_zero) & ~_sent_before(effort, start))
        found += _first(effort, rows, lambda row: (
            f'torque {size[row]:.4f} N*m {effort.t[row] - fault.start:.3f} s after '
            f'{fault.kind} ({fault.side}) began at {fault.start:.3f} s: zero required '
            f'from {1e3 * (start - fault.start):.0f} ms on'))
    return found


def torque_steps(faults: list[Fault], effort: Series, limits: Limits,
                 joints: Optional[Series] = None, wrench: Optional[Series] = None
                 ) -> list[Violation]:
    """
    Check that the torque rises by at most max_torque_step a message as force comes back.

    The torque's size (its largest axis) from the first message with torque at or after a
    fault's end, for come_back_window: the force coming back, not a touch seconds later; and
    only until another fault begins (a wrench flood's steps are its own). After
    a fault that makes the force untrue or one on the master's or the clock's side (the driver
    zeroes the torque for them); not after a stuck sensor, a loss burst or a delay step: the
    force that comes through them is the arm's, and a step in it is the arm's contact
    changing, as at a touch. Nor a rise that a step of the live wrench explains
    (_wrench_explains; joints: joint_states' positions and velocities, row for row with
    effort). Two messages the driver counted n apart (the recorder lost those between) may
    be n steps apart.
    """
    found = []
    size = np.max(np.abs(effort.values), axis=1, initial=0.0)
    rises = np.diff(size)
    apart = _messages_apart(effort)
    for fault in faults:
        if not (fault.force_untrue or fault.side in ('master', 'clock')):
            continue
        after = np.flatnonzero((effort.t >= fault.end) & (size > limits.torque_zero))
        if not after.size:
            continue
        back = float(effort.t[after[0]])
        until = min([back + limits.come_back_window] + [
            other.start for other in faults if other is not fault and other.start >= fault.end])
        rows = np.flatnonzero((effort.t[1:] >= back) & (effort.t[1:] < until) &
                              (rises > limits.max_torque_step * apart)) + 1
        rows = np.array([row for row in rows.tolist() if not _wrench_explains(
            row, float(rises[row - 1]), joints, wrench, limits)], dtype=int)
        found += _first(effort, rows, lambda row: (
            f'torque rose {rises[row - 1]:.4f} N*m in one message as force came back after '
            f'{fault.kind} ({fault.side}) ended at {fault.end:.3f} s (bound '
            f'{limits.max_torque_step:g} N*m a message'
            f'{"" if apart[row - 1] == 1 else f", {apart[row - 1]:g} messages apart"})'))
    return found


def _wrench_explains(row: int, rise: float, joints: Optional[Series],
                     wrench: Optional[Series], limits: Limits) -> bool:
    """
    Return whether a step of the live wrench gives the torque's rise at joints' `row`.

    A touch or a spike steps the arm's wrench, and the torque with it: the arm's force
    changing, not the force coming back. The driver and the recorder receive a wrench up to
    state_grace apart, so any two wrenches received from state_grace before the previous
    torque message to state_grace after this one may make the step, if no silence longer
    than wrench_timeout came between them (it made the force stale: what followed it is the
    force coming back, which a wrench from before it does not explain). The rise is
    explained if at most force_scale (lever |dF| (1 + contact_damping v) + |dM|), with the
    pose's longest lever (the largest |J| column's linear part, the same for either arm) and
    the wrist's speed v.
    """
    if joints is None or wrench is None:
        return False
    first, last = np.searchsorted(wrench.t, [joints.t[row - 1] - limits.state_grace,
                                             joints.t[row] + limits.state_grace])
    silences = np.flatnonzero(np.diff(wrench.t[first:last]) > limits.wrench_timeout) + 1
    force = moment = 0.0
    for live in np.split(wrench.values[first:last], silences):
        change = live[:, None, :] - live[None, :, :]
        force = max([force, *np.linalg.norm(change[..., :3], axis=2).ravel()])
        moment = max([moment, *np.linalg.norm(change[..., 3:], axis=2).ravel()])
    position, velocity = joints.values[row, :6], joints.values[row, 6:]
    jacobian = kinematics.jacobian(position)[:, :kinematics.DRIVEN_JOINTS]
    speed = (float(np.linalg.norm(jacobian[:3] @ velocity[:kinematics.DRIVEN_JOINTS]))
             if velocity.size == 6 else 0.0)
    lever = float(np.linalg.norm(jacobian[:3], axis=0).max())
    turn = float(np.linalg.norm(jacobian[3:], axis=0).max())
    return rise <= limits.force_scale * (
        lever * force * (1.0 + limits.contact_damping * speed) + turn * moment)


def frames_lost(stamps: np.ndarray, counts: list[tuple[float, int, int]], topic: str,
                limits: Limits) -> tuple[list[Violation], int]:
    """
    Check that every pot frame the driver counted as published is in the bag.

    stamps: the header stamps (ns) of the pots in the bag; counts: (receive time s, stamp ns,
    'pot frames published') of the driver's diagnostics. At each count, the frames counted
    less the frames in the bag stamped until then is a constant while nothing is lost (the
    frames before the recording began); it rises by each frame lost. A count that falls
    (a restarted driver) starts anew. Return the violations and the frames lost in all.
    """
    stamps = np.sort(stamps)
    found: list[Violation] = []
    lost = 0
    lowest: Optional[tuple[int, float]] = None  # (offset, time) of the least offset
    previous: Optional[tuple[int, int]] = None  # (offset, count) of the last count
    if not len(stamps):
        return found, lost

    def rise() -> int:
        missing = 0 if previous is None or lowest is None else previous[0] - lowest[0]
        return missing if missing > limits.frame_tolerance else 0

    for time, stamp, published in counts:
        if previous is not None and published < previous[1]:
            lost += rise()
            lowest = None
        if not stamps[0] < stamp < stamps[-1]:
            continue
        offset = published - int(np.searchsorted(stamps, stamp, side='right'))
        previous = (offset, published)
        if lowest is None or offset < lowest[0]:
            lowest = (offset, time)
        elif offset - lowest[0] > limits.frame_tolerance and not found:
            found.append(Violation(
                time, topic, f'{offset - lowest[0]} pot frames the driver counted as published '
                f'between {lowest[1]:.3f} s and {time:.3f} s are not in the bag'))
    return found, lost + rise()


def _booked_credit(own: Series, credit: Series) -> np.ndarray:
    """Return the credit (J) after each of credit's messages, booked by a PortEnergy."""
    books = PortEnergy()
    spent = np.searchsorted(own.t, credit.t, side='right') - 1
    booked = np.empty(len(credit))
    stamps = [None] * len(credit) if credit.stamp is None else np.round(credit.stamp * 1e9)
    for row, (value, stamp, last) in enumerate(zip(credit.values[:, 0].tolist(), stamps,
                                                   spent.tolist())):
        books.energy_out = float(own.values[last, 1]) if last >= 0 else 0.0
        books.credit(value, None if stamp is None else int(stamp))
        booked[row] = books.remote_in
    return booked


def energy_generated(own: Series, credit: Series, passivity: np.ndarray, port: str,
                     limits: Limits) -> tuple[list[Violation], float]:
    """
    Check that a port never hands out more energy than the other end's credit, passivity on.

    own: this port's energy in, out, dissipated (J); credit: the other port's, whose energy
    in, booked as the port books it (core/passivity.py: by their stamps, from the other end's
    first message and anew at its restart), up to energy_grace after, is this port's credit;
    passivity (N,) bool: whether it was on at each of own's messages. Return the violations and
    the largest excess (J) while on.
    """
    credit_in = _booked_credit(own, credit)
    index = np.searchsorted(credit.t, own.t + limits.energy_grace, side='right') - 1
    known = np.where(index >= 0, credit_in[np.maximum(index, 0)], 0.0)
    excess = np.where(passivity, own.values[:, 1] - known, -np.inf)
    worst = float(np.max(excess, initial=-np.inf))
    found = _first(own, np.flatnonzero(excess > limits.energy_tolerance), lambda row: (
        f'the {port} port handed out {own.values[row, 1]:.4f} J against a credit of '
        f'{known[row]:.4f} J (tolerance {limits.energy_tolerance:g} J), passivity on; '
        f'worst excess {worst:.4f} J'))
    return found, worst
