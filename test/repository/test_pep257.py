# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""pep257 docstring conventions over the package tree, as ament_pep257 checks them."""
from pathlib import Path

from ament_pep257.main import main
from harness import REPO
import pytest

CHECKED = ('kraft_master_driver', 'test', 'benchmarks', 'scripts', 'launch', 'doc', 'setup.py')


@pytest.mark.linter
@pytest.mark.pep257
def test_pep257(monkeypatch):
    monkeypatch.chdir(REPO)
    paths = [name for name in CHECKED if Path(name).exists()]
    rc = main(argv=paths)
    assert rc == 0, 'Found code style errors / warnings (listed in the captured output)'
