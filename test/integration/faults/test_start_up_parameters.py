# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""Bad parameters at start-up: the driver exits 1 naming them (parameters, calibration)."""
import concurrent.futures
import math
import re
import time
from typing import NamedTuple

from harness import REPO
from harness.driver import next_domain_id, WAIT_S
from harness.faults import bad_values, Driver, record
from kraft_master_driver.nodes.driver_parameters import PARAMETERS
import pytest
import yaml

pytestmark = [pytest.mark.faults, pytest.mark.integration]

STARTUP_WORKERS = 4


def yaml_literal(value):
    """Return `value` in the YAML syntax of a `-p name:=value` on the ROS command line."""
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, (list, tuple)):
        return '[' + ', '.join(yaml_literal(v) for v in value) + ']'
    if isinstance(value, float):
        return repr(value) if math.isfinite(value) else {'nan': '.nan'}.get(str(value), '.inf')
    return str(value)


class StartupCase(NamedTuple):
    """A driver start with bad parameters: it must exit 1 with a message naming `names`."""

    name: str
    parameters: tuple = ()  # (name, YAML literal) pairs for -p
    params_file: object = None  # a parameter file as a dict
    names: tuple = ()


def startup_case(case):
    """Return the pytest.param of a start-up case."""
    return pytest.param(case, id=case.name)


def parameter_start_cases():
    """
    Every parameter set to each kind of bad value at start-up.

    NaN goes through the same range checks as an out-of-range value (it is tried at run
    time); an empty value is tried once per kind of parameter (bool, int, float, str, choice,
    list), as it takes the same path for all parameters of a kind.
    """
    cases, kinds_tried = [], set()
    for name, spec in PARAMETERS.items():
        kind_of_parameter = (type(spec.default), bool(spec.choices))
        for kind, value in bad_values(name, spec):
            if kind == 'NaN' or (value is None and kind_of_parameter in kinds_tried):
                continue
            literal = '[]' if value is None else yaml_literal(value)
            cases.append(startup_case(
                StartupCase(f'{name} {kind}', ((name, literal),), names=(name,))))
        kinds_tried.add(kind_of_parameter)
    return cases


def calibration_file(change):
    """config/right_arm.yaml as a dict, its calibration mapping changed by `change`."""
    params = yaml.safe_load((REPO / 'config' / 'right_arm.yaml').read_text())
    change(params['/**']['ros__parameters']['calibration'])
    return params


def calibration_cases():
    """Calibration parameter files with a key missing, misspelt, too short, or a point twice."""
    keys = ('pot_a', 'pot_b', 'angle_a_deg', 'angle_b_deg')
    cases = []
    for key in keys:
        cases.append(startup_case(StartupCase(
            f'calibration {key} missing', params_file=calibration_file(lambda c: c.pop(key)),
            names=(f'calibration.{key}',))))
        cases.append(startup_case(StartupCase(
            f'calibration {key} with 5 values',
            params_file=calibration_file(lambda c: c[key].pop()),
            names=(f'calibration.{key}',))))
    cases.append(startup_case(StartupCase(
        'calibration pot_a misspelt', params_file=calibration_file(
            lambda c: c.update(pot_A=c.pop('pot_a'))), names=('calibration.pot_a',))))
    for first, second in (('pot_a', 'pot_b'), ('angle_a_deg', 'angle_b_deg')):
        cases.append(startup_case(StartupCase(
            f'calibration POT3 {first} == {second}', params_file=calibration_file(
                lambda c: c[second].__setitem__(2, c[first][2])),
            names=(f'calibration.{second}', 'POT3'))))
    return cases


STARTUP_CASES = parameter_start_cases() + calibration_cases()


class StartupRuns:
    """Runs the selected start-up cases a few at a time, once, when the first is needed."""

    def __init__(self, prefix, directory, cases):
        """Run `cases` (StartupCase) with the driver installed at `prefix`."""
        self.prefix, self.directory, self.cases = prefix, directory, cases
        self.results = {}

    def result(self, case):
        """Return (exit code or 'started', output, seconds) of `case`."""
        if case.name not in self.results:
            with concurrent.futures.ThreadPoolExecutor(STARTUP_WORKERS) as pool:
                pending = [c for c in self.cases if c.name not in self.results] or [case]
                for pending_case, outcome in zip(pending, pool.map(self._run, pending)):
                    self.results[pending_case.name] = outcome
        return self.results[case.name]

    def _run(self, case):
        params_file = None
        if case.params_file is not None:
            params_file = self.directory / (re.sub(r'\W+', '_', case.name) + '.yaml')
            params_file.write_text(yaml.safe_dump(case.params_file))
        started = time.monotonic()
        driver = Driver(self.prefix, next_domain_id(), case.parameters, params_file=params_file)
        try:
            outcome = driver.started_or_exited()
            deadline = started + WAIT_S
            while outcome is None and time.monotonic() < deadline:
                time.sleep(0.02)
                outcome = driver.started_or_exited()
        finally:
            driver.kill()
        return outcome, driver.output, time.monotonic() - started


@pytest.fixture(scope='module')
def startup_runs(install_prefix, tmp_path_factory, request):
    """Start-up outcomes of the cases of this session's selected tests."""
    selected = [item.callspec.params['case'] for item in request.session.items
                if item.originalname == 'test_bad_start_up_parameters_exit_1_naming_them']
    return StartupRuns(install_prefix, tmp_path_factory.mktemp('startup'), selected)


@pytest.mark.parametrize('case', STARTUP_CASES)
def test_bad_start_up_parameters_exit_1_naming_them(startup_runs, case):
    code, output, seconds = startup_runs.result(case)
    group = 'calibration' if case.params_file else 'start-up'
    record(group, case.name, outcome=code, seconds=round(seconds, 2))
    assert code == 1, f'exit {code!r}:\n{output}'
    assert 'Traceback' not in output, output
    for name in case.names:
        assert name in output, output
