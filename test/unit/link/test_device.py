# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Tests of KmcDevice against the simulated hand controller over a real pseudo-terminal.

Every test with the simulator runs once per built-in frame description.
"""
import math
import os
import random
import select
import socket
import threading
import time

from kraft_master_driver.core.calibration import POT_MAX
from kraft_master_driver.link.device import CycleResult, KmcDevice, LinkError
from kraft_master_driver.link.protocol import CODECS, STATUS_AMPLIFIERS_ENABLED
from kraft_master_driver.simulation.master.simulator import SimulatedKraftMaster
import pytest

SCALE = (1000.0, 500.0, 2000.0, 250.0, 100.0)
LIMIT = (3000, 2000, 1000, 500, 300)
WAIT_S = 10.0  # upper bound for conditions to come true on a loaded machine
ZERO = (0,) * 5


def wait_for(condition, timeout=WAIT_S):
    """Poll condition() until it is true (return True) or timeout seconds pass (False)."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.001)
    return True


def cycle_until(device, condition, torques=(0.0,) * 5, timeout=WAIT_S):
    """Cycle device until condition(result) holds; return the results, [] on timeout."""
    deadline = time.monotonic() + timeout
    results = []
    while time.monotonic() < deadline:
        results.append(device.cycle(torques))
        if condition(results[-1]):
            return results
        if not device.link_up:
            time.sleep(0.001)
    return []


def expected_counts(torques):
    """Return the counts the device must send: round(scale * torque) clamped, non-finite 0."""
    counts = []
    for torque, scale, limit in zip(torques, SCALE, LIMIT):
        count = round(torque * scale) if math.isfinite(torque) else 0
        counts.append(max(-limit, min(limit, count)))
    return tuple(counts)


@pytest.fixture(params=sorted(CODECS))
def sim(request):
    """Run a simulator that does not clamp, so it receives exactly what the device sends."""
    with SimulatedKraftMaster(codec=request.param, torque_limit=(32767,) * 5) as simulator:
        yield simulator


# The test's scales and limits, a generous reply timeout and quick reconnects.
DEVICE_OPTIONS = {'torque_scale': SCALE, 'torque_limit': LIMIT, 'reply_timeout': 0.5,
                  'reconnect_min': 0.01, 'reconnect_max': 0.1}


def make_device(sim, **options):
    """Return an open KmcDevice on sim's port and frame, DEVICE_OPTIONS updated by options."""
    device = KmcDevice(sim.port, codec=sim.codec, **{**DEVICE_OPTIONS, **options})
    assert device.open()
    return device


@pytest.mark.slow
def test_thousands_of_cycles_deliver_exact_torques(sim):
    rng = random.Random(1)
    specials = [math.nan, math.inf, -math.inf, 1e9, -1e9, 0.0, 2.9995, -2.9995]
    torque_sets = [
        tuple(rng.choice(specials) if rng.random() < 0.05 else rng.uniform(-4.0, 4.0)
              for _ in range(5))
        for _ in range(3000)]
    device = make_device(sim)
    sent_before = len(sim.received)
    results = [device.cycle(torques) for torques in torque_sets]
    device.close()
    assert all(isinstance(result, CycleResult) for result in results)
    assert wait_for(lambda: len(sim.received) == sent_before + len(torque_sets) + 1)
    received = [command for _, command in list(sim.received)[sent_before:]]
    assert [command.counts for command in received[:-1]] == [
        expected_counts(torques) for torques in torque_sets]
    assert received[-1].counts == ZERO
    for result, command, torques in zip(results, received, torque_sets):
        assert result.frame.sequence == command.sequence
        assert result.frame.status & STATUS_AMPLIFIERS_ENABLED
        assert all(0 <= pot <= POT_MAX for pot in result.frame.pots)
        assert result.commanded_nm == pytest.approx(
            [count / scale for count, scale in zip(expected_counts(torques), SCALE)])
        assert result.round_trip_s > 0
    assert results[-1].receive_ns > results[0].receive_ns
    stats = device.stats
    assert stats['cycles'] == stats['replies'] == len(torque_sets)
    assert stats['clamped_commands'] == sum(
        any(abs(round(t * s)) > limit for t, s, limit in zip(torques, SCALE, LIMIT)
            if math.isfinite(t)) for torques in torque_sets) > 0
    assert stats['nonfinite_commands'] == sum(
        not all(map(math.isfinite, torques)) for torques in torque_sets)
    assert stats['timeouts'] == stats['link_faults'] == stats['stale_replies'] == 0
    assert stats['zero_commands'] == 1


@pytest.mark.slow
def test_dropped_replies_count_as_timeouts(sim):
    sim.drop_reply_rate = 0.25
    device = make_device(sim, reply_timeout=0.02, timeouts_before_reconnect=1000)
    results = [device.cycle((0.1,) * 5) for _ in range(200)]
    stats = device.stats
    dropped = sim.stats['dropped']
    assert dropped > 0
    assert results.count(None) == stats['timeouts']
    # A reply later than the timeout (a loaded machine) is a timeout, then a stale reply.
    assert dropped <= stats['timeouts'] <= dropped + stats['stale_replies'] + 1
    assert stats['replies'] + stats['timeouts'] == stats['cycles'] == 200
    assert stats['link_faults'] == 0 and device.link_up
    device.close()


@pytest.mark.slow
def test_corrupt_bytes_are_counted_and_never_accepted(sim):
    sim.corrupt_byte_rate = 0.01
    device = make_device(sim, reply_timeout=0.02, timeouts_before_reconnect=1000)
    results = [device.cycle((0.2,) * 5) for _ in range(300)]
    stats = device.stats
    assert sim.stats['corrupted_bytes'] > 0
    assert stats['bad_crc'] + stats['truncated'] > 0
    assert stats['garbage_bytes'] > 0
    assert stats['timeouts'] > 0
    assert stats['replies'] + stats['timeouts'] == 300
    codec = device.codec
    for result in filter(None, results):
        assert result.frame.status & STATUS_AMPLIFIERS_ENABLED
        assert codec.encode_reply(*result.frame)  # every field of an accepted frame in range
    device.close()


def test_send_then_receive_is_one_cycle_and_an_unanswered_send_is_forgotten(sim):
    device = make_device(sim)
    assert device.receive() is None  # nothing sent yet
    assert device.send((0.1, 0.0, 0.0, 0.0, 0.0))
    first = device.receive()
    assert first is not None and first.commanded_nm[0] == 0.1
    assert device.receive() is None  # that reply was taken
    assert device.send((0.2, 0.0, 0.0, 0.0, 0.0))
    assert device.send((0.3, 0.0, 0.0, 0.0, 0.0))  # the reply to 0.2 is no longer wanted
    third = device.receive()
    assert third is not None and third.commanded_nm[0] == 0.3
    if device.codec.has_sequence:
        assert third.frame.sequence == (first.frame.sequence + 2) % 256
        assert device.stats['stale_replies'] == 1 and device.stats['timeouts'] == 0
    else:  # the reply to 0.2, dropped before 0.3 went out, or taken for 0.3's
        assert device.stats['stale_replies'] <= 1 and device.stats['timeouts'] == 0
    device.close()
    with pytest.raises(LinkError):
        device.send(ZERO)
    with pytest.raises(LinkError):
        device.receive()


def test_short_stall_times_out_then_recovers_without_reconnect(sim):
    device = make_device(sim, reply_timeout=0.02, timeouts_before_reconnect=1000)
    assert device.cycle((0.0,) * 5) is not None
    sim.stall(200)
    assert cycle_until(device, lambda result: result is None)
    assert device.stats['timeouts'] >= 1
    assert cycle_until(device, lambda result: result is not None)
    assert device.stats['link_faults'] == 0 and device.link_up
    # The stall outlasted the device's 0.1 s watchdog: its first reply after it says so.
    assert device.stats['device_command_timeouts'] == 1
    device.close()


@pytest.mark.slow
def test_long_stall_declares_the_link_dead_and_reconnects(sim):
    device = make_device(sim, reply_timeout=0.02, timeouts_before_reconnect=5)
    assert device.cycle((0.5,) * 5) is not None
    sim.stall(1000)
    results = cycle_until(device, lambda _: device.stats['link_faults'] >= 1)
    assert results and not any(results)
    assert 'consecutive' in device.last_error
    assert device.stats['timeouts'] >= 5
    results = cycle_until(device, lambda result: result is not None)
    assert results and device.link_up
    stats = device.stats
    assert stats['reconnects'] >= 1
    assert stats['zero_commands'] >= 1  # written before the port was closed
    assert sim.stats['timeouts'] >= 1  # the device's watchdog zeroed its torques
    device.close()


def test_unplug_marks_the_link_down_and_replug_reconnects(sim):
    device = make_device(sim)
    assert device.cycle((0.3,) * 5) is not None
    sim.unplug()
    assert device.cycle((0.3,) * 5) is None
    assert not device.link_up
    assert device.stats['link_faults'] == 1
    assert device.last_error
    # While unplugged, every cycle returns None at once; reopen attempts fail and back off.
    assert all(device.cycle((0.3,) * 5) is None for _ in range(100))
    assert wait_for(lambda: device.cycle((0.3,) * 5) is None and
                    device.stats['failed_opens'] >= 2)
    assert 'cannot open' in device.last_error
    sim.replug()
    assert cycle_until(device, lambda result: result is not None)
    assert device.link_up
    assert device.stats['reconnects'] == 1
    device.close()


def test_reopen_attempts_back_off_exponentially():
    device = KmcDevice('/nonexistent/kmc/tty', reconnect_min=0.01, reconnect_max=0.04)
    assert device.open() is False
    attempts = [time.monotonic()]
    while len(attempts) < 6:
        assert device.cycle((0.0,) * 5) is None
        if device.stats['failed_opens'] > len(attempts):
            attempts.append(time.monotonic())
        time.sleep(0.001)
    gaps = [later - earlier for earlier, later in zip(attempts, attempts[1:])]
    for gap, backoff in zip(gaps, (0.01, 0.02, 0.04, 0.04, 0.04)):
        assert gap >= backoff * 0.99
    device.close()


def test_zero_torques_on_close_and_context_exit(sim):
    with KmcDevice(sim.port, codec=sim.codec, **DEVICE_OPTIONS) as device:
        for _ in range(20):
            assert device.cycle((1.0, -1.0, 0.4, -0.4, 2.0)) is not None
        count = len(sim.received)
    assert wait_for(lambda: len(sim.received) == count + 1)
    assert sim.received[-1][1].counts == ZERO
    assert not device.link_up
    with pytest.raises(LinkError, match='closed'):
        device.cycle((0.0,) * 5)
    device.close()  # a second close is harmless
    assert device.stats['zero_commands'] == 1


def test_close_from_another_thread_ends_the_loop_with_zero_torques(sim):
    device = make_device(sim)
    outcome = []

    def control_loop():
        try:
            while True:
                device.cycle((0.7,) * 5)
        except LinkError as error:
            outcome.append(error)

    thread = threading.Thread(target=control_loop)
    thread.start()
    assert wait_for(lambda: device.stats['replies'] >= 50)
    device.close()
    thread.join(WAIT_S)
    assert not thread.is_alive() and outcome
    assert wait_for(lambda: sim.received[-1][1].counts == ZERO)
    assert device.stats['zero_commands'] == 1


def test_garbage_flood_is_skipped(sim):
    device = make_device(sim, reply_timeout=0.5, timeouts_before_reconnect=1000)
    for _ in range(10):
        sim.send_garbage(3000)
        device.cycle((0.1,) * 5)
    assert sim.stats['garbage_sent'] == 30000 and sim.stats['unsent'] == 0
    assert cycle_until(device, lambda _: device.stats['garbage_bytes'] >= 30000)
    assert all(device.cycle((0.1,) * 5) is not None for _ in range(50))
    stats = device.stats
    assert stats['garbage_bytes'] == 30000
    assert stats['link_faults'] == 0
    device.close()


@pytest.mark.parametrize('codec', sorted(CODECS))
def test_loop_url_times_out_every_cycle_without_raising(codec):
    device = KmcDevice('loop://', codec=codec, reply_timeout=0.005)
    assert device.open()
    assert all(device.cycle((0.5,) * 5) is None for _ in range(20))
    stats = device.stats
    assert stats['timeouts'] == stats['cycles'] == 20
    assert stats['replies'] == stats['stale_replies'] == 0
    # The loopback returns our own commands (15 bytes in kraft-default): nothing but garbage to
    # the reply decoder (up to one reply's length may still be held as a possible frame start).
    command, reply = device.codec.command_size, device.codec.reply_size
    assert 20 * command - reply < stats['garbage_bytes'] <= 20 * command
    device.close()


def test_unopenable_port_leaves_the_link_down():
    device = KmcDevice('/nonexistent/kmc/tty', reconnect_min=10.0, reconnect_max=10.0)
    assert device.open() is False
    assert not device.link_up
    assert '/nonexistent/kmc/tty' in device.last_error
    assert 'cannot open' in device.last_error
    assert all(device.cycle((0.0,) * 5) is None for _ in range(100))
    assert device.stats['failed_opens'] == 1  # the next attempt waits for the backoff
    assert device.stats['cycles'] == 0
    device.close()


def test_a_second_driver_on_the_same_port_fails_to_open(sim):
    first = make_device(sim)
    second = KmcDevice(sim.port, codec=sim.codec, **DEVICE_OPTIONS)
    assert second.open() is False
    assert 'lock' in second.last_error
    assert all(first.cycle((0.0,) * 5) is not None for _ in range(20))
    first.close()
    assert second.open()
    assert second.cycle((0.0,) * 5) is not None
    second.close()


def test_low_latency_on_a_pty_is_a_warning(sim):
    device = make_device(sim, low_latency=True)
    assert device.link_up
    assert device.stats['low_latency_failures'] == 1
    assert 'low latency' in device.last_error
    assert device.cycle((0.0,) * 5) is not None
    device.close()


def relay(listener, pty_path, stop):
    """Forward bytes between one TCP connection and the pty at pty_path until stop is set."""
    connection, _ = listener.accept()
    tty = os.open(pty_path, os.O_RDWR | os.O_NOCTTY)
    try:
        while not stop.is_set():
            for source in select.select([connection, tty], [], [], 0.05)[0]:
                if source is connection:
                    os.write(tty, connection.recv(4096))
                else:
                    connection.sendall(os.read(tty, 4096))
    finally:
        os.close(tty)
        connection.close()


def test_socket_url_through_a_tcp_relay(sim):
    listener = socket.create_server(('127.0.0.1', 0))
    stop = threading.Event()
    thread = threading.Thread(target=relay, args=(listener, sim.port, stop), daemon=True)
    thread.start()
    device = KmcDevice(f'socket://127.0.0.1:{listener.getsockname()[1]}', codec=sim.codec,
                       **DEVICE_OPTIONS)
    assert device.open()
    try:
        results = [device.cycle((0.25,) * 5) for _ in range(200)]
        assert all(results)
        assert [command.counts for _, command in list(sim.received)[-200:]] == [
            expected_counts((0.25,) * 5)] * 200
    finally:
        device.close()
        stop.set()
        thread.join()
        listener.close()


def test_wire_limited_rate():
    assert KmcDevice('loop://', baudrate=115200).wire_limited_rate() == pytest.approx(
        115200 / 330)
    assert KmcDevice('loop://').wire_limited_rate() == pytest.approx(1e6 / 330)
    example = KmcDevice('loop://', codec='example-be-crc8')
    assert example.wire_limited_rate() == pytest.approx(1e6 / 310)  # 14 + 17 bytes


@pytest.mark.parametrize('options, name', [
    ({'torque_scale': (1.0,) * 4}, 'torque_scale'),
    ({'torque_scale': (1.0, 1.0, 1.0, 1.0, math.nan)}, 'torque_scale'),
    ({'torque_scale': (1.0, 1.0, 1.0, 1.0, -1.0)}, 'torque_scale'),
    ({'torque_scale': (1.0, 1.0, 1.0, 1.0, math.inf)}, 'torque_scale'),
    ({'torque_limit': (100,) * 6}, 'torque_limit'),
    ({'torque_limit': (100, 100, 100, 100, 0)}, 'torque_limit'),
    ({'torque_limit': (100, 100, 100, 100, 32768)}, 'torque_limit'),
    ({'torque_limit': (100, 100, 100, 100, 10.5)}, 'torque_limit'),
    ({'torque_limit': 'fast'}, 'torque_limit'),
    ({'reply_timeout': 0}, 'reply_timeout'),
    ({'baudrate': -9600}, 'baudrate'),
    ({'codec': 'kmc-real'}, 'kraft-default'),
    ({'reconnect_min': 1.0, 'reconnect_max': 0.5}, 'reconnect_max'),
    ({'timeouts_before_reconnect': 0}, 'timeouts_before_reconnect'),
])
def test_bad_arguments_are_rejected(options, name):
    with pytest.raises(ValueError, match=name):
        KmcDevice('loop://', **options)


def test_bad_torques_are_rejected():
    device = KmcDevice('loop://', reply_timeout=0.001)
    device.open()
    with pytest.raises(ValueError, match='5 numbers'):
        device.cycle((0.0,) * 4)
    with pytest.raises(ValueError, match='5 numbers'):
        device.cycle(('a',) * 5)
    with pytest.raises(ValueError, match='5 numbers'):
        device.cycle('12345')
    assert device.stats['cycles'] == 0
    device.close()
