# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
`make demo` as a user runs it: the demo with its default arm, the MuJoCo Panda, behind the bridge.

The simulated operator pushes the master's wrist down; the Panda's hand must come down onto
its table and the master feel the table's push, in what the demo prints and in the messages
themselves; once the demo has exited, no process of its session may be left.
"""
import os
import re

from harness.demo import readouts, session_processes
from kraft_master_driver.tools.demo import TABLE_Z
import numpy as np
import pytest

pytestmark = pytest.mark.integration

DURATION = 12.0  # s of teleoperation: three strokes of the simulated operator's push
TABLE_SINK = 0.005  # m: the table top gives on its spring under the hand's push


def test_the_mujoco_demo_puts_the_hand_on_the_table_and_the_master_feels_it(start_demo):
    demo = start_demo(DURATION, arm='mujoco')
    code, output = demo.finish()
    assert code == 0, output
    assert not session_processes(demo.process.pid), 'a process of the demo was left behind'

    log_path = re.search(r"The processes' messages go to (\S+), and are shown here", output)[1]
    with open(log_path) as log_file:
        log = log_file.read()
    os.remove(log_path)
    assert 'right Kraft Master on' in log and 'Panda at' in log
    assert 'enable True: ENABLED' in log
    assert 'on the MuJoCo Franka Panda' in output

    # What the demo showed: the Panda's hand on the table top, the table pushing it up and the
    # master feeling that push, within 10 s.
    shown = readouts(output)
    assert shown and shown[-1][0] >= DURATION
    touching = [t for t, rows in shown
                if {'Panda (mm)', 'table on hand (N)', 'wrench on master (N)'} <= rows.keys()
                and rows['Panda (mm)'][2] <= 1e3 * TABLE_Z
                and rows['table on hand (N)'][2] > 1.0
                and rows['wrench on master (N)'][2] > 1.0 and any(rows['torques (N*m)'])]
    assert touching and touching[0] <= 10.0, output

    # What was published: the hand stopped on the top (which gave a little), and the wrench
    # sent to the master pushed up, out of the table.
    hand_z = np.array([p.pose.position.z for p in demo.recorder.messages('measured_cp')])
    assert TABLE_Z - TABLE_SINK < hand_z.min() < TABLE_Z
    forces = np.array([(w.wrench.force.x, w.wrench.force.y, w.wrench.force.z)
                       for w in demo.recorder.messages('wrench')])
    assert forces[:, 2].max() > 1.0
    # The hand's swings in free space are felt too (its inertia on the sensor, about 1 to 2 N);
    # the firmest force felt is the table's, and pushes up.
    firmest = forces[np.argmax(np.linalg.norm(forces, axis=1))]
    assert firmest[2] > np.linalg.norm(firmest[:2]), firmest
