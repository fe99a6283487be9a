# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""Synthetic recorded sessions: bags of the simulator's samples on the driver's topics."""
from kraft_master_driver.bag.common import BAG_VERSION, typestore
from kraft_master_driver.bag.recorder import BagRecorder
from kraft_master_driver.bag.samples import simulate_samples, write_samples
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.rosbag2.enums import CompressionFormat

SAMPLES = 3000  # per arm


def write_bag(path, storage, arms, compression=None, samples=SAMPLES):
    """Write a synthetic session: {namespace: (arm, seed)}; return {namespace: Samples}."""
    if compression is None:
        written = {}
        with BagRecorder(path, storage) as recorder:
            for namespace, (arm, seed) in arms.items():
                written[namespace] = simulate_samples(samples, arm, seed=seed)
                write_samples(recorder, namespace, written[namespace],
                              diagnostics_every=samples // 4)
        return written
    plain = path.with_name(path.name + '_plain')
    written = write_bag(plain, storage, arms, samples=samples)
    writer = Writer(path, version=BAG_VERSION,
                    storage_plugin=StoragePlugin[storage.upper()])
    writer.set_compression(compression, CompressionFormat.ZSTD)
    with Reader(plain) as reader, writer:
        connections = {c.id: writer.add_connection(c.topic, c.msgtype, typestore=typestore())
                       for c in reader.connections}
        for connection, log_time, data in reader.messages():
            writer.write(connections[connection.id], log_time, data)
    return written
