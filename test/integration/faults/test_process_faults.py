# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The driver process: signals, and a second driver on the same port."""
import re
import signal
import time

from harness.faults import (
    counter_growth, DECODER_ERRORS, Driver, FaultSession, LOOP_RATE_HZ, record,
    seconds_between, zero_commands)
import pytest

pytestmark = [pytest.mark.faults, pytest.mark.integration]


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM], ids=['SIGINT', 'SIGTERM'])
def test_signal_zeroes_torque_last_and_exits_0(install_prefix, sig):
    session = FaultSession(install_prefix)
    try:
        session.wait_torque()
        signal_ns = time.time_ns()
        code = session.driver.stop(sig)
        assert code == 0, session.driver.output
        assert 'Traceback' not in session.driver.output, session.driver.output
        session.wait(lambda: not any(session.commands()[-1][1].counts))
        # The loop may finish a cycle or two before it sees the stop, and a cycle whose reply
        # was late sends zero itself: the stop's zero begins the zeros that end the commands.
        after_signal = session.commands(signal_ns)
        last_torque = max((i for i, (_, c) in enumerate(after_signal) if any(c.counts)),
                          default=-1)
        assert last_torque < len(after_signal) - 1, 'no zero command after the signal'
        zero_ns = after_signal[last_torque + 1][0]
        record('process', signal.Signals(sig).name, seconds_between(signal_ns, zero_ns),
               None, 'zero command before exit',
               commands_after_signal=len(session.commands(signal_ns)))
    finally:
        session.close()


def test_second_driver_on_the_same_port_retries_and_leaves_the_first_alone(install_prefix):
    session = FaultSession(install_prefix)
    second = None
    try:
        second_namespace = f'{session.namespace}_second'
        second_diagnostics = session.watch(second_namespace)
        session.wait_torque()
        before = session.diagnostics_after(time.time_ns())
        device_errors = session.simulator.stats['decode_errors']
        start_ns = time.time_ns()
        second = Driver(install_prefix, session.domain_id, [
            ('port', session.port), ('loop_rate_hz', LOOP_RATE_HZ),
            ('force_enabled_at_start', 'true')], namespace=second_namespace)
        session.wait(lambda: second.log_since(start_ns, ('ERROR', 'WARN')))
        assert re.search(r'busy|lock', second.output, re.IGNORECASE), second.output
        first = session.diagnostics_after(start_ns, second_diagnostics)
        assert first.level == 2, first
        retried = session.wait(lambda: next(
            (d for d in second_diagnostics
             if d.count('link failed_opens') > first.count('link failed_opens')), None))
        assert second.stop() == 0, second.output
        end_ns = time.time_ns()
        after = session.diagnostics_after(end_ns)
        session.assert_alive()

        # The first driver is undisturbed, as far as a second opener could disturb it: no
        # foreign command (every command in sequence) or byte at the device, no reply bytes
        # taken from it, no link fault; the second never got a frame.
        window = session.commands(start_ns, end_ns)
        sequences = [c.sequence for _, c in window]
        assert all((b - a) % 256 == 1 for a, b in zip(sequences, sequences[1:]))
        assert session.simulator.stats['decode_errors'] == device_errors
        growth = counter_growth(before, after, ('link link_faults', 'link timeouts') +
                                DECODER_ERRORS)
        assert growth['link link_faults'] == 0, growth
        assert sum(growth[key] for key in DECODER_ERRORS) == 0, growth
        assert retried.count('pot frames received') == 0
        session.assert_nothing_lost()
        record('process', 'second driver on the same port', None, None,
               second_failed_opens=retried.count('link failed_opens'),
               first_counters=growth, first_zero_commands=zero_commands(window))
    finally:
        if second is not None:
            second.kill()
        session.close()
