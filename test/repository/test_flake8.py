# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""flake8 over the package tree with ament's configuration (99 columns, its plugins)."""
from pathlib import Path

from ament_flake8.main import main_with_errors
from harness import REPO
import pytest

CHECKED = ('kraft_master_driver', 'test', 'benchmarks', 'scripts', 'launch', 'doc', 'setup.py')


@pytest.mark.flake8
@pytest.mark.linter
def test_flake8(monkeypatch):
    # ament_flake8 excludes the hidden folders it finds under the working directory.
    monkeypatch.chdir(REPO)
    paths = [name for name in CHECKED if Path(name).exists()]
    rc, errors = main_with_errors(argv=paths)
    assert rc == 0, f'Found {len(errors)} code style errors / warnings:\n' + '\n'.join(errors)
