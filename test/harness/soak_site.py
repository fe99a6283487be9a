# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The session soak's processes (scripts/teleop_soak.py): both sites, the link, the operator.

Master's site (one DDS domain): the simulated master (soak_master.py, the 'task' operator
hand), the driver on it. Arm's site (another domain): the bridge and the MuJoCo Panda. Between
them a link (LINKS) carries pose and master_energy one way, wrench, slave_energy and
contact_model the other: the link emulator (one process on the master's domain), or two Zenoh
links (one on each domain) paired over TLS on 127.0.0.1, the arm's listening, with
certificates made for the run in a temporary directory that stop() deletes (the Zenoh links
carry clutch too: nothing publishes it on the master's domain). A recorder
(soak_recorder.py) joins both. Every process runs as
`python -m` of this checkout, in a session of its own, its output in a log file; each can be
killed (SIGKILL, its shared memory removed) and started again. The Operator, nodes in this
process, enables the bridge, clutches, and sets the fault switches that are parameters.
Leftovers() says what the run left: processes of its sessions, the simulator's pty directory,
the certificates' directory, Fast DDS shared memory.
"""
import glob
import os
import pathlib
import signal
import socket
import subprocess
import sys
import threading
import time
import traceback

from geometry_msgs.msg import PoseStamped
from harness import certificates, dds_shm, REPO
from harness.demo import session_processes
from harness.driver import ClientNode, next_domain_id, wait_for
from kraft_master_driver.nodes.ros_io import RepeatedRequest, take_newest
from kraft_master_driver.tools.demo import HOME, MUJOCO_BRIDGE, MUJOCO_DRIVER, ros_parameters
import rclpy
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Bool, String
from std_srvs.srv import SetBool

HARNESS = pathlib.Path(__file__).resolve().parent
PYTHON = [sys.executable, '-m']
START_S = 120.0  # a start-up on a loaded machine
STOP_S = 30.0  # a node's own guard ends a stuck shutdown in 10 s
UNANSWERED_S = 5.0  # an enable request the bridge has not answered will not be answered
MAX_DELAY_S = 0.5  # the largest one-way delay step: the driver admits wrenches that old
MAX_WRENCH_AGE_S = 0.1 + MAX_DELAY_S  # the driver's max_wrench_age
# The bridge as the demo runs it on the Panda (2 s timeouts for a loaded machine), passivity on,
# its box 5 cm taller: a stale pose that comes back registers the master wherever the hand is,
# and the arm's height drifts by up to the touch's depth each time.
BRIDGE = {**MUJOCO_BRIDGE, 'passivity': 'true',
          'workspace_max': [*MUJOCO_BRIDGE['workspace_max'][:2],
                            MUJOCO_BRIDGE['workspace_max'][2] + 0.05]}
TOP_OF_STROKE = 0.005  # m from home: the operator registers the master (enable, clutch) there
DRIVER = {**MUJOCO_DRIVER, 'force_enabled_at_start': 'true', 'passivity': 'true',
          'allow_multiple_wrench_sources': 'true'}
RELAYS = {'to_slave.topics': '[pose, master_energy]',
          'to_master.topics': '[wrench, slave_energy, contact_model]'}
LINKS = ('emulator', 'zenoh')
LOCALHOST = '127.0.0.1'
ZENOH_PAIR = 'kraft_master/soak'
# The arm's Zenoh link disables the bridge after this long without a pose: half the bridge's
# master_timeout, as the link's default is half the bridge's default (test_zenoh_link.py too).
ZENOH_ARM = {'stream_timeout': BRIDGE['master_timeout'] / 2}


# The participant ids a process started again takes, from the highest down: under
# ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST rmw_fastrtps announces a participant to ids 0 to 31
# alone (maxInitialPeersRange 32), so two restarted processes above it never find each other.
# First starts take ids from 0 up. Once these are spent, a restart takes the lowest free id.
FRESH_PARTICIPANT_IDS = range(31, 11, -1)
PARTICIPANT_PROFILE = (
    '<?xml version="1.0" encoding="UTF-8" ?>\n'
    '<profiles xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">\n'
    '  <participant profile_name="restarted" is_default_profile="true">\n'
    '    <rtps><participantID>{participant_id}</participantID></rtps>\n'
    '  </participant>\n'
    '</profiles>\n')


def free_port():
    """Return a TCP port of 127.0.0.1 that nothing listens on now."""
    with socket.socket() as probe:
        probe.bind((LOCALHOST, 0))
        return probe.getsockname()[1]


def rss_kib(pid):
    """Return the resident set size of process `pid` in KiB, None if it has ended."""
    try:
        for line in pathlib.Path(f'/proc/{pid}/status').read_text().splitlines():
            if line.startswith('VmRSS:'):
                return int(line.split()[1])
    except (FileNotFoundError, ProcessLookupError):
        pass
    return None


class Child:
    """One process of the session, in a session of its own; it can be killed and restarted."""

    def __init__(self, name, command, env, log_dir, pipes=False):
        """Start `command` in `env`; its output goes to log_dir/<name>.log (`pipes`: stdout)."""
        self.name, self.command, self.env, self.pipes = name, command, env, pipes
        self.log = open(log_dir / f'{name}.log', 'a')
        self.pids = []  # every incarnation's
        self.start()

    def start(self, dds_profile=None):
        """Start (again); with `dds_profile`, a Fast DDS XML profile file for its participant."""
        env = self.env if dds_profile is None else dict(
            self.env, FASTRTPS_DEFAULT_PROFILES_FILE=str(dds_profile))
        self.process = subprocess.Popen(
            self.command, env=env, cwd=REPO, text=True, start_new_session=True,
            stdin=subprocess.PIPE if self.pipes else subprocess.DEVNULL,
            stdout=subprocess.PIPE if self.pipes else self.log, stderr=self.log)
        self.pids.append(self.process.pid)

    def alive(self):
        """Return whether the current incarnation runs."""
        return self.process.poll() is None

    def kill(self):
        """SIGKILL it, as a crash would; remove the shared memory it leaves."""
        held = dds_shm.held_by(self.process.pid)
        self.process.kill()
        self.process.wait(STOP_S)
        dds_shm.remove(dds_shm.orphaned(held))

    def pause(self, paused):
        """Stop (SIGSTOP) or continue (SIGCONT) it: a stalled controller."""
        os.kill(self.process.pid, signal.SIGSTOP if paused else signal.SIGCONT)

    def stop(self, signum=signal.SIGINT):
        """Ask it to stop; SIGKILL after STOP_S. Return the exit code, None if it was killed."""
        if self.process.poll() is not None:
            return self.process.returncode
        # The signal alone: closing stdin first also ends a process that reads it, and a
        # signal that comes while its interpreter finalizes kills it (exit -2).
        self.process.send_signal(signum)
        try:
            return self.process.wait(STOP_S)
        except subprocess.TimeoutExpired:
            self.kill()
            return None
        finally:
            if self.pipes:
                self.process.stdin.close()

    def close(self):
        """Close its log."""
        self.log.close()


class Site:
    """Every process of the session, started in order; stop() ends them all."""

    def __init__(self, work, seed, operator_period=2.0, link='emulator'):
        """Start them, with logs and the bag in `work`; fail naming one that did not come up."""
        assert link in LINKS, f'link {link!r} is not one of {", ".join(LINKS)}'
        self.work, self.link = work, link
        self.master_domain, self.arm_domain = next_domain_id(), next_domain_id()
        base = dict(os.environ, PYTHONPATH=os.pathsep.join(
            filter(None, [str(REPO), str(REPO / 'test'), os.environ.get('PYTHONPATH')])),
            ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', PYTHONUNBUFFERED='1',
            PYTHONFAULTHANDLER='1')
        self.env = {'master': dict(base, ROS_DOMAIN_ID=str(self.master_domain)),
                    'arm': dict(base, ROS_DOMAIN_ID=str(self.arm_domain))}
        self.children = {}
        self._fresh_ids = iter(FRESH_PARTICIPANT_IDS)
        self.certificates = None
        self.watcher = dds_shm.Watcher()
        self.watcher.start()
        try:
            self._start(seed, operator_period)
        except BaseException:
            self.stop()
            self.watcher.stop()
            raise

    def _start(self, seed, operator_period):
        master = self.add('master', [sys.executable, str(HARNESS / 'soak_master.py'),
                                     '--seed', str(seed), '--operator-period',
                                     str(operator_period)], 'master', pipes=True)
        self.port = master.process.stdout.readline().partition('port: ')[2].strip()
        assert self.port, 'the simulated master did not start'
        self.add('driver', [*PYTHON, 'kraft_master_driver.nodes.driver', '--ros-args',
                            '-p', f'port:={self.port}', *ros_parameters(DRIVER),
                            '-p', f'max_wrench_age:={MAX_WRENCH_AGE_S}'], 'master')
        if self.link == 'emulator':
            self.add('link', [*PYTHON, 'kraft_master_driver.nodes.link_emulator', '--ros-args',
                              '-p', f'slave_domain_id:={self.arm_domain}', '-p', f'seed:={seed}',
                              *ros_parameters(RELAYS)], 'master')
        else:
            self._start_zenoh()
        self.add('bridge', [*PYTHON, 'kraft_master_driver.nodes.teleop', '--ros-args',
                            *ros_parameters(BRIDGE)], 'arm')
        self.add('arm', [*PYTHON, 'kraft_master_driver.nodes.arm_sim'], 'arm')
        self.bag = self.work / 'session'
        recorder = self.add('recorder', [sys.executable, str(HARNESS / 'soak_recorder.py'),
                                         '--bag', str(self.bag), '--master-domain',
                                         str(self.master_domain), '--arm-domain',
                                         str(self.arm_domain)], 'master', pipes=True)
        self.recorder_lines = []
        threading.Thread(target=self._read_recorder, args=(recorder.process,),
                         daemon=True).start()

    def _start_zenoh(self):
        """Make the certificates, start the arm's Zenoh link listening, the master's connecting."""
        self.certificates = certificates.Sites(
            {'master': f'IP:{LOCALHOST}', 'arm': f'IP:{LOCALHOST}'}).__enter__()
        endpoint = f'tls/{LOCALHOST}:{free_port()}'
        for side, end in (('arm', {'listen': endpoint}), ('master', {'connect': endpoint})):
            parameters = dict(certificates.link_parameters(
                self.certificates, side, 'arm' if side == 'master' else 'master',
                pair=ZENOH_PAIR, **end))
            if side == 'arm':
                parameters.update(ZENOH_ARM)
            self.add(f'zenoh_{side}', [*PYTHON, 'kraft_master_driver.nodes.zenoh_link',
                                       '--ros-args', *ros_parameters(parameters)], side)

    def add(self, name, command, site, pipes=False):
        """Start a child process on `site` ('master' or 'arm')."""
        self.children[name] = Child(name, command, self.env[site], self.work, pipes)
        return self.children[name]

    def _read_recorder(self, process):
        for line in process.stdout:
            self.recorder_lines.append(line.strip())

    def wait_recording(self):
        """Wait until the recorder has subscribed to every topic of both sites."""
        wait_for(lambda: 'recording' in self.recorder_lines or self.dead(), START_S)
        assert not self.dead(), f'{self.dead()} ended at start-up: see {self.work}'

    def dead(self):
        """Return the names of the children not running."""
        return [name for name, child in self.children.items() if not child.alive()]

    def master_fault(self, fault, on):
        """Switch a fault of the simulated master (soak_master.FAULTS); return its time."""
        process = self.children['master'].process
        process.stdin.write(f'{{"fault": "{fault}", "on": {str(on).lower()}}}\n')
        process.stdin.flush()
        answer = process.stdout.readline().split()
        assert answer and answer[0] == 'ok', f'soak_master: {answer}'
        return float(answer[1])

    def restart(self, name, started):
        """
        SIGKILL a child, start it again; return the kill's time, once started(dead) holds.

        Started again on a DDS participant id no process of the run had (fresh_participant).
        """
        killed = time.time()
        self.children[name].kill()
        dead = time.time()  # what the killed process sent is stamped before this
        self.children[name].start(self.fresh_participant())
        wait_for(lambda: started(dead) or not self.children[name].alive(), START_S)
        assert self.children[name].alive(), f'{name} did not start again: see {self.work}'
        return killed

    def fresh_participant(self):
        """
        Return a Fast DDS profile (a file in the work directory) with a participant id unused.

        From FRESH_PARTICIPANT_IDS; None once they are spent. On the id of the process it
        replaces, and so on its shared-memory port numbers, a restarted process was now and then
        never reached over shared memory on a loaded machine: Fast DDS 2.14 replaced its port's
        file while it listened (doc/safety.md).
        """
        participant_id = next(self._fresh_ids, None)
        if participant_id is None:
            return None
        profile = self.work / f'fastdds_participant_{participant_id}.xml'
        profile.write_text(PARTICIPANT_PROFILE.format(participant_id=participant_id))
        return profile

    def rss(self):
        """Return {name: (pid, KiB)} of the running children."""
        return {name: (child.process.pid, rss_kib(child.process.pid))
                for name, child in self.children.items() if child.alive()}

    def stop(self):
        """Stop every child (the recorder last, to keep the end); return {name: exit code}."""
        order = ['master', 'driver', 'link', 'zenoh_master', 'zenoh_arm', 'bridge', 'arm',
                 'recorder']
        codes = {}
        try:
            for name in order:
                if name in self.children:
                    child = self.children[name]
                    if child.alive():
                        child.pause(False)
                    codes[name] = child.stop(signal.SIGINT)
                    child.close()
        finally:
            if self.certificates is not None:
                self.certificates.__exit__(None, None, None)
        return codes

    def leftovers(self):
        """Return what the run left behind: one line each (none: nothing)."""
        found = []
        for name, child in self.children.items():
            for pid in child.pids:
                found += [f'{name}: process {p} of session {pid} still runs'
                          for p in session_processes(pid)]
        ours = {pid for child in self.children.values() for pid in child.pids}
        for directory in sorted(temp_dirs()):
            # The pty behind the port's symlink: /proc/<the simulator's pid>/fd/<n>.
            link = os.readlink(os.path.join(directory, 'tty')) if os.path.islink(
                os.path.join(directory, 'tty')) else ''
            if directory == os.path.dirname(self.port) or link.split('/')[2:3] in (
                    [str(pid)] for pid in ours):
                found.append(f"the simulator's pty directory {directory} is still there")
        if self.certificates is not None and os.path.exists(os.path.dirname(
                self.certificates.ca)):
            found.append(f"the certificates' directory {os.path.dirname(self.certificates.ca)} "
                         'is still there')
        noted = self.watcher.stop()
        left = dds_shm.orphaned({group for group in noted if '_port' not in group})
        dds_shm.remove(left)
        found += [f'Fast DDS shared memory {group} left (removed now): {noted[group]}'
                  for group in sorted(left)]
        return found


def temp_dirs():
    """Return the simulator's temporary directories there now."""
    return set(glob.glob('/tmp/kraft_master_sim_*'))


class Operator:
    """The operator's hands in ROS: enable, clutch, and the fault switches that are parameters."""

    def __init__(self, site):
        """Join both domains with a node each, spun by a thread of this process."""
        self.master_node = ClientNode(site.master_domain, 'soak_operator_master')
        self.arm_node = ClientNode(site.arm_domain, 'soak_operator_arm')
        node = self.arm_node.node
        reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.state = ''
        node.create_subscription(String, 'operating_state', self._on_state, QoSProfile(
            depth=1, reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL))
        self.arm_stamp = 0.0  # of the newest measured_cp, time.time() s
        node.create_subscription(PoseStamped, 'measured_cp', self._on_arm_pose, QoSProfile(
            depth=1, reliability=ReliabilityPolicy.BEST_EFFORT))
        self.clutch_pub = node.create_publisher(Bool, 'clutch', reliable)
        self.enabling = RepeatedRequest(node.create_client(SetBool, 'enable'), UNANSWERED_S)
        self.parameters = {'arm': AsyncParameterClient(node, '/kraft_master_arm_sim')}
        if site.link == 'emulator':
            self.parameters['link'] = AsyncParameterClient(self.master_node.node,
                                                           '/kraft_master_link_emulator')
        # Not spun: the newest master pose is taken when asked (the demo's Readout does so).
        self._pose_node = rclpy.create_node('soak_operator_eyes', context=self.master_node.context)
        self._pose = self._pose_node.create_subscription(
            PoseStamped, 'pose', lambda _msg: None,
            QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT))
        self._master_z = None
        self._stopping = threading.Event()
        self._lock = threading.Lock()
        self.spin_error = None  # what stopped the spinning thread, if anything did
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _on_state(self, msg):
        self.state = msg.data

    def _on_arm_pose(self, msg):
        self.arm_stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec

    def _spin(self):
        try:
            while not self._stopping.is_set():
                with self._lock:
                    for client in (self.arm_node, self.master_node):
                        client.executor.spin_once(timeout_sec=0.005)
        except Exception as error:  # noqa: B902 - a deaf operator is told, not left silent
            self.spin_error = repr(error)
            traceback.print_exc()

    def at_top_of_stroke(self):
        """Return whether the master's wrist is at home's height, where the task's moves are."""
        pose = take_newest(self._pose)
        if pose is not None:
            self._master_z = pose.pose.position.z
        return self._master_z is not None and abs(self._master_z - HOME[2]) < TOP_OF_STROKE

    def following(self):
        """Return whether the bridge follows the master (ENABLED, not holding)."""
        return self.state == 'ENABLED'

    def enable(self):
        """
        Ask the bridge to enable unless an earlier request is still waiting for its answer.

        A request unanswered for UNANSWERED_S is given up and asked again, as an operator would
        press enable again: it went to a bridge since killed (discovery still listed its
        service), or its answer was lost (ros_io.RepeatedRequest).
        """
        with self._lock:
            self.enabling.ask(SetBool.Request(data=True), lambda _done: None)

    def clutch(self, pressed):
        """Press or release the clutch."""
        self.clutch_pub.publish(Bool(data=pressed))

    def set_parameters(self, node, **values):
        """Set parameters of 'arm' or 'link' (dots written as '__'); fail if one is refused."""
        client = self.parameters[node]
        assert client.wait_for_services(timeout_sec=START_S), f'no parameter service on {node}'
        future = client.set_parameters([Parameter(name.replace('__', '.'), value=value)
                                        for name, value in values.items()])
        try:
            wait_for(future.done, START_S)
        except AssertionError:
            raise AssertionError(f'{node} did not answer set_parameters {values} within '
                                 f'{START_S:g} s') from None
        results = future.result().results
        assert all(r.successful for r in results), [r.reason for r in results]
        return time.time()

    def close(self):
        """Stop spinning and leave both domains."""
        self._stopping.set()
        self._thread.join(timeout=10.0)
        self._pose_node.destroy_node()
        self.arm_node.close()
        self.master_node.close()
