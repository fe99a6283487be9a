# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The message type hashes rosidl generated, to check the bags' and the endpoints' against."""
import json
import os
from pathlib import Path
import sys

import pytest


def generated_type_hash(msgtype):
    """Return the RIHS01 hash rosidl generated for `msgtype` at build time (its .json file)."""
    package, _, name = msgtype.split('/')
    prefixes = os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) + [sys.prefix]
    for prefix in filter(None, prefixes):
        path = Path(prefix) / 'share' / package / 'msg' / f'{name}.json'
        if path.exists():
            hashes = json.loads(path.read_text())['type_hashes']
            return next(h['hash_string'] for h in hashes if h['type_name'] == msgtype)
    pytest.skip(f'the type description of {msgtype} is not installed')
