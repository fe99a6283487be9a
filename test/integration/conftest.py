# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Every test under integration/ starts real processes: each is marked integration and process.

The fixture `start_demo` runs the demo as a user does (harness/demo.py).
"""
import pathlib

import pytest

HERE = pathlib.Path(__file__).parent


def pytest_collection_modifyitems(config, items):
    """Mark each test collected from this directory: integration, and process."""
    for item in items:
        if HERE in pathlib.Path(item.fspath).parents:
            item.add_marker(pytest.mark.integration)
            item.add_marker(pytest.mark.process)


@pytest.fixture
def start_demo():
    """Yield start(duration, **Demo options) -> Demo; whatever happens, nothing of it is left."""
    from harness.demo import Demo  # ROS is imported only where a test runs the demo
    started = []

    def start(duration, **options):
        started.append(Demo(duration, **options))
        return started[-1]

    yield start
    for demo in started:
        demo.kill()
        if demo.recorder.context.ok():
            demo.recorder.close()
