# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The command-line tools: demo, calibration, recording, reports, control, URDF."""
