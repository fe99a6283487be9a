# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The session checker (kraft_master_report --check) on bags written message by message."""
import dataclasses
import json

from harness.crafted_session import (
    BREAKS, ENABLE_AT, energy, FAULT_AT, joints, JUMP_AT, LOST_AT, NS, pose, session_messages,
    state, STRING, T0, TYPES, wrench, write_session)
from kraft_master_driver.bag.common import (
    JOINT_STATE, POSE_STAMPED, SessionError, TWIST_STAMPED, WRENCH_STAMPED)
from kraft_master_driver.nodes.driver_parameters import PARAMETERS
from kraft_master_driver.tools import report
from kraft_master_driver.tools.session_check import check_session, DEFAULTS, read_faults
from kraft_master_driver.tools.session_invariants import (
    command_steps, Fault, frames_lost, Limits, Series, torque_steps)
import numpy as np
import pytest

# break -> (check, topic, the earliest and latest time its first violation may name)
FIRES = {
    'jump': ('command steps', 'servo_cp', JUMP_AT, JUMP_AT + 0.01),
    'fault_move': ('holds after a fault', 'servo_cp', FAULT_AT + 0.5, FAULT_AT + 0.51),
    'torque_on': ('torque zero after a fault', 'joint_states', FAULT_AT + 0.2, FAULT_AT + 0.21),
    'torque_kick': ('torque steps as force comes back', 'joint_states', ENABLE_AT,
                    ENABLE_AT + 0.01),
    'lost': ('pot frames all recorded', 'pots', LOST_AT, LOST_AT + 0.6),
    'energy': ('energy never generated', 'master_energy', T0 + 3.5, T0 + 3.51),
}


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_a_session_that_keeps_every_invariant_passes_every_check(tmp_path, storage):
    write_session(tmp_path / 'bag', storage=storage)
    result = check_session(tmp_path / 'bag')
    assert result.violations == []
    assert result.summary['namespaces'] == [NS]
    assert all(outcome == {'ran_on': [NS], 'violations': 0}
               for outcome in result.summary['checks'].values()), result.summary['checks']
    fault = result.summary['faults']['recorded: bridge FAULT']
    assert fault['count'] == 1 and fault['side'] == 'arm' and fault['not_recovered'] == 0
    json.dumps(result.summary)  # JSON-able


@pytest.mark.parametrize('broken', BREAKS)
def test_each_broken_invariant_is_found_named_by_its_time_and_topic(tmp_path, broken):
    write_session(tmp_path / 'bag', [broken])
    result = check_session(tmp_path / 'bag')
    check, topic, earliest, latest = FIRES[broken]
    assert result.violations, broken
    fired = {name for name, outcome in result.summary['checks'].items()
             if outcome['violations']}
    assert fired == {check}, result.violations
    time, _, where = result.violations[0].partition(' s ')
    assert earliest <= float(time) <= latest, result.violations[0]
    assert where.startswith(f'{NS}/{topic}: '), result.violations[0]


def test_a_hold_at_the_measured_arm_is_no_jump_but_the_same_step_elsewhere_is(tmp_path):
    # At the FAULT the command steps 20 mm, beyond the 12.5 mm limit, to where the arm is.
    messages = session_messages()
    write_session(tmp_path / 'bag', messages=messages)
    assert check_session(tmp_path / 'bag').violations == []
    far = [m for m in messages if not m[0].endswith('measured_cp')]
    write_session(tmp_path / 'far', messages=far)
    lines = check_session(tmp_path / 'far').violations
    assert len(lines) == 1 and 'stepped 20.00 mm' in lines[0], lines
    assert abs(float(lines[0].split()[0]) - FAULT_AT) < 0.01


def test_a_step_to_where_the_arm_is_recorded_only_later_is_no_jump(tmp_path):
    # A restarted arm reaches the recorder after the bridge, which registered where it is:
    # no arm pose is recorded for a second around the FAULT's 20 mm step, then the arm is
    # recorded where the command went.
    gap = [m for m in session_messages()
           if not (m[0].endswith('measured_cp') and FAULT_AT - 0.5 <= m[2] < FAULT_AT + 0.5)]
    write_session(tmp_path / 'bag', messages=gap)
    assert check_session(tmp_path / 'bag').violations == []
    # Recorded later 30 mm from where the command went, and held still: a jump.
    elsewhere = [(topic, kind, at, moved(message, 0.03) if topic.endswith('measured_cp')
                  else message) for topic, kind, at, message in gap]
    write_session(tmp_path / 'elsewhere', messages=elsewhere)
    lines = check_session(tmp_path / 'elsewhere').violations
    assert any('stepped 20.00 mm' in line for line in lines), lines


@pytest.mark.parametrize('stamped_before, found', [(True, False), (False, True)])
def test_a_command_received_late_in_a_fault_counts_when_it_was_stamped(
        tmp_path, stamped_before, found):
    # A command 5 mm from the hold, received 0.5 s into the FAULT: sent before it (its stamp
    # 0.1 s before the FAULT, a recorder behind) it moved nothing in the FAULT; stamped in it,
    # it is a move.
    messages = session_messages()
    held = next(message.pose.position for topic, _, at, message in messages
                if topic.endswith('servo_cp') and at > FAULT_AT)
    stamp = FAULT_AT - 0.1 if stamped_before else FAULT_AT + 0.5
    late = (f'{NS}/servo_cp', POSE_STAMPED, FAULT_AT + 0.5,
            pose(stamp, (held.x, held.y + 0.005, held.z)))
    write_session(tmp_path / 'bag', messages=messages + [late])
    lines = check_session(tmp_path / 'bag').violations
    assert bool(lines) == found, lines
    assert all('commanded in FAULT' in line for line in lines), lines


@pytest.mark.parametrize('spends_old_credit, found', [(False, False), (True, True)])
def test_the_energy_books_start_anew_when_the_other_end_restarts(
        tmp_path, spends_old_credit, found):
    # The bridge restarts at T0 + 2 s: its energy in starts from zero again, and the master
    # port spends the new bridge's credit on top of what it spent before (beyond the first
    # bridge's largest energy in). Spending the first bridge's unspent credit (80 mJ) after
    # the restart generates energy.
    restart = T0 + 2.0
    messages = session_messages()
    before = max(m.vector.x for topic, _, at, m in messages
                 if topic.endswith('slave_energy') and at < restart)
    rebooked = []
    for topic, kind, at, message in messages:
        stamp = message.header.stamp.sec + message.header.stamp.nanosec * 1e-9 \
            if topic.endswith('energy') else None
        if topic.endswith('slave_energy') and at >= restart:
            x = message.vector.x - before
            message = energy(stamp, (x, 0.5 * x, 0.0))
        elif topic.endswith('master_energy') and at >= restart + 0.5 and spends_old_credit:
            vector = message.vector
            message = energy(stamp, (vector.x, vector.y + 0.05, vector.z))
        rebooked.append((topic, kind, at, message))
    write_session(tmp_path / 'bag', messages=rebooked)
    lines = check_session(tmp_path / 'bag').violations
    assert bool(lines) == found, lines
    assert all('master port handed out' in line for line in lines), lines


def moved(message, dz):
    """Return a copy of PoseStamped `message`, its position `dz` (m) higher."""
    position = message.pose.position
    stamp = message.header.stamp
    return pose(stamp.sec + stamp.nanosec * 1e-9, (position.x, position.y, position.z + dz))


def test_the_limits_come_from_the_settings_and_unknown_settings_are_refused(tmp_path):
    write_session(tmp_path / 'bag')
    # The arm follows at 0.1 m/s: 0.5 mm a message, beyond 0.2 m/s x 2 ms.
    slow = check_session(tmp_path / 'bag', settings={'max_linear_speed': 0.2,
                                                     'max_step_s': 0.002})
    assert slow.violations and all('servo_cp' in line for line in slow.violations)
    with pytest.raises(ValueError, match='unknown setting max_speed'):
        check_session(tmp_path / 'bag', settings={'max_speed': 1.0})


def test_a_given_fault_that_makes_the_force_untrue_needs_zero_torque(tmp_path):
    write_session(tmp_path / 'bag')
    blackout = {'kind': 'link blackout', 'side': 'link', 'start': T0 + 0.8, 'end': T0 + 1.2}
    result = check_session(tmp_path / 'bag', faults=[blackout])
    assert len(result.violations) == 1
    assert 'link blackout (link) began at 100.800 s' in result.violations[0]
    assert result.summary['faults']['link blackout']['count'] == 1
    master = dict(blackout, side='master', kind='device stall')
    assert check_session(tmp_path / 'bag', faults=[master]).violations == []
    told = dict(blackout, force_untrue=False)
    assert check_session(tmp_path / 'bag', faults=[told]).violations == []


@pytest.mark.parametrize('stamped_after, found', [(0.1, False), (0.12, True)])
def test_a_torque_received_late_in_a_fault_counts_when_it_was_stamped(
        tmp_path, stamped_after, found):
    # A torque received 0.3 s into a fault that makes the force untrue: stamped 0.1 s into it
    # (a recorder behind), the driver applied it within torque_zero_within (0.11 s); stamped
    # 0.12 s into it, after.
    messages = session_messages()
    late = (f'{NS}/joint_states', JOINT_STATE, FAULT_AT + 0.3,
            joints(FAULT_AT + stamped_after, [f'j{i}' for i in range(6)], np.zeros(6),
                   np.full(6, 0.2)))
    write_session(tmp_path / 'bag', messages=messages + [late])
    lines = check_session(tmp_path / 'bag').violations
    assert bool(lines) == found, lines
    assert all('torque 0.2000 N*m 0.300 s after recorded: bridge FAULT' in line
               for line in lines), lines


def zero_wrench(t):
    """Return a WrenchStamped of zeros stamped `t`."""
    zero = TYPES['geometry_msgs/msg/Vector3'](x=0.0, y=0.0, z=0.0)
    return TYPES[WRENCH_STAMPED](header=pose(t, (0, 0, 0)).header,
                                 wrench=TYPES['geometry_msgs/msg/Wrench'](force=zero, torque=zero))


@pytest.mark.parametrize('side, max_wrench_age, found', [
    ('arm', 0.5, False), ('arm', 0.1, True), ('link', 0.5, True)])
def test_a_fault_on_the_arms_side_reaches_the_master_with_the_wrench(
        tmp_path, side, max_wrench_age, found):
    # The wrench reaches the master's side 0.3 s after its stamp. A fault of the arm's side
    # from T0 + 0.8 s to T0 + 1.2 s (the torque on throughout) reaches the driver with the
    # first wrench stamped after it began: torque zero is due from 0.41 s into it, past its
    # end; but not if that wrench came later than max_wrench_age (the driver refuses it, and
    # meets the fault itself), nor for a fault of the link's side.
    wrenches = [(f'{NS}/wrench', WRENCH_STAMPED, T0 + 0.3 + k / 200, zero_wrench(T0 + k / 200))
                for k in range(800)]
    write_session(tmp_path / 'bag', messages=session_messages() + wrenches)
    fault = {'kind': 'a fault', 'side': side, 'start': T0 + 0.8, 'end': T0 + 1.2}
    lines = check_session(tmp_path / 'bag', faults=[fault],
                          settings={'max_wrench_age': max_wrench_age}).violations
    assert bool(lines) == found, lines


def test_the_checkers_max_wrench_age_is_the_drivers_default():
    assert DEFAULTS['max_wrench_age'] == PARAMETERS['max_wrench_age'].default


@pytest.mark.parametrize('late, found', [(0.03, False), (0.2, True)])
def test_an_enable_received_after_the_first_torque_and_command_is_out_of_order_within_grace(
        tmp_path, late, found):
    # The bridge's ENABLED, its first command and the master's first torque after it: the
    # recorder may receive them in either order, within state_grace (0.05 s).
    messages = [(topic, kind, at + late if topic.endswith('operating_state') and
                 at == ENABLE_AT else at, message)
                for topic, kind, at, message in session_messages()]
    write_session(tmp_path / 'bag', messages=messages)
    lines = check_session(tmp_path / 'bag').violations
    assert bool(lines) == found, lines
    assert all('after recorded: bridge FAULT' in line or 'commanded in FAULT' in line
               for line in lines), lines


def write_torque_step(path, wrenches=()):
    """Write the session with the torque stepping from 0.2 to 1 N*m; return when (s)."""
    step_at = T0 + 3.6
    messages = [(topic, kind, at, dataclasses.replace(message, effort=np.full(6, 1.0)))
                if topic.endswith('joint_states') and at > step_at else
                (topic, kind, at, message)
                for topic, kind, at, message in session_messages()]
    write_session(path, messages=messages + [
        (f'{NS}/wrench', WRENCH_STAMPED, step_at + at, wrench(step_at + at, (0.0, 0.0, force)))
        for at, force in wrenches])
    return step_at


@pytest.mark.parametrize('side, untrue, found', [
    ('arm', False, False), ('link', False, False), ('arm', True, True), ('master', False, True),
    ('clock', False, True)])
def test_a_torque_step_counts_only_after_a_fault_that_took_the_force_away(
        tmp_path, side, untrue, found):
    # At T0 + 3.6 s (past the recovery window of the recorded FAULT) the torque steps from 0.2
    # to 1 N*m: a stuck sensor's end (the arm's true force returning, as at a touch) may do
    # that; the driver's force coming back may not.
    step_at = write_torque_step(tmp_path / 'bag')
    fault = {'kind': 'a fault', 'side': side, 'start': step_at - 0.5, 'end': step_at - 0.01,
             'force_untrue': untrue}
    lines = [line for line in check_session(tmp_path / 'bag', faults=[fault]).violations
             if 'torque rose' in line]
    assert bool(lines) == found, lines


@pytest.mark.parametrize('flood_from, found', [(-0.005, False), (0.05, True)])
def test_a_torque_step_after_another_fault_began_is_not_the_force_coming_back(
        tmp_path, flood_from, found):
    # As above, the torque steps 0.01 s after an arm's fault that made the force untrue; a
    # wrench flood (a second source, side master) that began before the step owns it.
    step_at = write_torque_step(tmp_path / 'bag')
    faults = [{'kind': 'arm restart', 'side': 'arm', 'start': step_at - 0.5,
               'end': step_at - 0.01, 'force_untrue': True},
              {'kind': 'wrench flood', 'side': 'master', 'start': step_at + flood_from,
               'end': step_at + 0.3}]
    lines = [line for line in check_session(tmp_path / 'bag', faults=faults).violations
             if 'torque rose' in line]
    assert bool(lines) == found, lines
    assert all('after arm restart' in line for line in lines), lines


@pytest.mark.parametrize('before, after, silence, found', [
    (1.0, 4.0, False, False), (1.0, 2.0, False, True), (1.0, 4.0, True, True)])
def test_a_torque_step_that_a_step_of_the_live_wrench_explains_is_the_arms_force(
        tmp_path, before, after, silence, found):
    # The torque rises 0.8 N*m 0.01 s after a master's fault. At the crafted pose (all joints
    # at zero) the longest lever is 0.40 m: a live wrench stepping 3 N explains it (a touch),
    # 1 N does not, nor a step across a silence longer than wrench_timeout (the force coming
    # back after being stale, which the driver must ramp).
    # Every 5 ms, stepping 3 ms after step_at; the silence, 55 ms, ends with the step.
    times = np.arange(-0.5, 0.3, 0.005) + 0.003
    if silence:
        times = times[(times < -0.05) | (times > 0.0)]
    wrenches = [(at, before if at < 0.0 else after) for at in times]
    step_at = write_torque_step(tmp_path / 'bag', wrenches)
    fault = {'kind': 'a fault', 'side': 'master', 'start': step_at - 0.5, 'end': step_at - 0.01}
    lines = [line for line in check_session(tmp_path / 'bag', faults=[fault]).violations
             if 'torque rose' in line]
    assert bool(lines) == found, lines


def test_bad_faults_are_refused_naming_the_fault_or_the_line(tmp_path):
    write_session(tmp_path / 'bag')
    with pytest.raises(ValueError, match='fault 1: needs kind'):
        check_session(tmp_path / 'bag', faults=[{'side': 'arm', 'start': 1, 'end': 2}])
    with pytest.raises(ValueError, match="fault 1: side must be one of .* got 'wrist'"):
        check_session(tmp_path / 'bag', faults=[{'kind': 'x', 'side': 'wrist', 'start': 1,
                                                 'end': 2}])
    (tmp_path / 'faults.jsonl').write_text('{"kind": "x", "side": "arm", "start": 1, "end": 2}'
                                           '\n\n{oops\n')
    with pytest.raises(ValueError, match='faults.jsonl line 3: not JSON'):
        read_faults(tmp_path / 'faults.jsonl')


def test_a_bag_without_session_topics_is_refused(tmp_path):
    messages = [('/other', STRING, T0, state('x'))]
    write_session(tmp_path / 'bag', messages=messages)
    with pytest.raises(SessionError, match='none of the session topics'):
        check_session(tmp_path / 'bag')


def twist(t, linear):
    """Return a TwistStamped of `linear` (m/s), no rotation."""
    sec, nanosec = divmod(round(t * 1e9), 1_000_000_000)
    vector = TYPES['geometry_msgs/msg/Vector3']
    return TYPES[TWIST_STAMPED](
        header=TYPES['std_msgs/msg/Header'](
            stamp=TYPES['builtin_interfaces/msg/Time'](sec=sec, nanosec=nanosec),
            frame_id='base_link'),
        twist=TYPES['geometry_msgs/msg/Twist'](linear=vector(x=linear, y=0.0, z=0.0),
                                               angular=vector(x=0.0, y=0.0, z=0.0)))


def test_twist_mode_keeps_the_speed_limit_and_a_zero_twist_in_fault(tmp_path):
    topic = f'{NS}/servo_cv'
    states = [(f'{NS}/operating_state', STRING, T0, state('ENABLED')),
              (f'{NS}/operating_state', STRING, T0 + 1.0, state('FAULT: tracking'))]
    good = [(topic, TWIST_STAMPED, T0 + i / 100, twist(T0 + i / 100, 0.2 if i < 100 else 0.0))
            for i in range(1, 200)]
    write_session(tmp_path / 'good', messages=states + good)
    assert check_session(tmp_path / 'good').violations == []
    fast = [m if abs(m[2] - (T0 + 0.5)) > 1e-6 else (topic, TWIST_STAMPED, m[2],
                                                     twist(m[2], 0.3)) for m in good]
    moving = [m if abs(m[2] - (T0 + 1.5)) > 1e-6 else (topic, TWIST_STAMPED, m[2],
                                                       twist(m[2], 0.01)) for m in good]
    write_session(tmp_path / 'fast', messages=states + fast)
    write_session(tmp_path / 'moving', messages=states + moving)
    assert [line.split(': ')[1][:5] for line in check_session(tmp_path / 'fast').violations
            ] == ['twist']
    lines = check_session(tmp_path / 'moving').violations
    assert len(lines) == 1 and lines[0].startswith('101.500 s /right/servo_cv: a twist of')


LIMITS = Limits(0.25, 1.0, 0.05, 0.002, 0.05, 0.11, 0.1, 1e-9, 0.5, 1.0, 2, 0.003, 0.01)


def test_a_step_across_commands_the_recorder_lost_may_be_as_many_steps():
    # 20 mm steps (the limit is 12.5 mm a message) between commands their publisher counted
    # 1, 2 (one lost between), 3 (two lost) and 0 (not known) apart; the last step is 40 mm.
    heights = np.array([0.0, 0.02, 0.04, 0.06, 0.08, 0.12])
    sequence = np.array([1, 2, 4, 7, 0, 2])
    values = np.column_stack([np.zeros((6, 2)), heights, np.tile([0, 0, 0, 1.0], (6, 1))])
    series = Series('/servo_cp', np.arange(6.0), values, None, sequence)
    assert [v.time for v in command_steps(series, None, LIMITS)] == [1.0, 4.0, 5.0]
    unknown = Series('/servo_cp', np.arange(6.0), values)
    assert [v.time for v in command_steps(unknown, None, LIMITS)] == [1.0, 2.0, 3.0, 4.0, 5.0]


@pytest.mark.parametrize('sequence, found', [((1, 3), False), ((1, 2), True), ((0, 3), True)])
def test_a_torque_rise_across_messages_the_recorder_lost_may_be_as_many_steps(sequence, found):
    # After a master's fault the torque rises 0.8 N*m (the bound is 0.5 a message) between
    # messages the driver counted 2 apart (one lost between), 1 apart, and not known.
    effort = Series('/joint_states', np.array([1.0, 1.002]),
                    np.column_stack([[0.1, 0.9], np.zeros((2, 5))]), None, np.array(sequence))
    fault = Fault('a fault', 'master', 0.5, 0.9, False)
    assert bool(torque_steps([fault], effort, LIMITS)) == found


def test_a_restarted_driver_counts_anew_without_a_frame_lost():
    stamps = np.arange(1000, dtype=np.int64) * 1_000_000  # 1 kHz for 1 s
    # A driver counting 7 frames before the bag, restarted at 0.5 s (counting from 0 again).
    counts = [(i / 10, i * 100_000_000, i * 100 + 1 + 7) for i in range(1, 5)]
    counts += [(i / 10, i * 100_000_000, (i - 5) * 100 + 1) for i in range(5, 10)]
    assert frames_lost(stamps, counts, '/pots', LIMITS) == ([], 0)
    dropped = np.delete(stamps, np.arange(700, 710))
    found, lost = frames_lost(dropped, counts, '/pots', LIMITS)
    assert lost == 10 and len(found) == 1
    assert found[0].line == ('0.800 s /pots: 10 pot frames the driver counted as published '
                             'between 0.500 s and 0.800 s are not in the bag')


def test_report_check_prints_each_violation_and_exits_1_on_any(tmp_path, capsys):
    write_session(tmp_path / 'good')
    write_session(tmp_path / 'bad', ['jump', 'lost'])
    assert report.main(['--check', str(tmp_path / 'good'), '--json',
                        str(tmp_path / 'good.json')]) == 0
    out = capsys.readouterr().out
    assert out.rstrip().endswith('all invariants hold')
    assert 'recorded: bridge FAULT' in out and 'command steps: 0 violations on /right' in out
    assert json.loads((tmp_path / 'good.json').read_text())['violations'] == []
    (tmp_path / 'faults.jsonl').write_text(json.dumps(
        {'kind': 'wrist sensor dropout', 'side': 'arm', 'start': FAULT_AT - 0.1,
         'end': FAULT_AT + 0.4}) + '\n')
    assert report.main(['--check', str(tmp_path / 'bad'), '--faults',
                        str(tmp_path / 'faults.jsonl')]) == 1
    lines = capsys.readouterr().out.splitlines()
    assert sum('/right/servo_cp: the command stepped' in line for line in lines) == 2
    assert sum('/right/pots: 5 pot frames' in line for line in lines) == 1
    assert any(line.split()[:1] == ['wrist'] for line in lines) and lines[-1] == '3 violations'
    assert report.main(['--check', str(tmp_path / 'missing')]) == 1
    assert 'kraft_master_report: ' in capsys.readouterr().err
