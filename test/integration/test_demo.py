# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
`make demo ARM=point-mass` as a user runs it (harness/demo.py runs it and records).

The contact and the reflected force are checked in the messages themselves as well as in what
the demo prints; once the demo has exited, no process of its session may be left. The signal
tests stop `make demo` as it comes, with its default arm, the MuJoCo Panda.
"""
import os
import re
import signal

from harness.demo import readouts, session_processes
from harness.driver import wait_for
from kraft_master_driver.core import kinematics
from kraft_master_driver.nodes.driver_parameters import PARAMETERS as DRIVER_PARAMETERS
from kraft_master_driver.tools.demo import WALL_Z
import numpy as np
import pytest

pytestmark = pytest.mark.integration

DURATION = 12.0  # s of teleoperation: three strokes of the simulated operator's push
FORCE_SCALE = DRIVER_PARAMETERS['force_scale'].default
TORQUE_RESOLUTION = 1.5e-3  # N*m: the device's 1 mN*m counts, on th2 the sum of two
PAIRING_WINDOW = 0.1  # s: a torque matches a wrench stamped this close to its state


def implied_force(jacobian, effort):
    """Return the pure force F (3,) with effort = J^T (F, 0) on th1..th5 (least squares)."""
    return np.linalg.lstsq(jacobian[:3, :5].T, np.asarray(effort)[:5], rcond=None)[0]


def seconds(stamp):
    """Return a header stamp in seconds."""
    return stamp.sec + stamp.nanosec * 1e-9


def test_the_demo_shows_contact_and_reflected_force_and_leaves_nothing(start_demo):
    # Direct force: its torques are J^T F of the wrenches the bridge sent (auto, the demo's
    # default, may render the contact model when a busy machine delays them).
    demo = start_demo(DURATION, arm='point-mass', force_mode='direct')
    code, output = demo.finish()
    assert code == 0, output
    assert not session_processes(demo.process.pid), 'a process of the demo was left behind'

    # The processes' messages are in the log file and were shown above the readouts.
    log_path = re.search(r"The processes' messages go to (\S+), and are shown here", output)[1]
    with open(log_path) as log_file:
        log = log_file.read()
    os.remove(log_path)
    assert 'right Kraft Master on' in log and 'simulated arm in pose mode' in log
    assert 'enable True: ENABLED' in log
    for line in log.splitlines():
        assert line in output
    assert output.rstrip().endswith(f"The processes' messages: {log_path}")

    # What the demo showed: the arm at the wall and the force on the master, within 10 s.
    shown = readouts(output)
    assert shown and shown[-1][0] >= DURATION
    # The demo's own subscriptions may match after the arm reached the wall: '-' until then.
    touching = [t for t, rows in shown if {'arm (mm)', 'wrench on master (N)'} <= rows.keys()
                and rows['arm (mm)'][2] <= 1e3 * WALL_Z
                and rows['wrench on master (N)'][2] > 1.0 and any(rows['torques (N*m)'])]
    assert touching and touching[0] <= 10.0, output

    # What was published: the arm stopped at the wall, which pushed back along +z.
    arm_z = np.array([p.pose.position.z for p in demo.recorder.messages('measured_cp')])
    assert WALL_Z - 0.003 < arm_z.min() < WALL_Z
    forces = np.array([(w.wrench.force.x, w.wrench.force.y, w.wrench.force.z)
                       for w in demo.recorder.messages('wrench')])
    assert forces[:, 2].min() >= 0.0 and forces[:, 2].max() > 1.0
    np.testing.assert_array_equal(forces[:, :2], 0.0)

    # The master's torques are J^T (force_scale F) of that force, with the Jacobian of the
    # state before (the one the driver used), so they push the wrist up, out of the wall.
    # Only torques whose wrenches the recorder can have seen are paired: DDS sometimes matches
    # a late joiner's endpoints one announcement period (about 3 s) after the driver's, and
    # what the bridge sent before then never reached the recorder.
    states = demo.recorder.messages('joint_states')
    wrench_times = np.array([seconds(w.header.stamp) for w in demo.recorder.messages('wrench')])
    recorded_from = wrench_times.min() + PAIRING_WINDOW
    checked = matched = 0
    for previous, state in zip(states, states[1:]):
        if (np.abs(state.effort).max() < 20 * TORQUE_RESOLUTION
                or seconds(state.header.stamp) < recorded_from):
            continue
        force = implied_force(kinematics.jacobian(previous.position), state.effort) / FORCE_SCALE
        assert force[2] > 0.0, 'the torques must push the wrist up, out of the wall'
        assert np.linalg.norm(force[:2]) < 0.05 * force[2] + 0.02
        recent = forces[np.abs(wrench_times - seconds(state.header.stamp)) < PAIRING_WINDOW, 2]
        checked += 1
        if recent.size and np.abs(recent - force[2]).min() < 0.02 * force[2] + 0.02:
            matched += 1
    assert checked >= 100
    assert matched >= 0.95 * checked, f'{matched} of {checked} torques match a wrench sent'


# The demo started from a shell's background job comes with SIGINT ignored; Ctrl-C or a kill -INT
# must stop it all the same.
@pytest.mark.parametrize('sig, sigint_ignored', [(signal.SIGINT, False), (signal.SIGINT, True),
                                                 (signal.SIGTERM, False), (signal.SIGHUP, False)])
def test_a_signal_to_the_demo_stops_every_process(start_demo, sig, sigint_ignored):
    demo = start_demo(600.0, sigint_ignored=sigint_ignored)
    wait_for(lambda: any(' s | loop ' in line for line in demo.lines), timeout=120.0)
    demo.process.send_signal(sig)
    code, output = demo.finish(timeout=60.0)
    assert code == 0, output
    assert not session_processes(demo.process.pid), 'a process of the demo was left behind'
    assert "The processes' messages: " in output.splitlines()[-1]
