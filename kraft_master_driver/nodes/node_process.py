# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The life of a node's process: command line, start-up, spin, shutdown, exit code.

run_node() answers --help, checks the params files before rcl reads them (one line naming the
file, the line and the fault), turns every refusal into one line on stderr and exit code 1, and
ends the process if its shutdown hangs.

However a node is asked to stop, it stops the same way and exits 0: SIGINT (Ctrl-C), SIGTERM
(systemd, docker stop, a launch), SIGHUP (its terminal closed, unless it was started under
`nohup`), and the SIGTERM the kernel sends when its parent dies (core.process.stop_with_parent).
The first of these ends the spin; those that follow are ignored, so that a second Ctrl-C cannot
cut short the node's own stop (the driver's zero-torque command, the closing of its port and of
its simulator). A stop signal that came while the console script was still importing the node
(nodes.commands) ends it before it starts anything. A shutdown stuck for SHUTDOWN_LIMIT_S, in
C or in Python, ends with every thread's stack on stderr and exit 1. SIGUSR1 prints every
thread's stack to stderr and changes nothing else: `kill -USR1 <pid>` shows where a node that
seems stuck or deaf is (faulthandler, no interpreter lock needed).
"""
import contextlib
import faulthandler
import gc
import os
import re
import signal
import sys
import threading
import time

from kraft_master_driver.core.process import (
    stop_signal_remembered, STOP_SIGNALS, stop_with_parent)
from kraft_master_driver.nodes.parameters import ParameterError, read_params_file, usage
from kraft_master_driver.nodes.ros_io import RCLError
import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.signals import install_signal_handlers, SignalHandlerOptions
import rclpy.utilities

# Seconds a node's shutdown may take before _guard_shutdown ends its process with exit 1.
SHUTDOWN_LIMIT_S = 10.0
# Seconds rclpy's signal thread may take to wake the executors and shut the contexts down.
RCLPY_SIGNAL_WAIT_S = 5.0


def ros_argument_files(argv):
    """Return the --params-file paths among the --ros-args of a command line."""
    paths, in_ros_args, arguments = [], False, iter(argv)
    for argument in arguments:
        if argument == '--ros-args':
            in_ros_args = True
        elif argument == '--':
            in_ros_args = False
        elif in_ros_args and argument == '--params-file':
            paths.append(next(arguments, ''))
    return paths


def _program_arguments(argv):
    """Return the arguments of a command line that are not ROS arguments; refuse bad ROS ones."""
    try:
        return rclpy.utilities.remove_ros_args(argv)[1:]
    except RuntimeError as error:
        # rclpy's RCLInvalidROSArgsError (`-p name:=` with no value) or UnknownROSArgsError,
        # neither with a public name; before rclpy.init, run_node took them for a stop signal.
        raise ParameterError(f'bad ROS arguments: {_rcl_reason(error)}') from None


def _rcl_reason(error):
    """Return the message of an rcl start-up error without rcl's source locations."""
    text = str(error)
    text = text.split("Couldn't parse params file: ", 1)[-1]
    text = re.sub(r'(\. Error: error not set)?, at [^,]*\.c:\d+', '', text)
    return text.replace('failed to initialize rcl: ', '').replace(
        'Failed to parse ROS arguments: ', '')


def run_node(make_node, program, summary, table, args=None):
    """
    Spin the node make_node(params_files) returns until asked to stop; return the exit code.

    --help prints the usage and returns 0 without starting anything; a bad params file, an
    argument that is not a ROS argument, or a bad parameter prints one line and returns 1. A
    stop signal (see the module's docstring) returns 0, during start-up too. A shutdown that
    hangs ends the process with exit 1 (_guard_shutdown).
    """
    argv = sys.argv if args is None else args
    own = argv[1:argv.index('--ros-args')] if '--ros-args' in argv else argv[1:]
    if '-h' in own or '--help' in own:
        print(usage(program, summary, table))
        return 0
    stop_request = StopRequest()
    stop_with_parent()
    faulthandler.register(signal.SIGUSR1, all_threads=True)
    node = None
    exit_code = 0
    try:
        stop_request.raise_from_now_on()
        params_files = [read_params_file(path) for path in ros_argument_files(argv)]
        extra = _program_arguments(argv)
        if extra:
            raise ParameterError(f'unexpected argument {extra[0]!r}: ROS arguments go after '
                                 f'--ros-args (see {program} --help)')
        try:
            rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
        except RCLError as error:
            raise ParameterError(f'cannot start: {_rcl_reason(error)}') from None
        # The executor is made before rclpy's signal handlers are in (they shut the context
        # down) and with the KeyboardInterrupt held: either stopped its constructor half-way,
        # and the half-made executor's __del__ printed a traceback (2 stops in 8 at start-up).
        with stop_request.deferred():
            executor = rclpy.get_global_executor()
        install_signal_handlers(SignalHandlerOptions.ALL)
        stop_request.rclpy_handles_signals = True
        node = make_node(params_files)
        # The set-up's objects live as long as the process: leave them out of garbage
        # collection, whose full passes over them took 13 ms here (benchmarks/messages.py).
        gc.freeze()
        stop_request.leave_to_rclpy(executor)
        rclpy.spin(node, executor)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except RuntimeError:
        # A signal can shut the context down while the executor takes a message.
        if rclpy.ok():
            raise
    except ParameterError as error:
        print(f'{program}: {error}', file=sys.stderr)
        exit_code = 1
    finally:
        stop_request.received = True  # from here on, a signal changes nothing
        _guard_shutdown()
        if stop_request.seen_by_rclpy:
            _wait_for_rclpy_signal_thread()
        stop_request.end_waking()
        if node is not None:
            node.destroy_node()  # the driver's zeroes the torques and closes its port first
        try_shutdown()
        faulthandler.cancel_dump_traceback_later()
        stop_request.ignore_from_now_on()
    return exit_code


class StopRequest:
    """
    The signals that ask a node to stop: the first ends the spin, later ones change nothing.

    Until the node spins, the first raises KeyboardInterrupt once raise_from_now_on() is called,
    inside run_node's try: one that came earlier (nodes.commands remembers those that came
    before these handlers) is raised by that call. Once it spins, rclpy's handlers end the spin
    and this one wakes it (leave_to_rclpy): a KeyboardInterrupt raised inside a callback,
    between a lock's acquire and the `with` that releases it, left that lock held, and the link
    emulator's stop waited on it until the shutdown guard ended it with exit 1 (once in a
    fresh-clone run).

    SIGINT and SIGTERM are also caught by rclpy.init's handlers, which wake the executor and
    then call these. rclpy leaves SIGHUP alone, and Python runs a handler only once the main
    thread wakes: a thread of its own waits for SIGHUP (Python writes each signal's number to
    a wake-up pipe) and sends it on as SIGTERM.
    """

    def __init__(self):
        """Install the handlers (before rclpy.init, which calls them from its own)."""
        self.received = False
        self._raising = False
        self.rclpy_handles_signals = False
        self.seen_by_rclpy = False
        self._signalled = threading.Event()
        self._executor = None
        # Started before the node raises its own threads' priorities, so that it keeps the
        # default one (a thread inherits its maker's).
        self._waker = threading.Thread(target=self._wake_once_shut, name='stop_waker',
                                       daemon=True)
        self._waker.start()
        for signum in STOP_SIGNALS:
            signal.signal(signum, self._on_signal)
        if stop_signal_remembered():
            self.received = True
        if signal.SIGHUP in STOP_SIGNALS:
            read_end, write_end = os.pipe()
            os.set_blocking(write_end, False)
            signal.set_wakeup_fd(write_end, warn_on_full_buffer=False)
            threading.Thread(target=self._hangup_as_sigterm, args=(read_end,), name='sighup',
                             daemon=True).start()

    def raise_from_now_on(self):
        """Raise KeyboardInterrupt for the first signal, now if it has come already."""
        self._raising = True
        if self.received:
            raise KeyboardInterrupt

    def leave_to_rclpy(self, executor):
        """Raise nothing from now on: rclpy's handlers end the spin; then wake `executor`."""
        self._executor = executor
        self._raising = False

    def end_waking(self):
        """Return once the thread that wakes the executor (if a signal came) has ended."""
        self._signalled.set()
        self._waker.join()

    def _wake_once_shut(self):
        # rclpy's signal thread wakes the executor before it shuts the context down: an executor
        # that looked in between, with nothing else to do, waited for good (2 stops in 20).
        # Not in the handler: it runs in the main thread, which may hold the context's lock.
        self._signalled.wait()
        if self.seen_by_rclpy and self._executor is not None:
            _wait_for_rclpy_signal_thread()
            self._executor.wake()

    @contextlib.contextmanager
    def deferred(self):
        """Hold the first signal's KeyboardInterrupt while the block runs; raise it after."""
        self._raising = False
        try:
            yield
        finally:
            self.raise_from_now_on()

    def ignore_from_now_on(self):
        """Ignore the signals: the interpreter's exit would restore their default, fatal one."""
        self.received = True
        for signum in STOP_SIGNALS:
            signal.signal(signum, signal.SIG_IGN)

    def _on_signal(self, _signum, _frame):
        if not self.received:
            self.received = True
            self.seen_by_rclpy = self.rclpy_handles_signals
            if self._raising:
                raise KeyboardInterrupt
            self._signalled.set()

    @staticmethod
    def _hangup_as_sigterm(read_end):
        while int(signal.SIGHUP) not in os.read(read_end, 64):
            pass
        os.kill(os.getpid(), signal.SIGTERM)


def try_shutdown(context=None):
    """Shut `context` (the default one if None) down unless it is already."""
    try:
        rclpy.try_shutdown(context=context)
    except RCLError:
        # rclpy's own signal handler can shut the context down between try_shutdown's
        # check and its call (a parent's SIGTERM on a loaded machine did).
        if rclpy.ok(context=context):
            raise


def _wait_for_rclpy_signal_thread():
    """
    Wait until rclpy's signal thread has handled the stop signal: the default context is shut.

    That thread triggers every executor's signal guard condition, with no lock, then shuts the
    contexts down. An executor shut down meanwhile frees its guard condition and the list the
    thread walks: the link emulator, stopping its second executor, died of SIGSEGV so when the
    thread ran late, after Python's KeyboardInterrupt had started the node's shutdown (once in a
    fresh-clone run with a busy loop per core; 15 stops in 45 with the thread made late on
    purpose, 0 in 75 after this change).
    """
    deadline = time.monotonic() + RCLPY_SIGNAL_WAIT_S
    while rclpy.ok() and time.monotonic() < deadline:
        time.sleep(0.001)


def _guard_shutdown():
    """
    End the process with exit 1 if its shutdown outlasts SHUTDOWN_LIMIT_S, every stack dumped.

    The guard is faulthandler's watchdog, a C thread that needs no interpreter lock: a call
    stuck in C keeps that lock (Fast DDS's destroy_participant under destroy_node did, once in
    about 30 stops), so a Python timer would never fire. At the limit it writes `Timeout
    (0:00:10)!` and each thread's stack, the main thread's naming the stage that hangs, to
    stderr, then calls _exit(1). Output still buffered in Python is lost then: flushed here.
    """
    sys.stdout.flush()
    sys.stderr.flush()
    faulthandler.dump_traceback_later(SHUTDOWN_LIMIT_S, exit=True)
