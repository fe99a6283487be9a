# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The device link, ROS-free: the KMC 9100 frame codec and the serial device."""
