# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The benchmarks: figures, never asserts (doc/performance.md).

Each runs as a module from the repository's root, `.venv/bin/python -m benchmarks.loop`, so
that this checkout's package is the one imported; delay.py also needs test/ on PYTHONPATH for
the tests' harness. machine.py and sched_trace.py hold what the others share.
"""
