# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Wrench admission: every rule a received task wrench must pass before it may give torque.

Pure logic, no ROS. WrenchAdmission.admit() turns one received wrench (values, frame_id,
stamp, receipt time) into a WrenchInput ("use it") or a Rejection ("zero torque because
..."), by these rules, in this order: a set stamp within max_stamp_skew of the clock, six
finite numbers, a frame_id of the frame map, a receipt time in integer ns, a force within
max_force and a moment within max_moment, a stamp no older than max_wrench_age. The
ForceReflection it is handed to gives zero torque for a Rejection, and for a WrenchInput once
it is older than wrench_timeout since its receipt or than max_wrench_age by its stamp.
count_sources() applies the one-source rule: while more than one publisher is matched, and
allow_multiple_sources is false, every wrench is refused.

The driver's loop thread calls admit() and count_sources(), its executor thread configure()
and sources_refusal(): configure() hands over one immutable object in one assignment, so
admit() takes no lock.
"""
from collections.abc import Callable, Iterable, Mapping, Sequence
from functools import partial
import math
import numbers
import threading
from typing import Any, NamedTuple

from kraft_master_driver.core.validation import checked_changes, finite_real, flag

WRIST_FRAME, BASE_FRAME = 'wrist', 'base'
FRAMES = (BASE_FRAME, WRIST_FRAME)

REJECTION_REASONS = (
    'malformed', 'non_finite', 'unknown_frame', 'bad_timestamp', 'too_old', 'force_limit',
    'moment_limit')

MAX_WRENCH_AGE = 10.0


class WrenchInput(NamedTuple):
    """
    One admitted task wrench.

    wrench: (fx, fy, fz, mx, my, mz) in N and N*m, acting at the origin of the wrist {6};
    frame: BASE_FRAME ({0}) or WRIST_FRAME ({6}) for the axes it is expressed in;
    received_ns: time.monotonic_ns() at receipt; tag: an opaque id passed through (its stamp,
    ns, when WrenchAdmission made it); expires_ns: when its stamp grows older than
    max_wrench_age (monotonic), None if unstamped.
    """

    wrench: tuple[float, ...]
    frame: str
    received_ns: int
    tag: object = None
    expires_ns: int | None = None


class Rejection(NamedTuple):
    """A refused wrench: reason, the key of REJECTION_REASONS; text, why, as the driver logs it."""

    reason: str
    text: str


class AdmissionSettings(NamedTuple):
    """WrenchAdmission parameters (SI units); change them with WrenchAdmission.configure()."""

    max_force: float = 200.0
    max_moment: float = 20.0
    max_wrench_age: float = 0.1
    max_stamp_skew: float = 1.0


class _Limits(NamedTuple):
    """Settings plus what admit() derives from them, swapped in one assignment."""

    settings: AdmissionSettings
    max_age_ns: int
    max_skew_ns: float


def _limits(settings: AdmissionSettings) -> _Limits:
    return _Limits(settings, round(settings.max_wrench_age * 1e9), settings.max_stamp_skew * 1e9)


_VALIDATORS: dict[str, Callable[[Any], float]] = {
    'max_force': partial(finite_real, 'max_force'),
    'max_moment': partial(finite_real, 'max_moment'),
    'max_wrench_age': partial(finite_real, 'max_wrench_age', upper=MAX_WRENCH_AGE,
                              lower_open=True),
    'max_stamp_skew': partial(finite_real, 'max_stamp_skew', lower_open=True),
}


class WrenchAdmission:
    """
    Received wrench -> WrenchInput or Rejection, by every rule; and the one-source rule.

    frames maps a frame_id to BASE_FRAME or WRIST_FRAME (by default each to itself); topics
    names the wrench topics in the refusal of several sources.
    """

    def __init__(self, frames: Mapping[str, str] | None = None,
                 topics: Sequence[str] = ('wrench',), allow_multiple_sources: bool = False,
                 max_force: float = 200.0, max_moment: float = 20.0,
                 max_wrench_age: float = 0.1, max_stamp_skew: float = 1.0) -> None:
        """
        Validate the settings (ValueError naming the bad one).

        max_force (N), max_moment (N*m), max_wrench_age (s, in (0, 10]: the age by its stamp
        past which a wrench gives zero torque), max_stamp_skew (s, > 0: the furthest a set
        stamp may be from the clock).
        """
        self._frames = dict({frame: frame for frame in FRAMES} if frames is None else frames)
        # CRTK's servo_cf: crtk_python_client sends an empty frame_id, meaning the base frame.
        self._frames_or_empty = {**self._frames, '': BASE_FRAME}
        self._topics = ' and '.join(topics)
        self.allow_multiple_sources = flag('allow_multiple_sources', allow_multiple_sources)
        self.sources = 0
        self._write_lock = threading.Lock()
        self._limits = _limits(AdmissionSettings())
        self.configure(max_force=max_force, max_moment=max_moment,
                       max_wrench_age=max_wrench_age, max_stamp_skew=max_stamp_skew)

    @property
    def settings(self) -> AdmissionSettings:
        """Return the current AdmissionSettings (an immutable snapshot)."""
        return self._limits.settings

    def configure(self, **changes: object) -> None:
        """Change settings at run time, all or none (ValueError naming the bad one), at once."""
        checked = checked_changes(changes, _VALIDATORS)
        with self._write_lock:
            self._limits = _limits(self._limits.settings._replace(**checked))

    def admit(self, values: Iterable[float], frame_id: str, stamp_ns: int, received_ns: int,
              wall_ns: int, empty_is_base: bool = False) -> WrenchInput | Rejection:
        """
        Return the WrenchInput to use, or the Rejection that says why torques are zero.

        values: (fx, fy, fz, mx, my, mz), N and N*m; frame_id: looked up in the frame map
        (with empty_is_base, '' too, as the base frame); stamp_ns: its stamp, ns since the
        epoch, 0 if unset (an unset stamp skips the stamp rules); received_ns:
        time.monotonic_ns() at receipt; wall_ns: time.time_ns() at receipt. The stamp passes
        through as the WrenchInput's tag.
        """
        limits = self._limits
        settings = limits.settings
        stamp_age_ns = wall_ns - stamp_ns
        if stamp_ns and abs(stamp_age_ns) > limits.max_skew_ns:
            return Rejection('bad_timestamp', (
                f'its stamp is {stamp_age_ns / 1e9:+.3f} s off this clock '
                f'(max_stamp_skew {settings.max_stamp_skew:g} s)'))
        try:
            if isinstance(values, (str, bytes)):
                raise TypeError
            wrench = tuple(float(x) for x in values)
        except (TypeError, ValueError):
            return Rejection('malformed', f'malformed: expected 6 numbers, got {values!r}')
        if len(wrench) != 6:
            return Rejection('malformed', f'malformed: expected 6 numbers, got {len(wrench)}')
        if not all(math.isfinite(x) for x in wrench):
            return Rejection('non_finite', f'non_finite: wrench {wrench} is not finite')
        frames = self._frames_or_empty if empty_is_base else self._frames
        frame = frames.get(frame_id)
        if frame is None:
            return Rejection('unknown_frame', (
                f'frame_id {frame_id!r} is not one of {" or ".join(repr(f) for f in frames)}'))
        if isinstance(received_ns, bool) or not isinstance(received_ns, numbers.Integral):
            return Rejection('bad_timestamp', (
                f'bad_timestamp: received_ns must be integer ns, got {received_ns!r}'))
        force, moment = math.hypot(*wrench[:3]), math.hypot(*wrench[3:])
        if force > settings.max_force:
            return Rejection('force_limit', (
                f'force_limit: |f| = {force:g} N > max_force = {settings.max_force:g} N'))
        if moment > settings.max_moment:
            return Rejection('moment_limit', (
                f'moment_limit: |m| = {moment:g} N*m > max_moment = {settings.max_moment:g} N*m'))
        if not stamp_ns:
            return WrenchInput(wrench, frame, int(received_ns), stamp_ns)
        max_age_ns = limits.max_age_ns
        if stamp_age_ns > max_age_ns:
            return Rejection('too_old', (
                f'too_old: its stamp is {stamp_age_ns / 1e9:.3f} s old '
                f'> max_wrench_age = {max_age_ns / 1e9:g} s'))
        return WrenchInput(wrench, frame, int(received_ns), stamp_ns,
                           int(received_ns) + max_age_ns - stamp_age_ns)

    @staticmethod
    def malformed(error: str) -> Rejection:
        """Return the Rejection of bytes that are not a wrench, error saying why."""
        return Rejection('malformed', error)

    def count_sources(self, sources: int) -> tuple[bool, str | None]:
        """
        Record the publishers matched on the wrench topics now; return (refused, change).

        refused: every wrench is refused now (more than one publisher, and not
        allow_multiple_sources). change: the line to log when the count changes, saying so
        while refused, or that wrenches are accepted again as a refusal ends; else None.
        """
        refused = sources > 1 and not self.allow_multiple_sources
        if sources == self.sources:
            return refused, None
        was_refused = self.sources > 1 and not self.allow_multiple_sources
        self.sources = sources
        if refused:
            return refused, f'{self._several_sources(sources)}: torques zeroed'
        if was_refused:
            return refused, f'{sources} publisher(s) on wrench: wrenches accepted'
        return refused, None

    def sources_refusal(self) -> str | None:
        """Return why every wrench is refused for its sources now, None while none is."""
        sources = self.sources
        if sources > 1 and not self.allow_multiple_sources:
            return self._several_sources(sources)
        return None

    def _several_sources(self, sources: int) -> str:
        return (f'{sources} publishers on {self._topics}, only one wrench source is allowed '
                '(allow_multiple_wrench_sources)')
