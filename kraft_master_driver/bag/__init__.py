# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""rosbag2 I/O without rosbag2, ROS-free: MCAP and sqlite3 writers, reader, synthetic sessions."""
