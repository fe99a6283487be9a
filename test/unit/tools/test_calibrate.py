# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""kraft_master_calibrate against a simulated arm whose true calibration is not the paper's."""
import math
import threading
import time

from harness import REPO
from kraft_master_driver.core import kinematics
from kraft_master_driver.core.calibration import (
    ArmCalibration, CalibrationError, read_parameter_file)
from kraft_master_driver.link.device import KmcDevice
from kraft_master_driver.simulation.master.simulator import SimulatedKraftMaster
from kraft_master_driver.tools import calibrate
import numpy as np
import pytest

REPO_CONFIG = REPO / 'config'
TOLERANCE_DEG = 0.2
# Each pot's two calibration points moved by tens of counts: lines off by degrees.
SHIFT_A = np.array([40.0, -35.0, 25.0, -30.0, 45.0, -20.0])
SHIFT_B = np.array([-30.0, 25.0, -45.0, 35.0, -25.0, 30.0])


def true_calibration(arm):
    """Return a device calibration that differs from the nominal one of `arm`."""
    nominal = ArmCalibration.nominal(arm)
    return ArmCalibration(arm, nominal.pot_a + SHIFT_A, nominal.pot_b + SHIFT_B,
                          nominal.angle_a, nominal.angle_b, source='true')


def worst_error_deg(calibration, truth):
    """Largest joint angle error (deg), per joint, of `calibration` reading `truth`'s pots."""
    rng = np.random.default_rng(5)
    lower, upper = kinematics.joint_limits()
    theta = rng.uniform(lower, upper, (2000, 6))
    return np.degrees(np.abs(calibration.pots_to_joints(truth.joints_to_pots(theta)) - theta)
                      ).max(axis=0)


def assert_same_calibration(loaded, fitted):
    """Assert that the file holds the fit: counts exactly, angles to its 1e-9 deg."""
    assert loaded.arm == fitted.arm
    np.testing.assert_array_equal(loaded.pot_a, fitted.pot_a)
    np.testing.assert_array_equal(loaded.pot_b, fitted.pot_b)
    np.testing.assert_allclose(np.degrees(loaded.angle_a), np.degrees(fitted.angle_a), atol=1e-9)
    np.testing.assert_allclose(np.degrees(loaded.angle_b), np.degrees(fitted.angle_b), atol=1e-9)


@pytest.mark.slow
def test_operator_at_the_stops_recovers_the_true_lines_over_the_pty(tmp_path, capsys):
    truth = true_calibration('right')
    assert worst_error_deg(ArmCalibration.nominal('right'), truth).min() > 1.0
    simulator = SimulatedKraftMaster(arm='right', calibration=truth, operator='hold',
                                     pot_noise_counts=1.5, seed=3)
    port = simulator.start()
    stations = iter(calibrate.stop_stations())
    hand = calibrate.SimulatedOperator(simulator, log=lambda _: None)
    prompts = []

    def operator_at_the_device(prompt):
        prompts.append(prompt)
        station = next(stations)
        assert station.label in prompt
        hand(station)
        # The simulated arm now rests exactly on the stops the station names.
        known = ~np.isnan(station.joints_deg)
        np.testing.assert_allclose(np.degrees(simulator.joint_angles())[known],
                                   np.array(station.joints_deg)[known], atol=1e-9)
        return ''

    out = tmp_path / 'right.yaml'
    try:
        code = calibrate.main(['--arm', 'right', '--port', port, '--out', str(out),
                               '--samples', '100'], ask=operator_at_the_device)
    finally:
        simulator.stop()
    output = capsys.readouterr().out
    assert code == 0, output
    assert len(prompts) == 12
    loaded = ArmCalibration.from_yaml(out)
    assert np.all(worst_error_deg(loaded, truth) < TOLERANCE_DEG), worst_error_deg(loaded, truth)
    for pot in range(1, 7):
        assert f'POT{pot} ' in output
    assert 'SUSPICIOUS' not in output

    # The saved samples refit to the same lines, in the CSV mode.
    samples = tmp_path / 'right_samples.csv'
    fit = calibrate.fit_rows('right', calibrate.read_rows(samples))
    assert not fit.flags
    assert_same_calibration(loaded, fit.result.calibration)
    refit = tmp_path / 'refit.yaml'
    assert calibrate.main(['--arm', 'right', '--csv', str(samples), '--out', str(refit)]) == 0
    assert_same_calibration(ArmCalibration.from_yaml(refit), fit.result.calibration)

    # A parameter file of the same shape as the shipped one, which the node loads.
    written, shipped = (read_parameter_file(p) for p in (out, REPO_CONFIG / 'right_arm.yaml'))
    assert written.keys() <= shipped.keys()
    assert written['calibration'].keys() == shipped['calibration'].keys()


@pytest.mark.slow
def test_sim_port_runs_the_simulated_operator(tmp_path, capsys):
    truth = true_calibration('left')
    truth_file = tmp_path / 'truth.yaml'
    truth.to_yaml(truth_file)
    out = tmp_path / 'left.yaml'
    code = calibrate.main(['--arm', 'left', '--port', 'sim', '--sim-calibration',
                           str(truth_file), '--sim-noise', '1.0', '--samples', '30',
                           '--fixture', 'th1=0,th2=60,th3=-100', '--out', str(out)],
                          ask=pytest.fail)
    assert code == 0, capsys.readouterr()
    loaded = ArmCalibration.from_yaml(out)
    assert loaded.arm == 'left'
    assert np.all(worst_error_deg(loaded, truth) < TOLERANCE_DEG), worst_error_deg(loaded, truth)
    rows = calibrate.read_rows(tmp_path / 'left_samples.csv')
    assert len(rows) == 16 + 3  # the fixture gives POT1, POT2 and POT3 (th2 + th3)
    assert sorted(row.angle_deg for row in rows[-3:]) == [-40.0, 0.0, 60.0]


def test_operator_can_skip_and_quit_and_nothing_is_written(tmp_path, capsys):
    answers = iter(['s', ' Q '])
    prompts = []

    def ask(prompt):
        prompts.append(prompt)
        return next(answers)

    out = tmp_path / 'right.yaml'
    with SimulatedKraftMaster(arm='right') as simulator:
        code = calibrate.main(['--arm', 'right', '--port', simulator.port, '--out', str(out)],
                              ask=ask)
    assert code == 1
    assert len(prompts) == 2 and 'Enter' in prompts[0]
    assert 'stopped by the operator' in capsys.readouterr().out
    assert not out.exists()


@pytest.mark.slow
def test_silent_device_is_an_error(tmp_path, capsys):
    with SimulatedKraftMaster(arm='right', drop_reply_rate=1.0) as simulator:
        code = calibrate.main(['--arm', 'right', '--port', simulator.port,
                               '--out', str(tmp_path / 'x.yaml')], ask=lambda _: '')
    assert code == 1
    assert 'no reply from the device' in capsys.readouterr().err


def test_sampling_waits_while_the_device_reopens_a_link_it_dropped():
    with SimulatedKraftMaster(arm='right') as simulator, KmcDevice(simulator.port) as device:
        # Silent until the device has given the link up (25 missed replies): then answer.
        simulator.stall(60_000)

        def answer_after_the_link_fault():
            deadline = time.monotonic() + 60.0
            while device.stats['link_faults'] == 0 and time.monotonic() < deadline:
                time.sleep(0.001)
            simulator.stall(0)

        helper = threading.Thread(target=answer_after_the_link_fault)
        helper.start()
        try:
            pots = calibrate.sample(device, 20)
        finally:
            helper.join()
        assert pots.shape == (20, 6)
        stats = device.stats
        assert stats['link_faults'] == 1 and stats['reconnects'] == 1


def test_sampling_fails_when_the_port_cannot_be_reopened():
    with SimulatedKraftMaster(arm='right') as simulator, KmcDevice(simulator.port) as device:
        assert calibrate.sample(device, 5).shape == (5, 6)
        simulator.unplug()
        with pytest.raises(CalibrationError, match='no reply from the device.*cannot open'):
            calibrate.sample(device, 5)
        assert device.stats['failed_opens'] == 1


def synthetic_rows(truth, rng, samples=50, noise=1.0):
    """Rows of three poses per pot made with `truth`'s lines and Gaussian count noise."""
    lower, upper = np.degrees(kinematics.joint_limits(0.0))
    reads = np.array([lower, upper])[:, list(calibrate.POT_JOINT)]
    reads[:, 2] = (35.0, -135.0)  # what POT3 (th2 + th3) spans at the stops
    rows = []
    for pot in range(6):
        for angle in np.linspace(reads[0, pot], reads[1, pot], 3):
            centre = (math.radians(angle) - truth.offset[pot]) / truth.slope[pot]
            rows.append(calibrate.Row(pot + 1, float(angle),
                                      np.round(centre + rng.normal(0.0, noise, samples))))
    return rows


def test_csv_fit_flags_spread_saturation_and_outliers(tmp_path, capsys):
    truth = true_calibration('right')
    rng = np.random.default_rng(7)
    rows = synthetic_rows(truth, rng)
    rows[0] = rows[0]._replace(counts=rows[0].counts + np.resize([-12.0, 12.0], 50))
    rows[4] = rows[4]._replace(counts=np.append(rows[4].counts[1:], 4095.0))
    rows[7] = rows[7]._replace(angle_deg=rows[7].angle_deg + 2.0)
    samples = tmp_path / 'samples.csv'
    calibrate.write_rows(samples, rows)
    out = tmp_path / 'right.yaml'
    assert calibrate.main(['--arm', 'right', '--csv', str(samples), '--out', str(out)]) == 1
    output = capsys.readouterr()
    flagged = [line for line in output.out.splitlines() if line.startswith('SUSPICIOUS')]
    assert any('POT1' in line and 'spread' in line for line in flagged), output.out
    assert any('POT2' in line and '4095' in line for line in flagged), output.out
    assert any('POT3' in line and 'residual' in line for line in flagged), output.out
    assert not any(f'POT{pot}' in line for line in flagged for pot in (4, 5, 6)), output.out
    assert 'not written' in output.err and not out.exists()

    assert calibrate.main(['--arm', 'right', '--csv', str(samples), '--out', str(out),
                           '--force']) == 0
    fit = calibrate.fit_rows('right', calibrate.read_rows(samples))
    assert_same_calibration(ArmCalibration.from_yaml(out), fit.result.calibration)


def test_csv_fit_of_clean_samples_matches_the_truth(tmp_path):
    truth = true_calibration('left')
    samples = tmp_path / 'samples.csv'
    calibrate.write_rows(samples, synthetic_rows(truth, np.random.default_rng(8)))
    out = tmp_path / 'left.yaml'
    assert calibrate.main(['--arm', 'left', '--csv', str(samples), '--out', str(out)]) == 0
    loaded = ArmCalibration.from_yaml(out)
    assert np.all(worst_error_deg(loaded, truth) < TOLERANCE_DEG)


@pytest.mark.parametrize('text, fragment', [
    ('pot,angle_deg,counts\n', 'no samples'),
    ('1,90\n', 'expected pot,angle_deg,count'),
    ('7,90,100\n', 'pot 7'),
    ('1,ninety,100\n', 'not numbers'),
    ('1,90,5000\n', 'within 0..4095'),
    ('1,90,100\n1,-90,4000\n', 'POT2 (th2)'),
])
def test_bad_csv_is_an_error_naming_the_fault(tmp_path, capsys, text, fragment):
    samples = tmp_path / 'samples.csv'
    samples.write_text(text)
    out = tmp_path / 'x.yaml'
    assert calibrate.main(['--arm', 'right', '--csv', str(samples), '--out', str(out)]) == 1
    assert fragment in capsys.readouterr().err
    assert not out.exists()


def test_fixture_stations_know_what_each_pot_reads():
    station = calibrate.parse_fixture('bench:shoulder_pitch=90,th3=-90,th5=10')
    assert station.label == 'bench'
    angles = station.pot_angles_deg()
    assert angles[1] == 90.0 and angles[2] == 0.0 and angles[3] == 10.0
    assert np.isnan(angles[[0, 4, 5]]).all()
    assert np.isnan(calibrate.parse_fixture('th3=-90').pot_angles_deg()[2])
    for bad in ('th7=3', 'th1=east', 'th1=400', ''):
        with pytest.raises(ValueError):
            calibrate.parse_fixture(bad)


def test_stop_stations_cover_every_pot_at_two_angles():
    angles = np.array([s.pot_angles_deg() for s in calibrate.stop_stations()])
    for pot in range(6):
        assert np.unique(angles[:, pot][~np.isnan(angles[:, pot])]).size >= 2
    np.testing.assert_allclose(np.unique(angles[:, 2][~np.isnan(angles[:, 2])]),
                               [-135.0, -35.0, -15.0, 35.0])


def test_simulated_device_of_the_other_arm_is_an_error(tmp_path, capsys):
    truth_file = tmp_path / 'left.yaml'
    true_calibration('left').to_yaml(truth_file)
    code = calibrate.main(['--arm', 'right', '--port', 'sim', '--sim-calibration',
                           str(truth_file), '--out', str(tmp_path / 'x.yaml')])
    assert code == 1
    assert 'left arm' in capsys.readouterr().err
