# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The ROS 2 nodes: driver, bridge, point-mass and MuJoCo arms, link emulator, what they share."""
