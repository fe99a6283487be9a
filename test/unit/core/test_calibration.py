# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""Pot calibration: the paper's tables, the inverse map, least squares and the YAML files."""
import math

from harness import REPO
from kraft_master_driver.core import calibration
from kraft_master_driver.core.calibration import ArmCalibration, CalibrationError
from kraft_master_driver.core.kinematics import NOMINAL_LENGTHS
import numpy as np
import pytest

CONFIG = REPO / 'config'
ARMS = ('right', 'left')
# Section 6 table, by pot number: right POT_a, POT_b, left POT_a, POT_b, th_a, th_b (deg).
POT_TABLE = {
    1: (157, 4014, 119, 3983, 90.0, -90.0),
    2: (751, 3328, 777, 3354, 0.0, 120.0),
    3: (248, 3863, 240, 3859, 35.0, -135.0),
    5: (500, 2930, 808, 3280, 55.0, -55.0),
    4: (1126, 2766, 1228, 2856, -20.0, 50.0),
    6: (1395, 2656, 1402, 2634, 45.0, -45.0),
}
# Table III: the joint angle each pot reads, as indices into th1..th6 (POT3: th2 + th3).
POT_READS = {1: (0,), 2: (1,), 3: (1, 2), 4: (4,), 5: (3,), 6: (5,)}
SECTION8 = (
    ((2086, 2683, 992, 1595, 1715, 2025), (0.0, 90.0, -90.0, 0.0, 0.0, 0.0)),
    ((2622, 1610, 2268, 1829, 2488, 1745), (-25.0, 40.0, -100.0, -35.0, 10.0, 20.0)),
)
RIGHT_POT_A = 'pot_a: [157.0, 751.0, 248.0, 1126.0, 500.0, 1395.0]'
RIGHT_POT_B = 'pot_b: [4014.0, 3328.0, 3863.0, 2766.0, 2930.0, 2656.0]'
RIGHT_ANGLE_A = 'angle_a_deg: [90.0, 0.0, 35.0, -20.0, 55.0, 45.0]'
RIGHT_ANGLE_B = 'angle_b_deg: [-90.0, 120.0, -135.0, 50.0, -55.0, -45.0]'


def table_line(arm, pot, counts):
    """Return the angle (deg) that a pot reads at `counts`, by Eq. 11 and the table."""
    right_a, right_b, left_a, left_b, angle_a, angle_b = POT_TABLE[pot]
    pot_a, pot_b = (right_a, right_b) if arm == 'right' else (left_a, left_b)
    return angle_a + (angle_b - angle_a) / (pot_b - pot_a) * (counts - pot_a)


def assert_same_calibration(got, want, angle_tol=0.0):
    """Assert two calibrations have the same arm, points and lines."""
    assert got.arm == want.arm
    np.testing.assert_array_equal(got.pot_a, want.pot_a)
    np.testing.assert_array_equal(got.pot_b, want.pot_b)
    for name in ('angle_a', 'angle_b', 'slope', 'offset'):
        np.testing.assert_allclose(getattr(got, name), getattr(want, name), rtol=0,
                                   atol=angle_tol)


@pytest.mark.parametrize('arm', ARMS)
def test_nominal_tables(arm):
    cal = ArmCalibration.nominal(arm)
    for pot, (right_a, right_b, left_a, left_b, angle_a, angle_b) in POT_TABLE.items():
        expected_counts = (right_a, right_b) if arm == 'right' else (left_a, left_b)
        assert (cal.pot_a[pot - 1], cal.pot_b[pot - 1]) == expected_counts
        assert math.degrees(cal.angle_a[pot - 1]) == pytest.approx(angle_a, abs=1e-12)
        assert math.degrees(cal.angle_b[pot - 1]) == pytest.approx(angle_b, abs=1e-12)
    assert cal.arm == arm
    assert arm in repr(cal)


def test_nominal_right_matches_equation_12():
    cal = ArmCalibration.nominal('right')
    # Eq. 12, first line: th1 = 1.699 - 8.145e-4 * POT1 (rounded to four digits).
    assert cal.offset[0] == pytest.approx(1.699, abs=5e-4)
    assert cal.slope[0] == pytest.approx(-8.145e-4, abs=5e-8)


def test_pot_joint_map_is_table_iii():
    for pot, joints in POT_READS.items():
        assert calibration.POT_JOINT[pot - 1] == joints[-1]
    assert calibration.POT_MEASURES == ('th1', 'th2', 'th2 + th3', 'th5', 'th4', 'th6')


@pytest.mark.parametrize('pots, theta_deg', SECTION8)
def test_section8_pot_counts_to_angles(pots, theta_deg):
    theta = ArmCalibration.nominal('right').pots_to_joints(pots)
    np.testing.assert_allclose(np.degrees(theta), theta_deg, atol=0.05)


@pytest.mark.parametrize('arm', ARMS)
def test_pots_to_joints_follows_equation_11(arm):
    cal = ArmCalibration.nominal(arm)
    pots = np.random.default_rng(1).uniform(0, 4095, (200, 6))
    theta = np.degrees(cal.pots_to_joints(pots))
    for pot, joints in POT_READS.items():
        read = theta[:, joints].sum(axis=1)
        np.testing.assert_allclose(read, table_line(arm, pot, pots[:, pot - 1]), atol=1e-9)
    np.testing.assert_allclose(np.degrees(cal.pots_to_joints(pots[0])), theta[0], atol=1e-12)


@pytest.mark.parametrize('arm', ARMS)
def test_frame_to_joints_gives_the_floats_of_pots_to_joints(arm):
    cal = ArmCalibration.nominal(arm)
    for frame in np.random.default_rng(3).integers(0, 4096, (500, 6)).tolist():
        theta = cal.frame_to_joints(frame)
        assert all(type(angle) is float for angle in theta)
        assert theta == cal.pots_to_joints(frame).tolist()


@pytest.mark.parametrize('arm', ARMS)
def test_joints_to_frame_gives_the_floats_of_joints_to_pots(arm):
    cal = ArmCalibration.nominal(arm)
    for theta in np.random.default_rng(4).uniform(-2.0, 2.0, (500, 6)).tolist():
        pots = cal.joints_to_frame(theta)
        assert all(type(count) is float for count in pots)
        assert pots == cal.joints_to_pots(theta).tolist()


@pytest.mark.parametrize('arm', ARMS)
def test_pots_and_joints_are_inverse(arm):
    cal = ArmCalibration.nominal(arm)
    rng = np.random.default_rng(2)
    pots = rng.uniform(0, 4095, (500, 6))
    np.testing.assert_allclose(cal.joints_to_pots(cal.pots_to_joints(pots)), pots, atol=1e-9)
    theta = rng.uniform(-2.0, 2.0, (500, 6))
    np.testing.assert_allclose(cal.pots_to_joints(cal.joints_to_pots(theta)), theta, atol=1e-12)
    for single_pots, single_theta in zip(pots[:10], theta[:10]):
        assert cal.pots_to_joints(single_pots).shape == (6,)
        np.testing.assert_allclose(cal.joints_to_pots(cal.pots_to_joints(single_pots)),
                                   single_pots, atol=1e-9)
        np.testing.assert_allclose(cal.pots_to_joints(cal.joints_to_pots(single_theta)),
                                   single_theta, atol=1e-12)
    np.testing.assert_array_equal(cal.pots_to_joints(pots)[7], cal.pots_to_joints(pots[7]))
    np.testing.assert_array_equal(cal.joints_to_pots(theta)[7], cal.joints_to_pots(theta[7]))


def test_pot3_reads_the_absolute_elbow_angle():
    cal = ArmCalibration.nominal('right')
    theta = np.radians([10.0, 50.0, -90.0, 5.0, 15.0, -5.0])
    shifted = theta + np.radians([0.0, 20.0, -20.0, 0.0, 0.0, 0.0])
    before, after = cal.joints_to_pots(theta), cal.joints_to_pots(shifted)
    assert after[2] == pytest.approx(before[2], abs=1e-9)
    assert after[1] != pytest.approx(before[1], abs=1.0)
    np.testing.assert_allclose(np.delete(after, 1), np.delete(before, 1), atol=1e-9)


def line_samples(rng, slope, offset, noise, count):
    """Return (counts, angles) on a known line plus Gaussian noise."""
    counts = rng.uniform(200.0, 3900.0, count)
    return counts, offset + slope * counts + rng.normal(0.0, noise, count)


@pytest.mark.parametrize('arm', ARMS)
def test_fit_recovers_nominal_lines_from_noisy_samples(arm):
    rng = np.random.default_rng(3)
    truth = ArmCalibration.nominal(arm)
    noise, count = 1e-3, 400
    samples = [line_samples(rng, slope, offset, noise, count)
               for slope, offset in zip(truth.slope, truth.offset)]
    fit = ArmCalibration.fit(arm, samples)
    assert fit.calibration.arm == arm
    # About six standard errors of a fitted line over the whole 12-bit range.
    every_count = np.linspace(0.0, 4095.0, 50)[:, None] * np.ones(6)
    np.testing.assert_allclose(fit.calibration.joints_to_pots(truth.pots_to_joints(every_count)),
                               every_count, atol=6e-4 / np.abs(truth.slope).min())
    np.testing.assert_allclose(fit.calibration.slope, truth.slope, rtol=2e-3)
    np.testing.assert_allclose(fit.rms_residual, noise, rtol=0.15)
    assert np.all(fit.max_residual >= fit.rms_residual)
    assert np.all(fit.max_residual < 5 * noise)
    np.testing.assert_array_equal(fit.sample_count, [count] * 6)
    for pot, (counts, _) in enumerate(samples):
        assert fit.calibration.pot_a[pot] == counts.min()
        assert fit.calibration.pot_b[pot] == counts.max()


def test_fit_without_noise_is_exact():
    rng = np.random.default_rng(4)
    truth = ArmCalibration.nominal('left')
    samples = [line_samples(rng, slope, offset, 0.0, 3)
               for slope, offset in zip(truth.slope, truth.offset)]
    fit = ArmCalibration.fit('left', samples, source='bench run 7')
    np.testing.assert_allclose(fit.calibration.slope, truth.slope, rtol=1e-9)
    np.testing.assert_allclose(fit.calibration.offset, truth.offset, rtol=0, atol=1e-9)
    np.testing.assert_allclose(fit.rms_residual, 0.0, atol=1e-12)
    np.testing.assert_allclose(fit.max_residual, 0.0, atol=1e-12)
    assert fit.calibration.source == 'bench run 7'


@pytest.mark.parametrize('pot_samples, fault', (
    (([100.0, 200.0], [0.1]), 'POT3: need matching counts'),
    (([100.0], [0.1]), 'POT3: need matching counts'),
    (([], []), 'POT3: need matching counts'),
    (([300.0, 300.0, 300.0], [0.1, 0.2, 0.3]), 'POT3: need matching counts'),
    (([100.0, float('nan')], [0.1, 0.2]), 'POT3: samples must be finite'),
    (([100.0, 200.0], [0.1, float('inf')]), 'POT3: samples must be finite'),
    (([-500.0, 200.0], [0.1, 0.2]), 'calibration.pot_a: POT3 is -500'),
))
def test_fit_rejects_bad_samples(pot_samples, fault):
    good = ([100.0, 2000.0, 4000.0], [1.0, 0.0, -1.0])
    samples = [good, good, pot_samples, good, good, good]
    with pytest.raises(CalibrationError, match=fault) as error:
        ArmCalibration.fit('right', samples, source='bench')
    assert str(error.value).startswith('bench: ')
    with pytest.raises(CalibrationError, match='need samples for 6 pots, got 5'):
        ArmCalibration.fit('right', samples[:5])


@pytest.mark.parametrize('arm', ARMS)
def test_yaml_round_trip(arm, tmp_path):
    nominal = ArmCalibration.nominal(arm)
    path = tmp_path / f'{arm}.yaml'
    nominal.to_yaml(path, header='written by a test\nsecond line')
    text = path.read_text(encoding='utf-8')
    assert text.startswith('# written by a test\n# second line\n/**:\n  ros__parameters:\n')
    loaded = ArmCalibration.from_yaml(path)
    assert_same_calibration(loaded, nominal)
    assert loaded.source == str(path)
    # A fitted calibration has no round numbers: the file keeps 1e-9 degrees.
    rng = np.random.default_rng(5)
    samples = [line_samples(rng, slope, offset, 1e-3, 20)
               for slope, offset in zip(nominal.slope, nominal.offset)]
    fitted = ArmCalibration.fit(arm, samples).calibration
    fitted.to_yaml(path, node_name='kraft_master')
    assert_same_calibration(ArmCalibration.from_yaml(path), fitted, angle_tol=1e-10)
    assert calibration.read_parameter_file(path)['arm'] == arm


@pytest.mark.parametrize('arm', ARMS)
def test_shipped_config_files_are_nominal(arm):
    path = CONFIG / f'{arm}_arm.yaml'
    assert_same_calibration(ArmCalibration.from_yaml(path), ArmCalibration.nominal(arm))
    assert calibration.read_parameter_file(path)['link_lengths'] == list(NOMINAL_LENGTHS)


def test_from_parameters_names_its_source():
    parameters = ArmCalibration.nominal('right').to_parameters()
    loaded = ArmCalibration.from_parameters('right', parameters['calibration'], 'node params')
    assert_same_calibration(loaded, ArmCalibration.nominal('right'))
    parameters['calibration']['pot_b'][0] = 5000.0
    with pytest.raises(CalibrationError, match=r'^node params: calibration\.pot_b: POT1 is 5000'):
        ArmCalibration.from_parameters('right', parameters['calibration'], 'node params')


def edited_config(tmp_path, old, new):
    """Write config/right_arm.yaml with one piece of text replaced; return its path."""
    text = (CONFIG / 'right_arm.yaml').read_text(encoding='utf-8')
    assert old in text
    path = tmp_path / 'edited_arm.yaml'
    path.write_text(text.replace(old, new), encoding='utf-8')
    return path


def assert_rejected(path, *fragments):
    """Assert from_yaml raises CalibrationError, one line naming the file and every fragment."""
    with pytest.raises(CalibrationError) as error:
        ArmCalibration.from_yaml(path)
    message = str(error.value)
    assert message.startswith(f'{path}: ') or message.startswith(f'{path} line '), message
    assert '\n' not in message, message
    for fragment in fragments:
        assert fragment in message, message
    assert isinstance(error.value, ValueError)


def test_missing_file(tmp_path):
    assert_rejected(tmp_path / 'absent.yaml', 'cannot read', 'No such file')


def test_directory_instead_of_file(tmp_path):
    assert_rejected(tmp_path, 'cannot read')


@pytest.mark.parametrize('text, fault', (
    ('/**:\n  ros__parameters: [unclosed\n', 'line 3: not valid YAML'),
    ('/**:\n  ros__parameters:\n    arm: right\n   calibration: {}\n', 'line 4: not valid YAML'),
    ('', 'expected one node section'),
    ('- arm\n- right\n', 'expected one node section'),
    ('/a:\n  ros__parameters: {}\n/b:\n  ros__parameters: {}\n', 'expected one node section'),
    ('/**:\n  parameters:\n    arm: right\n', 'ros__parameters: missing or not a mapping'),
    ('/**:\n  ros__parameters: [1, 2]\n', 'ros__parameters: missing or not a mapping'),
    ('/**: 3\n', 'ros__parameters: missing or not a mapping'),
))
def test_bad_parameter_file_structure(tmp_path, text, fault):
    path = tmp_path / 'bad.yaml'
    path.write_text(text, encoding='utf-8')
    assert_rejected(path, fault)


def test_not_utf8(tmp_path):
    path = tmp_path / 'binary.yaml'
    path.write_bytes(b'/**:\n  ros__parameters:\n    arm: \xff\xfe\n')
    assert_rejected(path, 'not UTF-8')


def test_missing_arm(tmp_path):
    assert_rejected(edited_config(tmp_path, '    arm: right\n', ''), 'arm: missing key')


@pytest.mark.parametrize('arm', ('middle', 'Right', '42', '[right]'))
def test_unknown_arm(tmp_path, arm):
    assert_rejected(edited_config(tmp_path, 'arm: right', f'arm: {arm}'), 'arm: unknown arm')


def test_missing_calibration(tmp_path):
    text = (CONFIG / 'right_arm.yaml').read_text(encoding='utf-8')
    calibration_block = text[text.index('    calibration:'):]
    assert_rejected(edited_config(tmp_path, calibration_block, ''), 'calibration: missing key')


def test_calibration_not_a_mapping(tmp_path):
    text = (CONFIG / 'right_arm.yaml').read_text(encoding='utf-8')
    calibration_block = text[text.index('    calibration:'):]
    path = edited_config(tmp_path, calibration_block, '    calibration: [1, 2, 3]\n')
    assert_rejected(path, 'calibration: expected a mapping', 'pot_a')


@pytest.mark.parametrize('line', (RIGHT_POT_A, RIGHT_POT_B, RIGHT_ANGLE_A, RIGHT_ANGLE_B))
def test_missing_calibration_key(tmp_path, line):
    key = line.split(':')[0]
    assert_rejected(edited_config(tmp_path, line, 'unused: 0'), f'calibration.{key}: missing key')


@pytest.mark.parametrize('old, new, fragments', (
    (RIGHT_POT_A, 'pot_a: [157.0, 751.0, 248.0, 1126.0, 500.0]',
     ('calibration.pot_a', 'expected 6 numbers, got 5')),
    (RIGHT_POT_B, 'pot_b: [4014, 3328, 3863, 2766, 2930, 2656, 100]',
     ('calibration.pot_b', 'expected 6 numbers, got 7')),
    (RIGHT_ANGLE_A, 'angle_a_deg: []', ('calibration.angle_a_deg', 'expected 6 numbers, got 0')),
    (RIGHT_ANGLE_B, 'angle_b_deg: -90.0',
     ('calibration.angle_b_deg', 'expected a list of 6 numbers, got -90.0')),
))
def test_wrong_length(tmp_path, old, new, fragments):
    assert_rejected(edited_config(tmp_path, old, new), *fragments)


@pytest.mark.parametrize('old, new, fragments', (
    (RIGHT_POT_A, 'pot_a: [.nan, 751.0, 248.0, 1126.0, 500.0, 1395.0]',
     ('calibration.pot_a', 'POT1 is nan', 'finite')),
    (RIGHT_ANGLE_A, 'angle_a_deg: [90.0, .NaN, 35.0, -20.0, 55.0, 45.0]',
     ('calibration.angle_a_deg', 'POT2 is nan', 'finite')),
    (RIGHT_ANGLE_B, 'angle_b_deg: [-90.0, 120.0, -135.0, 50.0, -55.0, .inf]',
     ('calibration.angle_b_deg', 'POT6 is inf', 'finite')),
    (RIGHT_POT_B, 'pot_b: [4014.0, 3328.0, -.inf, 2766.0, 2930.0, 2656.0]',
     ('calibration.pot_b', 'POT3 is -inf', 'finite')),
))
def test_not_finite(tmp_path, old, new, fragments):
    assert_rejected(edited_config(tmp_path, old, new), *fragments)


@pytest.mark.parametrize('old, new, fragments', (
    (RIGHT_POT_A, 'pot_a: [157.0, abc, 248.0, 1126.0, 500.0, 1395.0]',
     ('calibration.pot_a', "POT2 is 'abc'", 'expected a number')),
    (RIGHT_POT_B, "pot_b: ['4014', 3328, 3863, 2766, 2930, 2656]",
     ('calibration.pot_b', "POT1 is '4014'", 'expected a number')),
    (RIGHT_ANGLE_A, 'angle_a_deg: ninety',
     ('calibration.angle_a_deg', "expected a list of 6 numbers, got 'ninety'")),
    (RIGHT_ANGLE_B, 'angle_b_deg: [-90.0, 120.0, -135.0, 50.0, -55.0, true]',
     ('calibration.angle_b_deg', 'POT6 is True', 'expected a number')),
    (RIGHT_POT_A, 'pot_a: [157.0, 751.0, [248.0], 1126.0, 500.0, 1395.0]',
     ('calibration.pot_a', 'POT3 is [248.0]', 'expected a number')),
    (RIGHT_POT_A, 'pot_a: {a: 1}',
     ('calibration.pot_a', 'expected a list of 6 numbers')),
    (RIGHT_POT_A, 'pot_a:', ('calibration.pot_a', 'expected a list of 6 numbers, got None')),
))
def test_not_numbers(tmp_path, old, new, fragments):
    assert_rejected(edited_config(tmp_path, old, new), *fragments)


@pytest.mark.parametrize('old, new, fragments', (
    (RIGHT_POT_A, 'pot_a: [-1.0, 751.0, 248.0, 1126.0, 500.0, 1395.0]',
     ('calibration.pot_a', 'POT1 is -1', '0..4095 counts')),
    (RIGHT_POT_B, 'pot_b: [4014.0, 3328.0, 3863.0, 2766.0, 4096, 2656.0]',
     ('calibration.pot_b', 'POT5 is 4096', '0..4095 counts')),
    (RIGHT_ANGLE_A, 'angle_a_deg: [90.0, 0.0, 35.0, -361.0, 55.0, 45.0]',
     ('calibration.angle_a_deg', 'POT4 is -361', '-360..360 deg')),
))
def test_out_of_range(tmp_path, old, new, fragments):
    assert_rejected(edited_config(tmp_path, old, new), *fragments)


def test_full_range_counts_are_accepted(tmp_path):
    path = edited_config(tmp_path, RIGHT_POT_A, 'pot_a: [0, 0, 0, 0, 0, 0]')
    text = path.read_text(encoding='utf-8')
    path.write_text(text.replace(RIGHT_POT_B, 'pot_b: [4095, 4095, 4095, 4095, 4095, 4095]'),
                    encoding='utf-8')
    cal = ArmCalibration.from_yaml(path)
    np.testing.assert_array_equal(cal.pot_a, np.zeros(6))
    np.testing.assert_array_equal(cal.pot_b, np.full(6, 4095.0))


def test_equal_pot_points(tmp_path):
    path = edited_config(tmp_path, RIGHT_POT_B, 'pot_b: [4014, 3328, 248, 2766, 2930, 2656]')
    assert_rejected(path, 'calibration.pot_b', 'POT3 has its two calibration points equal (248)')


def test_equal_angle_points(tmp_path):
    path = edited_config(tmp_path, RIGHT_ANGLE_B, 'angle_b_deg: [-90, 120, -135, -20, -55, -45]')
    assert_rejected(path, 'calibration.angle_b_deg',
                    'POT4 has its two calibration points equal (-20)')


@pytest.mark.parametrize('arm', ('middle', None))
def test_bad_arm_in_code(arm):
    with pytest.raises(CalibrationError, match='arm: unknown arm'):
        ArmCalibration.nominal(arm)
    nominal = ArmCalibration.nominal('right')
    with pytest.raises(CalibrationError, match='^mine: arm: unknown arm'):
        ArmCalibration(arm, nominal.pot_a, nominal.pot_b, nominal.angle_a, nominal.angle_b,
                       source='mine')
