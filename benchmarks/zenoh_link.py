#!/usr/bin/env python3
# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
What the Zenoh link adds to a pose's way between two hosts, against DDS directly, at 1 kHz.

Two hosts (test/harness/netns.py: two network namespaces joined by a veth pair; one machine,
one clock). Row `dds`: a publisher of stamped poses on one host and a receiver on the other,
one DDS domain across the veth (SUBNET, the peer as static peer, UDP), as
doc/teleoperation.md sets two machines up. Row `zenoh`: the same two, each on its own host's
DDS island (LOCALHOST, a domain each), and between them kraft_master_zenoh_link on each host
(the arm's listening, mutual TLS, certificates made by openssl in a temporary directory).
The rows alternate, `--runs` of each, `--seconds` of poses at `--rate` Hz per run. Figures: the
one-way delay (receipt minus stamp, system clock) p50, p99 and max, the share of poses that
did not arrive, how many the master's link sent and the arm's received, each link's CPU (its
process's user + system time over the run, in cores), the load average and the CPU share the
hypervisor stole. Run from the repository's root with
test/ on the path: `PYTHONPATH=test .venv/bin/python -m benchmarks.zenoh_link`.
"""
import argparse
import json
import os
import pathlib
import re
import signal
import subprocess
import sys
import time

from benchmarks.machine import cpu_times, steal_fraction
from harness.certificates import link_parameters, Sites
from harness.driver import next_domain_id
from harness.netns import SUBNET, TwoHosts
import numpy as np

REPO = pathlib.Path(__file__).resolve().parents[1]
STREAM = REPO / 'test' / 'harness' / 'stamped_stream.py'
TICKS_PER_S = os.sysconf('SC_CLK_TCK')


def process_cpu_s(pid):
    """Return the user + system CPU seconds process `pid` has used."""
    fields = pathlib.Path(f'/proc/{pid}/stat').read_text().rpartition(')')[2].split()
    return (int(fields[11]) + int(fields[12])) / TICKS_PER_S


def island_env(domain_id, base=None):
    """Return the environment of one host's own DDS island on this checkout's package."""
    env = dict(os.environ if base is None else base)
    env.update({'ROS_DOMAIN_ID': str(domain_id), 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
                'FASTDDS_BUILTIN_TRANSPORTS': 'UDPv4', 'PYTHONUNBUFFERED': '1',
                'PYTHONPATH': os.pathsep.join([str(REPO), str(REPO / 'test')])})
    return env


def start_link(host, env, sites, side, peer, extra=(), **endpoint):
    """Start kraft_master_zenoh_link of `side` in `host`, `extra` parameters too; return it."""
    command = [sys.executable, '-m', 'kraft_master_driver.nodes.zenoh_link', '--ros-args']
    for name, value in [*link_parameters(sites, side, peer, **endpoint), *extra]:
        command += ['-p', f'{name}:={value}']
    return host.popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                      text=True)


def wait_for_lines(process, *texts):
    """Read `process`'s output until each of `texts` has been in a line, in any order."""
    missing = set(texts)
    for line in process.stdout:
        missing = {text for text in missing if text not in line}
        if not missing:
            return
    raise RuntimeError(f'{", ".join(sorted(missing))} never came: the process ended')


def link_counts(links):
    """Stop the (arm, master) links; return the poses the master's sent, the arm's received."""
    counts = {}
    for link, key, pattern in ((links[1], 'master_link_sent', r'sent pose (\d+)'),
                               (links[0], 'arm_link_received', r'received pose (\d+)')
                               ) if links else ():
        link.send_signal(signal.SIGINT)
        found = re.findall(pattern, link.communicate(timeout=60)[0])
        counts[key] = int(found[-1]) if found else None
    return counts


def stream(publisher_host, publisher_env, receiver_host, receiver_env, rate, seconds):
    """Publish on one host, receive on the other; return the delays in ms and the count sent."""
    receiver = receiver_host.popen([sys.executable, STREAM, 'receive'], env=receiver_env,
                                   stdout=subprocess.PIPE, text=True)
    if receiver.stdout.readline().strip() != 'ready':
        raise RuntimeError('the receiver did not start')
    publisher_host.run([sys.executable, STREAM, 'publish', '--rate', str(rate), '--seconds',
                        str(seconds)], env=publisher_env, check=True, timeout=seconds + 300)
    # The last poses are on their way for well under a second.
    time.sleep(0.5)
    receiver.send_signal(signal.SIGINT)
    delays = json.loads(receiver.communicate(timeout=60)[0].strip().splitlines()[-1])
    return np.array(delays['delays_ns']) / 1e6, int(rate * seconds)


def run(kind, sites, rate, seconds):
    """Run one row of `kind` (dds or zenoh); return its figures."""
    with TwoHosts() as (master, arm):
        links = []
        if kind == 'dds':
            domain_id = next_domain_id()
            master_env = master.ros_env(domain_id, island_env(domain_id))
            arm_env = arm.ros_env(domain_id, island_env(domain_id))
        else:
            master_env, arm_env = island_env(next_domain_id()), island_env(next_domain_id())
            endpoint = f'tls/{arm.address}:7447'
            # No bridge here: the arm's link relays once it has waited for one; no gap in the
            # stream holds its poses back (stream_timeout at its maximum).
            links.append(start_link(arm, arm_env, sites, 'arm', 'master',
                                    [('stream_timeout', 10.0)], listen=endpoint))
            links.append(start_link(master, master_env, sites, 'master', 'arm',
                                    connect=endpoint))
            wait_for_lines(links[0], 'authenticated peer master connected', 'relaying the poses')
        cpu_before = [process_cpu_s(link.pid) for link in links]
        started = time.monotonic()
        delays, sent = stream(master, master_env, arm, arm_env, rate, seconds)
        elapsed = time.monotonic() - started
        cpu = [(process_cpu_s(link.pid) - before) / elapsed
               for link, before in zip(links, cpu_before)]
        counts = link_counts(links)
    return {'kind': kind, 'received': len(delays), 'lost_pct': 100.0 * (1 - len(delays) / sent),
            **counts,
            'p50_ms': float(np.percentile(delays, 50)), 'p99_ms': float(np.percentile(delays, 99)),
            'max_ms': float(np.max(delays)),
            'arm_link_cores': cpu[0] if cpu else None,
            'master_link_cores': cpu[1] if cpu else None}


def main(argv=None):
    """Run the rows, print them and what the Zenoh hop added."""
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('--rate', type=float, default=1000.0)
    parser.add_argument('--seconds', type=float, default=10.0)
    parser.add_argument('--runs', type=int, default=3)
    args = parser.parse_args(argv)
    load_before, times_before = os.getloadavg(), cpu_times()
    rows = []
    with Sites({'master': 'DNS:master-site', 'arm': f'IP:{SUBNET}2'}) as sites:
        for _ in range(args.runs):
            for kind in ('dds', 'zenoh'):
                row = run(kind, sites, args.rate, args.seconds)
                rows.append(row)
                print(json.dumps(row), flush=True)
    for kind in ('dds', 'zenoh'):
        mine = [r for r in rows if r['kind'] == kind]
        print(f'{kind}: p50 ms ' + ', '.join(f'{r["p50_ms"]:.3f}' for r in mine)
              + '; p99 ms ' + ', '.join(f'{r["p99_ms"]:.3f}' for r in mine))
    print('the Zenoh hop added, run by run: p50 ms ' + ', '.join(
        f'{z["p50_ms"] - d["p50_ms"]:+.3f}' for d, z in zip(rows[::2], rows[1::2]))
        + '; p99 ms ' + ', '.join(
        f'{z["p99_ms"] - d["p99_ms"]:+.3f}' for d, z in zip(rows[::2], rows[1::2])))
    print(f'load average {load_before[0]:.2f} before, {os.getloadavg()[0]:.2f} after; '
          f'stolen {100 * steal_fraction(times_before, cpu_times()):.1f} % of the CPU time')
    return 0


if __name__ == '__main__':
    sys.exit(main())
