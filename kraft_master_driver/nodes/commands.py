# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The nodes' console scripts: a stop signal is a request to stop from their first instant.

Each asks for its parent's death signal and remembers the stop signals before it imports its
node (rclpy and numpy took 2 s on a loaded machine), then runs the node, which stops at once,
with exit 0, if a stop signal came in the meantime (core.process, nodes.node_process). The
parent-death signal comes first: a parent that dies in between is then not missed.
"""
import importlib

from kraft_master_driver.core.process import remember_stop_signals, stop_with_parent


def _run(module):
    stop_with_parent()
    remember_stop_signals()
    return importlib.import_module(f'kraft_master_driver.nodes.{module}').main()


def driver():
    """kraft_master_node."""
    return _run('driver')


def slave_sim():
    """kraft_master_slave_sim."""
    return _run('slave_sim')


def link_emulator():
    """kraft_master_link_emulator."""
    return _run('link_emulator')


def teleop():
    """kraft_master_teleop."""
    return _run('teleop')


def arm_sim():
    """kraft_master_arm_sim."""
    return _run('arm_sim')


def zenoh_link():
    """kraft_master_zenoh_link."""
    return _run('zenoh_link')
