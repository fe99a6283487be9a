# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""mypy over what setup.cfg's [mypy] section names (core/, link/, bag/, ros_io.py), strictly."""
import os
import subprocess
import sys

from harness import REPO
import pytest


@pytest.mark.process
def test_mypy():
    # No cache read or written: as cold as a fresh clone in CI, and no .mypy_cache in the tree.
    result = subprocess.run(
        [sys.executable, '-m', 'mypy', '--config-file', 'setup.cfg', '--no-incremental',
         '--cache-dir', os.devnull],
        cwd=REPO, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, f'mypy found type errors:\n{result.stdout}{result.stderr}'
