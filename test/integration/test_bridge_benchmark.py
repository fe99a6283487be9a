# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""benchmarks/bridge.py runs briefly end to end and prints its table (no timing is checked)."""
import subprocess
import sys

from harness import REPO
from harness.driver import next_domain_id, WAIT_S
import pytest

pytestmark = pytest.mark.integration


def test_the_bridge_benchmark_runs_and_prints_its_figures():
    run = subprocess.run(
        [sys.executable, '-m', 'benchmarks.bridge', '--duration', '1',
         '--domain-id', str(next_domain_id())],
        cwd=REPO, capture_output=True, text=True, timeout=4 * WAIT_S)
    assert run.returncode == 0, run.stdout + run.stderr
    lines = run.stdout.splitlines()
    for row in ('pose -> servo_cp', 'measured_cf -> wrench', 'at enable', 'at clutch release'):
        assert any(line.strip().startswith(row) for line in lines), run.stdout
    states = next(line for line in lines if line.startswith('operating states: '))
    assert states.endswith('ENABLED -> CLUTCHED -> ENABLED'), run.stdout
