# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""kraft_master_calibrate --check-torques against a simulated arm with the operator's hand off."""
import math
from pathlib import Path

from kraft_master_driver.core.calibration import ArmCalibration, read_parameter_file
from kraft_master_driver.link.device import KmcDevice
from kraft_master_driver.link.protocol import CODECS
from kraft_master_driver.nodes.driver_parameters import PARAMETERS
from kraft_master_driver.simulation.master.model import DEFAULT_DYNAMICS, HAND_OFF
from kraft_master_driver.simulation.master.simulator import SimulatedKraftMaster
from kraft_master_driver.tools import calibrate, torque_check
import pytest

FRAMES = Path(calibrate.__file__).parent.parent / 'link' / 'frames'


def hand_off(**options):
    """Return a simulated right arm whose operator has let go of the handle (not started)."""
    return SimulatedKraftMaster(arm='right', dynamics=HAND_OFF, pot_noise_counts=1.0,
                                **options)


def flipped_frame(tmp_path, axis):
    """Write kraft-default with torque sign -1 on `axis` (1..5): the same bytes otherwise."""
    text = (FRAMES / 'kraft-default.yaml').read_text()
    signs = ['1'] * 5
    signs[axis - 1] = '-1'
    assert 'sign: [1, 1, 1, 1, 1]' in text
    text = text.replace('sign: [1, 1, 1, 1, 1]', f'sign: [{", ".join(signs)}]')
    path = tmp_path / f'flipped-{axis}.yaml'
    path.write_text(text.replace('name: kraft-default', f'name: flipped-{axis}'))
    return path


def commands(simulator):
    """Return the torque counts of every command the simulator received."""
    return [command.counts for _, command in simulator.received]


@pytest.mark.slow
def test_every_axis_agrees_and_the_scale_is_near_the_true_inertia():
    lines = []
    with hand_off() as simulator, KmcDevice(simulator.port) as device:
        check = torque_check.TorqueCheck(device, ArmCalibration.nominal('right'),
                                         log=lines.append)
        results = check.run()
    assert [result.axis for result in results] == [1, 2, 3, 4, 5]
    assert all(result.moved and result.agrees for result in results), lines
    for result, inertia in zip(results, DEFAULT_DYNAMICS.inertia):
        # Rough: friction and damping make it larger, never 3 times the truth here.
        assert 0.8 * inertia < result.apparent_inertia < 3.0 * inertia, lines
        assert result.torque <= torque_check.Settings().torque
    assert all('sign agrees' in line for line in lines)
    assert commands(simulator)[-1] == (0,) * 5


@pytest.mark.slow
def test_sim_port_writes_every_sign_positive_into_the_nominal_file(tmp_path, capsys):
    out = tmp_path / 'right.yaml'
    code = calibrate.main(['--arm', 'right', '--port', 'sim', '--check-torques',
                           '--out', str(out)], ask=pytest.fail)
    output = capsys.readouterr()
    assert code == 0, output
    assert read_parameter_file(out)['torque_signs'] == [1] * 5
    assert ArmCalibration.from_yaml(out).arm == 'right'


@pytest.mark.slow
def test_a_sign_the_check_is_not_told_about_is_found_and_the_file_then_fixes_it(
        tmp_path, capsys):
    # The device's frame negates axis 3 on the wire; the check speaks kraft-default.
    calibration = tmp_path / 'right.yaml'
    ArmCalibration.nominal('right').to_yaml(calibration)
    with hand_off(codec=str(flipped_frame(tmp_path, 3))) as simulator:
        code = calibrate.main(['--arm', 'right', '--port', simulator.port, '--check-torques',
                               '--calibration', str(calibration)])
        output = capsys.readouterr()
        assert code == 0, output
        lines = output.out.splitlines()
        assert any(line.startswith('axis 3') and 'sign REVERSED' in line for line in lines)
        assert sum('sign agrees' in line for line in lines) == 4, output.out
        written = read_parameter_file(calibration)
        assert written['torque_signs'] == [1, 1, -1, 1, 1]
        # Every key is a parameter of the driver, which loads the file and applies the signs.
        names = {f'calibration.{key}' for key in written['calibration']}
        assert names | {'arm', 'torque_signs'} <= set(PARAMETERS)

        # Checked again through the file's signs: every axis agrees, the signs stay.
        code = calibrate.main(['--arm', 'right', '--port', simulator.port, '--check-torques',
                               '--calibration', str(calibration)])
        output = capsys.readouterr()
    assert code == 0, output
    assert sum('sign agrees' in line for line in output.out.splitlines()) == 5, output.out
    assert read_parameter_file(calibration)['torque_signs'] == [1, 1, -1, 1, 1]


@pytest.mark.slow
def test_a_motion_beyond_the_bound_zeroes_the_torques_and_stops(tmp_path, capsys):
    out = tmp_path / 'right.yaml'
    with hand_off() as simulator:
        # The wrist (inertia 0.005 kg*m^2) at a quarter of 1 N*m moves 3 deg in 50 ms.
        code = calibrate.main(['--arm', 'right', '--port', simulator.port, '--check-torques',
                               '--torque', '1', '--max-motion', '2', '--out', str(out)])
        sent = commands(simulator)
    output = capsys.readouterr()
    assert code == 1
    assert 'STOPPED: axis 4' in output.err and 'torques zeroed' in output.err, output
    assert not out.exists()
    assert sent[-1] == (0,) * 5
    assert not any(counts[4] for counts in sent), 'axis 5 was pulsed after the stop'
    # The first zero after the pulse on axis 4 came at once: no pulse command after it.
    pulsing = [i for i, counts in enumerate(sent) if counts[3]]
    assert all(counts == (0,) * 5 for counts in sent[pulsing[-1] + 1:])


def test_refused_while_another_program_holds_the_port(tmp_path, capsys):
    out = tmp_path / 'right.yaml'
    with hand_off() as simulator, KmcDevice(simulator.port) as driver:
        assert driver.link_up
        code = calibrate.main(['--arm', 'right', '--port', simulator.port, '--check-torques',
                               '--out', str(out)])
    output = capsys.readouterr()
    assert code == 1
    assert 'refused' in output.err and 'busy' in output.err, output
    assert not out.exists()


def test_refused_while_a_hand_moves_the_arm_and_no_torque_is_sent(tmp_path, capsys):
    out = tmp_path / 'right.yaml'
    with SimulatedKraftMaster(arm='right', operator='sweep') as simulator:
        code = calibrate.main(['--arm', 'right', '--port', simulator.port, '--check-torques',
                               '--out', str(out)])
        sent = commands(simulator)
    output = capsys.readouterr()
    assert code == 1
    assert 'refused: axis 1' in output.err and 'hand off the handle' in output.err, output
    assert sent and all(counts == (0,) * 5 for counts in sent)
    assert not out.exists()


@pytest.mark.slow
def test_too_small_a_torque_leaves_the_sign_unknown_after_three_pulses():
    with hand_off() as simulator, KmcDevice(simulator.port) as device:
        # Below the shoulder's Coulomb friction (0.03 N*m) axis 1 does not move at all.
        settings = torque_check.Settings(torque=0.02)
        check = torque_check.TorqueCheck(device, ArmCalibration.nominal('right'), settings,
                                         log=lambda _: None)
        (result,) = check.run(axes=[1])
        sent = commands(simulator)
    assert not result.moved and result.torque == pytest.approx(0.02)
    assert sorted({counts[0] for counts in sent if counts[0] > 0}) == [5, 10, 20]
    assert 'sign unknown' in torque_check.report_line(result, settings)


@pytest.mark.parametrize('arguments, fragment', [
    (['--csv', 'x.csv', '--check-torques'], '--check-torques needs --port'),
    (['--port', 'sim', '--check-torques', '--max-motion', '0.1'], '--max-motion'),
    (['--port', 'sim', '--check-torques', '--torque', '0'], '--torque'),
    (['--port', 'sim', '--check-torques', '--pulse', '5'], '--pulse'),
])
def test_bad_check_settings_are_a_usage_error(capsys, arguments, fragment):
    with pytest.raises(SystemExit) as stop:
        calibrate.main(['--arm', 'right', *arguments])
    assert stop.value.code == 2
    assert fragment in capsys.readouterr().err


def test_a_calibration_file_with_bad_signs_is_an_error(tmp_path, capsys):
    calibration = tmp_path / 'right.yaml'
    ArmCalibration.nominal('right').to_yaml(calibration)
    calibration.write_text(calibration.read_text() + '    torque_signs: [1, 0, 1, 1, 1]\n')
    code = calibrate.main(['--arm', 'right', '--port', 'sim', '--check-torques',
                           '--calibration', str(calibration)])
    assert code == 1
    assert 'torque_signs' in capsys.readouterr().err


def test_the_sign_of_the_device_multiplies_the_counts_after_the_clamp():
    assert 'kraft-default' in CODECS
    with SimulatedKraftMaster(arm='right') as simulator, KmcDevice(
            simulator.port, torque_sign=(1, -1, 1, 1, -1)) as device:
        result = device.cycle((0.5, 0.5, -0.25, 0.0, 9.0))
        assert result is not None
        assert result.commanded_nm == (0.5, 0.5, -0.25, 0.0, 3.0)  # the driver's sense
        assert commands(simulator)[-1] == (500, -500, -250, 0, -3000)
    for bad in ((1, 0, 1, 1, 1), (1, 1, 1, 1), (1, 2, 1, 1, 1)):
        with pytest.raises(ValueError, match='torque_sign'):
            KmcDevice('loop://', torque_sign=bad)
    assert math.isclose(torque_check.Settings().max_motion, math.radians(10.0))
