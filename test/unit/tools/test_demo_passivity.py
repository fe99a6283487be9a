# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The demo's choices that need no process."""
from kraft_master_driver.tools.demo import bridge_passivity


def test_the_bridges_passivity_is_on_only_for_direct_force_with_passivity_on():
    assert bridge_passivity(True, 'direct')
    assert not bridge_passivity(True, 'auto')
    assert not bridge_passivity(True, 'model')
    assert not bridge_passivity(False, 'direct')
