# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The subpackages that must run without ROS import none of it, module by module."""
import json
import subprocess
import sys

from harness import REPO
import pytest

ROS_FREE = ('core', 'link', 'simulation', 'bag')

# Run in a fresh interpreter: imports every module of one subpackage, found by pkgutil, and
# names the first one after whose import rclpy (or any rclpy.*) is loaded.
IMPORT_ALL = """
import importlib
import json
import pkgutil
import sys

package = importlib.import_module(sys.argv[1])
modules = [info.name for info in pkgutil.walk_packages(package.__path__, package.__name__ + '.')]
ros_after = None
for name in modules:
    importlib.import_module(name)
    if ros_after is None and any(m == 'rclpy' or m.startswith('rclpy.') for m in sys.modules):
        ros_after = name
ros = sorted(m for m in sys.modules if m == 'rclpy' or m.startswith('rclpy.'))
print(json.dumps({'modules': modules, 'ros_after': ros_after, 'ros': ros}))
"""


@pytest.mark.process
@pytest.mark.parametrize('subpackage', ROS_FREE)
def test_ros_free_subpackages_import_no_rclpy(subpackage):
    result = subprocess.run(
        [sys.executable, '-c', IMPORT_ALL, f'kraft_master_driver.{subpackage}'],
        cwd=REPO, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    found = json.loads(result.stdout.splitlines()[-1])
    assert found['modules'], f'pkgutil found no modules in kraft_master_driver.{subpackage}'
    assert found['ros'] == [], f"importing {found['ros_after']} loads rclpy"
