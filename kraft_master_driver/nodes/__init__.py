# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The ROS 2 nodes: the driver, the simulated slave, the link emulator, and what they share."""
