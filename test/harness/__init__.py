# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Helpers of the tests (pytest puts test/ on the path): `from harness.driver import ...`.

driver: the installed driver and slave as processes, a client node, DDS domains. netns: two
hosts as network namespaces. remote_session: one teleoperation session across them, with
remote_probe.py and remote_recorder.py the scripts run inside a host. faults: the fault
suite's session and injections (scripts/soak.py uses them too), with wrench_source.py the
wrench publisher it runs as a process. type_hashes: the message type hashes rosidl generated.
dds_shm: Fast DDS's shared-memory files, and ending DDS processes so that they remove theirs.
session_bags: synthetic recorded sessions, the bags the report's tests read. joints: joint
vectors inside the limits. force_reflection: an enabled force reflection, its inputs, and the
checks of zero torque and of a bad setting, for its tests and the wrench admission's.
reaper: a command run under a subreaper, which tells the exit of all it started.
teleop_soak: the session soak (scripts/teleop_soak.py), with soak_site (its processes and
operator), soak_faults (the faults and their schedule), soak_master.py and soak_recorder.py
(the simulated master with its fault switches, and the recorder of both sites, as processes).
This module: where the repository is.
"""
import pathlib

REPO = pathlib.Path(__file__).resolve().parents[2]
PACKAGE = 'kraft_master_driver'
