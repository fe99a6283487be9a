# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
A Zenoh peer that tries a link's listener: forged streams in, a subscription to everything out.

Run inside a host of netns.TwoHosts by the Zenoh link's tests:

    python zenoh_peer.py --connect tls/10.231.7.2:7447 --pair P --posing-as master \
        --ca ca.pem [--certificate c.pem --private-key c.key] --seconds 3

Posing as the master it puts a PoseStamped that moves 1 mm per message along x on
`<pair>/to_arm/pose`; posing as the arm, a WrenchStamped of 30 N up on `<pair>/to_master/wrench`,
100 times a second, stamped now. It subscribes to what the listener sends the side it poses
as, `<pair>/to_<side>/*`; after `--seconds` it prints `received <samples> peers <sessions>`
and exits 0. Without a certificate it still speaks TLS and trusts the CA: only its own
certificate is missing.
"""
import argparse
import json
import sys
import time

from geometry_msgs.msg import PoseStamped, WrenchStamped
from kraft_master_driver.nodes import zenoh_config
from rclpy.serialization import serialize_message
import zenoh


def forged(posing_as, count):
    """Return (topic, CDR bytes) of the count-th forged message."""
    now = time.time_ns()
    if posing_as == 'master':
        msg = PoseStamped()
        msg.header.frame_id = 'kraft_master_base'
        msg.pose.position.x = 0.3 + 0.001 * count
        msg.pose.orientation.w = 1.0
        topic = 'pose'
    else:
        msg = WrenchStamped()
        msg.header.frame_id = 'kraft_master_base'
        msg.wrench.force.z = 30.0
        topic = 'wrench'
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(now, 1_000_000_000)
    return topic, serialize_message(msg)


def main():
    """Try the listener; print what came; return 0."""
    parser = argparse.ArgumentParser(description=__doc__)
    for name in ('--connect', '--pair', '--ca'):
        parser.add_argument(name, required=True)
    parser.add_argument('--posing-as', choices=zenoh_config.SIDES, required=True)
    parser.add_argument('--certificate')
    parser.add_argument('--private-key')
    parser.add_argument('--seconds', type=float, default=3.0)
    args = parser.parse_args()
    tls = {'root_ca_certificate': args.ca}
    if args.certificate:
        tls.update(connect_certificate=args.certificate, connect_private_key=args.private_key,
                   enable_mtls=True)
    config = {'mode': 'peer', 'connect': {'endpoints': [args.connect]},
              'scouting': {'multicast': {'enabled': False}},
              'transport': {'link': {'tls': tls}}}
    session = zenoh.open(zenoh.Config.from_json5(json.dumps(config)))
    received = []
    # What the side it poses as subscribes to: access control admits no wider key.
    session.declare_subscriber(f'{args.pair}/to_{args.posing_as}/*',
                               lambda sample: received.append(1))
    receiver = zenoh_config.other_side(args.posing_as)
    deadline = time.monotonic() + args.seconds
    count = 0
    while time.monotonic() < deadline:
        topic, data = forged(args.posing_as, count)
        session.put(zenoh_config.key(args.pair, topic, receiver), data)
        count += 1
        time.sleep(0.01)
    print(f'received {len(received)} peers {len(list(session.info.peers_zid()))}', flush=True)
    session.close()
    return 0


if __name__ == '__main__':
    sys.exit(main())
