# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The simulated Kraft Master, ROS-free: the device model, its faults, its transports."""
