# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The session soak's faults: their kinds, a schedule drawn from a seed, and their injection.

Each kind has a side (the checker's: master, arm, link or clock), a range of durations and a
function that injects it on a soak_site.Site and returns (start, end) in time.time() seconds,
the clock the recorder stamps messages with: start when the fault had surely taken effect,
end when it was cleared at the earliest (for a kill and restart, when the new process was
started). `force_untrue`: whether the force the master feels is no longer the arm's while it
lasts (the wrist sensor's faults, a stalled or dead arm, a link down). Not counted as untrue:
a stuck sensor reading, which looks like a true one and nothing on the path can tell apart
(doc/safety.md says so), and a loss burst, through which the messages that come are true.
`links`: the links between the sites it runs with (soak_site.LINKS): the link's own faults are
the emulator's parameters, or a restart of one of the two Zenoh links.
"""
import math
import random
import time
from typing import Callable, NamedTuple

from harness.faults import BASE, FLOOD_RATE_HZ, SOURCE_RATE_HZ, WRENCH

BAD_WRENCHES = {  # the driver's soak's rejected wrenches: (wrench, frame_id, stamp)
    'NaN force': ((math.nan, 0.0, 0.0, 0.0, 0.0, 0.0), BASE, 0.0),
    '1e9 N force': ((1e9, 0.0, 0.0, 0.0, 0.0, 0.0), BASE, 0.0),
    'unknown frame_id': (WRENCH, 'map', 0.0),
    'stamp 10 s in the future': (WRENCH, BASE, 10.0),
}


class Kind(NamedTuple):
    """One kind of fault."""

    name: str
    side: str
    shortest: float  # s
    longest: float  # s
    inject: Callable  # (soak, duration, rng) -> (start, end)
    force_untrue: bool = False
    links: tuple[str, ...] = ('emulator', 'zenoh')


def hold(soak, seconds):
    """Let the session run `seconds` while a fault lasts."""
    soak.run_for(seconds)


def device(fault):
    """Return the injection of a fault of the simulated master."""
    def inject(soak, duration, _rng):
        start = soak.site.master_fault(fault, True)
        hold(soak, duration)
        return start, soak.site.master_fault(fault, False)
    return inject


def bad_wrench(soak, duration, rng):
    """Stream, from a second source, a wrench the driver must reject."""
    wrench, frame_id, stamp = BAD_WRENCHES[rng.choice(sorted(BAD_WRENCHES))]
    start_ns, _ = soak.wrench_source().switch(SOURCE_RATE_HZ, wrench, frame_id, stamp)
    hold(soak, duration)
    end_ns, _ = soak.wrench_source().switch(0.0)
    return start_ns / 1e9, end_ns / 1e9


def wrench_flood(soak, duration, _rng):
    """Flood the driver with valid wrenches at 20 kHz from a second source."""
    start_ns, _ = soak.wrench_source().switch(FLOOD_RATE_HZ)
    hold(soak, duration)
    end_ns, _ = soak.wrench_source().switch(0.0)
    return start_ns / 1e9, end_ns / 1e9


def sensor(fault):
    """Return the injection of wrist sensor fault `fault` (the arm's ft_fault)."""
    def inject(soak, duration, _rng):
        start = soak.operator.set_parameters('arm', ft_fault=fault)
        hold(soak, duration)
        end = time.time()  # cleared between here and the answer: the earliest end
        soak.operator.set_parameters('arm', ft_fault='none')
        return start, end
    return inject


def arm_stall(soak, duration, _rng):
    """Stop the arm's process (SIGSTOP) for `duration`: a stalled controller."""
    arm = soak.site.children['arm']
    start = time.time()
    arm.pause(True)
    try:
        time.sleep(duration)  # nothing else may run meanwhile: a stall this short is exact
    finally:
        arm.pause(False)
    return start, time.time()


def restart_arm(soak, _duration, _rng):
    """
    SIGKILL the arm's process and start it again: over when it publishes its pose.

    The end is that pose's stamp, not when the soak received it: the bridge may take it and
    follow again (with force) seconds before the soak's operator hears of it.
    """
    start = soak.site.restart('arm', lambda killed: soak.operator.arm_stamp > killed)
    return start, soak.operator.arm_stamp


def restart_bridge(soak, _duration, _rng):
    """SIGKILL the bridge's process and start it again: over once it says its state."""
    soak.operator.state = ''
    start = soak.site.restart('bridge', lambda _killed: soak.operator.state)
    return start, time.time()


def link(soak, duration, values, cleared):
    """Set the link emulator's parameters `values` for `duration`, then `cleared`."""
    start = soak.operator.set_parameters('link', **values)
    hold(soak, duration)
    end = time.time()  # cleared between here and the answer: the earliest end
    soak.operator.set_parameters('link', **cleared)
    return start, end


def blackout(soak, duration, _rng):
    """Lose everything in both directions of the link."""
    return link(soak, duration, {'to_slave__blackout': True, 'to_master__blackout': True},
                {'to_slave__blackout': False, 'to_master__blackout': False})


def delay_step(soak, duration, rng):
    """Step both directions' delay from 0 to up to 500 ms, and back."""
    delay = rng.uniform(0.05, 0.5)
    return link(soak, duration, {'to_slave__delay': delay, 'to_master__delay': delay},
                {'to_slave__delay': 0.0, 'to_master__delay': 0.0})


def loss_burst(soak, duration, _rng):
    """Lose 30 % of the messages both ways, in runs of 50 on average."""
    lossy = {'loss': 0.3, 'loss_burst': 50.0}
    clear = {'loss': 0.0, 'loss_burst': 0.0}
    return link(soak, duration, {f'{d}__{k}': v for d in ('to_slave', 'to_master')
                                 for k, v in lossy.items()},
                {f'{d}__{k}': v for d in ('to_slave', 'to_master') for k, v in clear.items()})


def clock_skew(soak, duration, rng):
    """Move one site's stamps 0.5 to 5 s ahead or behind (the arm's, or the master's)."""
    direction = rng.choice(('to_slave', 'to_master'))
    skew = rng.choice((-1.0, 1.0)) * rng.uniform(0.5, 5.0)
    return link(soak, duration, {f'{direction}__stamp_offset': skew},
                {f'{direction}__stamp_offset': 0.0})


def zenoh_restart(side):
    """
    Return the injection of a restart of `side`'s Zenoh link: SIGKILL, started again after.

    SIGKILL, as a crash or the OOM killer ends it: no goodbye to the peer, no DDS teardown (the
    shared memory it leaves is removed). Over, at the earliest, when it is started again: it
    carries nothing before; the peers then find each other again on their own. Started again
    on a DDS participant id no process of the run had (Site.fresh_participant).
    """
    def inject(soak, duration, _rng):
        link = soak.site.children[f'zenoh_{side}']
        start = time.time()
        link.kill()
        hold(soak, duration)
        end = time.time()
        link.start(soak.site.fresh_participant())
        return start, end
    return inject


EMULATOR = ('emulator',)
ZENOH = ('zenoh',)
KINDS = [
    Kind('master: device unplugged', 'master', 0.5, 3.0, device('unplugged')),
    Kind('master: 1 reply in 10 dropped', 'master', 1.0, 3.0, device('replies dropped')),
    Kind('master: corrupt bytes 1e-2', 'master', 1.0, 3.0, device('corrupt bytes 1e-2')),
    Kind('master: device stalls', 'master', 0.05, 0.5, device('stall')),
    Kind('master: garbage flood', 'master', 1.0, 3.0, device('garbage')),
    Kind('master: bad wrench', 'master', 0.5, 2.0, bad_wrench),
    Kind('master: wrench flood', 'master', 0.5, 2.0, wrench_flood),
    Kind('wrist: dropout', 'arm', 0.2, 4.0, sensor('dropout'), True),
    Kind('wrist: NaN burst', 'arm', 0.1, 2.0, sensor('nan'), True),
    Kind('wrist: stuck value', 'arm', 0.5, 4.0, sensor('stuck')),
    Kind('wrist: spike over the limit', 'arm', 0.05, 1.0, sensor('spike'), True),
    Kind('wrist: frame change', 'arm', 0.2, 2.0, sensor('frame'), True),
    Kind('arm: controller stall', 'arm', 0.05, 2.0, arm_stall, True),
    Kind('arm: killed and restarted', 'arm', 0.0, 0.0, restart_arm, True),
    Kind('bridge: killed and restarted', 'arm', 0.0, 0.0, restart_bridge, True),
    Kind('link: blackout', 'link', 0.1, 10.0, blackout, True, EMULATOR),
    Kind('link: delay step', 'link', 2.0, 8.0, delay_step, links=EMULATOR),
    Kind('link: loss burst', 'link', 1.0, 5.0, loss_burst, links=EMULATOR),
    Kind('clock: stamp skew', 'clock', 1.0, 5.0, clock_skew, links=EMULATOR),
    Kind("link: master's Zenoh link restarted", 'link', 1.0, 5.0, zenoh_restart('master'),
         True, ZENOH),
    Kind("link: arm's Zenoh link restarted", 'link', 1.0, 5.0, zenoh_restart('arm'), True,
         ZENOH),
]


def kinds(link):
    """Return the kinds of fault that run with `link` (emulator or zenoh)."""
    return [kind for kind in KINDS if link in kind.links]


class Scheduled(NamedTuple):
    """One fault of the schedule: when (s after the soak started), which, how long."""

    at: float
    kind: Kind
    duration: float


def schedule(seed, duration, longest=math.inf, link='emulator'):
    """
    Return the faults of a run of `duration` s with `link` between the sites, drawn with `seed`.

    Every kind that runs with the link once in a random order, again and again, at times spread
    evenly with random jitter over the run, the first after 10 % of it; each lasts a duration
    drawn in its kind's range, cut to `longest`. At least one of each kind.
    """
    rng = random.Random(seed)
    drawn = kinds(link)
    rounds = max(1, round(duration / (20.0 * len(drawn))))
    order = []
    for _ in range(rounds):
        order += rng.sample(drawn, len(drawn))
    gap = 0.9 * duration / len(order)
    faults = []
    for number, kind in enumerate(order):
        at = 0.1 * duration + gap * (number + rng.uniform(0.0, 0.5))
        seconds = rng.uniform(kind.shortest, min(kind.longest, max(kind.shortest, longest)))
        faults.append(Scheduled(round(at, 2), kind, round(seconds, 3)))
    return faults, rng
