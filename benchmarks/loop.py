#!/usr/bin/env python3
# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The driver's force loop measured end to end, every party in its own process.

The simulated device (kraft_master_sim on a pseudo-terminal), the driver
(kraft_master_node), a wrench publisher and a joint_states subscriber run side by side for
--duration seconds at each loop rate; then the figures are printed as a table and written
as JSON:

- achieved cycle rate (commands the device received per second), joint_states per second at
  the subscriber (js/s), late and missed cycles;
- bare/s: the cycles per second a loop that does nothing but sleep to each deadline reaches at
  the same rate, alone, just before the run (machine.bare_loop, at the driver's loop_priority,
  skipping missed periods as the driver does): the most this machine allowed at that moment;
- bare work: that loop running a fixed amount of the driver's kinematics (BARE_WORK_US alone)
  after each wake-up, just before the run: how long the same Python takes on this machine at
  that moment (median, p99, max), against the loop thread's time running in a cycle;
- bare pty: that loop exchanging a command and a reply of the device's sizes over a
  pseudo-terminal with a process that only answers (machine.bare_pty, at the driver's and the
  simulator's priorities), just before the run: its reply period p99 is the least the
  pseudo-terminal allows the driver's period;
- cycle period distribution: between the commands the device received (the loop as the
  hardware sees it), and between the joint_states stamps the subscriber received (taken when
  each pot frame arrived; a message the subscriber lost doubles a gap, so read it with js/s);
- pot frame at the driver -> joint_states received by the subscriber;
- wrench published -> the matching torque command received by the device: the publisher
  flips the sign of its moment about z every 20 ms, which flips the sign of the axis-1
  command (tau1 = mz), and each flip of the measured window from the first command that
  carried a torque is matched with the first command of the new sign; for
  the flips slower than 20 ms (one never applied waits for the next of its sign), the share of
  the commands meanwhile that were zero or still of the old sign, the longest gap between
  them, and the driver's counters of zeroed wrenches;
- CPU time per cycle of the driver's loop thread by phase, and of the whole process; the cores
  each of the four processes used;
- with wire timing at 115200 baud and 1 Mbaud: achieved rate over the wire-limited rate;
- the share of the machine's CPU time the hypervisor stole during the run (a shared VM's
  neighbours), without which the other figures cannot be read.

--load runs a busy loop per core beside everything (the bare loop too); --dds-profile gives the
driver and the wrench publisher config/fastdds_realtime.xml (DDS threads at SCHED_FIFO 50);
--publisher-priority runs the wrench publisher's thread SCHED_FIFO, as a bridge would.
--sched-trace splits the device's gaps by what the driver's loop thread did in them, from the
kernel's scheduler events (benchmarks/sched_trace.py; perf, as root); --worker-priority, an
experiment, runs the kernel workers that carry the pseudo-terminal's bytes SCHED_FIFO.
"""
import argparse
import json
import os
import pathlib
import platform
import signal
import subprocess
import sys
import tempfile
import time

from benchmarks.machine import bare_loop, bare_pty, bare_work, cpu_times, steal_fraction
from benchmarks.sched_trace import Recording, SLOW_GAP_MS, summarize
from kraft_master_driver.link.protocol import get_codec
import numpy as np

REPO = pathlib.Path(__file__).resolve().parents[1]

DEFAULT_LOOP_PRIORITY = 50  # the driver's loop_priority default
DDS_PROFILE = REPO / 'config' / 'fastdds_realtime.xml'
FLIP_PERIOD_S = 0.02
WRENCH_RATE_HZ = 1000.0
MOMENT_NM = 0.5
# The bare work loop's Python per cycle: about the driver's loop thread's CPU per 1 kHz cycle.
BARE_WORK_US = 350.0


def ros_env(domain_id):
    """Environment of every process of a run: local discovery, one private domain."""
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               PYTHONPATH=str(REPO), PYTHONUNBUFFERED='1')
    return env


# -- the peer processes ----------------------------------------------------------------------

def run_subscriber(out_path, duration):
    """Record (receive time, stamp) of every joint_states message and the last diagnostics."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import ExternalShutdownException
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import JointState

    rclpy.init()
    node = rclpy.create_node('loop_benchmark_subscriber')
    capacity = int(duration * 6000) + 10000
    received = np.zeros((capacity, 2), dtype=np.int64)
    count = [0]
    diagnostics = {}

    ready = pathlib.Path(out_path + '.ready')

    def on_state(msg):
        i = count[0]
        if i == 0:
            ready.touch()
        if i < capacity:
            received[i, 0] = time.time_ns()
            received[i, 1] = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            count[0] = i + 1

    def on_diagnostics(msg):
        for status in msg.status:
            diagnostics.update({kv.key: kv.value for kv in status.values})

    qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    node.create_subscription(JointState, 'joint_states', on_state, qos)
    node.create_subscription(DiagnosticArray, 'diagnostics', on_diagnostics, 10)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        np.save(out_path + '.npy', received[:count[0]])
        with open(out_path + '.json', 'w') as stream:
            json.dump(diagnostics, stream)
        rclpy.try_shutdown()


def run_publisher(out_path, duration, priority=0):
    """Publish a wrench at 1 kHz whose moment about z flips sign every 20 ms."""
    import rclpy
    from geometry_msgs.msg import WrenchStamped
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    if priority:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    rclpy.init()
    node = rclpy.create_node('loop_benchmark_wrench')
    publisher = node.create_publisher(
        WrenchStamped, 'wrench', QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT))
    while publisher.get_subscription_count() == 0:
        time.sleep(0.05)
    pathlib.Path(out_path + '.ready').touch()
    msg = WrenchStamped()
    msg.header.frame_id = 'kraft_master_base'
    flips = []
    period_ns = int(1e9 / WRENCH_RATE_HZ)
    flip_every = int(FLIP_PERIOD_S * WRENCH_RATE_HZ)
    sign = 1.0
    stop = []
    signal.signal(signal.SIGINT, lambda *_: stop.append(True))
    deadline = time.monotonic_ns()
    i = 0
    while not stop:
        if i % flip_every == 0:
            sign = -sign
            flips.append((time.time_ns(), sign))
        now = time.time_ns()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(now, 1_000_000_000)
        msg.wrench.torque.z = sign * MOMENT_NM
        publisher.publish(msg)
        i += 1
        deadline += period_ns
        delay = deadline - time.monotonic_ns()
        if delay > 0:
            time.sleep(delay / 1e9)
    np.save(out_path, np.array(flips, dtype=np.float64))
    rclpy.try_shutdown()


# -- one run -----------------------------------------------------------------------------------

def process_cpu_seconds(pid):
    """User + system CPU time of a process so far, from /proc."""
    fields = pathlib.Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def set_unbound_workers(priority):
    """
    Run every unbound kernel worker (kworker/u*) SCHED_FIFO `priority`, or 0: normal again.

    The tty layer hands a pseudo-terminal's bytes to their reader in one of these. Workers the
    kernel starts later keep normal priority. Returns how many were set.
    """
    policy = os.SCHED_FIFO if priority else os.SCHED_OTHER
    count = 0
    for task in pathlib.Path('/proc').glob('[0-9]*'):
        try:
            if (task / 'comm').read_text().startswith('kworker/u'):
                os.sched_setscheduler(int(task.name), policy, os.sched_param(priority))
                count += 1
        except (FileNotFoundError, ProcessLookupError):
            continue
    return count


def start_simulator(env, record, baud, priority):
    command = [sys.executable, '-m', 'kraft_master_driver.simulation.master.simulator',
               '--record', record, '--priority', str(priority)]
    if baud:
        command += ['--baud', str(baud)]
    sim = subprocess.Popen(command, env=env, stdout=subprocess.PIPE, text=True)
    line = sim.stdout.readline()
    if not line.startswith('port: '):
        raise RuntimeError(f'kraft_master_sim did not print its port: {line!r}')
    return sim, line.split(': ', 1)[1].strip()


def wait_ready(paths, processes, timeout=60.0):
    """Wait until the peers have matched the driver (they touch a file each)."""
    deadline = time.monotonic() + timeout
    while not all(os.path.exists(path) for path in paths):
        failed = [p.args for p in processes if p.poll() is not None]
        if failed or time.monotonic() > deadline:
            raise RuntimeError(f'peers not ready; exited: {failed}')
        time.sleep(0.05)


def percentiles(values, scale):
    values = np.asarray(values, dtype=float) * scale
    if values.size == 0:
        return {'median': None, 'p99': None, 'p99.9': None, 'max': None, 'n': 0}
    median, p99, p999 = np.percentile(values, (50, 99, 99.9))
    return {'median': median, 'p99': p99, 'p99.9': p999, 'max': values.max(),
            'n': int(values.size)}


def loop_priority(driver_parameters):
    """Return the loop_priority among `driver_parameters` (NAME:=VALUE), else its default."""
    for parameter in driver_parameters:
        name, _, value = parameter.partition(':=')
        if name == 'loop_priority':
            return int(value)
    return DEFAULT_LOOP_PRIORITY


def wrench_latencies(flips, commands):
    """Flip publish time -> first device command with the new sign of axis 1 (s)."""
    times, axis1 = commands[:, 0], commands[:, 1]
    latencies = []
    for published_ns, sign in flips:
        after = np.flatnonzero((times >= published_ns) & (np.sign(axis1) == sign))
        if after.size:
            latencies.append((times[after[0]] - published_ns) / 1e9)
    return latencies


def slow_flips(flips, commands):
    """
    Return what the device got while each flip slower than FLIP_PERIOD_S was on its way.

    A flip is matched with the first command of its sign, so one never applied waits for the
    next flip of that sign: its latency is a multiple of the flip period. Returns the count of
    such flips and, over the commands between each and its match, the share that were zero
    (the driver refused or timed out the wrench), the share of the old sign (the new wrench not
    yet taken) and the longest gap between two commands (the loop stalled), in ms.
    """
    times, axis1 = commands[:, 0], commands[:, 1]
    zero = old = total = 0
    longest_gap_ns = 0.0
    count = 0
    for published_ns, sign in flips:
        after = np.flatnonzero((times >= published_ns) & (np.sign(axis1) == sign))
        if not after.size or times[after[0]] - published_ns <= FLIP_PERIOD_S * 1e9:
            continue
        count += 1
        between = (times >= published_ns) & (times < times[after[0]])
        zero += int(np.sum(between & (axis1 == 0.0)))
        old += int(np.sum(between & (np.sign(axis1) == -sign)))
        total += int(np.sum(between))
        window = times[(times >= published_ns) & (times <= times[after[0]])]
        if window.size > 1:
            longest_gap_ns = max(longest_gap_ns, float(np.diff(window).max()))
    return {'count': count, 'zero_share': zero / total if total else None,
            'old_sign_share': old / total if total else None,
            'longest_gap_ms': longest_gap_ns / 1e6 if count else None}


def run(rate_hz, duration, baud, domain_id, workdir, driver_parameters=(), sim_priority=0,
        dds_profile=False, publisher_priority=0, sched_trace=False, worker_priority=0):
    """Run the four processes for `duration` s; return the figures of this run."""
    env = ros_env(domain_id)
    realtime_env = dict(env, FASTRTPS_DEFAULT_PROFILES_FILE=str(DDS_PROFILE)) if dds_profile \
        else env
    floor = pty_floor = work_floor = None
    if not baud:
        priority = loop_priority(driver_parameters)
        floor = bare_loop(rate_hz, duration, priority)
        work_floor = bare_work(rate_hz, duration, priority, BARE_WORK_US)
        codec = get_codec('kraft-default')
        pty_floor = bare_pty(rate_hz, duration, priority, sim_priority, codec.command_size,
                             codec.reply_size)
    tag = f'{rate_hz:g}Hz_{baud or "pty"}'
    record = str(workdir / f'device_{tag}.npy')
    sim, port = start_simulator(env, record, baud, sim_priority)
    node_args = ['--ros-args', '-p', f'port:={port}', '-p', f'loop_rate_hz:={rate_hz}',
                 '-p', 'force_enabled_at_start:=true', '-p', 'reply_timeout:=0.02']
    if baud:
        node_args += ['-p', f'baud:={baud}']
    for parameter in driver_parameters:
        node_args += ['-p', parameter]
    driver = subprocess.Popen([sys.executable, '-m', 'kraft_master_driver.nodes.driver',
                               *node_args],
                              env=realtime_env, stdout=subprocess.DEVNULL)
    subscriber_out = str(workdir / f'subscriber_{tag}')
    publisher_out = str(workdir / f'publisher_{tag}.npy')
    # A repeated run's peers signal readiness anew: the last run's files would end the wait
    # at once, and the measured window would begin before the peers run.
    for ready in (subscriber_out + '.ready', publisher_out + '.ready'):
        pathlib.Path(ready).unlink(missing_ok=True)
    peers = [subprocess.Popen([sys.executable, '-m', 'benchmarks.loop', '--role', role,
                               '--out', out, '--duration', str(duration),
                               '--publisher-priority', str(publisher_priority)], env=role_env)
             for role, out, role_env in (('subscriber', subscriber_out, env),
                                         ('publisher', publisher_out, realtime_env))]
    processes = (*peers, driver, sim)
    # Started now, perf is recording by the time the peers are ready.
    recording = Recording(workdir / f'sched_{tag}.data') if sched_trace else None
    try:
        wait_ready([subscriber_out + '.ready', publisher_out + '.ready'], processes)
        workers = set_unbound_workers(worker_priority) if worker_priority else None
        machine_start = cpu_times()
        cpu_start, wall_start = process_cpu_seconds(driver.pid), time.time_ns()
        roles = {'simulator': sim, 'driver': driver, 'subscriber': peers[0],
                 'publisher': peers[1]}
        role_cpu_start = {role: process_cpu_seconds(p.pid) for role, p in roles.items()}
        time.sleep(duration)
        cpu_end, wall_end = process_cpu_seconds(driver.pid), time.time_ns()
        role_cpu = {role: process_cpu_seconds(p.pid) - role_cpu_start[role]
                    for role, p in roles.items()}
        steal = steal_fraction(machine_start, cpu_times())
    finally:
        if worker_priority:
            set_unbound_workers(0)
        if recording:
            recording.stop()
        for process in processes:
            process.send_signal(signal.SIGINT)
            try:
                process.wait(timeout=30)
            except subprocess.TimeoutExpired:
                process.kill()

    states = np.load(subscriber_out + '.npy')
    with open(subscriber_out + '.json') as stream:
        diagnostics = json.load(stream)
    flips = np.load(publisher_out)
    device = np.load(record)
    in_window = (device[:, 0] >= wall_start) & (device[:, 0] < wall_end)
    states_window = states[(states[:, 1] >= wall_start) & (states[:, 1] < wall_end)]
    window_s = (wall_end - wall_start) / 1e9
    cycles = int(in_window.sum())
    # The flips of the measured window (not the last 0.1 s, whose match may come after it),
    # from the first command that carried a torque: the publisher starts once it has matched
    # the driver's subscription, and the driver's reader may match it later.
    in_window_flips = flips[(flips[:, 0] >= wall_start) & (flips[:, 0] < wall_end - 1e8)]
    torques = device[device[:, 1] != 0.0, 0]
    first_torque_ns = torques[0] if torques.size else np.inf
    measured_flips = in_window_flips[in_window_flips[:, 0] >= first_torque_ns]
    figures = {
        'loop_rate_hz': rate_hz,
        'baud': baud,
        'window_s': window_s,
        'cycles_per_s': cycles / window_s,
        'joint_states_per_s': len(states_window) / window_s,
        'bare_loop': floor,
        'bare_pty': pty_floor,
        'bare_work': work_floor,
        'late_cycles': int(diagnostics.get('late cycles', -1)),
        'missed_cycles': int(diagnostics.get('missed cycles', -1)),
        'period_ms': percentiles(np.diff(device[in_window, 0]), 1e-6),
        'stamp_period_ms': percentiles(np.diff(np.sort(states_window[:, 1])), 1e-6),
        'pot_frame_to_subscriber_ms': percentiles(states_window[:, 0] - states_window[:, 1],
                                                  1e-6),
        'wrench_to_device_ms': percentiles(
            wrench_latencies(measured_flips, device), 1e3),
        'slow_flips': slow_flips(measured_flips, device),
        'flips_before_first_torque': int(np.sum(in_window_flips[:, 0] < first_torque_ns)),
        'wrench_zeroed': {key: int(diagnostics.get(f'force {key}', -1))
                          for key in ('watchdog_trips', 'age_expiries', 'rejected_too_old')},
        'cpu_steal': steal,
        'workers_at_priority': workers,
        'process_cores': {role: seconds * 1e9 / (wall_end - wall_start)
                          for role, seconds in role_cpu.items()},
        'cpu_per_cycle_us': {
            'link': float(diagnostics.get('cpu per cycle link (us)', 'nan')),
            'kinematics': float(diagnostics.get('cpu per cycle kinematics (us)', 'nan')),
            'publish': float(diagnostics.get('cpu per cycle publish (us)', 'nan')),
            'process': 1e6 * (cpu_end - cpu_start) / max(cycles, 1),
        },
    }
    if sched_trace:
        # The device's times are the system clock's, perf's the monotonic clock's.
        offset_ns = time.time_ns() - time.monotonic_ns()
        figures['sched_trace'] = summarize(recording.path, device[in_window, 0] - offset_ns,
                                           driver.pid, sim.pid)
    if baud:
        wire_rate = 1.0 / get_codec('kraft-default').wire_cycle_time(baud)
        figures['wire_limited_rate'] = wire_rate
        figures['achieved_over_wire_limited'] = figures['cycles_per_s'] / wire_rate
    return figures


def median_run(repeats):
    """Each figure's median over repeated runs of one configuration (marked 'median')."""
    def median_of(values):
        if all(value == values[0] for value in values):
            return values[0]
        if isinstance(values[0], dict):
            return {key: median_of([value[key] for value in values]) for key in values[0]}
        if isinstance(values[0], (int, float)) and not isinstance(values[0], bool):
            known = [value for value in values if value is not None]
            return float(np.median(known)) if known else None
        return values[0]
    figures = median_of([{key: value for key, value in r.items() if key != 'sched_trace'}
                         for r in repeats])
    figures['median_of'] = len(repeats)
    return figures


# -- output ------------------------------------------------------------------------------------

def fmt(value, digits=3):
    return '-' if value is None else f'{value:.{digits}f}'


def print_table(results):
    print(f'{"run":>21} {"cycles/s":>9} {"bare/s":>7} {"bare pty p99":>12} {"js/s":>7} '
          f'{"js p99":>6} {"late":>5} {"missed":>6} | '
          f'period ms: {"med":>6} {"p99":>6} {"p99.9":>6} {"max":>6} | pot->sub ms: '
          f'{"med":>6} {"p99":>6} {"max":>6} | wrench->dev ms: {"med":>6} {"p99":>6} {"max":>6} | '
          f'cpu us/cycle: {"link":>5} {"kin":>5} {"pub":>5} {"proc":>6} | of wire | steal')
    for r in results:
        period, sub, wrench, cpu = (r['period_ms'], r['pot_frame_to_subscriber_ms'],
                                    r['wrench_to_device_ms'], r['cpu_per_cycle_us'])
        name = f'{r["loop_rate_hz"]:g} Hz {r["baud"] or "pty"}'
        if 'median_of' in r:
            name = f'median {name}'
        wire = r.get('achieved_over_wire_limited')
        bare = '-' if r['bare_loop'] is None else f'{r["bare_loop"]["cycles_per_s"]:.1f}'
        pty = '-' if r.get('bare_pty') is None else f'{r["bare_pty"]["period_ms"]["p99"]:.3f}'
        print(f'{name:>21} {r["cycles_per_s"]:9.1f} {bare:>7} {pty:>12} '
              f'{r["joint_states_per_s"]:7.1f} {fmt(r["stamp_period_ms"]["p99"]):>6} '
              f'{r["late_cycles"]:5.0f} '
              f'{r["missed_cycles"]:6.0f} |            {fmt(period["median"]):>6} '
              f'{fmt(period["p99"]):>6} {fmt(period["p99.9"]):>6} {fmt(period["max"]):>6} | '
              f'              {fmt(sub["median"]):>6} {fmt(sub["p99"]):>6} '
              f'{fmt(sub["max"]):>6} |                 {fmt(wrench["median"]):>6} '
              f'{fmt(wrench["p99"]):>6} {fmt(wrench["max"]):>6} |               '
              f'{cpu["link"]:5.0f} {cpu["kinematics"]:5.0f} {cpu["publish"]:5.0f} '
              f'{cpu["process"]:6.0f} | {"-" if wire is None else f"{100 * wire:.1f}%":>7} | '
              f'{100 * r["cpu_steal"]:4.0f}%')


def describe_slow_flips(figures):
    """One run's slow flips and zeroing counters, in words."""
    slow, zeroed = figures['slow_flips'], figures['wrench_zeroed']
    counters = ', '.join(f'{key} {value}' for key, value in zeroed.items())
    if not slow['count']:
        return f'none ({counters})'
    return (f'{slow["count"]}, commands zero {100 * slow["zero_share"]:.0f} % and of the old '
            f'sign {100 * slow["old_sign_share"]:.0f} %, longest gap '
            f'{slow["longest_gap_ms"]:.1f} ms ({counters})')


def describe_work(work):
    """Say the bare work loop's figures in a few words."""
    wall, cpu = work['work_wall_ms'], work['work_cpu_ms']
    return (f'{wall["median"]:.3f} / {wall["p99"]:.3f} / {wall["max"]:.3f}, '
            f'{cpu["median"]:.3f} / {cpu["p99"]:.3f}')


def describe_sched_trace(figures):
    """One run's split of the device's gaps by what the loop and the simulator did, in words."""
    trace = figures['sched_trace']

    def listed(counts, unit=''):
        return ', '.join(f'{key} {value:.1f}{unit}' if unit else f'{key} {value}'
                         for key, value in counts.items()) or '-'

    lines = [f'{figures["loop_rate_hz"]:g} Hz {figures["baud"] or "pty"}: the device\'s '
             f'{trace["gaps"]} gaps, {trace["slow_gaps"]} over {SLOW_GAP_MS} ms; '
             'ms per gap, all / slow:']
    for role in ('loop', 'simulator'):
        thread = trace[role]
        if thread is None:
            lines.append(f'  {role} thread: not in the trace')
            continue
        means = ', '.join(f'{state} {thread["mean_ms_all"][state]:.3f} / '
                          f'{thread["mean_ms_slow"][state]:.3f}'
                          for state in thread['mean_ms_all'])
        lines.append(f'  {role} thread: {means}; slow gaps by the state with most time beyond '
                     f'its mean: {listed(thread["slow_gaps_by_excess"])}; ran while it waited '
                     f'for a CPU in them: {listed(thread["ahead_ms"], " ms")}')
    workers = trace['workers']
    each = workers['percentiles_ms']
    lines.append(f'  kernel workers woken in a gap waited for a CPU '
                 f'{workers["wait_ms"]["all"]:.3f} / {workers["wait_ms"]["slow"]:.3f} (each: '
                 f'median {fmt(each["median"])}, p99 {fmt(each["p99"])}, max '
                 f'{fmt(each["max"])}); in the slow gaps behind: '
                 f'{listed(workers["ahead_ms"], " ms")}')
    return '\n'.join(lines)


def run_all(args, domain_id):
    """Run every configuration the arguments ask for; return the figures of each run."""
    results = []
    with tempfile.TemporaryDirectory() as workdir:
        runs = [(rate, None) for rate in args.rates] + [(1000.0, baud) for baud in args.bauds]
        for rate, baud in runs:
            repeats = []
            for attempt in range(1, args.repeat + 1):
                print(f'running {rate:g} Hz, {baud or "pty without wire timing"}, '
                      f'{args.duration:g} s ({attempt}/{args.repeat}) ...', flush=True)
                repeats.append(run(rate, args.duration, baud, domain_id,
                                   pathlib.Path(workdir), args.set, args.sim_priority,
                                   args.dds_profile, args.publisher_priority,
                                   args.sched_trace, args.worker_priority))
            results.extend(repeats)
            if args.repeat > 1:
                results.append(median_run(repeats))
    return results


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--duration', type=float, default=20.0,
                        help='measured seconds per run (default 20)')
    parser.add_argument('--rates', type=float, nargs='*', default=[500.0, 1000.0, 2000.0],
                        help='loop_rate_hz of the runs without wire timing')
    parser.add_argument('--bauds', type=int, nargs='*', default=[115200, 1_000_000],
                        help='wire-timed runs at 1000 Hz (default 115200 1000000)')
    parser.add_argument('--repeat', type=int, default=1,
                        help='runs per configuration; with more than one, a median row too')
    parser.add_argument('--set', metavar='NAME:=VALUE', nargs='*', default=[],
                        help='extra driver parameters, e.g. loop_priority:=0')
    parser.add_argument('--sim-priority', type=int, default=0,
                        help="the simulator's --priority (default 0: normal)")
    parser.add_argument('--load', action='store_true',
                        help='a busy loop per core beside every run (the bare loop too)')
    parser.add_argument('--dds-profile', action='store_true',
                        help='driver and wrench publisher with config/fastdds_realtime.xml')
    parser.add_argument('--publisher-priority', type=int, default=0,
                        help="the wrench publisher's SCHED_FIFO priority (default 0: normal)")
    parser.add_argument('--sched-trace', action='store_true',
                        help="split the device's gaps by what the loop thread did (perf; root)")
    parser.add_argument('--worker-priority', type=int, default=0,
                        help='an experiment: the unbound kernel workers, which carry the '
                             "pseudo-terminal's bytes, SCHED_FIFO at this priority in each run")
    parser.add_argument('--json', help='write the figures here (default benchmarks/results/)')
    parser.add_argument('--role', choices=('subscriber', 'publisher'), help=argparse.SUPPRESS)
    parser.add_argument('--out', help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.role == 'subscriber':
        return run_subscriber(args.out, args.duration)
    if args.role == 'publisher':
        return run_publisher(args.out, args.duration, args.publisher_priority)

    domain_id = 100 + os.getpid() % 100
    load = [subprocess.Popen([sys.executable, '-c', 'while True: pass'])
            for _ in range(os.cpu_count() if args.load else 0)]
    try:
        results = run_all(args, domain_id)
    finally:
        for busy in load:
            busy.kill()
            busy.wait()
    print_table(results)
    print('cores used by each process (CPU s per s): ' + '; '.join(
        f'{r["loop_rate_hz"]:g} Hz {r["baud"] or "pty"}: ' + ', '.join(
            f'{role} {cores:.2f}' for role, cores in r['process_cores'].items())
        for r in results if 'median_of' not in r))
    print(f'wrench flips slower than {1e3 * FLIP_PERIOD_S:g} ms, the commands the device got '
          "meanwhile, and the driver's zeroing counters: " + '; '.join(
              f'{r["loop_rate_hz"]:g} Hz {r["baud"] or "pty"}: {describe_slow_flips(r)}'
              for r in results if 'median_of' not in r))
    print(f"bare work ({BARE_WORK_US:g} us of the driver's kinematics after each wake-up, "
          "alone at the loop's priority), wall ms median / p99 / max and CPU ms median / p99: "
          + '; '.join(f'{r["loop_rate_hz"]:g} Hz: {describe_work(r["bare_work"])}'
                      for r in results if r.get('bare_work') and 'median_of' not in r))
    for r in results:
        if 'sched_trace' in r and 'median_of' not in r:
            print(describe_sched_trace(r))
    out = pathlib.Path(args.json or REPO / 'benchmarks' / 'results' /
                       time.strftime('loop-%Y%m%d-%H%M%S.json'))
    out.parent.mkdir(parents=True, exist_ok=True)
    machine = {'platform': platform.platform(), 'python': platform.python_version(),
               'cpus': os.cpu_count()}
    out.write_text(json.dumps({'machine': machine, 'driver_parameters': args.set,
                               'sim_priority': args.sim_priority, 'load': args.load,
                               'dds_profile': args.dds_profile,
                               'publisher_priority': args.publisher_priority,
                               'worker_priority': args.worker_priority,
                               'runs': results}, indent=2, default=float))
    print(f'figures written to {out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
