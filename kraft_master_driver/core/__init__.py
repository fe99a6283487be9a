# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The ROS-free core: kinematics, rotations, force reflection, passivity, the bridge, the loop."""
