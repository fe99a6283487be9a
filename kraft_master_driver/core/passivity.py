# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Time-domain passivity (TDPA) for force reflection across a delaying, lossy network.

Pure logic, no ROS. Each end of the communication channel keeps the energy that flowed into
the channel at its port (energy_in) and out of it (energy_out), and sends its energy_in to
the other end. The channel stays passive if, at each end, what leaves never exceeds what the
other end has put in as far as this end knows (Ryu, Artigas and Preusche, Mechatronics 2010):

    observed = remote_energy_in - energy_out >= 0

When a step would make it negative, the port's passivity controller dissipates exactly the
excess in that step (Hannaford and Ryu, IEEE TRA 2002):

- MasterPort (the channel hands a force to the operator): the wrench is scaled down,
  F' = k F with 0 <= k < 1, so that F' . v dt, the energy predicted to reach the hand, drops by
  the excess. (The damper F - alpha v of Hannaford and Ryu, driven by a filtered velocity
  that lags the motion, pumped energy into the hand in benchmarks/delay_model.py; scaling never
  turns the wrench and takes only energy that would leave.)
- SlavePort (the channel hands a motion to the slave): a variable series damper on the
  commanded velocity, v' = v + beta F, so that -F . v' dt, the energy handed to the
  environment, drops by the excess. What it takes off the motion is the master-slave drift;
  the port gives it back only with energy to spare (Coelho et al. 2019): freely in free space,
  within the surplus in contact.

Sign conventions (both in the master's base frame, wrench and twist at the wrist):
master port power into the channel P_m = -F_m . v_m (F_m: wrench on the operator's hand,
v_m: the master's twist); slave port power P_s = F_s . v_s (F_s: the environment's force on
the slave, v_s: the slave's commanded velocity).
"""
from collections.abc import Iterable, Sequence
import math
import operator

MAX_STEP = 0.05  # s: a longer gap between two steps is integrated as this long
# J: energy the hand puts in at the master port that is kept there, not sent as credit, to
# pay for outflow the velocity prediction missed (a pot count flipping back and forth under a
# held force books out and in by turns: one count, 0.16 mm at the wrist, under 10 N is 1.6 mJ).
# Credit kept back is credit the slave lacks: 2 mJ cost 3 % of the steady contact force at
# 0 ms round trip in benchmarks/delay_model.py, 5 mJ 7.5 %.
MASTER_RESERVE_J = 0.002


def _dot(a: Iterable[float], b: Iterable[float]) -> float:
    total: float = sum(map(operator.mul, a, b))
    return total


class PortEnergy:
    """
    The energy bookkeeping of one port: in, out, dissipated, and the other end's credit.

    energy_in and energy_out only grow; remote_in is the credit: the largest energy_in
    received from the other end, so a lost, late or reordered sample only delays credit.

    Given the samples' stamps, the credit follows the other end's process. Its books are
    taken from its first sample on: what it had in before was credit for another peer. A
    smaller energy_in stamped later than the newest taken is the other end started again
    (its books start from zero), taken from there on in the same way. At such a start this
    port's unspent credit is dropped and a deficit kept; a sample stamped before it is
    ignored (a late one of the process before).
    """

    def __init__(self) -> None:
        """Start with nothing in, out or received."""
        self.energy_in = 0.0
        self.energy_out = 0.0
        self.dissipated = 0.0
        self.remote_in = 0.0
        self.enabled = True
        self._remote_start_ns: int | None = None  # the stamp of the other end's first sample
        self._newest_ns = 0
        self._remote_largest = 0.0  # the largest energy_in of the other end since its start
        self._remote_offset = 0.0  # remote_in less _remote_largest

    def credit(self, remote_energy_in: float, stamp_ns: int | None = None) -> None:
        """
        Take the other end's energy_in (J), stamped `stamp_ns` by its clock (None: unknown).

        A non-finite value is ignored, and so is a smaller one but where the stamp shows
        the other end started again.
        """
        if not math.isfinite(remote_energy_in):
            return
        if stamp_ns is not None:
            if self._remote_start_ns is None or (
                    stamp_ns > self._newest_ns and remote_energy_in < self._remote_largest):
                self._remote_start_ns = stamp_ns
                self._remote_largest = remote_energy_in
                self._remote_offset = self.energy_out + min(self.observed, 0.0) - remote_energy_in
            elif stamp_ns < self._remote_start_ns:
                return
            self._newest_ns = max(self._newest_ns, stamp_ns)
        self._remote_largest = max(self._remote_largest, remote_energy_in)
        self.remote_in = self._remote_offset + self._remote_largest

    @property
    def observed(self) -> float:
        """Return the passivity observer (J): the other end's credit minus what left here."""
        return self.remote_in - self.energy_out

    def _excess(self, power_out: float, dt: float) -> float:
        """Return the energy (J) by which a step handing out power_out (W) would overdraw."""
        if not self.enabled or power_out <= 0.0:
            return 0.0
        return max(self.energy_out + power_out * dt - self.remote_in, 0.0)

    def _account(self, power_out: float, dt: float, dissipated: float) -> None:
        """Book one step of power_out (W, negative: power in) after `dissipated` (J)."""
        if power_out > 0.0:
            self.energy_out += power_out * dt
        else:
            self.energy_in -= power_out * dt
        self.dissipated += dissipated


class MasterPort(PortEnergy):
    """
    The master's end: limits the force the operator feels (scales the wrench down).

    Each cycle, moved() books the work the wrench applied since the last sample did over the
    displacement measured since (exact for a force held between samples, whatever the velocity
    estimate), then step() limits the next wrench to the credit left, predicting the motion
    until the next sample from the velocity estimate. With passivity on, work the prediction
    missed is paid first from `reserve`: up to MASTER_RESERVE_J of the hand's own energy in,
    kept at this port (a passive store: it only gives back what it got), never sent as credit.
    Beyond the reserve, the wrench fades out as the deficit grows to MASTER_RESERVE_J.

    damped() adds a light damper on the wrist's translation, booked with the wrench: the
    energy the hand puts into it is energy in (it fills the reserve, then goes as credit), so
    the slave port has credit to press before the contact's force has crossed back.

    With rise_time set, the share of the wrench the port lets through falls at once but rises
    from one step to the next by at most the step's time over rise_time (a tenth of it at
    most): credit that arrives after a dry spell lets the force back in without a step.
    Giving less than the credit allows takes no energy out, so the port stays passive.
    """

    def __init__(self, damping: float = 0.0, rise_time: float = 0.0) -> None:
        """
        damping: N*s/m of the booked damper; rise_time: s (0: the share rises at once).

        Start idle; the first step() sets the clock.
        """
        super().__init__()
        self.damping = float(damping)
        self.rise_time = float(rise_time)
        self._share = 1.0  # the share of the wrench let through at the last step
        self.reserve = 0.0
        self._applied: Sequence[float] | None = None  # the wrench applied since the last sample
        self._last_ns: int | None = None
        self._period = 0.0

    def moved(self, displacement: Iterable[float]) -> None:
        """Book the work of the wrench applied over `displacement` (6 floats: m and rad)."""
        if self._applied is not None:
            work_out = _dot(self._applied, displacement)
            if not self.enabled:
                self._account(work_out, 1.0, 0.0)
            elif work_out > 0.0:
                drawn = min(work_out, self.reserve)
                self.reserve -= drawn
                self._account(work_out - drawn, 1.0, 0.0)
            else:
                kept = min(-work_out, MASTER_RESERVE_J - self.reserve)
                self.reserve += kept
                self._account(work_out + kept, 1.0, 0.0)
        self._applied = None

    def step(self, force: Sequence[float], velocity: Iterable[float],
             now_ns: int) -> Sequence[float]:
        """
        Return the wrench (6 floats) to apply in place of `force` until the next sample.

        force: the reflected wrench on the operator's hand; velocity: the master's twist (its
        estimate), both 6 floats in one frame; now_ns: monotonic time of this step. Call
        scaled() if only part of the result is applied.
        """
        if self._last_ns is not None:
            self._period = min((now_ns - self._last_ns) / 1e9, MAX_STEP)
        self._last_ns = now_ns
        dt = self._period
        deficit = -self.observed if self.enabled else 0.0
        share = 1.0
        if deficit > 0.0:
            # Outflow the prediction missed, beyond the reserve: the wrench fades out as the
            # deficit grows to MASTER_RESERVE_J, so that a velocity estimate that lags cannot
            # keep it growing, and fades back in as credit covers it.
            share = max(0.0, 1.0 - deficit / MASTER_RESERVE_J)
        power_out = share * _dot(force, velocity)
        # At most this step's own outflow: a deficit waits for credit.
        excess = min(self._excess(power_out, dt), power_out * dt)
        if excess > 0.0:
            share *= 1.0 - excess / (power_out * dt)
            self.dissipated += excess
        if self.enabled and self.rise_time > 0.0:
            rise = min(dt, 0.1 * self.rise_time) / self.rise_time
            share = min(share, self._share + rise)
        self._share = share
        if share < 1.0:
            force = [share * f for f in force]
        self._applied = force
        return force

    def damped(self, velocity: Sequence[float]) -> list[float]:
        """
        Return the damper's wrench (6 floats) at `velocity`, booked with the wrench step() gave.

        Zeros while passivity is off or before step(): only a port that books it harvests.
        """
        if not self.enabled or self._applied is None or not self.damping:
            return [0.0] * 6
        damper = [-self.damping * v for v in velocity[:3]] + [0.0, 0.0, 0.0]
        self._applied = [f + d for f, d in zip(self._applied, damper)]
        return damper

    def scaled(self, factor: float) -> None:
        """Note that the last wrench was applied scaled by `factor` (0..1)."""
        if self._applied is not None:
            self._applied = [factor * f for f in self._applied]

    def idle(self, now_ns: int) -> None:
        """Note a step with no channel force (zero torque): no energy, the clock moves on."""
        self._last_ns = now_ns
        self._applied = None


class SlavePort(PortEnergy):
    """
    The slave's end: turns the (delayed) master target into the slave's commanded position.

    Each step the channel's motion is the change of the target; the port adds the passivity
    controller's series damper and the drift compensation, and integrates the result into
    `command`, the position a slave's servo should track. drift = target - command.
    """

    def __init__(self, drift_gain: float = 2.0, max_speed: float = math.inf) -> None:
        """
        drift_gain (1/s): rate at which drift is given back when energy allows.

        max_speed (m/s): the giving back never makes the command move faster than this (nor
        faster than the channel's own motion, where that is faster).
        """
        super().__init__()
        self.drift_gain = float(drift_gain)
        self.max_speed = float(max_speed)
        self.command: list[float] | None = None
        self._target: list[float] | None = None

    def reset(self, position: Iterable[float]) -> None:
        """Start at rest with the target and the command at `position` (3 floats)."""
        self._target = list(position)
        self.command = list(position)

    @property
    def drift(self) -> list[float]:
        """Return target - command (3 floats, m), zeros before reset()."""
        if self.command is None or self._target is None:  # both None until reset()
            return [0.0, 0.0, 0.0]
        return [t - c for t, c in zip(self._target, self.command)]

    def step(self, target: Sequence[float], force: Sequence[float], dt: float) -> list[float]:
        """
        Move the command toward `target` passively over `dt` s; return the command.

        force: the environment's force on the slave now (3 floats, N); target: where the
        master's (delayed) motion asks the slave to be (3 floats, m).
        """
        if self.command is None or self._target is None:  # both None until reset()
            self.reset(target)
            return self.command  # type: ignore[return-value]  # reset() has just set it
        if dt <= 0.0:
            return self.command
        dt = min(dt, MAX_STEP)
        velocity = [(new - old) / dt for new, old in zip(target, self._target)]
        self._target = list(target)
        velocity, power_out, dissipated = self._passive(velocity, force, dt)
        # Give drift back with what is left over after this step, never more: the drift this
        # step's motion leaves, not the one before it (that would lead the target by a step).
        drift = [t - c - v * dt for t, c, v in zip(self._target, self.command, velocity)]
        if any(abs(d) > 1e-12 for d in drift):
            gain = self._drift_gain_within_speed(velocity, drift)
            back = [v + gain * d for v, d in zip(velocity, drift)]
            back_power = -_dot(force, back)
            if self._excess(back_power, dt) == 0.0:
                velocity, power_out = back, back_power
        self._account(power_out, dt, dissipated)
        self.command = [c + v * dt for c, v in zip(self.command, velocity)]
        return self.command

    def _drift_gain_within_speed(self, velocity: Sequence[float],
                                 drift: Sequence[float]) -> float:
        """Return the largest gain <= drift_gain with |velocity + gain drift| in max_speed."""
        limit = max(self.max_speed, math.sqrt(_dot(velocity, velocity)))
        dd, vd, vv = _dot(drift, drift), _dot(velocity, drift), _dot(velocity, velocity)
        # The root >= 0 of |v + g d|^2 = limit^2; vv <= limit^2 makes it real.
        root = (-vd + math.sqrt(max(vd * vd - dd * (vv - limit * limit), 0.0))) / dd
        return min(self.drift_gain, root)

    def _passive(self, velocity: list[float], force: Sequence[float],
                 dt: float) -> tuple[list[float], float, float]:
        """Return (velocity, power out, dissipated) with the series damper applied if needed."""
        power_out = -_dot(force, velocity)
        excess = self._excess(power_out, dt)
        force_work = dt * _dot(force, force)
        if excess > 0.0 and force_work > 0.0:
            beta = excess / force_work
            velocity = [v + beta * f for v, f in zip(velocity, force)]
            power_out -= excess / dt
            return velocity, power_out, excess
        return velocity, power_out, 0.0
