# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
`make demo` as a user runs it: the demo module with its own processes, its output piped.

A recorder on the demo's DDS domain keeps every message the driver, the bridge and the
simulated arm publish, so that tests check the contact and the reflected force in the messages
themselves as well as in what the demo prints. The demo runs in a session of its own: once it
has exited, no process of that session may be left. The fixture `start_demo` (conftest.py of
test/integration) starts it and ends whatever is left.
"""
import os
import re
import signal
import subprocess
import sys
import threading

from geometry_msgs.msg import PoseStamped, WrenchStamped
from harness import dds_shm, REPO
from harness.driver import AT_A_TERMINAL, next_domain_id, wait_for
from kraft_master_driver.nodes.ros_io import subscribe_raw, take_all
import rclpy
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState


class Recorder:
    """Takes every message of the demo's topics from deep queues, without an executor."""

    TOPICS = (('joint_states', JointState), ('wrench', WrenchStamped),
              ('measured_cp', PoseStamped))

    def __init__(self, domain_id):
        """Subscribe on `domain_id` and start taking in a thread."""
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = rclpy.create_node('demo_recorder', context=self.context)
        self.raw = {topic: [] for topic, _ in self.TOPICS}
        self._subscriptions = [
            (topic, subscribe_raw(self.node, msg_type, topic, lambda _msg: None, 5000))
            for topic, msg_type in self.TOPICS]
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._take_until_stopped)
        self._thread.start()

    def _take_until_stopped(self):
        while not self._stop.wait(0.05):
            for topic, subscription in self._subscriptions:
                self.raw[topic].extend(take_all(subscription))

    def messages(self, topic):
        """Return the messages taken on `topic`, oldest first."""
        msg_type = dict(self.TOPICS)[topic]
        return [deserialize_message(data, msg_type) for data in self.raw[topic]]

    def close(self):
        """Stop taking and leave the domain."""
        self._stop.set()
        self._thread.join()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def session_processes(session_id):
    """Return the ids of the processes in session `session_id`."""
    found = []
    for entry in filter(str.isdigit, os.listdir('/proc')):
        try:
            with open(f'/proc/{entry}/stat') as stat:
                fields = stat.read().rpartition(')')[2].split()
        except (FileNotFoundError, ProcessLookupError):  # it ended meanwhile
            continue
        if int(fields[3]) == session_id:
            found.append(int(entry))
    return found


class Demo:
    """The demo module run as `make demo` runs it, on a DDS domain of its own, output piped."""

    def __init__(self, duration, sigint_ignored=False, arm=None, force_mode=None):
        """
        Start recording, then the demo (`sigint_ignored`: as a background job); read it.

        `arm`, `force_mode`: the demo's --arm and --force-mode options, or None for its default.
        """
        domain_id = next_domain_id()
        self.recorder = Recorder(domain_id)
        # PYTHONFAULTHANDLER: a demo that hangs shows its threads' stacks on SIGABRT.
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id),
                   ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', PYTHONFAULTHANDLER='1')
        command = [sys.executable, '-m', 'kraft_master_driver.tools.demo',
                   '--duration', str(duration), *(['--arm', arm] if arm else []),
                   *(['--force-mode', force_mode] if force_mode else [])]
        if sigint_ignored:
            command = ['sh', '-c', 'trap "" INT; exec "$@"', 'sh', *command]
        command = [*AT_A_TERMINAL, *command]
        self.process = subprocess.Popen(
            command, cwd=REPO, env=env, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT, text=True, start_new_session=True)
        self.lines = []
        self._reader = threading.Thread(target=lambda: self.lines.extend(self.process.stdout))
        self._reader.start()

    def finish(self, timeout=180.0):
        """Wait for the demo to exit; return (exit code, output); fail with both if it hangs."""
        try:
            code = self.process.wait(timeout)
        except subprocess.TimeoutExpired:
            self.process.send_signal(signal.SIGABRT)
            code = self.process.wait(30.0)
            hung = True
        else:
            hung = False
        finally:
            self._reader.join(timeout=30.0)
            self.recorder.close()
        output = ''.join(self.lines)
        assert not hung, f'the demo did not exit within {timeout:g} s; its output:\n{output}'
        return code, output

    def kill(self):
        """Make sure the demo and everything in its session are gone: SIGTERM, then SIGKILL."""
        for pid in session_processes(self.process.pid):
            try:
                os.kill(pid, signal.SIGTERM)
            except ProcessLookupError:
                pass
        try:
            wait_for(lambda: self.process.poll() is not None and not session_processes(
                self.process.pid), timeout=60.0)
        except AssertionError:
            for pid in session_processes(self.process.pid):
                held = dds_shm.held_by(pid)
                try:
                    os.kill(pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
                dds_shm.remove(dds_shm.orphaned(held))
        if self.process.poll() is None:
            self.process.wait()


def readouts(output):
    """
    Return the piped readouts: (seconds, {line label: numbers}) each.

    A line's label ends at its first ')'; a reading not there yet (shown as '-') is left out.
    """
    blocks = []
    for block in re.split(r'\n\n', output):
        match = re.match(r' *([0-9.]+) s \| loop', block)
        if match:
            rows = {}
            for line in block.splitlines()[1:]:
                label, parenthesis, numbers = line.partition(')')
                values = [float(v) for v in re.findall(r'-?\d+\.\d+', numbers)]
                if parenthesis and values:
                    rows[label + parenthesis] = values
            blocks.append((float(match.group(1)), rows))
    return blocks
