# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""ROS 2 driver for the Kraft Master force-reflecting hand controller."""
