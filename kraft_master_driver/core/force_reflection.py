# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Force reflection: from a task wrench to the five torques sent to the device.

Pure logic, no ROS. The node's loop thread calls ForceReflection.compute() once per cycle; the
ROS executor thread calls submit() for each wrench and configure() for parameter changes. Each
hands over one immutable object in one assignment, so the hot path takes no lock.

Zero torque is the answer to every doubt: force output disabled, no wrench yet, a stale or
rejected wrench, or a non-finite result all give exactly zero torques, with a state saying why.
"""
from functools import partial
import math
import numbers
import operator
import threading
from typing import NamedTuple

from kraft_master_driver.core import kinematics
from kraft_master_driver.core.validation import (
    choice, finite_real, finite_reals, flag)
import numpy as np

WRIST_FRAME, BASE_FRAME = 'wrist', 'base'
FRAMES = (BASE_FRAME, WRIST_FRAME)
COUPLINGS = ('actuator', 'joint')

DISABLED, NO_WRENCH, STALE, REJECTED, ACTIVE = (
    'disabled', 'no_wrench', 'stale', 'rejected', 'active')
STATES = (DISABLED, NO_WRENCH, STALE, REJECTED, ACTIVE)

REJECTION_REASONS = (
    'malformed', 'non_finite', 'unknown_frame', 'bad_timestamp', 'too_old', 'force_limit',
    'moment_limit')

DRIVEN_AXES = kinematics.DRIVEN_JOINTS
MAX_WRENCH_TIMEOUT = 5.0
MAX_WRENCH_AGE = 10.0
DEFAULT_TORQUE_LIMITS = (2.0,) * DRIVEN_AXES


class WrenchInput(NamedTuple):
    """
    One accepted task wrench.

    wrench: (fx, fy, fz, mx, my, mz) in N and N*m, acting at the origin of the wrist {6};
    frame: BASE_FRAME ({0}) or WRIST_FRAME ({6}) for the axes it is expressed in;
    received_ns: time.monotonic_ns() at receipt; tag: an opaque id passed through;
    expires_ns: when its stamp grows older than max_wrench_age (monotonic), None if unstamped.
    """

    wrench: tuple
    frame: str
    received_ns: int
    tag: object = None
    expires_ns: int = None


class Rejection(NamedTuple):
    """The last input was rejected; it stands in place of a wrench until a valid one arrives."""

    reason: str
    tag: object = None


class TorqueOutput(NamedTuple):
    """
    The result of one cycle.

    actuator: 5 torques in N*m, axes 1..5, the exact values to send; joint: the joint torques
    th1..th6 they amount to (th6 = 0); state: one of STATES; saturated: the torques were scaled
    down to respect torque_limits; tag: the tag of the wrench used, or None.
    """

    actuator: tuple
    joint: tuple
    state: str
    saturated: bool
    tag: object


class Settings(NamedTuple):
    """ForceReflection parameters (SI units); change them with ForceReflection.configure()."""

    enabled: bool = False
    force_scale: float = 1.0
    torque_limits: tuple = DEFAULT_TORQUE_LIMITS
    coupling: str = 'actuator'
    wrench_timeout: float = 0.05
    max_wrench_age: float = 0.1
    max_force: float = 200.0
    max_moment: float = 20.0
    centre_stiffness: tuple = (0.0, 0.0)
    centre_damping: tuple = (0.0, 0.0)


class _HotPath(NamedTuple):
    """Settings plus what compute() derives from them, swapped in one assignment."""

    settings: Settings
    timeout_ns: int
    stiffness: tuple  # six gains (linear x3, angular x3), or None when all zero
    damping: tuple


_ZERO_OUTPUTS = {
    state: TorqueOutput((0.0,) * DRIVEN_AXES, (0.0,) * 6, state, False, None)
    for state in STATES if state != ACTIVE}


_VALIDATORS = {
    'enabled': partial(flag, 'enabled'),
    'force_scale': partial(finite_real, 'force_scale'),
    'torque_limits': partial(finite_reals, 'torque_limits', length=DRIVEN_AXES, lower_open=True),
    'coupling': partial(choice, 'coupling', COUPLINGS),
    'wrench_timeout': partial(finite_real, 'wrench_timeout', upper=MAX_WRENCH_TIMEOUT,
                              lower_open=True),
    'max_wrench_age': partial(finite_real, 'max_wrench_age', upper=MAX_WRENCH_AGE,
                              lower_open=True),
    'max_force': partial(finite_real, 'max_force'),
    'max_moment': partial(finite_real, 'max_moment'),
    'centre_stiffness': partial(finite_reals, 'centre_stiffness', length=2),
    'centre_damping': partial(finite_reals, 'centre_damping', length=2),
}


def _six_gains(linear_angular):
    linear, angular = linear_angular
    return (linear,) * 3 + (angular,) * 3 if linear or angular else None


def _setting(name):
    return property(lambda self: getattr(self._hot.settings, name),
                    doc=f'Current {name} (read-only; change it with configure()).')


class ForceReflection:
    """
    Task wrench -> five device torques: frames, scaling, return-to-centre, saturation, watchdog.

    Torques are J^T (force_scale * F + W_centre) with F in {0} at the wrist origin, th6 dropped
    (no motor), mapped to the actuator form (elbow motor drives th2 + th3) when coupling is
    'actuator', then scaled down as a whole vector if any axis exceeds its torque limit.

    submit(), clear() and configure() may be called from any thread; compute() from one thread
    only (it keeps the watchdog and saturation state).
    """

    force_scale = _setting('force_scale')
    torque_limits = _setting('torque_limits')
    coupling = _setting('coupling')
    wrench_timeout = _setting('wrench_timeout')
    max_wrench_age = _setting('max_wrench_age')
    max_force = _setting('max_force')
    max_moment = _setting('max_moment')
    centre_stiffness = _setting('centre_stiffness')
    centre_damping = _setting('centre_damping')

    def __init__(self, force_scale=1.0, torque_limits=DEFAULT_TORQUE_LIMITS, coupling='actuator',
                 wrench_timeout=0.05, max_force=200.0, max_moment=20.0,
                 centre_stiffness=(0.0, 0.0), centre_damping=(0.0, 0.0), enabled=False,
                 max_wrench_age=0.1):
        """
        Validate the settings (ValueError naming the bad one); force output starts disabled.

        force_scale (1), torque_limits (5 values, N*m, actuator axes 1..5, > 0),
        coupling 'actuator' or 'joint', wrench_timeout (s, in (0, 5]), max_wrench_age (s, in
        (0, 10]: the age by its stamp past which a wrench gives zero torque), max_force (N),
        max_moment (N*m), centre_stiffness (N/m, N*m/rad), centre_damping (N*s/m, N*m*s/rad).
        """
        self._write_lock = threading.Lock()
        self._hot = None
        self._latest = None
        self._tripped = None
        self._expired = None
        self._was_saturated = False
        self.rejections = dict.fromkeys(REJECTION_REASONS, 0)
        self._watchdog_trips = 0
        self._age_expiries = 0
        self._saturation_events = 0
        self._saturated_cycles = 0
        self._non_finite_results = 0
        self.configure(
            enabled=enabled, force_scale=force_scale, torque_limits=torque_limits,
            coupling=coupling, wrench_timeout=wrench_timeout, max_wrench_age=max_wrench_age,
            max_force=max_force,
            max_moment=max_moment, centre_stiffness=centre_stiffness,
            centre_damping=centre_damping)

    @property
    def settings(self):
        """Return the current Settings (an immutable snapshot)."""
        return self._hot.settings

    @property
    def enabled(self):
        """Force output on (True) or off (False: zero torques)."""
        return self._hot.settings.enabled

    @enabled.setter
    def enabled(self, value):
        self.configure(enabled=value)

    def configure(self, **changes):
        """
        Change settings at run time: all are validated first, then applied in one assignment.

        Raise ValueError naming the setting on an unknown name or a bad value; then nothing
        changes.
        """
        unknown = sorted(set(changes) - set(Settings._fields))
        if unknown:
            raise ValueError(
                f'unknown setting(s) {", ".join(unknown)}; known: {", ".join(Settings._fields)}')
        checked = {name: _VALIDATORS[name](value) for name, value in changes.items()}
        with self._write_lock:
            settings = (self._hot.settings if self._hot else Settings())._replace(**checked)
            self._hot = _HotPath(settings, round(settings.wrench_timeout * 1e9),
                                 _six_gains(settings.centre_stiffness),
                                 _six_gains(settings.centre_damping))

    def submit(self, wrench, frame, received_ns, tag=None, stamp_age_ns=None):
        """
        Validate and store a task wrench; return (accepted, reason).

        wrench: (fx, fy, fz, mx, my, mz), N and N*m; frame: BASE_FRAME or WRIST_FRAME;
        received_ns: time.monotonic_ns() at receipt; stamp_age_ns: its age by its stamp at
        receipt (None if unstamped). One older than max_wrench_age is rejected, and one
        accepted gives zero torque once it has grown older. A rejected wrench replaces the
        current one, so torques are zero until a valid wrench arrives; reason then starts with
        the key of `rejections` that was counted, and is '' for an accepted wrench.
        """
        key, detail, values = self._check(wrench, frame, received_ns)
        max_age_ns = round(self._hot.settings.max_wrench_age * 1e9)
        if key is None and stamp_age_ns is not None and stamp_age_ns > max_age_ns:
            key, detail = 'too_old', (
                f'its stamp is {stamp_age_ns / 1e9:.3f} s old '
                f'> max_wrench_age = {max_age_ns / 1e9:g} s')
        if key is None:
            expires_ns = (None if stamp_age_ns is None
                          else int(received_ns) + max_age_ns - int(stamp_age_ns))
            self._latest = WrenchInput(values, frame, int(received_ns), tag, expires_ns)
            return True, ''
        self.reject(key, tag)
        return False, f'{key}: {detail}'

    def reject(self, key, tag=None):
        """Reject an input for a reason the caller found (a key of `rejections`): zero torque."""
        self._latest = Rejection(key, tag)
        self.rejections[key] += 1

    def _check(self, wrench, frame, received_ns):
        """Return (rejection key or None, detail, the wrench as 6 floats)."""
        try:
            if isinstance(wrench, (str, bytes)):
                raise TypeError
            values = tuple(float(x) for x in wrench)
        except (TypeError, ValueError):
            return 'malformed', f'expected 6 numbers, got {wrench!r}', None
        if len(values) != 6:
            return 'malformed', f'expected 6 numbers, got {len(values)}', None
        if not all(math.isfinite(x) for x in values):
            return 'non_finite', f'wrench {values} is not finite', None
        if frame not in FRAMES:
            return 'unknown_frame', f'frame {frame!r} is not one of {", ".join(FRAMES)}', None
        if isinstance(received_ns, bool) or not isinstance(received_ns, numbers.Integral):
            return 'bad_timestamp', f'received_ns must be integer ns, got {received_ns!r}', None
        settings = self._hot.settings
        force, moment = math.hypot(*values[:3]), math.hypot(*values[3:])
        if force > settings.max_force:
            return 'force_limit', f'|f| = {force:g} N > max_force = {settings.max_force:g} N', None
        if moment > settings.max_moment:
            return ('moment_limit',
                    f'|m| = {moment:g} N*m > max_moment = {settings.max_moment:g} N*m', None)
        return None, '', values

    def clear(self):
        """Forget the wrench: torques are zero (state 'no_wrench') until the next submit()."""
        self._latest = None

    @property
    def counters(self):
        """Return a snapshot of the event counters, flat: name -> count."""
        counters = {
            'watchdog_trips': self._watchdog_trips,
            'age_expiries': self._age_expiries,
            'saturation_events': self._saturation_events,
            'saturated_cycles': self._saturated_cycles,
            'non_finite_results': self._non_finite_results,
        }
        counters.update({f'rejected_{key}': n for key, n in self.rejections.items()})
        return counters

    def _idle(self, state, port=None, now_ns=0):
        self._was_saturated = False
        if port is not None:
            port.idle(now_ns)
        return _ZERO_OUTPUTS[state]

    def compute(self, rotation, jacobian, now_ns, pose=None, centre=None,
                cartesian_velocity=None, port=None):
        """
        Return the TorqueOutput for this cycle.

        rotation: 0R6 (3x3), used for wrist-frame wrenches; jacobian: 0J (6x6); each an
        array or a list of rows (the loop's plain floats); now_ns: time.monotonic_ns().
        pose and centre (4x4 0T6 arrays, metres) feed the return-to-centre spring,
        cartesian_velocity (vx, vy, vz, wx, wy, wz of the wrist in {0}, i.e. 0J dtheta) its
        damper; each acts only while its coefficients are non-zero and its inputs given.
        port (passivity.MasterPort), with cartesian_velocity, limits the reflected wrench to
        the energy the far end has sent, before the centre terms and the torque limits.
        """
        hot = self._hot
        settings = hot.settings
        latest = self._latest
        if not settings.enabled:
            return self._idle(DISABLED, port, now_ns)
        if latest is None:
            return self._idle(NO_WRENCH, port, now_ns)
        if type(latest) is Rejection:
            return self._idle(REJECTED, port, now_ns)
        # A large negative age (receipt stamped in the future) is as doubtful as a large one.
        if abs(now_ns - latest.received_ns) > hot.timeout_ns:
            if latest is not self._tripped:
                self._tripped = latest
                self._watchdog_trips += 1
            return self._idle(STALE, port, now_ns)
        if latest.expires_ns is not None and now_ns > latest.expires_ns:
            if latest is not self._expired:
                self._expired = latest
                self._age_expiries += 1
            return self._idle(STALE, port, now_ns)

        scale = settings.force_scale
        fx, fy, fz, mx, my, mz = latest.wrench
        if latest.frame == WRIST_FRAME:
            rows = _as_lists(rotation)
            wrench = _rotate(rows, fx, fy, fz) + _rotate(rows, mx, my, mz)
        else:
            wrench = [fx, fy, fz, mx, my, mz]
        wrench = [scale * x for x in wrench]
        if port is not None and cartesian_velocity is not None:
            wrench = port.step(wrench, _as_lists(cartesian_velocity), now_ns)
        if hot.stiffness is not None and pose is not None and centre is not None:
            dp, dw = kinematics.pose_difference(pose, centre)
            wrench = _minus_product(wrench, hot.stiffness, dp.tolist() + dw.tolist())
        if hot.damping is not None and cartesian_velocity is not None:
            wrench = _minus_product(wrench, hot.damping, _as_lists(cartesian_velocity))

        # Plain floats: a few tolist() calls beat a chain of tiny numpy operations here.
        columns = list(zip(*_as_lists(jacobian)))
        torques = [sum(map(operator.mul, column, wrench)) for column in columns[:DRIVEN_AXES]]
        actuator_form = settings.coupling == 'actuator'
        if actuator_form:
            torques[1] -= torques[2]  # kinematics.actuator_torques, inlined
        if not all(map(math.isfinite, torques)):
            self._non_finite_results += 1
            if port is not None:
                port.scaled(0.0)  # nothing reflected after all
            return self._idle(REJECTED, port, now_ns)
        limits = settings.torque_limits
        saturated = any(abs(tau) > limit for tau, limit in zip(torques, limits))
        if saturated:
            # One factor for the whole vector keeps its direction; the clamp only trims rounding.
            peak = max(abs(tau) / limit for tau, limit in zip(torques, limits))
            torques = [min(max(tau / peak, -limit), limit) for tau, limit in zip(torques, limits)]
            if port is not None:
                port.scaled(1.0 / peak)
            self._saturated_cycles += 1
            if not self._was_saturated:
                self._saturation_events += 1
        self._was_saturated = saturated
        t1, t2, t3, t4, t5 = torques
        # kinematics.joint_torques_from_actuator, inlined; th6 has no motor.
        joint = (t1, t2 + t3, t3, t4, t5, 0.0) if actuator_form else (t1, t2, t3, t4, t5, 0.0)
        return TorqueOutput(tuple(torques), joint, ACTIVE, saturated, latest.tag)


def _as_lists(values):
    """Return an array as (nested) lists of floats; lists pass through."""
    return values.tolist() if isinstance(values, np.ndarray) else values


def _rotate(rows, x, y, z):
    """Return R (x, y, z) as a list, R given as three row lists."""
    return [r1 * x + r2 * y + r3 * z for r1, r2, r3 in rows]


def _minus_product(wrench, gains, values):
    """Return wrench - gains * values, elementwise over six floats."""
    return [w - k * v for w, k, v in zip(wrench, gains, values)]
