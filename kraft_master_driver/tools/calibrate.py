# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
kraft_master_calibrate: a guided least-squares calibration of the pots of one arm.

With the device connected (--port PATH, or 'sim' for the built-in simulator) the operator
holds the arm at known poses, one after the other: by default against the mechanical stops
of Table II, plus any fixtures given with --fixture. At each the tool averages pot samples
read with zero torque commanded. Each pot's line is fitted by least squares to the (mean
counts, known angle) pairs of the poses where its angle is known (POT3 reads th2 + th3, so
it needs th2 known too), residuals are printed per pot in degrees and suspicious samples
flagged: a large spread while holding, a residual outlier, counts at 0 or 4095. The result
is a ROS 2 parameter file (config/right_arm.yaml format) that the node loads unchanged with
--params-file; the samples are saved as CSV beside it, so a session can be fitted again.

With --csv the tool fits such a CSV instead (for scripts and tests): one row per pose and
pot, `pot,angle_deg,count,count,...`, pot 1..6, angle_deg of what the pot reads. Lines
starting with '#' and a first line starting with 'pot' are skipped.

With --check-torques the tool checks the torque sign and rough scale of each motor axis
instead (torque_check.py), the operator's hand off the handle, and writes the signs as
`torque_signs` into the calibration file (--calibration, updated in place unless --out).

Exit status: 0 calibration written; 1 an error (device, file, fit), suspicious samples
(nothing written unless --force), or a torque check refused, stopped or unsure of a sign
(nothing written); 2 bad command line.
"""
import argparse
import csv
import math
from pathlib import Path
import sys
import time
from typing import NamedTuple

from kraft_master_driver.core import kinematics
from kraft_master_driver.core.calibration import (
    ArmCalibration, CalibrationError, POT_COUNT, POT_JOINT, POT_MAX, POT_MEASURES,
    read_parameter_file)
from kraft_master_driver.core.gravity import GravityModel
from kraft_master_driver.link.device import KmcDevice
from kraft_master_driver.link.protocol import CODECS, DEFAULT_CODEC
from kraft_master_driver.tools import gravity_identification, torque_check
import numpy as np
import yaml

ZERO_TORQUES = (0.0,) * kinematics.DRIVEN_JOINTS
SIM_PORT = 'sim'
JOINT_KEYS = tuple(f'th{i}' for i in range(1, 7))
MAX_MISSED_REPLIES = 50  # consecutive commands without a reply before sampling gives up
REOPEN_POLL = 0.005  # s between looks at a link the device is reopening
STOP_OVERSHOOT = math.radians(5.0)  # how far beyond a stop the simulated hand pushes
STOP_TOLERANCE = 1e-9  # rad: a joint on its stop (th3 = q3 - q2 rounds)
SETTLE_TIMEOUT = 20.0  # s the simulated hand may take to come to rest
SETTLE_POLL = 0.02  # s between looks at the simulated arm
SETTLE_STILL_POLLS = 5  # consecutive looks without motion that count as at rest


class Station(NamedTuple):
    """A pose the operator holds: joint angles th1..th6 in degrees, NaN where not known."""

    label: str
    joints_deg: tuple

    def pot_angles_deg(self):
        """Return the angle (deg) each pot POT1..POT6 reads at this pose, NaN if not known."""
        theta = np.array(self.joints_deg, dtype=float)
        measured = theta[list(POT_JOINT)]
        measured[2] += theta[1]  # POT3 reads th2 + th3
        return measured


class Hold(NamedTuple):
    """The pot counts read while the operator held one station: (samples, 6)."""

    station: Station
    counts: np.ndarray


class Row(NamedTuple):
    """Samples of one pot at one known angle."""

    pot: int  # 1..6
    angle_deg: float
    counts: np.ndarray
    label: str = ''


class Flag(NamedTuple):
    """A suspicious row: its index in the rows fitted and what is wrong."""

    row: int
    message: str


class Fit(NamedTuple):
    """A least-squares calibration with per-row residuals (deg) and the rows flagged."""

    result: object  # calibration.FitResult
    rows: list
    residual_deg: np.ndarray
    flags: list


def stop_stations():
    """Return the stations at the mechanical stops of Table II, in an order easy to follow."""
    lower, upper = np.degrees(kinematics.joint_limits(0.0))
    th2_max = upper[1]
    elbow_upper_at_max = math.degrees(kinematics.joint_limits(math.radians(th2_max))[1][2])
    unknown = math.nan

    def pose(**angles):
        return tuple(float(angles.get(key, unknown)) for key in JOINT_KEYS)

    return [
        Station(f'shoulder yaw at its {upper[0]:+g} deg stop', pose(th1=upper[0])),
        Station(f'shoulder yaw at its {lower[0]:+g} deg stop', pose(th1=lower[0])),
        Station(f'shoulder pitch at its {lower[1]:g} deg stop, elbow at its {lower[2]:g} deg '
                'stop', pose(th2=lower[1], th3=lower[2])),
        Station(f'shoulder pitch at its {lower[1]:g} deg stop, elbow at its {upper[2]:g} deg '
                'stop', pose(th2=lower[1], th3=upper[2])),
        Station(f'shoulder pitch at its {th2_max:g} deg stop, elbow at its '
                f'{elbow_upper_at_max:g} deg stop', pose(th2=th2_max, th3=elbow_upper_at_max)),
        Station(f'shoulder pitch at its {th2_max:g} deg stop, elbow at its {lower[2]:g} deg '
                'stop', pose(th2=th2_max, th3=lower[2])),
        Station(f'wrist yaw at its {upper[3]:+g} deg stop', pose(th4=upper[3])),
        Station(f'wrist yaw at its {lower[3]:+g} deg stop', pose(th4=lower[3])),
        Station(f'wrist pitch at its {lower[4]:+g} deg stop', pose(th5=lower[4])),
        Station(f'wrist pitch at its {upper[4]:+g} deg stop', pose(th5=upper[4])),
        Station(f'wrist roll at its {upper[5]:+g} deg stop', pose(th6=upper[5])),
        Station(f'wrist roll at its {lower[5]:+g} deg stop', pose(th6=lower[5])),
    ]


def parse_fixture(text):
    """
    Parse a fixture station: '[label:]th2=90,th3=-90' (joint angles in degrees).

    Joints are th1..th6 or the joint names of kinematics.JOINT_NAMES.
    """
    label, _, assignments = text.rpartition(':')
    keys = dict(zip(JOINT_KEYS, JOINT_KEYS), **dict(zip(kinematics.JOINT_NAMES, JOINT_KEYS)))
    angles = {}
    for item in filter(None, (part.strip() for part in assignments.split(','))):
        key, _, value = item.partition('=')
        if key.strip() not in keys:
            raise ValueError(f'fixture {text!r}: unknown joint {key.strip()!r}, expected one '
                             f'of {", ".join(JOINT_KEYS)} or a joint name')
        try:
            angle = float(value)
        except ValueError:
            raise ValueError(f'fixture {text!r}: {item!r} is not joint=degrees') from None
        if not math.isfinite(angle) or abs(angle) > 360.0:
            raise ValueError(f'fixture {text!r}: {item!r} is not an angle within +-360 deg')
        angles[keys[key.strip()]] = angle
    if not angles:
        raise ValueError(f'fixture {text!r}: no joint angles, expected e.g. th2=90,th3=-90')
    joints = tuple(angles.get(key, math.nan) for key in JOINT_KEYS)
    return Station(label or 'fixture ' + ', '.join(f'{k}={v:g}' for k, v in angles.items()),
                   joints)


# -- sampling the device ---------------------------------------------------------------------


def sample(device, count):
    """
    Read `count` pot frames with zero torque commanded; return them as (count, 6).

    Only commands that went out unanswered count as missed: while the device reopens a link
    it dropped after missing replies, sampling waits; it fails if the port cannot be reopened.
    """
    frames, missed = [], 0
    failed_opens = device.stats['failed_opens']
    while len(frames) < count:
        if not device.send(ZERO_TORQUES):
            if device.stats['failed_opens'] > failed_opens:
                raise CalibrationError(f'{device.port}: no reply from the device '
                                       f'({device.last_error})')
            time.sleep(REOPEN_POLL)
            continue
        result = device.receive()
        if result is None:
            missed += 1
            if missed >= MAX_MISSED_REPLIES:
                raise CalibrationError(f'{device.port}: no reply from the device '
                                       f'({device.last_error or "timeouts"})')
            continue
        missed = 0
        frames.append(result.frame.pots)
    return np.array(frames, dtype=float)


def collect(device, stations, samples, operator):
    """
    Take each station in turn; return the list of Hold and whether the operator quit.

    operator(station) gets the arm held at the station and returns '' to sample it, 's' to
    skip it or 'q' to stop. Ctrl-C stops as 'q' does: the poses taken so far are kept.
    """
    holds = []
    try:
        for station in stations:
            answer = operator(station)
            if answer == 'q':
                return holds, True
            if answer != 's':
                holds.append(Hold(station, sample(device, samples)))
    except KeyboardInterrupt:
        return holds, True
    return holds, False


class ConsoleOperator:
    """A person at the device: the station is shown and the answer read from `ask`."""

    def __init__(self, ask=input):
        """Read answers with `ask(prompt)` (default: input)."""
        self._ask = ask
        self.count = 0

    def __call__(self, station):
        """Ask for the station; return '', 's' or 'q'."""
        self.count += 1
        answer = self._ask(f'[{self.count}] Hold the arm with {station.label}, then press '
                           'Enter (s: skip, q: quit): ')
        return answer.strip().lower()[:1]


class SimulatedOperator:
    """The simulator's operator hand: it pushes the arm to each station and waits for rest."""

    def __init__(self, simulator, log=print):
        """Work the hand of a running SimulatedKraftMaster created with operator='hold'."""
        self.simulator = simulator
        self._log = log
        self._home = None

    def target(self, station):
        """
        Return (actuator coordinates the hand pulls toward (rad), which joints meet a stop).

        The hand pushes beyond a stop in the coordinate the stop limits (q3 = th2 + th3 for
        the elbow), so the arm rests on the stop itself, not where friction leaves it.
        """
        from kraft_master_driver.simulation.master.model import joints_to_actuators, Workspace
        if self._home is None:
            self._home = Workspace().home()
        known = np.radians(np.array(station.joints_deg, dtype=float))
        theta = np.where(np.isnan(known), self._home, known)
        lower, upper = kinematics.joint_limits(theta[1])
        beyond = np.where(np.isclose(known, upper), 1.0,
                          np.where(np.isclose(known, lower), -1.0, 0.0))
        return joints_to_actuators(theta) + STOP_OVERSHOOT * beyond, beyond != 0.0

    def __call__(self, station):
        """Move the hand to `station`, wait until the arm rests (on its stops); return ''."""
        self._log(f'simulated operator: {station.label}')
        target, at_stop = self.target(station)
        stops = np.radians(np.array(station.joints_deg, dtype=float))[at_stop]
        self.simulator.hold_at(target)
        still, previous = 0, None
        deadline = time.monotonic() + SETTLE_TIMEOUT
        while time.monotonic() < deadline:
            time.sleep(SETTLE_POLL)
            angles = self.simulator.joint_angles()
            still = still + 1 if previous is not None and np.array_equal(angles, previous) else 0
            previous = angles
            # Stillness alone could be a starved simulator thread: stops must be reached too.
            if still >= SETTLE_STILL_POLLS and np.allclose(angles[at_stop], stops, rtol=0.0,
                                                           atol=STOP_TOLERANCE):
                break
        return ''


def holds_to_rows(holds):
    """Return one Row per station and pot whose angle is known there."""
    rows = []
    for hold in holds:
        for pot, angle in enumerate(hold.station.pot_angles_deg()):
            if np.isfinite(angle):
                rows.append(Row(pot + 1, float(angle), hold.counts[:, pot], hold.station.label))
    return rows


# -- CSV -------------------------------------------------------------------------------------


def write_rows(path, rows):
    """Write rows as CSV: pot, angle_deg, then the count samples."""
    with open(path, 'w', newline='', encoding='utf-8') as stream:
        stream.write('# kraft_master_calibrate samples: pot (1..6), angle_deg of what the pot '
                     'reads (POT3: th2 + th3), count samples...\n')
        writer = csv.writer(stream)
        writer.writerow(['pot', 'angle_deg', 'counts'])
        for row in rows:
            writer.writerow([row.pot, repr(row.angle_deg)] + [f'{c:g}' for c in row.counts])


def read_rows(path):
    """Read rows from a CSV written by write_rows (or by hand); raise CalibrationError."""
    rows = []
    try:
        with open(path, newline='', encoding='utf-8') as stream:
            lines = [(number, line) for number, line in enumerate(stream, 1)
                     if line.strip() and not line.lstrip().startswith('#')]
    except (OSError, UnicodeDecodeError) as error:
        raise CalibrationError(f'{path}: cannot read: {error}') from None
    if lines and lines[0][1].lstrip().lower().startswith('pot'):
        lines = lines[1:]
    for number, line in lines:
        where = f'{path}:{number}'
        fields = next(csv.reader([line]))
        if len(fields) < 3:
            raise CalibrationError(f'{where}: expected pot,angle_deg,count[,count...], '
                                   f'got {line.strip()!r}')
        try:
            pot, angle = int(fields[0]), float(fields[1])
            counts = np.array([float(x) for x in fields[2:]])
        except ValueError:
            raise CalibrationError(f'{where}: not numbers: {line.strip()!r}') from None
        if not 1 <= pot <= POT_COUNT:
            raise CalibrationError(f'{where}: pot {pot} is not 1..{POT_COUNT}')
        if not (math.isfinite(angle) and abs(angle) <= 360.0):
            raise CalibrationError(f'{where}: angle {angle:g} deg is not within +-360')
        if not np.all(np.isfinite(counts)) or counts.min() < 0 or counts.max() > POT_MAX:
            raise CalibrationError(f'{where}: counts must be numbers within 0..{POT_MAX}')
        rows.append(Row(pot, angle, counts, f'line {number}'))
    if not rows:
        raise CalibrationError(f'{path}: no samples')
    return rows


# -- fitting ---------------------------------------------------------------------------------


def fit_rows(arm, rows, max_spread=3.0, max_residual_deg=0.5, source='least-squares fit'):
    """
    Fit each pot's line to the mean counts of its rows; return a Fit.

    Flags rows whose counts spread (standard deviation) more than `max_spread` counts, that
    touch 0 or POT_MAX, or whose residual exceeds `max_residual_deg`. Raises
    CalibrationError naming the pots that lack two distinct poses.
    """
    means = np.array([row.counts.mean() for row in rows])
    angles = np.radians([row.angle_deg for row in rows])
    pots = np.array([row.pot for row in rows])
    lacking = [f'POT{pot} ({POT_MEASURES[pot - 1]})' for pot in range(1, POT_COUNT + 1)
               if np.unique(np.round(means[pots == pot], 6)).size < 2]
    if lacking:
        raise CalibrationError(f'{source}: need poses at two or more distinct counts for '
                               f'{", ".join(lacking)}')
    result = ArmCalibration.fit(
        arm, [(means[pots == pot], angles[pots == pot]) for pot in range(1, POT_COUNT + 1)],
        source=source)
    calibration = result.calibration
    index = pots - 1
    fitted = calibration.offset[index] + calibration.slope[index] * means
    residual_deg = np.degrees(angles - fitted)
    flags = []
    for number, (row, residual) in enumerate(zip(rows, residual_deg)):
        where = f'POT{row.pot} at {row.angle_deg:g} deg ({row.label or f"row {number + 1}"})'
        spread = row.counts.std()
        if spread > max_spread:
            flags.append(Flag(number, f'{where}: counts spread {spread:.1f} (limit '
                                      f'{max_spread:g}): the arm moved while held?'))
        if row.counts.min() <= 0 or row.counts.max() >= POT_MAX:
            flags.append(Flag(number, f'{where}: counts reach 0 or {POT_MAX}: the pot is at '
                                      'the end of its range or disconnected'))
        if abs(residual) > max_residual_deg:
            flags.append(Flag(number, f'{where}: residual {residual:+.3f} deg (limit '
                                      f'{max_residual_deg:g}): wrong pose or a loose stop?'))
    return Fit(result, rows, residual_deg, flags)


def report_lines(fit):
    """Return text lines: per pot, its line, pose count and residuals in degrees."""
    calibration = fit.result.calibration
    lines = ['pot   reads       poses  rms (deg)  max (deg)  deg/count   line']
    for pot in range(POT_COUNT):
        lines.append(
            f'POT{pot + 1}  {POT_MEASURES[pot]:<10}  {fit.result.sample_count[pot]:5d}  '
            f'{math.degrees(fit.result.rms_residual[pot]):9.4f}  '
            f'{math.degrees(fit.result.max_residual[pot]):9.4f}  '
            f'{math.degrees(calibration.slope[pot]):+.6f}  '
            f'({calibration.pot_a[pot]:.1f}, {math.degrees(calibration.angle_a[pot]):+.3f} deg)'
            f' - ({calibration.pot_b[pot]:.1f}, {math.degrees(calibration.angle_b[pot]):+.3f}'
            ' deg)')
    for pot, label, residual in zip([r.pot for r in fit.rows], [r.label for r in fit.rows],
                                    fit.residual_deg):
        lines.append(f'  POT{pot} {label}: residual {residual:+.4f} deg')
    return lines


# -- command line ----------------------------------------------------------------------------


def _parser():
    parser = argparse.ArgumentParser(
        prog='kraft_master_calibrate',
        description='Least-squares calibration of the pots of one Kraft Master arm: hold the '
                    'arm at known poses (the mechanical stops, fixtures), or fit a CSV of '
                    'samples; writes a parameter file the node loads with --params-file.')
    parser.add_argument('--arm', choices=kinematics.ARMS, required=True)
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument('--port', help="serial port or pyserial URL of the device; 'sim' "
                                       'starts the built-in simulator and its operator hand')
    source.add_argument('--csv', metavar='FILE', help='fit these samples instead: rows of '
                                                      'pot,angle_deg,count,count,...')
    parser.add_argument('--out', metavar='YAML', help='parameter file to write (default: '
                                                      '<arm>_arm_calibrated.yaml)')
    parser.add_argument('--samples', type=int, default=200,
                        help='pot frames averaged at each pose (default 200)')
    parser.add_argument('--fixture', action='append', default=[], metavar='[LABEL:]th2=90,...',
                        help='an extra pose at known joint angles (deg); repeatable')
    parser.add_argument('--no-stops', action='store_true',
                        help='use only the --fixture poses, not the mechanical stops')
    parser.add_argument('--max-spread', type=float, default=3.0,
                        help='flag a pose whose counts spread more (std, counts; default 3)')
    parser.add_argument('--max-residual', type=float, default=0.5,
                        help='flag a pose whose residual is larger (deg; default 0.5)')
    parser.add_argument('--force', action='store_true',
                        help='write the calibration even with flagged samples')
    parser.add_argument('--baud', type=int, default=1_000_000, help='baud rate (bit/s)')
    parser.add_argument('--codec', default=DEFAULT_CODEC,
                        help=f'the frame of the link: {", ".join(sorted(CODECS))} or the path of '
                             f'a frame description .yaml (default {DEFAULT_CODEC})')
    parser.add_argument('--sim-calibration', metavar='YAML',
                        help="with --port sim: the simulated device's true calibration")
    parser.add_argument('--sim-noise', type=float, default=1.0,
                        help='with --port sim: pot noise, counts (1 sigma, default 1)')
    check = parser.add_argument_group('torque check (--check-torques)')
    check.add_argument('--check-torques', action='store_true',
                       help='hand off the handle: pulse each motor axis 1..5 in turn, say '
                            'whether its sign agrees with the kinematics and its rough scale, '
                            'write torque_signs into the calibration file')
    check.add_argument('--calibration', metavar='YAML',
                       help='the parameter file of the pot calibration (and any torque_signs, '
                            'applied while checking); written back with torque_signs unless '
                            '--out (default: the nominal calibration)')
    check.add_argument('--identify-gravity', action='store_true',
                       help='hand off the handle: hold the arm at poses across the workspace, '
                            'fit its weight, write gravity_parameters into the calibration file '
                            '(with --port sim, the simulated links weigh)')
    defaults = torque_check.Settings()
    check.add_argument('--torque', type=float, default=defaults.torque,
                       help='largest pulse torque (N*m; default %(default)g); pulses start '
                            'at a quarter of it')
    check.add_argument('--pulse', type=float, default=defaults.pulse,
                       help='duration of one pulse, +torque then -torque (s; default '
                            '%(default)g)')
    check.add_argument('--max-motion', type=float,
                       default=math.degrees(defaults.max_motion),
                       help='a larger motion of any axis zeroes the torques and stops the '
                            'check (deg; default %(default)g)')
    return parser


def _stations(args, parser):
    try:
        fixtures = [parse_fixture(text) for text in args.fixture]
    except ValueError as error:
        parser.error(str(error))
    stations = ([] if args.no_stops else stop_stations()) + fixtures
    if not stations:
        parser.error('--no-stops needs at least one --fixture')
    return stations


def _simulator(args):
    """Return the built-in simulator of --port sim, not started."""
    from kraft_master_driver.simulation.master.simulator import SimulatedKraftMaster
    truth = ArmCalibration.from_yaml(args.sim_calibration) if args.sim_calibration else None
    try:
        return SimulatedKraftMaster(arm=args.arm, calibration=truth, codec=args.codec,
                                    operator='hold', pot_noise_counts=args.sim_noise)
    except ValueError as error:
        raise CalibrationError(f'--port sim: {error}') from None


def _measure(args, stations, out, ask):
    """Sample the device at each station; save the samples CSV; return (rows, quit)."""
    simulator = _simulator(args) if args.port == SIM_PORT else None
    try:
        try:
            device = KmcDevice(args.port if simulator is None else simulator.start(),
                               baudrate=args.baud, codec=args.codec)
        except ValueError as error:
            raise CalibrationError(f'{args.port}: {error}') from None
        operator = ConsoleOperator(ask) if simulator is None else SimulatedOperator(simulator)
        with device:
            if not device.link_up:
                raise CalibrationError(f'{args.port}: {device.last_error}')
            holds, quit_early = collect(device, stations, args.samples, operator)
    finally:
        if simulator is not None:
            simulator.stop()
    rows = holds_to_rows(holds)
    if rows:
        samples_path = out.with_name(out.stem + '_samples.csv')
        write_rows(samples_path, rows)
        print(f'samples saved to {samples_path}')
    return rows, quit_early


# -- torque check ----------------------------------------------------------------------------


def _torque_settings(args, parser):
    """Return the torque_check.Settings of the command line; parser.error if not usable."""
    if not args.port:
        parser.error('--check-torques needs --port')
    defaults = torque_check.Settings()
    if not 0.0 < args.torque <= 5.0:
        parser.error('--torque must be within 0..5 N*m')
    if not 0.0 < args.pulse <= 1.0:
        parser.error('--pulse must be within 0..1 s')
    max_motion = math.radians(args.max_motion)
    if not defaults.min_motion < max_motion <= math.radians(90.0):
        parser.error(f'--max-motion must be above {math.degrees(defaults.min_motion):g} and '
                     'at most 90 deg')
    return defaults._replace(torque=args.torque, pulse=args.pulse, max_motion=max_motion)


def _calibration_parameters(args):
    """Return (the parameters of --calibration or the nominal ones, the signs they apply)."""
    if args.calibration:
        parameters = read_parameter_file(args.calibration)
        if parameters.get('arm', args.arm) != args.arm:
            raise CalibrationError(f'{args.calibration}: arm: {parameters["arm"]!r}, but '
                                   f'--arm {args.arm}')
        ArmCalibration.from_parameters(args.arm, parameters.get('calibration'),
                                       args.calibration)
    else:
        parameters = ArmCalibration.nominal(args.arm).to_parameters()
    signs = parameters.get('torque_signs', [1] * kinematics.DRIVEN_JOINTS)
    if not (isinstance(signs, list) and len(signs) == kinematics.DRIVEN_JOINTS
            and all(sign in (1, -1) and not isinstance(sign, bool) for sign in signs)):
        raise CalibrationError(f'{args.calibration}: torque_signs: expected five of 1 or -1, '
                               f'got {signs!r}')
    return parameters, signs


def hand_off_simulator(args, gravity=False):
    """Return the built-in simulator of --port sim with the operator's hand off, not started."""
    from kraft_master_driver.simulation.master.model import HAND_OFF
    from kraft_master_driver.simulation.master.simulator import SimulatedKraftMaster
    truth = ArmCalibration.from_yaml(args.sim_calibration) if args.sim_calibration else None
    try:
        return SimulatedKraftMaster(
            arm=args.arm, calibration=truth, codec=args.codec, operator='hold',
            pot_noise_counts=args.sim_noise, dynamics=HAND_OFF, gravity=gravity,
            lockstep=torque_check.CYCLE_PERIOD if gravity else None)
    except ValueError as error:
        raise CalibrationError(f'--port sim: {error}') from None


class _HandOffDevice:
    """The device of --port (or the built-in simulator, hand off), open, its link up."""

    def __init__(self, args, applied_signs, gravity=False):
        """Start the simulator of --port sim; nothing is opened until entered."""
        self.args, self.signs = args, applied_signs
        self.simulator = hand_off_simulator(args, gravity) if args.port == SIM_PORT else None
        self.device = None

    def __enter__(self):
        """Open the port; CalibrationError if it cannot be, or is busy."""
        args = self.args
        try:
            port = args.port if self.simulator is None else self.simulator.start()
            self.device = KmcDevice(port, baudrate=args.baud, codec=args.codec,
                                    torque_sign=self.signs)
        except ValueError as error:
            self.__exit__()
            raise CalibrationError(f'{args.port}: {error}') from None
        self.device.open()
        if not self.device.link_up:
            self.__exit__()
            # A driver running on the port holds its exclusive lock: refused here.
            raise CalibrationError(f'refused: {self.device.last_error}')
        return self.device

    def __exit__(self, *_exc):
        """Zero the torques and close; stop the simulator."""
        if self.device is not None:
            self.device.close()
        if self.simulator is not None:
            self.simulator.stop()


def _write_parameters(args, parameters, what):
    """Write the calibration file back with what was measured; return its path."""
    out = Path(args.out or args.calibration or f'{args.arm}_arm_calibrated.yaml')
    header = (f'{args.arm} arm, kraft_master_calibrate, {time.strftime("%Y-%m-%d %H:%M:%S")}\n'
              f'{what} measured on {args.port} (codec {args.codec})')
    text = yaml.safe_dump({'/**': {'ros__parameters': parameters}},
                          default_flow_style=None, sort_keys=False)
    out.write_text(''.join(f'# {line}\n' for line in header.splitlines()) + text,
                   encoding='utf-8')
    return out


def check_torques(args, settings):
    """Run the torque check; write torque_signs; return the exit status."""
    parameters, applied = _calibration_parameters(args)
    calibration = ArmCalibration.from_parameters(args.arm, parameters['calibration'],
                                                 args.calibration or 'nominal')
    with _HandOffDevice(args, applied) as device:
        print(f'torque check on {args.port}: hand off the handle; pulses up to '
              f'{settings.torque:g} N*m, stop beyond {math.degrees(settings.max_motion):g}'
              ' deg')
        results = torque_check.TorqueCheck(device, calibration, settings).run()
    unsure = [result.axis for result in results if not result.moved]
    if unsure:
        print(f'sign unknown on axis {", ".join(map(str, unsure))}: nothing written',
              file=sys.stderr)
        return 1
    signs = torque_check.measured_signs(results, applied)
    parameters['torque_signs'] = signs
    out = _write_parameters(args, parameters, f'torque_signs {signs}')
    reversed_axes = [result.axis for result in results if not result.agrees]
    if reversed_axes:
        print(f'reversed: axis {", ".join(map(str, reversed_axes))}; the driver applies the '
              'torque_signs written when it loads this file')
    print(f'wrote torque_signs {signs} to {out}')
    return 0


def identify_gravity(args):
    """Hold the poses, fit the arm's weight, write gravity_parameters; return the status."""
    parameters, applied = _calibration_parameters(args)
    calibration = ArmCalibration.from_parameters(args.arm, parameters['calibration'],
                                                 args.calibration or 'nominal')
    lengths = parameters.get('link_lengths')
    model = GravityModel(args.arm, None if lengths is None else kinematics.LinkLengths(*lengths))
    with _HandOffDevice(args, applied, gravity=True) as device:
        print(f'gravity identification on {args.port}: hand off the handle; the arm is held '
              f'at {len(gravity_identification.POSES_DEG)} poses, each from above and below')
        result = gravity_identification.identify(
            gravity_identification.PdHold(device, calibration), model)
    for line in gravity_identification.describe(result):
        print(line)
    parameters['gravity_parameters'] = [round(value, 7) for value in result.base]
    out = _write_parameters(args, parameters, 'gravity_parameters')
    print(f'wrote gravity_parameters to {out}; the driver adds them with '
          'gravity_compensation:=true')
    return 0


def main(argv=None, ask=input):
    """Run the calibration; return the exit status (0 written, 1 error or flagged)."""
    parser = _parser()
    args = parser.parse_args(argv)
    if args.check_torques and args.identify_gravity:
        parser.error('--check-torques and --identify-gravity: one at a time')
    if args.check_torques or args.identify_gravity:
        try:
            if args.identify_gravity:
                return identify_gravity(args)
            return check_torques(args, _torque_settings(args, parser))
        except (CalibrationError, OSError) as error:
            print(f'kraft_master_calibrate: {error}', file=sys.stderr)
            return 1
    if args.samples < 1:
        parser.error('--samples must be at least 1')
    if args.sim_calibration and args.port != SIM_PORT:
        parser.error('--sim-calibration needs --port sim')
    out = Path(args.out or f'{args.arm}_arm_calibrated.yaml')
    try:
        if args.csv:
            rows, source = read_rows(args.csv), args.csv
        else:
            rows, quit_early = _measure(args, _stations(args, parser), out, ask)
            if quit_early:
                print('stopped by the operator: no calibration written')
                return 1
            source = f'{args.port} ({len(rows)} pose and pot readings)'
        fit = fit_rows(args.arm, rows, args.max_spread, args.max_residual,
                       source=f'least-squares fit of {source}')
    except (CalibrationError, OSError) as error:
        print(f'kraft_master_calibrate: {error}', file=sys.stderr)
        return 1
    for line in report_lines(fit):
        print(line)
    for flag in fit.flags:
        print(f'SUSPICIOUS: {flag.message}')
    if fit.flags and not args.force:
        print(f'{len(fit.flags)} suspicious samples: {out} not written; take those poses '
              'again, or pass --force to write it anyway', file=sys.stderr)
        return 1
    worst = max(math.degrees(x) for x in fit.result.max_residual)
    try:
        fit.result.calibration.to_yaml(out, header=(
            f'{args.arm} arm, kraft_master_calibrate, {time.strftime("%Y-%m-%d %H:%M:%S")}\n'
            f'{fit.result.calibration.source}; largest residual {worst:.4f} deg'))
    except OSError as error:
        print(f'kraft_master_calibrate: cannot write {out}: {error}', file=sys.stderr)
        return 1
    print(f'wrote {out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
