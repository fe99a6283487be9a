# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
A simulated Kraft Master hand controller on a real pseudo-terminal, or on TCP.

The device answers each torque command with one pot reply in the link's frame format
(protocol.py). It is put together from:

- model.py: six joints with inertia, damping, friction and end stops, and the workspace;
- operators.py: a scripted operator hand that pulls the device about;
- electronics.py: torque commands to motor torques, the watchdog, the pots;
- faults.py: dropped replies, corrupted bytes and stalls, for tests;
- transport.py: the port, a pty behind a stable symlink that can be unplugged and replugged,
  or a TCP server reached as socket://;
- serving.py: the thread that alone touches the port, and sends the replies on time.

Time is wall time: the model is integrated in substeps of at most 0.5 ms up to the moment
each command arrives, and every few milliseconds when no command comes. With a baud rate,
each reply leaves when the wire would have carried it.
"""
import argparse
import atexit
import collections
import gc
import os
import random
import signal
import sys
import threading
import time

from kraft_master_driver.core import kinematics, realtime
from kraft_master_driver.core.calibration import ArmCalibration, CalibrationError
from kraft_master_driver.core.gravity import GravityModel, SIMULATED_MASSES
from kraft_master_driver.core.process import STOP_SIGNALS, stop_with_parent
from kraft_master_driver.link.protocol import CODECS, DEFAULT_CODEC, get_codec
from kraft_master_driver.simulation.master.electronics import COUPLINGS, Electronics
from kraft_master_driver.simulation.master.faults import FaultInjector
from kraft_master_driver.simulation.master.model import (
    DEFAULT_DYNAMICS, DeviceModel, HAND_OFF, Workspace)
from kraft_master_driver.simulation.master.operators import (
    HoldOperator, make_operator, OPERATORS, PushOperator, TaskOperator)
from kraft_master_driver.simulation.master.serving import ServingThread
from kraft_master_driver.simulation.master.transport import make_transport
import numpy as np

MAX_CATCH_UP = 0.05  # s of model time per step; a longer idle gap is skipped, not replayed


class SimulatedKraftMaster:
    """A simulated Kraft Master on a pseudo-terminal or TCP; start() returns the port."""

    def __init__(self, arm='right', calibration=None, codec=DEFAULT_CODEC,
                 torque_scale=None, coupling='actuator', operator='hold',
                 pot_noise_counts=0.0, baudrate=None, seed=0, *,
                 torque_limit=None, command_timeout=0.1,
                 operator_period=2.0, drop_reply_rate=0.0, corrupt_byte_rate=0.0,
                 dynamics=DEFAULT_DYNAMICS, record=10000, priority=0, transport='pty',
                 gravity=False, lockstep=None):
        """
        Configure the device; nothing runs until start().

        calibration is the device's true calibration (default: the arm's nominal one);
        codec is the frame it speaks, a name in protocol.CODECS or the path of a frame
        description; torque_scale is in command counts per N*m, torque_limit in counts (larger
        commands are clamped, status bit1), both by default the codec's; baudrate None means
        no wire timing; command_timeout (s)
        is the watchdog; operator_period (s) is the sweep time per joint or the mean
        segment of the random walk; `record` is the length of the `received` deque;
        priority (1-99) runs the serving thread SCHED_FIFO, answering as promptly as the
        device's own electronics would (0: the normal scheduler; if the OS refuses,
        priority_error says why and the thread runs normally). transport 'pty': the port is
        a pseudo-terminal behind a symlink; 'tcp': a TCP server on 127.0.0.1 that serves one
        host at a time, its port a pyserial URL socket://127.0.0.1:N. gravity: the links
        weigh core.gravity.SIMULATED_MASSES (made up); holding_torques() gives their true
        torques. lockstep (s): the mechanics advance exactly this much after each command, not
        with the clock (simulated time, as a host cycling at 1/lockstep Hz would see on an idle
        machine): for tests of a loop's algorithm that must not depend on the machine's load.
        """
        self._transport = make_transport(transport, self._forget_in_flight)
        self.transport = transport
        if not (isinstance(priority, int) and 0 <= priority <= 99):
            raise ValueError(f'priority must be an integer in 0..99, got {priority!r}')
        self.priority = priority
        self.priority_error = None
        self.arm = kinematics.check_arm(arm)
        self.calibration = ArmCalibration.nominal(arm) if calibration is None else calibration
        if self.calibration.arm != arm:
            raise ValueError(f'calibration is for the {self.calibration.arm} arm, not {arm}')
        self.codec = codec
        self._codec = get_codec(codec)
        if operator not in OPERATORS:
            raise ValueError(f'operator must be one of {", ".join(OPERATORS)}, got {operator!r}')
        self.operator = operator
        self._wire_time = 0.0 if baudrate is None else self._codec.wire_cycle_time(baudrate)
        self.baudrate = baudrate
        if not command_timeout > 0.0 or not operator_period > 0.0:
            raise ValueError('command_timeout and operator_period must be positive, got '
                             f'{command_timeout!r} and {operator_period!r}')

        operator_seed, noise_seed, fault_seed = np.random.SeedSequence(seed).spawn(3)
        self._faults = FaultInjector(random.Random(int(fault_seed.generate_state(1)[0])),
                                     drop_reply_rate, corrupt_byte_rate)
        workspace = Workspace()
        self._operator = make_operator(operator, workspace, operator_period,
                                       np.random.default_rng(operator_seed))
        self.gravity = gravity
        self.lockstep = lockstep
        self._gravity_model = GravityModel(arm) if gravity else None
        self.true_gravity = (None if self._gravity_model is None
                             else self._gravity_model.base_parameters(SIMULATED_MASSES))
        self._model = DeviceModel(dynamics, workspace.home(),
                                  weight=self.holding_torques if gravity else None)
        self._model_lock = threading.Lock()
        self._electronics = Electronics(
            self._model, self.calibration, coupling=coupling,
            torque_scale=self._codec.torque_scale if torque_scale is None else torque_scale,
            torque_limit=self._codec.torque_limit if torque_limit is None else torque_limit,
            command_timeout=command_timeout, pot_noise_counts=pot_noise_counts,
            noise_rng=np.random.default_rng(noise_seed), pot_range=self._codec.pot_range)
        self.coupling = coupling
        self._decoder = self._codec.command_decoder()

        self.received = collections.deque(maxlen=record)
        self._stats = dict.fromkeys(
            ('commands', 'replies', 'dropped', 'corrupted_bytes', 'stalled', 'clamped',
             'timeouts', 'garbage_sent', 'unsent'), 0)
        self._thread = None  # the ServingThread while serving
        self._model_time = 0.0
        self._start_time = 0.0
        self._waits_for_host = False  # the operator's time stands at 0 until the first command

    def holding_torques(self, theta):
        """Return the motor torques (N*m, axes 1..5) that hold the links up at theta."""
        if self._gravity_model is None:
            return [0.0] * kinematics.DRIVEN_JOINTS
        return self._gravity_model.holding_torques(theta, self.true_gravity).tolist()

    # Fault switches.

    @property
    def drop_reply_rate(self):
        """Probability (0..1) that a reply is lost after the command was applied."""
        return self._faults.drop_reply_rate

    @drop_reply_rate.setter
    def drop_reply_rate(self, rate):
        self._faults.drop_reply_rate = rate

    @property
    def corrupt_byte_rate(self):
        """Probability (0..1) per outgoing byte that random bits of it are flipped."""
        return self._faults.corrupt_byte_rate

    @corrupt_byte_rate.setter
    def corrupt_byte_rate(self, rate):
        self._faults.corrupt_byte_rate = rate

    def hold_at(self, actuator_target):
        """Make the 'hold' operator hand pull toward actuator coordinates (6 values, rad)."""
        if not isinstance(self._operator, HoldOperator):
            raise ValueError("only the 'hold' operator hand can be held at a pose")
        self._operator.hold_at(actuator_target)

    def stall(self, ms):
        """Answer nothing for `ms` milliseconds; commands meanwhile are consumed, not applied."""
        self._faults.stall(ms)

    def unplug(self):
        """Close the pty master and remove the port symlink (tcp: close the server)."""
        self._call_in_loop(self._transport.unplug)

    def replug(self):
        """Open a new pty behind the port symlink (tcp: serve the same port again)."""
        self._call_in_loop(self._transport.plug)

    def send_garbage(self, n_bytes):
        """Write `n_bytes` random bytes to the host, between replies."""
        if not n_bytes >= 0:
            raise ValueError(f'send_garbage needs a byte count >= 0, got {n_bytes!r}')
        self._call_in_loop(lambda: self._write_garbage(int(n_bytes)))

    # Observation.

    @property
    def port(self):
        """Return the stable port to open, a symlink to the pty slave or a URL; None if stopped."""
        return self._transport.port

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
        if self._thread is not None:
            return self.port
        self._transport.start()
        self._start_time = self._model_time = time.monotonic()
        self._electronics.restart_watchdog(self._start_time)
        self._waits_for_host = isinstance(self._operator, (PushOperator, TaskOperator))
        self._thread = ServingThread(self._transport, self._wire_time, self._stats,
                                     on_data=self._receive, on_tick=self._advance)
        self._thread.start()
        # However its owner ends (a signal between two of its statements), the directory goes.
        atexit.register(self.stop)
        if self.priority:
            try:  # Linux: a thread id in place of a process id sets that thread alone
                os.sched_setscheduler(self._thread.native_id, os.SCHED_FIFO,
                                      os.sched_param(self.priority))
            except OSError as error:
                self.priority_error = f'SCHED_FIFO {self.priority} refused: {error}'
        return self.port

    def stop(self):
        """Stop serving, close every descriptor, remove the temporary directory."""
        atexit.unregister(self.stop)
        if self._thread is not None:
            self._thread.stop()
            self._thread = None
        self._transport.stop()

    def __enter__(self):
        """Start serving and return the simulator."""
        self.start()
        return self

    def __exit__(self, *_exc):
        """Stop serving."""
        self.stop()

    # Run in the serving thread.

    def _advance(self, now):
        """Run the watchdog, then integrate the model up to `now`."""
        if self._electronics.watchdog(now):
            self._stats['timeouts'] += 1
        elapsed = now - self._model_time
        if elapsed <= 0.0 or self.lockstep:
            return
        self._model_time = now
        target = self._operator.target(0.0 if self._waits_for_host else now - self._start_time)
        with self._model_lock:
            self._model.step(min(elapsed, MAX_CATCH_UP), target)

    def _receive(self, data, now):
        for command in self._decoder.feed(data):
            self._handle(command, now)

    def _handle(self, command, now):
        self.received.append((time.time_ns(), command))  # before the reply: a host can count on it
        stats = self._stats
        stats['commands'] += 1
        if self._faults.stalled(now):
            stats['stalled'] += 1
            return
        clamped = self._electronics.clamped(command.counts)
        if clamped:
            stats['clamped'] += 1  # before the reply: a host that has it can count on it
        # The pots were read when the command arrived: answer first, then drive the motors.
        self._answer(command.sequence, clamped, now)
        self._electronics.drive(command.counts, now)
        if self.lockstep:
            with self._model_lock:
                self._model.step(self.lockstep, self._operator.target(
                    self._model_time - self._start_time))
            self._model_time += self.lockstep
        if self._waits_for_host:
            self._waits_for_host = False
            self._start_time = now

    def _answer(self, sequence, clamped, now):
        """Send (or, under wire timing, schedule) the reply to command `sequence`."""
        status = self._electronics.status(clamped, sum(self._decoder.errors.values()))
        if self._faults.drops_reply():
            self._stats['dropped'] += 1
            return
        reply, corrupted = self._faults.corrupt(
            self._codec.encode_reply(sequence, self._electronics.read_pots(), status))
        self._stats['corrupted_bytes'] += corrupted
        self._thread.send(reply, now)

    def _write_garbage(self, n_bytes):
        if self._thread.write(self._faults.garbage(n_bytes)):
            self._stats['garbage_sent'] += n_bytes

    def _forget_in_flight(self):
        """Drop the partial command and the replies not yet sent: the host's end has closed."""
        self._decoder.reset()
        if self._thread is not None:
            self._thread.drop_pending()

    def _call_in_loop(self, function):
        """Have the serving thread call function(), so that only it touches the port."""
        if self._thread is None or not self._thread.serving:
            raise RuntimeError('the simulator is not running: call start() first')
        self._thread.call(function)


RECORD_ALL = None  # an unbounded deque


def main(argv=None):
    """Run the simulator from the command line until Ctrl-C, SIGTERM or SIGHUP; return 0."""
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
    parser.add_argument('--codec', default=DEFAULT_CODEC,
                        help=f'the frame spoken: {", ".join(sorted(CODECS))} or the path of a '
                             f'frame description .yaml (default {DEFAULT_CODEC})')
    parser.add_argument('--seed', type=int, default=0, help='random seed (default 0)')
    parser.add_argument('--priority', type=int, default=0,
                        help='SCHED_FIFO priority 1-99 of the thread that answers commands, '
                             'as prompt as the real electronics (default 0: normal)')
    parser.add_argument('--tcp', action='store_true',
                        help='serve on TCP, 127.0.0.1, instead of a pty: the port is a '
                             'socket:// URL, as of a serial device server')
    parser.add_argument('--gravity', action='store_true',
                        help='the links weigh what core.gravity.SIMULATED_MASSES says (made up)')
    parser.add_argument('--hand-off', action='store_true',
                        help="the operator's hand off the handle (no --operator)")
    parser.add_argument('--record', metavar='NPY',
                        help='on exit, save every received command as rows (time_ns, '
                             'counts axis 1..5, sequence or -1 when the frame has none) in '
                             'this .npy file')
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
            arm=arm, calibration=calibration, codec=args.codec, coupling=args.coupling,
            operator=args.operator,
            pot_noise_counts=args.noise, baudrate=args.baud, seed=args.seed,
            drop_reply_rate=args.drop_rate, corrupt_byte_rate=args.corrupt_rate,
            record=RECORD_ALL if args.record else 10000, priority=args.priority,
            transport='tcp' if args.tcp else 'pty', gravity=args.gravity,
            dynamics=HAND_OFF if args.hand_off else DEFAULT_DYNAMICS)
    except ValueError as error:
        parser.error(str(error))

    # A plain list, not an Event: Event.set() in a handler deadlocks if the signal comes while
    # this thread holds the Event's lock inside wait() (a full test run once hung so).
    stop = []
    handlers = {signum: signal.signal(signum, lambda signum, _frame: stop.append(signum))
                for signum in STOP_SIGNALS}
    stop_with_parent()
    try:
        with simulator:
            if simulator.priority_error:
                print(f'kraft_master_sim: warning: {simulator.priority_error}', file=sys.stderr)
            elif args.priority:
                # This thread wakes to look for a stop and shares the interpreter lock with the
                # serving thread: preempted while holding it, it would hold up a reply.
                realtime.set_fifo_priority(max(1, args.priority - 1))
            print(f'port: {simulator.port}', flush=True)
            gc.freeze()  # no full garbage collection passes over the set-up (parameters.run_node)
            while not stop:
                time.sleep(0.5)
            print(f'kraft_master_sim: stopped, {simulator.stats}', file=sys.stderr)
        if args.record:
            np.save(args.record, np.array(
                [(t, *command.counts, -1 if command.sequence is None else command.sequence)
                 for t, command in simulator.received],
                dtype=np.int64).reshape(-1, 7))
    finally:
        for signum, handler in handlers.items():
            signal.signal(signum, handler)
    return 0


if __name__ == '__main__':
    sys.exit(main())
