# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The teleoperation bridge's logic, no ROS: master pose -> arm target, arm F/T -> master wrench.

Teleoperation runs one master/arm pair through four operating states (OperatingState):

- DISABLED: nothing is sent to the arm; the master gets zero wrench. enable() leaves it.
- ENABLED: the arm's target follows the master. The offset between them is taken anew
  (registration) at enable, at every clutch release and when a stale master pose comes back,
  so the target starts exactly where the arm is held and never jumps.
- CLUTCHED: the arm holds, the master is free (zero wrench) and may be moved anywhere.
- FAULT: an input was refused, went stale or the arm left its command; the arm holds where it
  was measured, the master gets zero wrench, and only enable() leaves it.

Data flows one way: each input and each tick goes in as one call, and the call returns what
to send (Outputs): the arm's command, the master's wrench, the slave port's energies, the
operating state when it changed, and why an input was refused. enable() and disable() return
an Answer, which carries those Outputs. The motion path (mapping, limits, the slave port) is
core/teleoperation_motion.py, the force path core/teleoperation_force.py, the input checks
core/teleoperation_inputs.py, the settings core/teleoperation_settings.py; configure() takes
new settings while it runs (core/teleoperation_tuning.py: what a change asks for, and the
force path ramped across changes).

Frames: the master's pose is in the master's base frame, the arm's pose and its target in the
arm's base frame; `base_rotation` turns master-base vectors into arm-base ones. The wrist F/T
reading is the wrench the tool applies to the sensor, in the sensor's frame (`sensor_rotation`
from the arm's measured tool frame). Times are monotonic seconds given by the caller.
"""
from enum import StrEnum
from typing import Callable, NamedTuple, Optional, Sequence

from kraft_master_driver.core.contact_model import ContactModel
from kraft_master_driver.core.passivity import SlavePort
from kraft_master_driver.core.rotations import norm, rotation_parameter
from kraft_master_driver.core.teleoperation_contact import ContactSharing, Registration
from kraft_master_driver.core.teleoperation_inputs import (
    arm_side_late, checked_pose, checked_reading, enable_refusal, Floats, hold_reason,
    stale_arm_side, tare_refusal, tracking_error)
from kraft_master_driver.core.teleoperation_motion import Motion, Pose, Settling
from kraft_master_driver.core.teleoperation_settings import Array, checked, MAX_STEP, Settings
from kraft_master_driver.core.teleoperation_tuning import (
    changed, FORCE, RampedForce, REGISTERING, Sensed)
import numpy as np


class OperatingState(StrEnum):
    """The bridge's operating state; its text is what operating_state shows."""

    DISABLED = 'DISABLED'
    ENABLED = 'ENABLED'
    CLUTCHED = 'CLUTCHED'
    FAULT = 'FAULT'


DRIVING = (OperatingState.ENABLED, OperatingState.CLUTCHED)  # the states that command the arm
UNTIL_STILL = 'holding: until the arm is still'  # enabled, not following the master yet


class StateChange(NamedTuple):
    """A new operating state and why ('': no reason given)."""

    state: OperatingState
    reason: str

    @property
    def text(self) -> str:
        """Return it as operating_state shows it: 'STATE' or 'STATE: reason'."""
        return f'{self.state}: {self.reason}' if self.reason else str(self.state)


class Outputs(NamedTuple):
    """What to send after an input or a tick; None: nothing of that kind."""

    command: Optional[tuple[float, ...]] = None  # servo_cp (x, y, z, qx, qy, qz, qw), servo_cv
    wrench: Optional[Array] = None  # for the master (6: N, N*m, master base frame)
    slave_energy: Optional[tuple[float, float, float]] = None  # in, out, dissipated (J)
    state: Optional[StateChange] = None  # the operating state, when it changed
    refusal: Optional[str] = None  # why the input was refused or is a FAULT, in one line
    contact_model: Optional[ContactModel] = None  # for the master (its frame and units)


class Answer(NamedTuple):
    """The answer to enable or disable: why not (None: done), the state then, what to send."""

    refusal: Optional[str]
    state: str  # as operating_state shows it
    outputs: Outputs


class NoBaseRotation(Exception):
    """Raised by a base_rotation lookup (enable's base_rotation_from_tf): why there is none."""


class Commands:
    """
    What the bridge sends, read from its state: the arm's command and the master's wrench.

    Teleoperation's part that computes them; the attributes are Teleoperation's.
    """

    settings: Settings
    state: OperatingState
    motion: Motion
    force: RampedForce
    base_rotation: Array
    arm: Optional[tuple[Pose, float]]
    reading: Optional[tuple[Array, float]]

    @property
    def following(self) -> bool:
        """Whether the arm follows the master now (ENABLED and registered)."""
        return self.state is OperatingState.ENABLED and self.motion.registration is not None

    def _command(self) -> Optional[tuple[float, ...]]:
        """Return servo_cp's values (pose mode) or servo_cv's (twist mode) now, or None."""
        if self.settings.mode == 'pose':
            pose = self.arm_command()
            return None if pose is None else (*pose.position, *pose.quaternion)
        if self.state is OperatingState.DISABLED:
            return None
        return tuple(self.arm_twist())

    def arm_command(self) -> Optional[Pose]:
        """Return the pose the arm should be at now, or None (DISABLED: send nothing)."""
        if self.state is OperatingState.DISABLED:
            return None
        pose = self.motion.command if self.following else self.motion.hold
        if pose is not None and self.settings.orientation == 'ignore' and self.arm is not None:
            return Pose(pose.position, self.arm[0].rotation)
        return pose

    def arm_twist(self) -> Array:
        """Return the twist command (6: m/s, rad/s, arm base), zeros unless following."""
        arm = self.arm
        return self.motion.twist(arm[0]) if self.following and arm is not None else np.zeros(6)

    def contact_wrench(self) -> Array:
        """Return the environment's wrench on the tool (6, arm base frame), less bias and tool."""
        assert self.reading is not None and self.arm is not None
        return self.force.path.contact_wrench(self.reading[0], self.arm[0].rotation)

    def master_wrench(self, now: float) -> Array:
        """Return the wrench for the master (6, master base frame); zeros unless following."""
        sensed = None
        if self.following and self.reading is not None:
            assert self.arm is not None and self.motion.command is not None  # following
            sensed = Sensed(self.reading[0], self.arm[0].rotation,
                            norm(self.motion.command.position - self.arm[0].position))
        return self.force.wrench(sensed, self.settings.force_feedback, self.base_rotation, now)


class Teleoperation(Commands):
    """
    One master/arm pair: hand it each input as it comes and the ticks; it returns what to send.

    A refused input's Outputs say why in `refusal`, in one line; the state is then FAULT with
    that reason.
    """

    def __init__(self, settings: Settings = Settings()) -> None:
        """Check the settings (ValueError naming the bad one); start DISABLED."""
        self.settings = settings
        checked_settings = checked(settings)
        self.base_rotation = checked_settings.base_rotation
        self.port = SlavePort(settings.drift_gain, settings.max_linear_speed)
        self.port.enabled = settings.passivity
        self.motion = Motion(settings, checked_settings.box, self.port)
        self.force = RampedForce(settings, checked_settings.sensor_rotation)
        self.contact = ContactSharing(settings)
        self.state = OperatingState.DISABLED
        self.reason = 'not enabled'
        self.clutch_pressed = False
        self.master: Optional[tuple[Pose, float]] = None  # (pose, receipt time)
        self.arm: Optional[tuple[Pose, float]] = None
        self.arm_settling = Settling()
        self.reading: Optional[tuple[Array, float]] = None  # (6 floats, sensor frame; time)
        self._reported: Optional[tuple[OperatingState, str]] = None  # the state last returned

    # -- state -------------------------------------------------------------------------

    def describe(self) -> str:
        """Return the state as operating_state shows it: 'STATE' or 'STATE: reason'."""
        return StateChange(self.state, self.reason).text

    def _outputs(self, command: Optional[tuple[float, ...]] = None,
                 wrench: Optional[Array] = None,
                 slave_energy: Optional[tuple[float, float, float]] = None,
                 refusal: Optional[str] = None,
                 contact_model: Optional[ContactModel] = None) -> Outputs:
        """Return what to send, with the state if it changed since it was last returned."""
        state = None
        if (self.state, self.reason) != self._reported:
            self._reported = (self.state, self.reason)
            state = StateChange(self.state, self.reason)
        return Outputs(command, wrench, slave_energy, state, refusal, contact_model)

    def _answer(self, refusal: Optional[str]) -> Answer:
        return Answer(refusal, self.describe(), self._outputs())

    def first_outputs(self) -> Outputs:
        """Return what to send before any input: the state (DISABLED: not enabled)."""
        return self._outputs()

    def _fault(self, reason: str, now: float) -> None:
        """Go to FAULT: a following arm holds where measured if fresh, else where sent."""
        if self.following:
            self.motion.hold_at_fault(self.arm, now)
        self.state, self.reason = OperatingState.FAULT, reason
        self.motion.registration = None

    def _refuse(self, reason: str, now: float) -> Outputs:
        """Go to FAULT for `reason`, a refused input; return it to be said."""
        self._fault(reason, now)
        return self._outputs(refusal=reason)

    def enable(self, now: float,
               base_rotation_from_tf: Optional[Callable[[], Sequence[float]]] = None) -> Answer:
        """
        Enable (or re-enable after a fault); the answer says why not (the state unchanged).

        base_rotation_from_tf: where given, it is called while the arm is not driven, and
        returns base_rotation (x, y, z, w) or raises NoBaseRotation saying why there is none.
        """
        if base_rotation_from_tf is not None and self.state not in DRIVING:
            try:
                quaternion = base_rotation_from_tf()
            except NoBaseRotation as error:
                return self._answer(f'{error}: not enabled')
            refusal = self.set_base_rotation(quaternion)
            if refusal is not None:
                return self._answer(f'TF {refusal}: not enabled')
        return self._answer(self._enable(now))

    def _enable(self, now: float) -> Optional[str]:
        """Enable if every input is fresh and the arm in the box; return None, or why not."""
        refusal = enable_refusal(self.settings, self.master, self.arm, self.reading,
                                 self.motion.box, now)
        if refusal is not None or self.state in DRIVING:
            return refusal
        assert self.arm is not None  # enable_refusal needs it fresh
        # Registered at a master pose once the arm is still: its target starts where it is.
        # Until then it holds where it was held (after a FAULT), or where measured.
        motion = self.motion
        motion.command, motion.registration = None, None
        motion.hold, motion.held_for_arm = motion.hold or self.arm[0], True
        self.state = OperatingState.CLUTCHED if self.clutch_pressed else OperatingState.ENABLED
        self.reason = '' if self.arm_settling.still else UNTIL_STILL
        return None

    def set_base_rotation(self, quaternion: Floats) -> Optional[str]:
        """Take base_rotation anew (x, y, z, w) while not driving the arm; return why not."""
        if self.state in DRIVING:
            return 'base_rotation is fixed while enabled'
        try:
            self.base_rotation = rotation_parameter('base_rotation', quaternion)
        except ValueError as error:
            return str(error)
        return None

    def configure(self, settings: Settings, now: float) -> None:
        """
        Take new settings at `now`; ValueError names a bad one, and then nothing changes.

        They are checked as at start-up. mode and the frames are the caller's to keep. A change
        of the mapping registers anew where the arm was last sent, a change of the force path
        is ramped in (core/teleoperation_tuning.py).
        """
        checked_settings = checked(settings)
        changes = changed(self.settings, settings)
        held = self.arm_command() if self.state in DRIVING else None
        if FORCE & changes:
            self.force.retune(self.settings, self.base_rotation, settings,
                              checked_settings.sensor_rotation, now)
        if 'base_rotation' in changes:
            self.base_rotation = checked_settings.base_rotation
        self.settings = self.motion.settings = self.contact.settings = settings
        self.motion.box = checked_settings.box
        self.port.drift_gain = settings.drift_gain
        self.port.max_speed = settings.max_linear_speed
        self.port.enabled = settings.passivity
        if held is not None and REGISTERING & changes:
            if self.following:
                assert self.master is not None  # the registration took a master pose
                self.motion.register(self.master[0], held)
            else:
                self.motion.hold = held

    def disable(self) -> Answer:
        """Stop: nothing more is sent to the arm."""
        self.state, self.reason = OperatingState.DISABLED, 'disabled'
        self.motion.registration = None
        self.motion.hold = self.motion.command = None
        return self._answer(None)

    def set_clutch(self, pressed: bool) -> Outputs:
        """Press or release the clutch: hold while pressed, register anew on release."""
        if pressed != self.clutch_pressed:
            self.clutch_pressed = pressed
            if pressed and self.state is OperatingState.ENABLED:
                self.motion.hold_here()
                self.state, self.reason = OperatingState.CLUTCHED, ''
            elif not pressed and self.state is OperatingState.CLUTCHED:
                self.state = OperatingState.ENABLED  # registered at the next master pose
        return self._outputs()

    def tick(self, now: float) -> Outputs:
        """
        Apply the timeouts at `now`; return what to send at every tick.

        The slave port's energies and the contact model (core/teleoperation_contact.py), and
        while not following the arm's hold command and the master's zero wrench (also while
        following without force feedback: no F/T reading sends it).
        """
        self._check(now)
        port = self.port
        energy = (port.energy_in, port.energy_out, port.dissipated)
        feeling = self.following and self.settings.force_feedback
        mapped = self.motion.registration if feeling else None
        model = self.contact.to_send(
            None if mapped is None else Registration(*mapped, self.base_rotation), now)
        return self._outputs(None if self.following else self._command(),
                             None if feeling else self.master_wrench(now), energy,
                             contact_model=model)

    def _check(self, now: float) -> None:
        """Apply the timeouts: a stale master holds, a stale arm or F/T is a FAULT."""
        if self.state not in DRIVING:
            return
        assert self.master is not None  # enable needed it
        settings = self.settings
        stale = stale_arm_side(settings, self.arm, self.reading, now)
        if stale is not None:
            self._fault(stale, now)
            return
        hold = hold_reason(settings, self.master[1], self.arm, self.reading, now)
        if self.following and hold is not None:
            self.reason = hold[0]
            self.motion.hold_here(for_arm=hold[1])
            if hold[1]:
                # The poses the arm's side sends next may be ones that waited on the way, their
                # stamps going on from the last: only those taken from now on tell it still.
                self.arm_settling.restart()

    # -- inputs ------------------------------------------------------------------------

    def master_pose(self, frame_id: str, position: Floats, quaternion: Floats,
                    now: float) -> Outputs:
        """Take the master's wrist pose (master base frame); registers if not registered."""
        pose = checked_pose('pose', frame_id, self.settings.master_frame, position, quaternion,
                            self.settings)
        if isinstance(pose, str):
            return self._refuse(pose, now)
        previous = self.master
        self.master = (pose, now)
        if self.state is OperatingState.ENABLED:
            if self.motion.registration is None:
                if arm_side_late(self.settings, self.arm, self.reading, now) is not None:
                    return self._outputs()  # held until the arm's side is fresh again
                assert self.arm is not None  # fresh, just checked
                if self.motion.held_for_arm and not self.arm_settling.still:
                    self.reason = UNTIL_STILL
                    return self._outputs()  # a moving arm's pose is behind where it is
                self.reason = ''
                self.motion.follow_again(pose, self.arm[0])
            else:
                assert previous is not None  # the registration took a master pose
                contact = self.contact_wrench() if self.reading is not None else None
                self.motion.follow(pose, min(now - previous[1], MAX_STEP), self.base_rotation,
                                   self.force.port_force(self.settings, self.base_rotation,
                                                         contact))
        return self._outputs(self._command() if self.following else None)

    def arm_pose(self, frame_id: str, position: Floats, quaternion: Floats,
                 now: float, stamp: Optional[float] = None) -> Outputs:
        """
        Take the arm's measured tool pose (arm base frame); check the tracking error.

        stamp: when the arm measured it (s, the arm's clock; None: `now`), to tell it still.
        """
        pose = checked_pose('measured_cp', frame_id, self.settings.arm_frame, position,
                            quaternion, self.settings)
        if isinstance(pose, str):
            return self._refuse(pose, now)
        self.arm = (pose, now)
        self.arm_settling.measured(pose, now if stamp is None else stamp,
                                   self.settings.arm_hold_timeout)
        reference = self.motion.command if self.following else self.motion.hold
        if self.state in DRIVING and reference is not None:
            error = tracking_error(pose, reference, self.settings)
            if error is not None:
                return self._refuse(error, now)
        return self._outputs()

    def ft_reading(self, frame_id: str, wrench: Floats, now: float) -> Outputs:
        """Take one F/T reading (force N, moment N*m, sensor frame); the master's wrench."""
        reading = checked_reading(frame_id, wrench, self.settings)
        if isinstance(reading, str):
            self._fault(reading, now)
            return self._outputs(wrench=self.master_wrench(now), refusal=reading)
        self.reading = (reading, now)
        if self.arm is not None and stale_arm_side(self.settings, self.arm, None, now) is None:
            command = self.motion.command if self.following else None
            self.motion.floor = self.contact.reading(
                self.arm[0].position, self.contact_wrench()[:3], command, now)
        return self._outputs(wrench=self.master_wrench(now))

    def master_energy(self, energy_in: float, stamp_ns: Optional[int] = None) -> None:
        """Take the master port's energy in (J), stamped `stamp_ns`: the slave port's credit."""
        self.port.credit(energy_in, stamp_ns)

    def tare(self, now: float) -> Optional[str]:
        """Take the current reading, less the tool's weight, as the bias; None or why not."""
        reading, arm = self.reading, self.arm
        refusal = tare_refusal(self.settings, arm, reading, now)
        if refusal is None:
            assert reading is not None and arm is not None
            self.force.tare(reading[0], arm[0].rotation)
        return refusal
