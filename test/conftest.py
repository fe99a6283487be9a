# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""Fixtures for tests that start the installed driver as a real process."""
import gc
import os
import shutil
import subprocess
import sys

from harness import dds_shm, PACKAGE, REPO
import pytest

# Simulated devices run as threads of this process and must answer within the driver's 10 ms
# reply timeout: hand the interpreter lock over every 0.5 ms, not every 5 ms (the default), as
# the node does for its loop thread.
sys.setswitchinterval(0.0005)


def pytest_runtest_setup(item):
    """
    Collect what earlier tests left, then freeze the survivors out of the collector's scans.

    Without this a full collection walked every object the suite had kept so far: in a run of
    test/unit and test_node.py the longest pauses inside tests were 438 to 725 ms (one in
    test_node.py), long enough for a simulated device in this process to miss the driver's
    replies until the link went down (a fresh clone's run failed so). Frozen, each test's
    collections walk only what that test made: the longest were 128 to 163 ms, none in
    test_node.py.
    """
    gc.collect()
    gc.freeze()


@pytest.fixture(scope='session')
def install_prefix(tmp_path_factory):
    """Build and install the package with colcon, as on a ROS machine; return the prefix."""
    colcon = shutil.which('colcon', path=os.path.dirname(sys.executable))
    assert colcon, 'colcon is not installed next to this Python (see requirements.txt)'
    base = tmp_path_factory.mktemp('colcon')
    result = subprocess.run(
        [colcon, '--log-base', str(base / 'log'), 'build', '--base-paths', str(REPO),
         '--build-base', str(base / 'build'), '--install-base', str(base / 'install')],
        cwd=base, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    prefix = base / 'install' / PACKAGE
    assert (prefix / 'share' / PACKAGE / 'hook' / 'ament_prefix_path.dsv').exists(), (
        'colcon built a plain Python package, not an ament package: check package.xml')
    return prefix


@pytest.fixture(scope='session', autouse=True)
def no_orphaned_dds_shared_memory():
    """
    Fail the run if its processes leave Fast DDS shared memory in /dev/shm behind.

    Counted: the participants' segments that appeared during the run, that a process of this run
    (this one or a descendant) was seen holding, and that no process holds at the end (a
    participant killed before its teardown). They are removed, then named. Seen: the holders
    are looked at every 0.2 s, so a process killed sooner after it started goes uncounted;
    another test run on the same machine is never counted.
    """
    watcher = dds_shm.Watcher()
    watcher.start()
    yield
    # Participants' segments only: a port is shared by the participants of a domain, and
    # one was seen left after a run whose processes had all torn down (not understood yet).
    noted = watcher.stop()
    left = dds_shm.orphaned({group for group in noted if '_port' not in group})
    dds_shm.remove(left)
    assert not left, (f'{len(left)} Fast DDS shared-memory segments or ports were left by '
                      'processes that did not tear down (removed now): '
                      + '; '.join(f'{group}, held by {noted[group]}' for group in sorted(left)))
