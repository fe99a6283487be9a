# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The Zenoh link's plain logic: which streams cross, their keys, the session's configuration.

No ROS and no Zenoh here: zenoh_link.py opens the session with session_config()'s dictionary
(as JSON5) and moves the messages. A master/arm pair shares one key prefix, `pair`; each stream
goes on `<pair>/to_<side that receives it>/<topic>`. The session is a peer that only speaks
TLS, with mutual authentication against one root CA, no multicast scouting and no gossip (it
meets only the endpoints given), a bounded back-off between connection attempts and bounded
pending handshakes. Access control lets only the peer whose certificate bears the expected
common name put the streams this side receives and subscribe to those it sends; nothing else.
Every refusal is a ValueError of one line. PoseGate is the arm's rule for the master's poses;
PeerBook names each peer that comes, by its certificate, and says which access control shuts
out.
"""
import os
import re
import threading

SIDES = ('master', 'arm')
# topic -> (message type, the side whose DDS island publishes it)
STREAMS = {
    'pose': ('geometry_msgs/msg/PoseStamped', 'master'),
    'master_energy': ('geometry_msgs/msg/Vector3Stamped', 'master'),
    'clutch': ('std_msgs/msg/Bool', 'master'),
    'wrench': ('geometry_msgs/msg/WrenchStamped', 'arm'),
    'slave_energy': ('geometry_msgs/msg/Vector3Stamped', 'arm'),
    'contact_model': ('sensor_msgs/msg/JointState', 'arm'),
}
# One chunk of a key prefix: no wildcards (* $ ? #), no empty chunk.
CHUNK = re.compile(r'^[A-Za-z0-9_.-]+$')
ENDPOINT = re.compile(r'^tls/(?P<host>\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+):(?P<port>\d+)$')
# Between two connection attempts to an endpoint that refuses: from 0.5 s, doubling, to 4 s.
RETRY_MS = {'period_init_ms': 500, 'period_max_ms': 4000, 'period_increase_factor': 2}
# Handshakes a listener holds at once, and how long each may take (ms).
ACCEPT_PENDING = 4
ACCEPT_TIMEOUT_MS = 2000


def other_side(side):
    """Return the side opposite `side`."""
    check_side(side)
    return SIDES[1 - SIDES.index(side)]


def check_side(side):
    """Raise ValueError unless `side` is one of SIDES."""
    if side not in SIDES:
        raise ValueError(f'side: {side!r} is not one of {", ".join(SIDES)}')


def check_pair(pair):
    """Return `pair` if it is a key prefix of plain chunks joined by '/', else raise."""
    if not isinstance(pair, str) or not all(CHUNK.match(c) for c in pair.split('/')):
        raise ValueError(f'pair: {pair!r} must be chunks of letters, digits, "_", "-", "." '
                         f'joined by "/" (no wildcard, no empty chunk)')
    return pair


def key(pair, topic, receiving_side):
    """Return the Zenoh key of `topic` on its way to `receiving_side`."""
    return f'{check_pair(pair)}/to_{receiving_side}/{topic}'


def outgoing(side):
    """Return the topics `side` takes from its DDS island and sends."""
    check_side(side)
    return tuple(topic for topic, (_, source) in STREAMS.items() if source == side)


def incoming(side):
    """Return the topics `side` receives and publishes on its DDS island."""
    return outgoing(other_side(side))


def check_endpoint(endpoint, role):
    """Return `endpoint` if it is tls/<host>:<port>, else raise naming the `role` parameter."""
    match = ENDPOINT.match(endpoint) if isinstance(endpoint, str) else None
    if match is None or not 0 < int(match['port']) < 65536:
        raise ValueError(f'{role}: {endpoint!r} is not tls/<host>:<port> (only TLS is spoken, '
                         f'port 1..65535)')
    return endpoint


def check_pem(path, role, label):
    """Return `path` if it is a readable PEM file holding a `label` block, else raise."""
    if not path:
        raise ValueError(f'{role}: no file given')
    try:
        with open(path, encoding='ascii', errors='replace') as pem:
            text = pem.read()
    except OSError as error:
        raise ValueError(f'{role}: cannot read {path}: {error.strerror}') from None
    if not re.search(rf'^-----BEGIN ([A-Z]+ )?{label}-----$', text, re.MULTILINE):
        raise ValueError(f'{role}: {path} holds no PEM {label}')
    return os.path.abspath(path)


def check_common_name(name):
    """Return `name` if it can be a certificate's common name, else raise."""
    if not isinstance(name, str) or not name or name != name.strip() or ',' in name:
        raise ValueError(f'tls.peer_common_name: {name!r} must be the common name of the '
                         f"other site's certificate")
    return name


def access_control(side, pair, peer_common_name):
    """Return the access control: the peer named puts what `side` receives, nothing else."""
    receiving, sending = f'{pair}/to_{side}/*', f'{pair}/to_{other_side(side)}/*'
    rules = [
        ('peer_puts', 'put', 'ingress', receiving),
        ('peer_subscribes', 'declare_subscriber', 'ingress', sending),
        ('we_put', 'put', 'egress', sending),
        ('we_subscribe', 'declare_subscriber', 'egress', receiving),
    ]
    return {
        'enabled': True,
        'default_permission': 'deny',
        'rules': [{'id': rule, 'messages': [message], 'flows': [flow], 'permission': 'allow',
                   'key_exprs': [key_expr]} for rule, message, flow, key_expr in rules],
        'subjects': [{'id': 'peer_site', 'cert_common_names': [peer_common_name]}],
        'policies': [{'id': 'teleop_streams', 'rules': [rule[0] for rule in rules],
                      'subjects': ['peer_site']}],
    }


def session_config(side, pair, listen, connect, root_ca, certificate, private_key,
                   peer_common_name):
    """
    Return the Zenoh session's configuration as a dictionary; raise ValueError if refused.

    Exactly one of `listen` and `connect` is an endpoint, the other ''; the three files are
    PEM (the root CA's certificate, this site's certificate and its private key).
    """
    check_side(side)
    check_pair(pair)
    if bool(listen) == bool(connect):
        raise ValueError('listen, connect: give exactly one (one side listens, the other '
                         'connects)')
    role = 'listen' if listen else 'connect'
    endpoint = check_endpoint(listen or connect, role)
    tls = {
        'root_ca_certificate': check_pem(root_ca, 'tls.root_ca', 'CERTIFICATE'),
        f'{role}_certificate': check_pem(certificate, 'tls.certificate', 'CERTIFICATE'),
        f'{role}_private_key': check_pem(private_key, 'tls.private_key', 'PRIVATE KEY'),
        'enable_mtls': True,
    }
    ends = {'listen': {'endpoints': []}, 'connect': {'endpoints': []}}
    ends[role]['endpoints'].append(endpoint)
    if role == 'connect':
        ends['connect']['retry'] = dict(RETRY_MS)
    return {
        'mode': 'peer',
        **ends,
        'scouting': {'multicast': {'enabled': False}, 'gossip': {'enabled': False}},
        'transport': {
            'unicast': {'accept_pending': ACCEPT_PENDING, 'accept_timeout': ACCEPT_TIMEOUT_MS},
            'link': {'protocols': ['tls'], 'tls': tls},
        },
        'access_control': access_control(side, pair, check_common_name(peer_common_name)),
    }


class PoseGate:
    """
    Whether the arm's link relays the master's poses: only once the bridge has been disabled.

    The gate is shut when the link starts, and when more than `timeout` s pass without a pose
    once one has been relayed: the pose that ends such a gap is dropped. Shut, it says why
    (reason()); the link then has the bridge disabled and reopens it (reopen()), so that whatever
    comes back must be enabled again. Poses come on Zenoh's thread, the checks on another.
    """

    def __init__(self, timeout):
        """Start shut: the bridge may be following on poses of a link before this one."""
        self.timeout = timeout
        self._lock = threading.Lock()
        self._reason = 'the link started'
        self._last_pose = None

    def admit(self, now):
        """Return whether the pose that came at `now` (s, monotonic) goes on to the bridge."""
        with self._lock:
            self._shut_if_lapsed(now)
            if self._reason is None:
                self._last_pose = now
            return self._reason is None

    def reason(self, now):
        """Return why the bridge must be disabled before poses go on, or None if they go."""
        with self._lock:
            self._shut_if_lapsed(now)
            return self._reason

    def reopen(self):
        """Let poses through again: the bridge is disabled; no gap counts until the next."""
        with self._lock:
            self._reason = None
            self._last_pose = None

    def _shut_if_lapsed(self, now):
        if (self._reason is None and self._last_pose is not None
                and now - self._last_pose > self.timeout):
            self._reason = f'no pose for more than stream_timeout {self.timeout:g} s'
            self._last_pose = None


class PeerBook:
    """
    The peers connected to this site, told apart by the common name of their certificates.

    Zenoh tells each link's remote id, address and authentication identifier (with TLS, the
    common name of the certificate the peer showed, which the root CA signed). A peer whose name
    is not `expected` has a session, yet access control lets it put and subscribe nothing: it
    is shut out, and said so, not counted as authenticated.
    """

    def __init__(self, expected):
        """Start with no peer; `expected` is tls.peer_common_name."""
        self.expected = expected
        self._peers = {}  # remote id -> (address, certificate name)

    @property
    def authenticated(self):
        """Return how many peers bearing the expected name are connected."""
        return sum(name == self.expected for _, name in self._peers.values())

    def update(self, links):
        """
        Take the links now open, as (remote id, address, certificate name or None).

        Return a (warning, line) for each peer come or gone since the last update, warning
        True for a peer shut out.
        """
        now = {}
        for peer, address, name in links:
            now.setdefault(peer, (address, name))
        changes = []
        for peer, (address, name) in now.items():
            if peer not in self._peers:
                changes.append(self._came(address, name))
        for peer, (address, name) in self._peers.items():
            if peer not in now:
                who = 'authenticated peer' if name == self.expected else 'shut-out peer'
                changes.append((False, f'{who} {name} ({address}) gone'))
        self._peers = now
        return changes

    def _came(self, address, name):
        if name == self.expected:
            return False, f'authenticated peer {name} connected ({address})'
        shown = 'no certificate name' if name is None else f'a certificate for {name}'
        return True, (f'peer {address} shut out: it shows {shown}, not for {self.expected} '
                      '(tls.peer_common_name); access control lets it put and subscribe '
                      'nothing')
