# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""Faults of the serial link, injected by the simulated device: one test per row."""
import time

from harness.faults import (
    counter_growth, FaultSession, inject_link_fault, LINK_FAULTS, LOG_THROTTLE_NS,
    longest_zero_run_s, milliseconds, record, seconds_between, SETTLE_S, zero_commands,
    zeroing_times_s)
import pytest

pytestmark = [pytest.mark.faults, pytest.mark.integration]

# Counters that tell why a cycle gave zero torque or ran late.
CYCLE_COUNTERS = ('link timeouts', 'link stale_replies', 'force watchdog_trips', 'late cycles',
                  'missed cycles')


def link_fault_case(fault):
    """Return the pytest.param of a link fault."""
    return pytest.param(fault, id=fault.row)


@pytest.fixture(scope='class')
def link_session(install_prefix):
    """One driver session shared by the link fault rows; each row clears its fault."""
    session = FaultSession(install_prefix)
    yield session
    session.close()


class TestLinkFaults:
    """Faults of the serial link, injected by the simulated device."""

    @pytest.mark.parametrize('fault', [link_fault_case(f) for f in LINK_FAULTS])
    def test_link_fault(self, link_session, fault):
        session = link_session
        session.wait_torque()
        before = session.diagnostics_after(time.time_ns())
        states = session.states
        injected = inject_link_fault(session, fault)
        session.wait(lambda: session.states > states)
        after = session.diagnostics_after(injected.back_ns)
        session.assert_alive()

        growth = counter_growth(before, after, fault.counters + CYCLE_COUNTERS)
        assert sum(growth[key] for key in fault.counters) > 0, growth
        # Zero torque on the cycle after each lost reply: at least one zero command per timeout.
        window = session.commands(before.stamp_ns, after.stamp_ns + int(SETTLE_S * 1e9))
        assert zero_commands(window) >= growth['link timeouts'], (zero_commands(window), growth)
        assert (after.level, after.message) == (0, 'running')
        if fault.link_down:
            assert any(d.level == 2 and 'link down' in d.message for d in session.diagnostics
                       if injected.fault_ns <= d.stamp_ns < injected.clear_ns)
            assert after.count('link reconnects') > before.count('link reconnects')
        faulty = session.commands(injected.fault_ns, injected.back_ns + 1)
        record('link', fault.row, injected.safe_s, injected.recovery_s, injected.how,
               first_zero_after_fault_ms=milliseconds(seconds_between(
                   injected.fault_ns, session.first_command(injected.fault_ns, zero=True))),
               falls_to_zero=len(zeroing_times_s(faulty)),
               longest_zero_torque_ms=milliseconds(longest_zero_run_s(faulty)),
               counters=growth, simulator=session.simulator.stats)
        # A repeated warning comes at most once a second: a lost reply in the second before the
        # fault (a busy machine has some) may be the one the log shows.
        session.expect_log(injected.fault_ns - LOG_THROTTLE_NS, fault.log)

    def test_nothing_lost_across_the_link_faults(self, link_session):
        link_session.assert_alive()
        assert link_session.assert_nothing_lost() > 0
