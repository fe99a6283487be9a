# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The simulated arms behind the bridge, ROS-free: the point-mass arm and the MuJoCo Panda."""
