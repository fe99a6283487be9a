# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
kraft_master_zenoh_link: the teleop streams between two sites over Zenoh, with mutual TLS.

One link runs on each site, inside its DDS island: side master beside the driver, side arm
beside the bridge. The master's link sends `pose`, `master_energy` and `clutch`, the arm's
`wrench`, `slave_energy` and `contact_model` (zenoh_config.STREAMS), each as its CDR bytes on
`<pair>/to_<side>/<topic>`, and each publishes what it receives on its own island. One side
listens, the other connects; both speak only TLS, each with its certificate signed by one root
CA, and let only the peer whose certificate bears `tls.peer_common_name` put or subscribe.

Latest only, both ways: the DDS subscriptions are taken by a thread of the link's own, which
sends the newest message of each topic at each wake-up (nodes/ros_io.py); Zenoh drops a
message it cannot queue rather than block (congestion control DROP); the DDS publishers keep
one message. The energies are running totals, so a lost sample only delays the credit it
carried. The link emulator's delay line (delay, jitter, loss of what this side receives) can
sit on top, for tests. Each peer's coming and going is logged with the common name of its
certificate; one signed for another name is logged as shut out (access control lets it do
nothing), not as authenticated. While no authenticated peer is connected, one line every 10 s
says so.

The arm's link relays no pose to the bridge until it has called the bridge's `enable`
service with false and had its answer (zenoh_config.PoseGate): when it starts, and whenever
more than `stream_timeout` s pass without a pose from the master (the peer gone, or a blip
Zenoh's session does not notice). The arm holds, and following resumes only once the operator
enables the bridge again, not on its own when the poses come back. A disable unanswered for
DISABLE_PATIENCE_S is asked again: an answer to a client just started can be lost. Where no
bridge offers `enable` (none within BRIDGE_WAIT_S of the start, or none later), the link says
so and relays.
The master's side needs no such call: the driver's watchdog gives zero torque once the
wrenches stop.
"""
import json
import sys
import threading
import time

from kraft_master_driver.core.delay_line import DelayLine, LinkModel
from kraft_master_driver.nodes import zenoh_config
from kraft_master_driver.nodes.link_emulator import DelayedSender, message_class, Releaser
from kraft_master_driver.nodes.node_process import run_node
from kraft_master_driver.nodes.parameters import declare_parameters, ParameterError, Spec
from kraft_master_driver.nodes.ros_io import (
    forward_inputs, GIL_SWITCH_INTERVAL_S, InputWaitSet, PacedThread, RepeatedRequest,
    steady_timer, subscribe_raw, take_newest)
import rclpy.logging
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_srvs.srv import SetBool

LOG_PERIOD_S = 10.0
PEER_CHECK_S = 1.0
# The longest the arm's link waits at start for the bridge's enable service to be discovered.
BRIDGE_WAIT_S = 5.0
# The bridge answers disable within milliseconds; an answer this late was lost (RepeatedRequest).
DISABLE_PATIENCE_S = 1.0
# How often the arm's link looks for a lapsed pose stream and a bridge to disable.
STREAM_CHECK_S = 0.02
# The DDS side's raw subscriptions: the newest is sent, so a short queue loses nothing useful.
QUEUE_DEPTH = 10

PARAMETERS = {
    'side': Spec('master', 'This site: master (beside the driver) or arm (beside the bridge).',
                 choices=zenoh_config.SIDES),
    'pair': Spec('kraft_master/pair', 'Key prefix of this master/arm pair, the same on both '
                 'sites.'),
    'listen': Spec('', 'Endpoint to listen on, tls/<address>:<port>; empty: connect.'),
    'connect': Spec('', 'Endpoint of the listening site, tls/<host>:<port>; empty: listen.'),
    'tls.root_ca': Spec('', 'PEM certificate of the root CA that signed the certificates '
                        'of both sites.'),
    'tls.certificate': Spec('', 'PEM certificate of this site, signed by the root CA.'),
    'tls.private_key': Spec('', 'PEM private key of the certificate of this site.'),
    'tls.peer_common_name': Spec('', 'Common name in the certificate of the other site: the '
                                 'one peer allowed to put or subscribe.'),
    'stream_timeout': Spec(0.05, 'Side arm: a longer gap between the poses disables the bridge '
                           '(s); below its master_timeout, above the pose period.',
                           low=0.001, high=10.0),
    'seed': Spec(-1, 'Seed of the emulated loss and jitter draws; -1: a different one each '
                 'run.'),
    'delay': Spec(0.0, 'Emulated one-way delay (s) added to what this side receives.'),
    'jitter': Spec(0.0, 'Emulated extra delay (s), uniform in [0, jitter], order kept.'),
    'loss': Spec(0.0, 'Emulated long-run fraction of received messages lost, in [0, 1).'),
    'loss_burst': Spec(0.0, 'Mean length of a run of emulated losses, >= 1; 0: independent.'),
}


def _import_zenoh():
    """Return the zenoh module, or raise ParameterError saying it is not installed."""
    try:
        import zenoh
    except ImportError:
        raise ParameterError('eclipse-zenoh is not installed: pip install eclipse-zenoh '
                             '(its pinned version is in constraints.txt)') from None
    return zenoh


class ZenohLinkNode(Node):
    """One site's end of the link: its DDS island's streams to Zenoh and back."""

    def __init__(self, params_files=(), **kwargs):
        """Check the parameters, open the TLS session, wire both directions."""
        super().__init__('kraft_master_zenoh_link', **kwargs)
        config = declare_parameters(self, PARAMETERS, params_files)
        zenoh = _import_zenoh()
        side, pair = config['side'], config['pair']
        try:
            model = LinkModel(*(config[field] for field in LinkModel._fields)).checked()
            session_config = zenoh_config.session_config(
                side, pair, config['listen'], config['connect'], config['tls.root_ca'],
                config['tls.certificate'], config['tls.private_key'],
                config['tls.peer_common_name'])
        except ValueError as error:
            raise ParameterError(f'parameter {error}') from None
        self.endpoint = config['listen'] or config['connect']
        self.role = 'listening on' if config['listen'] else 'connecting to'
        # Zenoh's own log (a refused handshake, say) only where RUST_LOG asks for it.
        zenoh.try_init_log_from_env()
        try:
            self.session = zenoh.open(zenoh.Config.from_json5(json.dumps(session_config)))
        except zenoh.ZError as error:
            raise ParameterError(f'cannot open the Zenoh session {self.role} {self.endpoint}: '
                                 f'{str(error).splitlines()[0]}') from None
        self.line = DelayLine(model, seed=None if config['seed'] < 0 else config['seed'])
        self.releaser = Releaser()
        self.releaser.start()
        self.sent = dict.fromkeys(zenoh_config.outgoing(side), 0)
        self.received = dict.fromkeys(zenoh_config.incoming(side), 0)
        self.started = time.monotonic()
        self.gate = None
        if side == 'arm':
            self.gate = zenoh_config.PoseGate(config['stream_timeout'])
            self.disabling = RepeatedRequest(self.create_client(SetBool, 'enable'),
                                             DISABLE_PATIENCE_S)
            steady_timer(self, STREAM_CHECK_S, self._disable_bridge)
        self.zenoh_subscribers = [self._receive(topic, zenoh_config.key(pair, topic, side))
                                  for topic in self.received]
        other = zenoh_config.other_side(side)
        self.outputs = [(topic, subscribe_raw(self, message_class(zenoh_config.STREAMS[topic][0]),
                                              topic, lambda _data: None, QUEUE_DEPTH),
                         self.session.declare_publisher(
                             zenoh_config.key(pair, topic, other),
                             congestion_control=zenoh.CongestionControl.DROP,
                             priority=zenoh.Priority.REAL_TIME, express=True))
                        for topic in self.sent]
        self.peer_book = zenoh_config.PeerBook(config['tls.peer_common_name'])
        self.peers = 0
        self.alone_since = time.monotonic()
        self._running = True
        # One thread sends the DDS messages as they come; another asks Zenoh for the peers
        # once a second, so that the streams never wait on that call.
        self.sender = threading.Thread(target=forward_inputs, name='zenoh_link_send', args=(
            InputWaitSet(self.context, [s for _, s, _ in self.outputs]), self._send_newest,
            lambda: self._running and self.context.ok()))
        self.sender.start()
        self.peer_checks = PacedThread(self, 'zenoh_link_peers', PEER_CHECK_S,
                                       self._check_peers)
        self.peer_checks.start()
        steady_timer(self, LOG_PERIOD_S, self._log_counts)
        self.get_logger().info(
            f'{side} side of pair {pair}, {self.role} {self.endpoint} (TLS, peer '
            f'{config["tls.peer_common_name"]}): sending {", ".join(self.sent)}; receiving '
            f'{", ".join(self.received)} with {model}')

    def _receive(self, topic, key):
        """Subscribe to `key`; publish what comes on DDS `topic`, through the delay line."""
        publisher = self.create_publisher(
            message_class(zenoh_config.STREAMS[topic][0]), topic,
            QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE))
        sender = DelayedSender(self.line, self.releaser, publisher.publish)

        gate = self.gate if topic == 'pose' else None

        def on_sample(sample):
            self.received[topic] += 1
            if gate is not None and not gate.admit(time.monotonic()):
                return
            try:
                sender.send(sample.payload.to_bytes())
            except RuntimeError:
                # Ctrl-C shut the context down before the session closed: nothing to publish.
                if self.context.ok():
                    raise
        return self.session.declare_subscriber(key, on_sample)

    def _send_newest(self):
        """Put the newest message of each DDS topic that brought one since the last time."""
        for topic, subscription, publisher in self.outputs:
            data = take_newest(subscription)
            if data is not None:
                publisher.put(data)
                self.sent[topic] += 1

    def _check_peers(self, _missed):
        """Log each peer's coming and going by name; while none is let in, a line every 10 s."""
        changes = self.peer_book.update(
            (str(link.zid), link.dst, link.auth_identifier) for link in self.session.info.links())
        for warning, line in changes:
            # Two calls: rclpy refuses another severity from the same line of code.
            if warning:
                self.get_logger().warning(f'{self.role} {self.endpoint}: {line}')
            else:
                self.get_logger().info(f'{self.role} {self.endpoint}: {line}')
        peers = self.peer_book.authenticated
        now = time.monotonic()
        if peers != self.peers:
            self.peers = peers
            self.alone_since = now
        elif not peers:
            self.get_logger().warning(
                f'no authenticated peer {self.role} {self.endpoint} for '
                f'{now - self.alone_since:.0f} s (a peer is refused without a certificate the '
                f'root CA signed, or with another common name)',
                throttle_duration_sec=LOG_PERIOD_S)

    def _disable_bridge(self):
        """While the gate is shut, have the bridge disabled; open the gate on its answer."""
        reason = self.gate.reason(time.monotonic())
        if reason is None or self.disabling.waiting():
            return
        if self.disabling.overdue():
            self.get_logger().warning(f'{reason}: the bridge did not answer disable within '
                                      f'{DISABLE_PATIENCE_S:g} s; asking again')
        if self.disabling.ask(SetBool.Request(data=False),
                              lambda done: self._bridge_disabled(reason, done)):
            return
        if time.monotonic() - self.started > BRIDGE_WAIT_S:
            self.get_logger().warning(f'{reason}, and no bridge offers enable here: relaying '
                                      'the poses')
            self.gate.reopen()

    def _bridge_disabled(self, reason, done):
        self.get_logger().warning(f'{reason}: disabled the bridge ({done.result().message}); '
                                  'relaying the poses, the bridge follows after enable')
        self.gate.reopen()

    def _log_counts(self, logger=None):
        stats = self.line.stats.summary()
        (logger or self.get_logger()).info(
            'sent ' + ', '.join(f'{t} {n}' for t, n in self.sent.items()) + '; received '
            + ', '.join(f'{t} {n}' for t, n in self.received.items()) + '; delay line: '
            + ', '.join(f'{k} {v}' for k, v in stats.items()))

    def destroy_node(self):
        """Stop sending, close the session, then stop the releases; log the counts."""
        self._running = False
        self.peer_checks.stop()
        self.sender.join()
        self.session.close()
        self.releaser.stop()
        # Not through rosout: a Ctrl-C has shut the context down already (as in link_emulator).
        self._log_counts(rclpy.logging.get_logger(f'{self.get_name()}.exit'))
        super().destroy_node()


def main(args=None):
    """Run the link until Ctrl-C or SIGTERM; exit 1 on a bad parameter or without Zenoh."""
    sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
    return run_node(ZenohLinkNode, 'kraft_master_zenoh_link', __doc__.strip().splitlines()[0],
                    PARAMETERS, args)


if __name__ == '__main__':
    sys.exit(main())
