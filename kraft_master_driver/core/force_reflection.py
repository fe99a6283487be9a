# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Force reflection: from a task wrench to the five torques sent to the device.

Pure logic, no ROS. The driver's loop thread hands ForceReflection.hold() each wrench that the
WrenchAdmission (core/wrench_admission.py) let in or refused, and calls compute() once per
cycle; the ROS executor thread calls configure() for parameter changes and clear() when force
output is switched off. Each hands over one immutable object in one assignment, so the hot
path takes no lock.

Zero torque is the answer to every doubt: force output disabled, no wrench yet, a stale or
rejected wrench, or a non-finite result all give exactly zero torques, with a state saying why.
Force that comes back after such a zero, a cycle without a reply or a gap in the cycles is
ramped in over force_ramp_time, so the hand is not kicked.
"""
from collections.abc import Callable, Sequence
from functools import partial
import math
import operator
import threading
from typing import Any, NamedTuple, Protocol, TypeVar

from kraft_master_driver.core import kinematics
from kraft_master_driver.core.force_ramp import ForceRamp, ShareSlew
from kraft_master_driver.core.torque_limits import TorqueLimiter
from kraft_master_driver.core.validation import (
    checked_changes, choice, finite_real, finite_reals, flag)
from kraft_master_driver.core.wrench_admission import (
    Rejection, REJECTION_REASONS, WrenchInput, WRIST_FRAME)
import numpy as np
from numpy.typing import NDArray

COUPLINGS = ('actuator', 'joint')

DISABLED, NO_WRENCH, STALE, REJECTED, ACTIVE = (
    'disabled', 'no_wrench', 'stale', 'rejected', 'active')
STATES = (DISABLED, NO_WRENCH, STALE, REJECTED, ACTIVE)

DRIVEN_AXES = kinematics.DRIVEN_JOINTS
MAX_WRENCH_TIMEOUT = 5.0
MAX_FORCE_RAMP_TIME = 1.0
DEFAULT_TORQUE_LIMITS = (2.0,) * DRIVEN_AXES

# A matrix as an array or as a sequence of rows (the loop's plain floats), a vector likewise.
Matrix = NDArray[np.float64] | Sequence[Sequence[float]]
Vector = NDArray[np.float64] | Sequence[float]
_Lists = TypeVar('_Lists', Sequence[Sequence[float]], Sequence[float])


class Port(Protocol):
    """The master port of passivity control (core.passivity.MasterPort), as compute() uses it."""

    def step(self, force: Sequence[float], velocity: Sequence[float],
             now_ns: int) -> Sequence[float]:
        """Return the wrench (6 floats) to apply in place of `force` until the next sample."""

    def damped(self, velocity: Sequence[float]) -> list[float]:
        """Return the port's own damper wrench (6 floats), booked with step()'s wrench."""

    def scaled(self, factor: float) -> None:
        """Note that the last wrench was applied scaled by `factor` (0..1)."""

    def idle(self, now_ns: int) -> None:
        """Note a step with no channel force (zero torque): no energy, the clock moves on."""


class TorqueOutput(NamedTuple):
    """
    The result of one cycle.

    actuator: 5 torques in N*m, axes 1..5, the exact values to send; joint: the joint torques
    th1..th6 they amount to (th6 = 0); state: one of STATES; saturated: the torques were scaled
    down to respect torque_limits; tag: the tag of the wrench used, or None; model_share: the
    contact model's share of the force sent (0..1).
    """

    actuator: tuple[float, ...]
    joint: tuple[float, ...]
    state: str
    saturated: bool
    tag: object
    model_share: float = 0.0


class Settings(NamedTuple):
    """ForceReflection parameters (SI units); change them with ForceReflection.configure()."""

    enabled: bool = False
    force_scale: float = 1.0
    torque_limits: tuple[float, ...] = DEFAULT_TORQUE_LIMITS
    coupling: str = 'actuator'
    wrench_timeout: float = 0.05
    centre_stiffness: tuple[float, ...] = (0.0, 0.0)
    centre_damping: tuple[float, ...] = (0.0, 0.0)
    contact_damping: float = 0.0
    force_ramp_time: float = 0.0


class _HotPath(NamedTuple):
    """Settings plus what compute() derives from them, swapped in one assignment."""

    settings: Settings
    timeout_ns: int
    stiffness: tuple[float, ...] | None  # six gains (linear x3, angular x3), None if all zero
    damping: tuple[float, ...] | None
    ramp_ns: int


_ZERO_OUTPUTS = {
    state: TorqueOutput((0.0,) * DRIVEN_AXES, (0.0,) * 6, state, False, None)
    for state in STATES if state != ACTIVE}


_VALIDATORS: dict[str, Callable[[Any], object]] = {
    'enabled': partial(flag, 'enabled'),
    'force_scale': partial(finite_real, 'force_scale'),
    'torque_limits': partial(finite_reals, 'torque_limits', length=DRIVEN_AXES, lower_open=True),
    'coupling': partial(choice, 'coupling', COUPLINGS),
    'wrench_timeout': partial(finite_real, 'wrench_timeout', upper=MAX_WRENCH_TIMEOUT,
                              lower_open=True),
    'centre_stiffness': partial(finite_reals, 'centre_stiffness', length=2),
    'centre_damping': partial(finite_reals, 'centre_damping', length=2),
    'contact_damping': partial(finite_real, 'contact_damping'),
    'force_ramp_time': partial(finite_real, 'force_ramp_time', upper=MAX_FORCE_RAMP_TIME),
}


def _six_gains(linear_angular: tuple[float, ...]) -> tuple[float, ...] | None:
    linear, angular = linear_angular
    return (linear,) * 3 + (angular,) * 3 if linear or angular else None


def _hot_path(settings: Settings) -> _HotPath:
    return _HotPath(settings, round(settings.wrench_timeout * 1e9),
                    _six_gains(settings.centre_stiffness), _six_gains(settings.centre_damping),
                    round(settings.force_ramp_time * 1e9))


def _setting(name: str) -> property:
    return property(lambda self: getattr(self._hot.settings, name),
                    doc=f'Current {name} (read-only; change it with configure()).')


class ForceReflection:
    """
    Task wrench -> five device torques: frames, scaling, return-to-centre, saturation, watchdog.

    Torques are J^T (force_scale * F + W_centre - contact_damping |F| v) with F in {0} at the
    wrist origin (after the passivity port, if any) and v the wrist's linear velocity, th6 dropped
    (no motor), mapped to the actuator form (elbow motor drives th2 + th3) when coupling is
    'actuator', then scaled down as a whole vector if any axis exceeds its torque limit, and
    ramped in after an interruption.

    hold(), clear() and configure() may be called from any thread; compute() from one thread
    only (it keeps the watchdog and saturation state).
    """

    force_scale = _setting('force_scale')
    torque_limits = _setting('torque_limits')
    coupling = _setting('coupling')
    wrench_timeout = _setting('wrench_timeout')
    centre_stiffness = _setting('centre_stiffness')
    centre_damping = _setting('centre_damping')
    contact_damping = _setting('contact_damping')
    force_ramp_time = _setting('force_ramp_time')

    def __init__(self, force_scale: float = 1.0,
                 torque_limits: Sequence[float] = DEFAULT_TORQUE_LIMITS,
                 coupling: str = 'actuator', wrench_timeout: float = 0.05,
                 centre_stiffness: Sequence[float] = (0.0, 0.0),
                 centre_damping: Sequence[float] = (0.0, 0.0), contact_damping: float = 0.0,
                 enabled: bool = False, force_ramp_time: float = 0.0) -> None:
        """
        Validate the settings (ValueError naming the bad one); force output starts disabled.

        force_scale (1), torque_limits (5 values, N*m, actuator axes 1..5, > 0),
        coupling 'actuator' or 'joint', wrench_timeout (s, in (0, 5]),
        centre_stiffness (N/m, N*m/rad), centre_damping (N*s/m, N*m*s/rad), contact_damping
        (s/m: N*s/m of linear damping per N of the force reflected, >= 0), force_ramp_time
        (s, in [0, 1]: the force comes back from zero over this time after an interruption;
        0: at once).
        """
        self._write_lock = threading.Lock()
        self._hot = _hot_path(Settings())
        self._latest: WrenchInput | Rejection | None = None
        self._tripped: WrenchInput | None = None
        self._cleared = False  # clear() took the wrench away: nothing, not even the weight
        self._expired: WrenchInput | None = None
        self._limiter = TorqueLimiter()
        self._ramp = ForceRamp()
        self._model_share = ShareSlew()
        self.rejections = dict.fromkeys(REJECTION_REASONS, 0)
        self._watchdog_trips = 0
        self._age_expiries = 0
        self.configure(
            enabled=enabled, force_scale=force_scale, torque_limits=torque_limits,
            coupling=coupling, wrench_timeout=wrench_timeout, centre_stiffness=centre_stiffness,
            centre_damping=centre_damping, contact_damping=contact_damping,
            force_ramp_time=force_ramp_time)

    @property
    def settings(self) -> Settings:
        """Return the current Settings (an immutable snapshot)."""
        return self._hot.settings

    @property
    def enabled(self) -> bool:
        """Force output on (True) or off (False: zero torques)."""
        return self._hot.settings.enabled

    @enabled.setter
    def enabled(self, value: bool) -> None:
        self.configure(enabled=value)

    def configure(self, **changes: object) -> None:
        """
        Change settings at run time: all are validated first, then applied in one assignment.

        Raise ValueError naming the setting on an unknown name or a bad value; then nothing
        changes.
        """
        checked = checked_changes(changes, _VALIDATORS)
        with self._write_lock:
            self._hot = _hot_path(self._hot.settings._replace(**checked))

    def hold(self, admitted: WrenchInput | Rejection) -> None:
        """
        Take what the WrenchAdmission made of the newest wrench: it replaces the current one.

        A WrenchInput gives torque until it is stale; a Rejection gives zero torque (state
        'rejected') until a valid wrench arrives, and is counted in `rejections`.
        """
        self._latest = admitted
        self._cleared = False
        if isinstance(admitted, Rejection):
            self.rejections[admitted.reason] += 1

    def clear(self) -> None:
        """Forget the wrench: torques are zero, the contact model's too, until the next hold()."""
        self._latest = None
        self._cleared = True

    def interrupt(self) -> None:
        """Note that zero torque went out without compute() (no reply): the force ramps in."""
        self._ramp.restart()

    @property
    def counters(self) -> dict[str, int]:
        """Return a snapshot of the event counters, flat: name -> count."""
        counters = {
            'watchdog_trips': self._watchdog_trips,
            'age_expiries': self._age_expiries,
            'saturation_events': self._limiter.saturation_events,
            'saturated_cycles': self._limiter.saturated_cycles,
            'non_finite_results': self._limiter.non_finite_results,
        }
        counters.update({f'rejected_{key}': n for key, n in self.rejections.items()})
        return counters

    def _idle(self, state: str, port: Port | None = None, now_ns: int = 0) -> TorqueOutput:
        self._limiter.reset()
        if port is not None:
            port.idle(now_ns)
        return _ZERO_OUTPUTS[state]

    def compute(self, rotation: Matrix, jacobian: Matrix, now_ns: int,
                pose: NDArray[np.float64] | None = None,
                centre: NDArray[np.float64] | None = None,
                cartesian_velocity: Vector | None = None,
                port: Port | None = None,
                model: tuple[Sequence[float], float] | None = None,
                holding: Sequence[float] | None = None) -> TorqueOutput:
        """
        Return the TorqueOutput for this cycle.

        rotation: 0R6 (3x3), used for wrist-frame wrenches; jacobian: 0J (6x6); each an
        array or a list of rows (the loop's plain floats); now_ns: time.monotonic_ns().
        pose and centre (4x4 0T6 arrays, metres) feed the return-to-centre spring,
        cartesian_velocity (vx, vy, vz, wx, wy, wz of the wrist in {0}, i.e. 0J dtheta) its
        damper; each acts only while its coefficients are non-zero and its inputs given.
        port (passivity.MasterPort), with cartesian_velocity, limits the reflected wrench to
        the energy the far end has sent, before the centre terms and the torque limits, and
        adds its damper (MasterPort.damped), after contact_damping.
        model: the contact model's force (N, 3, base frame; core/contact_rendering.py) and its
        share of the force (0..1, core/force_mode.py): the wrench is the direct one times
        (1 - share) plus force_scale times the model's times share, then the centre terms; with
        no direct wrench to give (none yet, stale, refused) the model's alone; after clear(),
        nothing, the model's neither, until the next hold(). The share used
        moves to its goal, and back, over force_ramp_time (ShareSlew): no step at the hand.
        holding: the motor torques (N*m, actuator axes 1..5) that hold the arm up against its
        weight (core/gravity.py): added to a wrench being reflected, or alone before any
        wrench has come; a stale or refused wrench, clear() and disabled force give zero, the
        weight included. At the torque limits the weight keeps its place (clamped per axis)
        and the reflected torques are scaled down.
        """
        hot = self._hot
        settings = hot.settings
        self._ramp.step(now_ns, hot.ramp_ns)
        if not settings.enabled:
            self._ramp.restart()
            return self._idle(DISABLED, port, now_ns)
        if self._cleared:
            # Several wrench sources (or force disabled): nothing is felt, not even the contact
            # model's wall, and what comes after ramps in.
            self._ramp.restart()
            return self._idle(NO_WRENCH, port, now_ns)
        goal = 0.0 if model is None else model[1]
        state, wrench = self._direct(rotation, now_ns, cartesian_velocity, port, goal)
        if wrench is None and model is not None and any(model[0]):
            goal = 1.0  # no direct force to blend with: the model's alone, not a step to zero
        share = self._model_share.step(goal, now_ns, hot.ramp_ns)
        if share > 0.0:
            assert model is not None
            scaled = share * settings.force_scale
            direct = wrench if wrench is not None else (0.0,) * 6
            wrench = [(1.0 - share) * w for w in direct]
            for axis in range(3):
                wrench[axis] += scaled * model[0][axis]
            state = ACTIVE
        actuator_form = settings.coupling == 'actuator'
        if wrench is None:
            # The arm's weight alone only before any wrench: stale or refused give zero, the
            # weight included.
            if holding is None or state != NO_WRENCH:
                self._ramp.restart()
                return _ZERO_OUTPUTS[state]
            # The port has nothing of this to book (the wrench's path idled it).
            return self._limited([0.0] * DRIVEN_AXES, holding, actuator_form, state, None, 0.0,
                                 None, now_ns)
        latest = self._latest
        tag = latest.tag if isinstance(latest, WrenchInput) else None
        if hot.stiffness is not None and pose is not None and centre is not None:
            dp, dw = kinematics.pose_difference(pose, centre)
            wrench = _minus_product(wrench, hot.stiffness, dp.tolist() + dw.tolist())
        if hot.damping is not None and cartesian_velocity is not None:
            wrench = _minus_product(wrench, hot.damping, _as_lists(cartesian_velocity))
        if state == ACTIVE and share < 1.0 and cartesian_velocity is not None:
            wrench = self._damped(wrench, _as_lists(cartesian_velocity), port, 1.0 - share)
        # Plain floats: a few tolist() calls beat a chain of tiny numpy operations here.
        columns = list(zip(*_as_lists(jacobian)))
        torques = [sum(map(operator.mul, column, wrench)) for column in columns[:DRIVEN_AXES]]
        if actuator_form:
            torques[1] -= torques[2]  # kinematics.actuator_torques, inlined
        return self._limited(torques, holding, actuator_form, ACTIVE, tag, share, port, now_ns)

    def _limited(self, torques: list[float], holding: Sequence[float] | None,
                 actuator_form: bool, state: str, tag: object, share: float,
                 port: Port | None, now_ns: int) -> TorqueOutput:
        """Add the holding torques inside the torque limits (TorqueLimiter), then ramp."""
        limited = self._limiter.limit(torques, holding, self._hot.settings.torque_limits,
                                      actuator_form)
        if limited is None:
            if port is not None:
                port.scaled(0.0)  # nothing reflected after all
            self._ramp.restart()
            return self._idle(REJECTED, port, now_ns)
        ramp = self._ramp.share
        if port is not None and limited.factor * ramp < 1.0:
            port.scaled(limited.factor * ramp)
        t1, t2, t3, t4, t5 = torques = [tau * ramp for tau in limited.torques]
        # kinematics.joint_torques_from_actuator, inlined; th6 has no motor.
        joint = (t1, t2 + t3, t3, t4, t5, 0.0) if actuator_form else (t1, t2, t3, t4, t5, 0.0)
        return TorqueOutput(tuple(torques), joint, state, limited.saturated, tag, share)

    def _direct(self, rotation: Matrix, now_ns: int, cartesian_velocity: Vector | None,
                port: Port | None, share: float) -> tuple[str, list[float] | None]:
        """
        Return the state and the wrench reflected directly (None: zero, the state says why).

        The wrench admitted, scaled and through the port. While the model takes all of the
        force (share 1) the port idles.
        """
        hot = self._hot
        settings = hot.settings
        latest = self._latest
        if latest is None or share >= 1.0:
            self._idle(NO_WRENCH, port, now_ns)
            return NO_WRENCH, None
        if isinstance(latest, Rejection):
            self._idle(REJECTED, port, now_ns)
            return REJECTED, None
        # A large negative age (receipt stamped in the future) is as doubtful as a large one.
        if abs(now_ns - latest.received_ns) > hot.timeout_ns:
            if latest is not self._tripped:
                self._tripped = latest
                self._watchdog_trips += 1
            self._idle(STALE, port, now_ns)
            return STALE, None
        if latest.expires_ns is not None and now_ns > latest.expires_ns:
            if latest is not self._expired:
                self._expired = latest
                self._age_expiries += 1
            self._idle(STALE, port, now_ns)
            return STALE, None
        scale = settings.force_scale
        fx, fy, fz, mx, my, mz = latest.wrench
        wrench: Sequence[float]
        if latest.frame == WRIST_FRAME:
            rows = _as_lists(rotation)
            wrench = _rotate(rows, fx, fy, fz) + _rotate(rows, mx, my, mz)
        else:
            wrench = [fx, fy, fz, mx, my, mz]
        wrench = [scale * x for x in wrench]
        if port is not None and cartesian_velocity is not None:
            wrench = port.step(wrench, _as_lists(cartesian_velocity), now_ns)
        return ACTIVE, list(wrench)

    def _damped(self, wrench: Sequence[float], velocity: Sequence[float], port: Port | None,
                share: float) -> list[float]:
        """Return the wrench with the contact damper and the port's, times the direct share."""
        if self._hot.settings.contact_damping:
            # A damper as strong as the force felt: none in free space, in contact it takes
            # out the energy that the force's lag behind the wrist would put in.
            fx, fy, fz = wrench[:3]
            gain = share * self._hot.settings.contact_damping * math.sqrt(
                fx * fx + fy * fy + fz * fz)
            vx, vy, vz = velocity[:3]
            wrench = [fx - gain * vx, fy - gain * vy, fz - gain * vz, *wrench[3:]]
        if port is not None:
            damper = port.damped(velocity)
            wrench = [w + share * d for w, d in zip(wrench, damper)]
        return list(wrench)


def _as_lists(values: NDArray[np.float64] | _Lists) -> _Lists:
    """Return an array as (nested) lists of floats; lists pass through."""
    if isinstance(values, np.ndarray):
        lists: _Lists = values.tolist()
        return lists
    return values


def _rotate(rows: Sequence[Sequence[float]], x: float, y: float, z: float) -> list[float]:
    """Return R (x, y, z) as a list, R given as three row lists."""
    return [r1 * x + r2 * y + r3 * z for r1, r2, r3 in rows]


def _minus_product(wrench: Sequence[float], gains: Sequence[float],
                   values: Sequence[float]) -> list[float]:
    """Return wrench - gains * values, elementwise over six floats."""
    return [w - k * v for w, k, v in zip(wrench, gains, values)]
