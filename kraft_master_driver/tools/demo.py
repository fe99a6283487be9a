# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
kraft_master_demo: the paper's worked examples, then simulated teleoperation, live.

The driver runs against the simulated hand controller (its own process, on a real
pseudo-terminal), whose simulated operator takes hold when the driver starts and pushes the
wrist 80 mm down and back, 2 s each way. The teleoperation bridge (kraft_master_teleop) maps
the master's pose to a simulated arm and reflects the arm's wrist force reading: by default the
Franka Panda in MuJoCo (kraft_master_arm_sim), whose hand each stroke brings down onto its
table; with --arm point-mass a point mass (kraft_master_slave_sim, ARM below) meeting a stiff
wall 40 mm down. The demo enables the bridge with the master's wrist near its home, the top of
the stroke, so the arm travels the stroke from where it starts, and its contact wrench is
reflected to the master as joint torques. A few refreshed lines show what happens;
the processes' messages go to a log file and are shown above them.
"""
import argparse
import math
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, Vector3Stamped, WrenchStamped
from kraft_master_driver.core import kinematics
from kraft_master_driver.core.calibration import ArmCalibration
from kraft_master_driver.core.force_mode import ForceMode
from kraft_master_driver.core.process import STOP_SIGNALS
from kraft_master_driver.nodes.arm_sim import PARAMETERS as MUJOCO_ARM_PARAMETERS
from kraft_master_driver.nodes.driver_parameters import PARAMETERS as DRIVER_PARAMETERS
from kraft_master_driver.nodes.ros_io import take_all, take_newest
from kraft_master_driver.nodes.slave_sim import PARAMETERS as ARM_PARAMETERS
from kraft_master_driver.simulation.master.model import Workspace
import numpy as np
import rclpy
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from std_srvs.srv import SetBool

SECTION_8_POTS = ((2086, 2683, 992, 1595, 1715, 2025), (2622, 1610, 2268, 1829, 2488, 1745))
# The simulated device answers at the loop's priority, as hardware answers by itself: at the
# normal one, beside the MuJoCo arm and the bridge (1.8 of 2 cores), its replies came late and
# the loop ran at 903 to 978 Hz at the median in ten demos; at this one, 993 to 999 in three.
# Where the OS refuses it, the simulator says so and runs at the normal one.
SIMULATOR = [sys.executable, '-m', 'kraft_master_driver.simulation.master.simulator',
             '--operator', 'push',
             '--priority', str(DRIVER_PARAMETERS['loop_priority'].default)]
DRIVER = [sys.executable, '-m', 'kraft_master_driver.nodes.driver', '--ros-args',
          '-p', 'force_enabled_at_start:=true']
# The simulated arm behind the bridge: any node that takes servo_cp and publishes measured_cp
# and measured_cf (frames base_link and ft_sensor, the bridge's defaults) can stand here.
ARM = [sys.executable, '-m', 'kraft_master_driver.nodes.slave_sim']
WALL_Z = ARM_PARAMETERS['wall.point'][0][2]  # m, the arm's wall below its start at 0
# `--arm mujoco`: the Franka Panda in MuJoCo (doc/arm-sim.md), its fingertips 37 mm above the
# table top at the start.
MUJOCO_ARM = [sys.executable, '-m', 'kraft_master_driver.nodes.arm_sim']
TABLE_Z = MUJOCO_ARM_PARAMETERS['table.height'].default  # m, the table top
# The bridge: scale 1, the arm's force reflected one to one (as the earlier simulated slave
# did itself), its slave port's energy at the arm's 500 Hz; the point-mass arm's tool keeps
# its orientation. Its timeouts allow a loaded machine's stalls (a stale pose would register
# the master anew, shifting the arm's stroke; at 0.5 s a stale measured_cp faulted the bridge
# with the machine's load average at 27 on 2 cores), and its tracking limit the wall: the
# stroke commands the arm up to 40 mm past it.
BRIDGE = {'rate_hz': 500.0, 'orientation': 'fixed', 'master_timeout': 2.0, 'arm_timeout': 2.0,
          'ft_timeout': 2.0, 'max_tracking_error': 0.2}
# The bridge for the Panda (teleop.launch.py's too): the hand's weight beyond its sensor taken
# out of the reading (the arm node logs both figures), the target kept in a box in front of the
# arm, within its reach hand down, that reaches 5 cm into the table. Its stroke down from the
# start commands the hand 43 mm past the top, pressing the table with the controller's 1000 N/m.
# The dead band keeps the sensor's reading of the hand's own inertia (0.3 N: 1 kg at 0.3 m/s^2)
# off the master.
MUJOCO_BRIDGE = {**BRIDGE, 'tool_mass': 1.0045, 'tool_com': [0.0, -0.0005, 0.0431],
                 'force_deadband': 0.3,
                 'arm_stiffness': MUJOCO_ARM_PARAMETERS['translational_stiffness'].default,
                 'workspace_min': [0.2, -0.3, 0.35], 'workspace_max': [0.5, 0.3, 0.55]}
# The driver for the Panda (teleop.launch.py's too): a damper as strong as the force felt
# keeps the table's contact, reflected through the arm's lag, still at 2500 and 5000 N/m too.
MUJOCO_DRIVER = {'contact_damping': 6.0}
TELEOP = [sys.executable, '-m', 'kraft_master_driver.nodes.teleop', '--ros-args']
DRIVER_NAME = 'kraft_master_node'
MAX_WRENCH_AGE_S = DRIVER_PARAMETERS['max_wrench_age'].default
HOME = kinematics.forward(Workspace().home(), 'right')[:3, 3]  # the push's top
ENGAGE_DISTANCE = 0.005  # m from HOME within which the demo enables the bridge
START_TIMEOUT = 60.0  # s for the driver, the bridge and the arm to come up and be enabled
REFRESH = {True: 0.1, False: 1.0}  # s between readouts on a terminal, and piped
ENGAGE_REFRESH = 0.02  # s between looks at the master's pose until the bridge is enabled
EMULATOR = [sys.executable, '-m', 'kraft_master_driver.nodes.link_emulator', '--ros-args',
            '-p', 'to_slave.topics:=[pose, master_energy]',
            '-p', 'to_master.topics:=[wrench, slave_energy, contact_model]']


def ros_parameters(parameters):
    """Return `parameters` ({name: value}) as the -p arguments of a node's command line."""
    return [argument for name, value in parameters.items()
            for argument in ('-p', f'{name}:={value}')]


def _rows(matrix, scales):
    return '\n'.join('    ' + ' '.join(f'{v * s:9.3f}' for v, s in zip(row, scales))
                     for row in matrix)


def print_examples(out=sys.stdout):
    """Print Section 8: pot counts -> joint angles -> 0T6 and 0J (mm in the printout)."""
    calibration = ArmCalibration.nominal('right')
    for number, pots in enumerate(SECTION_8_POTS, start=1):
        theta = calibration.pots_to_joints(pots)
        pose, jac = kinematics.forward_and_jacobian(theta)
        print(f'Section 8, example {number} (right arm): POT = {pots}', file=out)
        print('  th (deg) = ' + ', '.join(f'{math.degrees(t):.2f}' for t in theta), file=out)
        print('  0T6 (position in mm):', file=out)
        print(_rows(pose[:3], (1, 1, 1, 1000)), file=out)
        print('  0J (rows v in mm/rad, then w in rad/rad):', file=out)
        print(_rows(jac[:3], (1000,) * 6), file=out)
        print(_rows(jac[3:], (1,) * 6), file=out)
        print(file=out)


class Readout:
    """
    Client nodes that take the newest message of each topic when asked, never spinning.

    Depth-1 subscriptions hold only the newest message, and nothing in this process wakes for
    the 1 kHz topics: a refresh takes what is there (nodes/ros_io.py). One node listens on the
    driver's domain, one on the bridge's (the same unless the link emulator is between them),
    where it also calls the bridge's `enable`.
    """

    def __init__(self, bridge_domain, mujoco=False):
        """
        Subscribe to the driver's state and diagnostics, the arm's pose, the bridge's state.

        `mujoco`: the arm is the MuJoCo Panda, which also publishes the table's force on its
        hand (table_force, on the bridge's domain).
        """
        self.mujoco = mujoco
        rclpy.init(signal_handler_options=SignalHandlerOptions.NO)  # Ctrl-C is ours
        self.node = rclpy.create_node('kraft_master_demo')
        self.arm_context = rclpy.Context()
        rclpy.init(context=self.arm_context, domain_id=bridge_domain,
                   signal_handler_options=SignalHandlerOptions.NO)
        self.arm_node = rclpy.create_node('kraft_master_demo_arm', context=self.arm_context)
        self.enabler = rclpy.create_node('kraft_master_demo_enable', context=self.arm_context)
        self.enable_client = self.enabler.create_client(SetBool, 'enable')
        self._answered = False  # whether the bridge answered an enable call yet
        self.executor = rclpy.executors.SingleThreadedExecutor(context=self.arm_context)
        self.executor.add_node(self.enabler)
        self.latest = {}
        self.driver_status = {}
        state_qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                               durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self._subscriptions = [
            node.create_subscription(
                msg_type, topic, lambda _msg: None,
                qos or QoSProfile(depth=depth, reliability=ReliabilityPolicy.BEST_EFFORT),
                event_callbacks=SubscriptionEventCallbacks(use_default_callbacks=False))
            for node, msg_type, topic, depth, qos in (
                (self.node, JointState, 'joint_states', 1, None),
                (self.node, PoseStamped, 'pose', 1, None),
                (self.node, WrenchStamped, 'wrench', 1, None),
                (self.node, DiagnosticArray, '/diagnostics', 10, None),
                (self.arm_node, PoseStamped, 'measured_cp', 1, None),
                (self.arm_node, String, 'operating_state', 1, state_qos),
                *([(self.arm_node, Vector3Stamped, 'table_force', 1, None)] if mujoco
                  else []))]

    def take(self):
        """Take the newest message of each topic, and the driver's newest status."""
        for subscription in self._subscriptions:
            topic = subscription.topic_name
            if topic == '/diagnostics':  # each array: the driver's status is in some only
                for array in take_all(subscription):
                    self._keep_statuses(array)
            elif (message := take_newest(subscription)) is not None:
                self.latest[topic] = message

    def _keep_statuses(self, array):
        for status in array.status:
            if status.name.partition(': ')[0].rpartition('/')[2] == DRIVER_NAME:
                self.driver_status = {kv.key: kv.value for kv in status.values}

    def bridge_state(self):
        """Return the bridge's operating state ('ENABLED', ...), or None before it came."""
        state = self.latest.get('/operating_state')
        return state.data.partition(':')[0] if state is not None else None

    def engage(self):
        """Call enable once the master's wrist is near HOME; return whether the call succeeded."""
        pose = self.latest.get('/pose')
        if pose is None or not self.enable_client.service_is_ready():
            return False
        # Every readout line matched first, so that the wrench shows from the first contact.
        if not all(s.get_publisher_count() for s in self._subscriptions):
            return False
        # The bridge registers the master where it is when the request comes, so the request
        # must come at once. A first call can come late: the bridge may not have discovered
        # this client yet (0.1 to 0.45 s here, once 3 s, which registered the master 50 mm
        # below HOME). So a first call, `enable false`, which leaves a disabled bridge as it
        # is, opens the way: once it is answered, calls come in a few milliseconds.
        if not self._answered:
            self._answered = self._call_enable(False) is not None
            return False
        p = pose.pose.position
        if np.linalg.norm(np.array([p.x, p.y, p.z]) - HOME) > ENGAGE_DISTANCE:
            return False
        # Refused while an input is not fresh yet (the bridge logs why): tried again.
        response = self._call_enable(True)
        return response is not None and response.success

    def _call_enable(self, data):
        """Call the bridge's enable with `data`; return its answer, None if none in 10 s."""
        future = self.enable_client.call_async(SetBool.Request(data=data))
        self.executor.spin_until_future_complete(future, timeout_sec=10.0)
        return future.result()

    def running(self):
        """Return True once the driver's state and the arm's pose have come."""
        return '/joint_states' in self.latest and '/measured_cp' in self.latest

    def lines(self, seconds):
        """Return the readout, a few lines, at `seconds` of teleoperation."""
        latest, status = self.latest, self.driver_status
        if not self.running():
            return ['waiting for the driver, the bridge and the arm ...']
        state = latest['/joint_states']
        p = latest['/pose'].pose.position if '/pose' in latest else None
        wrench = latest['/wrench'].wrench.force if '/wrench' in latest else None
        arm = latest['/measured_cp'].pose.position
        link_errors = sum(int(status.get(f'link {k}', 0)) for k in (
            'timeouts', 'bad_crc', 'garbage_bytes', 'truncated', 'link_faults'))
        if self.mujoco:
            table = latest['/table_force'].vector if '/table_force' in latest else None
            arm_lines = [
                f'Panda (mm)        {1e3 * arm.x:7.1f} {1e3 * arm.y:7.1f} {1e3 * arm.z:7.1f}'
                f'   (table top at z = {1e3 * TABLE_Z:.1f})',
                'table on hand (N)   ' + (f'{table.x:7.2f} {table.y:7.2f} {table.z:7.2f}'
                                          if table else '-')]
        else:
            arm_lines = [f'arm (mm)          {1e3 * arm.x:7.1f} {1e3 * arm.y:7.1f} '
                         f'{1e3 * arm.z:7.1f}   (wall at z = {1e3 * WALL_Z:.1f})']
        return [
            f'{seconds:5.1f} s | loop {status.get("loop rate (Hz)", "-")} Hz, period p99 '
            f'{status.get("period p99 (ms)", "-")} ms | link errors {link_errors} | '
            f'force {status.get("force state", "-")} | bridge {self.bridge_state() or "-"}',
            'joints (deg)    ' + ' '.join(f'{math.degrees(v):8.2f}' for v in state.position),
            'torques (N*m)   ' + ' '.join(f'{v:8.3f}' for v in state.effort),
            'master wrist (mm) ' + (f'{1e3 * p.x:7.1f} {1e3 * p.y:7.1f} {1e3 * p.z:7.1f}'
                                    if p else '-'),
            *arm_lines,
            'wrench on master (N) ' + (f'{wrench.x:7.2f} {wrench.y:7.2f} {wrench.z:7.2f}'
                                       if wrench else '-'),
        ]

    def close(self):
        """Leave ROS."""
        self.executor.shutdown()
        for node in (self.enabler, self.arm_node, self.node):
            node.destroy_node()
        rclpy.try_shutdown(context=self.arm_context)
        rclpy.try_shutdown()


class ProcessLog:
    """One file for the messages of the demo's processes; new lines are read from it."""

    def __init__(self):
        """Create the file in the temporary directory."""
        descriptor, self.path = tempfile.mkstemp(prefix='kraft_master_demo_', suffix='.log')
        os.close(descriptor)
        self.file = open(self.path, 'a')  # appends: the processes share it
        self._reader = open(self.path)
        self._partial = ''

    def new_lines(self):
        """Return the complete lines written since the last call."""
        lines = (self._partial + self._reader.read()).split('\n')
        self._partial = lines.pop()
        return lines

    def close(self):
        """Close both ends; the file stays."""
        self.file.close()
        self._reader.close()


class Screen:
    """Writes log lines and readouts: on a terminal the readout stays below, refreshed."""

    def __init__(self, out):
        """Write to `out`; refresh in place if it is a terminal."""
        self.out = out
        self.interactive = out.isatty()
        self._shown = 0
        self._last = None

    def show(self, log_lines, readout):
        """Write the new log lines, then the readout (in place of the last one on a terminal)."""
        if self.interactive:
            width = shutil.get_terminal_size().columns - 1
            readout = [line[:width] for line in readout]
            if self._shown:
                self.out.write(f'\x1b[{self._shown}F\x1b[J')  # back over the last readout
            self._shown = len(readout)
        elif readout == self._last:
            readout = []  # piped, a readout that says nothing new is not repeated
        else:
            self._last = readout
            readout = [''] + readout if readout else []
        self.out.write(''.join(line + '\n' for line in log_lines + readout))
        self.out.flush()

    def keep(self):
        """Leave the last readout as it is: what follows goes below it."""
        self._shown = 0


def cpu_seconds(pid):
    """Return the user + system CPU seconds process `pid` has used (Linux /proc)."""
    with open(f'/proc/{pid}/stat') as stat:
        fields = stat.read().rpartition(')')[2].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def stop(processes):
    """Ctrl-C each process in turn (the driver first: it zeroes the device's torques)."""
    for process in processes:
        if process.poll() is None:
            process.send_signal(signal.SIGINT)
        try:
            process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


def _stop_on_signal(*_):
    raise KeyboardInterrupt


def bridge_passivity(passivity, force_mode):
    """
    Return whether the bridge's slave port is on, the driver's passivity and force_mode given.

    The port guards a force that crosses the link: with the contact model (force_mode other
    than 'direct', which with passivity on is the model at any round trip) none does, and the
    port would only starve the arm (doc/passivity.md).
    """
    return passivity and force_mode == ForceMode.DIRECT


def teleoperate(duration, out=sys.stdout, delay_ms=0.0, passivity=False, arm='mujoco',
                force_mode='auto'):
    """
    Run the processes for `duration` s once all are up (or until Ctrl-C), showing them.

    With delay_ms > 0 the bridge and the arm run on the next DDS domain and the link emulator
    relays between it and the driver's with half of delay_ms each way; passivity turns on the
    driver's master port, and the bridge's slave port with force_mode 'direct'. `arm`: 'point-mass'
    (kraft_master_slave_sim) or 'mujoco' (kraft_master_arm_sim, with the bridge it needs).
    force_mode: the driver's (direct, model or auto; doc/force-feedback.md).
    """
    mujoco = arm == 'mujoco'
    log = ProcessLog()
    print(f"The processes' messages go to {log.path}, and are shown here.", file=out,
          flush=True)
    child = {'stdin': subprocess.DEVNULL, 'stderr': log.file,
             'env': dict(os.environ, PYTHONUNBUFFERED='1')}
    simulator = subprocess.Popen(SIMULATOR, stdout=subprocess.PIPE, text=True, **child)
    processes = [simulator]
    screen = Screen(out)
    # SIGTERM and SIGHUP (a closed terminal, unless under nohup) stop the demo as Ctrl-C does,
    # and Ctrl-C stops it even where it came ignored (a shell's background job ignores it).
    previous = {signum: signal.signal(signum, _stop_on_signal) for signum in STOP_SIGNALS}
    readout = None
    try:
        port = simulator.stdout.readline().partition('port: ')[2].strip()
        if not port:
            screen.show(log.new_lines(), ['the simulator did not start'])
            return 1
        passive = ['-p', f'passivity:={str(passivity).lower()}']
        arm_passive = ['-p', f'passivity:={str(bridge_passivity(passivity, force_mode)).lower()}']
        mode = ['-p', f'force_mode:={force_mode}']
        # The wrench reaches the driver one way's delay after its stamp: admit that much more.
        wrench_age = ['-p', f'max_wrench_age:={MAX_WRENCH_AGE_S + delay_ms / 2e3}']
        arm_child = child
        bridge_domain = int(os.environ.get('ROS_DOMAIN_ID', '0'))
        if delay_ms > 0.0:
            bridge_domain = (bridge_domain + 1) % 233
            arm_child = dict(child, env=dict(child['env'], ROS_DOMAIN_ID=str(bridge_domain)))
            one_way = delay_ms / 2e3
            processes.append(subprocess.Popen(
                [*EMULATOR, '-p', f'slave_domain_id:={bridge_domain}',
                 '-p', f'to_slave.delay:={one_way}', '-p', f'to_master.delay:={one_way}'],
                stdout=log.file, **child))
        processes[:0] = [
            subprocess.Popen([*DRIVER, '-p', f'port:={port}', *passive, *mode, *wrench_age,
                              *ros_parameters(MUJOCO_DRIVER if mujoco else {})],
                             stdout=log.file, **child),
            subprocess.Popen([*TELEOP, *ros_parameters(MUJOCO_BRIDGE if mujoco else BRIDGE),
                              *arm_passive],
                             stdout=log.file, **arm_child),
            subprocess.Popen(MUJOCO_ARM if mujoco else ARM, stdout=log.file, **arm_child)]
        readout = Readout(bridge_domain, mujoco)
        return _show(readout, processes, duration, log, screen)
    except KeyboardInterrupt:
        return 0
    finally:
        # Another stop signal must not cut the stopping short.
        for signum in STOP_SIGNALS:
            signal.signal(signum, signal.SIG_IGN)
        if readout is not None:
            readout.close()
        stop(processes)
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        screen.keep()
        screen.show(log.new_lines(), [])
        log.close()
        print(f"The processes' messages: {log.path}", file=out, flush=True)


def _show(readout, processes, duration, log, screen):
    """Refresh the readout until `duration` s after the bridge was enabled; return the code."""
    started = shown = time.monotonic()
    up = None
    while up is None or time.monotonic() - up < duration:
        time.sleep(REFRESH[screen.interactive] if up is not None else ENGAGE_REFRESH)
        readout.take()
        if up is None and readout.running() and readout.engage():
            up = time.monotonic()
            cpu = [cpu_seconds(p.pid) for p in processes], time.process_time()
        now = time.monotonic()
        if up is None and now - shown < REFRESH[screen.interactive]:
            continue  # looking for the moment to enable: the readout at its own pace
        shown = now
        if any(process.poll() is not None for process in processes):
            screen.show(log.new_lines(), ['a demo process ended early; see its messages'])
            return 1
        if up is None and now - started > START_TIMEOUT:
            screen.show(log.new_lines(), [f'the bridge was not enabled within '
                                          f'{START_TIMEOUT:g} s'])
            return 1
        screen.show(log.new_lines(), readout.lines(0.0 if up is None else now - up))
    elapsed = time.monotonic() - up
    shares = [100.0 * (cpu_seconds(p.pid) - before) / elapsed
              for p, before in zip(processes, cpu[0])]
    readout_share = 100.0 * (time.process_time() - cpu[1]) / elapsed
    screen.keep()
    screen.show([f'CPU over {elapsed:.0f} s, % of a core: driver {shares[0]:.0f}, bridge '
                 f'{shares[1]:.0f}, arm {shares[2]:.0f}, simulator {shares[3]:.0f}, readout '
                 f'{readout_share:.0f}'], [])
    return 0


def main(argv=None):
    """Print the examples and run the teleoperation demo."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--duration', type=float, default=20.0,
                        help='seconds of teleoperation once the bridge is enabled '
                             '(default 20); Ctrl-C ends it earlier')
    parser.add_argument('--delay-ms', type=float, default=0.0,
                        help='round trip between the driver and the bridge through the link '
                             'emulator')
    parser.add_argument('--passivity', choices=('on', 'off'), default='off',
                        help="time-domain passivity: the driver's, and the bridge's with "
                             '--force-mode direct (default off)')
    parser.add_argument('--force-mode', choices=tuple(ForceMode), default='auto',
                        help="what the operator feels: 'direct', the arm's wrench; 'model', the "
                             "arm's contact model rendered by the driver; 'auto' (default), "
                             'chosen by the measured round trip (doc/force-feedback.md)')
    parser.add_argument('--arm', choices=('mujoco', 'point-mass'), default='mujoco',
                        help="the simulated arm: 'mujoco' (default), the Franka Panda on its "
                             "table, or 'point-mass', a point mass against a wall")
    args = parser.parse_args(argv)
    print_examples()
    panda = ' on the MuJoCo Franka Panda' if args.arm == 'mujoco' else ''
    print(f'Simulated teleoperation{panda} for {args.duration:g} s (Ctrl-C to stop) ...',
          flush=True)
    return teleoperate(args.duration, delay_ms=args.delay_ms,
                       passivity=args.passivity == 'on', arm=args.arm,
                       force_mode=args.force_mode)


if __name__ == '__main__':
    sys.exit(main())
