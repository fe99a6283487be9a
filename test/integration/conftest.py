# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""Every test under integration/ starts real processes: `-m "not integration"` leaves it out."""
import pathlib

import pytest

HERE = pathlib.Path(__file__).parent


def pytest_collection_modifyitems(config, items):
    """Mark each test collected from this directory as an integration test."""
    for item in items:
        if HERE in pathlib.Path(item.fspath).parents:
            item.add_marker(pytest.mark.integration)
