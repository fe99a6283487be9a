# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The simulations, ROS-free: the Kraft Master hand controller (master/) and the arms (arms/)."""
