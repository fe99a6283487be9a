# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The package as installed: its commands in the venv, and every import it makes declared."""
import ast
import functools
import importlib.metadata
import os
import pathlib
import re
import subprocess
import sys
import xml.etree.ElementTree as ET

from harness import PACKAGE, REPO
from harness.driver import next_domain_id
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
import pytest

BIN = pathlib.Path(sys.executable).parent
# rosdep keys of package.xml and the module each one installs (rosdistro's rosdep/python.yaml).
ROSDEP_MODULES = {'python3-numpy': 'numpy', 'python3-serial': 'serial', 'python3-yaml': 'yaml',
                  'python3-matplotlib': 'matplotlib', 'python3-rosbags-pip': 'rosbags',
                  'python3-mujoco-pip': 'mujoco',
                  'python3-gymnasium-robotics-pip': 'gymnasium_robotics',
                  'python3-eclipse-zenoh-pip': 'zenoh'}

# ROS packages that are not on PyPI, imported only where installed (the bridge's TF lookup and
# its test): package.xml declares them for a ROS install; no pip file can bring them.
NOT_ON_PYPI = {'tf2_ros', 'tf2_msgs'}


def console_scripts():
    """Return {command: 'module:function'} of setup.py's console_scripts."""
    tree = ast.parse((REPO / 'setup.py').read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Dict):
            for key, value in zip(node.keys, node.values):
                if isinstance(key, ast.Constant) and key.value == 'console_scripts':
                    entries = (e.value.partition('=') for e in value.elts)
                    return {name.strip(): target.strip() for name, _, target in entries}
    raise AssertionError('setup.py has no console_scripts')


def outside_env():
    """Return this environment without PYTHONPATH, on a DDS domain of its own."""
    env = {k: v for k, v in os.environ.items() if k != 'PYTHONPATH'}
    env['ROS_DOMAIN_ID'] = str(next_domain_id())
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    return env


@pytest.mark.parametrize('name', sorted(console_scripts()))
def test_every_console_script_is_installed_in_the_venv(name):
    path = BIN / name
    assert os.access(path, os.X_OK), f'{path} missing: run make venv (pip install -e .)'
    installed = {e.name: e.value for e in importlib.metadata.entry_points(group='console_scripts')}
    assert installed.get(name) == console_scripts()[name], 'stale install: run make venv'


@pytest.mark.process
@pytest.mark.parametrize('name', sorted(console_scripts()))
def test_every_console_script_answers_help_from_outside_the_repo(name, tmp_path):
    process = subprocess.Popen(
        [str(BIN / name), '--help'], cwd=tmp_path, env=outside_env(), stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        output, errors = process.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        process.kill()
        output, errors = process.communicate()
        pytest.fail(f'{name} --help ran on instead of printing its usage:\n{output}{errors}')
    assert process.returncode == 0, output + errors
    assert output.startswith(f'usage: {name}'), output + errors


@pytest.mark.process
def test_the_colcon_install_ships_py_typed(install_prefix):
    """PEP 561: a type checker uses the installed package's type hints."""
    markers = list(install_prefix.glob(f'lib/python3*/site-packages/{PACKAGE}/py.typed'))
    assert markers, f'{install_prefix}: no {PACKAGE}/py.typed installed (setup.py package_data)'


def readme_python_blocks():
    """Return the ```python blocks of the README and of the pages in doc/."""
    pages = [REPO / 'README.md', *sorted((REPO / 'doc').glob('*.md'))]
    return [block for page in pages for block in re.findall(
        r'^```python\n(.*?)^```', page.read_text(), re.MULTILINE | re.DOTALL)]


@pytest.mark.process
def test_the_readme_python_snippets_run_from_any_directory(tmp_path):
    """Each snippet runs in the venv's Python, outside the repository (a device via the sim)."""
    blocks = readme_python_blocks()
    assert blocks
    simulator = subprocess.Popen([str(BIN / 'kraft_master_sim')], cwd=tmp_path,
                                 env=outside_env(), stdout=subprocess.PIPE, text=True)
    try:
        port = simulator.stdout.readline().partition('port: ')[2].strip()
        assert port, 'kraft_master_sim printed no port'
        for block in blocks:
            code = re.sub(r'/tmp/kraft_master_sim_\w+/tty', port, block)
            result = subprocess.run([sys.executable, '-c', code], cwd=tmp_path,
                                    env=outside_env(), capture_output=True, text=True,
                                    timeout=120)
            assert result.returncode == 0, f'{block}\n{result.stderr}'
    finally:
        simulator.terminate()
        simulator.communicate(timeout=20)


# -- dependencies ---------------------------------------------------------------------------


def import_groups(path, first_party=()):
    """
    Return the third-party imports of a Python file as groups of alternatives.

    Every import is a group of one, except those in a try whose handler catches ImportError:
    the imports of its body and handlers are one group, any one of which suffices.
    """
    tree = ast.parse(path.read_text())
    local = {PACKAGE, *first_party}

    def names(nodes):
        found = set()
        for node in nodes:
            for sub in ast.walk(node):
                if isinstance(sub, ast.Import):
                    found.update(alias.name.split('.')[0] for alias in sub.names)
                elif isinstance(sub, ast.ImportFrom) and sub.level == 0:
                    found.add(sub.module.split('.')[0])
        return found - local

    groups, grouped = [], set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Try) and any(
                isinstance(h.type, ast.Name) and h.type.id in ('ImportError',
                                                               'ModuleNotFoundError')
                for h in node.handlers):
            group = names(node.body + node.handlers)
            if group:
                groups.append(frozenset(group))
            grouped.update(id(sub) for sub in ast.walk(node))
    others = [n for n in ast.walk(tree)
              if isinstance(n, (ast.Import, ast.ImportFrom)) and id(n) not in grouped]
    groups += [frozenset([name]) for name in names(others)]
    return [g for g in groups if not g & sys.stdlib_module_names]


def package_modules():
    """Return the package's modules and launch files: what is installed and run."""
    return sorted((REPO / PACKAGE).rglob('*.py')) + sorted((REPO / 'launch').glob('*.py'))


def exec_depends():
    """Return package.xml's exec_depend keys."""
    root = ET.parse(REPO / 'package.xml').getroot()
    return {element.text.strip() for element in root.iter('exec_depend')}


@functools.lru_cache(maxsize=None)
def distributions_of_modules():
    """Return {top-level module: canonical names of the installed distributions providing it}."""
    return {top: {canonicalize_name(d) for d in dists}
            for top, dists in importlib.metadata.packages_distributions().items()}


def top_level_modules(distribution):
    """Return the top-level module names an installed distribution provides."""
    return {top for top, dists in distributions_of_modules().items()
            if canonicalize_name(distribution) in dists}


def requirements_lines(path):
    """Return the requirement lines of a requirements file, following -r includes."""
    lines = []
    for line in path.read_text().splitlines():
        line = line.split('#')[0].strip()
        if line.startswith('-r '):
            lines += requirements_lines(path.parent / line[3:])
        elif line:
            lines.append(line)
    return lines


def requirements_closure(path=None, lines=()):
    """Return the canonical names of the distributions that installing `path` or `lines` does."""
    pending = [(Requirement(line), '') for line in (requirements_lines(path) if path else lines)]
    seen = set()
    while pending:
        requirement, parent_extra = pending.pop()
        if requirement.marker and not requirement.marker.evaluate({'extra': parent_extra}):
            continue
        name = canonicalize_name(requirement.name)
        for extra in ('', *sorted(requirement.extras)):
            if (name, extra) in seen:
                continue
            seen.add((name, extra))
            pending += [(Requirement(text), extra)
                        for text in importlib.metadata.requires(name) or []]
    return {name for name, _ in seen}


def provided_by(closure, module):
    """Whether a distribution of `closure` provides top-level `module`."""
    return bool(distributions_of_modules().get(module, set()) & closure)


def test_every_import_of_the_package_is_declared_in_package_xml():
    declared = exec_depends()
    modules = {ROSDEP_MODULES.get(key, key) for key in declared}
    # A pip key installs its distribution's own requirements too (rosbags: lz4, backports).
    for key in declared & set(ROSDEP_MODULES):
        if key.endswith('-pip'):
            distribution = key.removeprefix('python3-').removesuffix('-pip')
            for text in importlib.metadata.requires(distribution) or []:
                modules |= top_level_modules(Requirement(text).name)
    missing = {f'{path.relative_to(REPO)}: {" or ".join(sorted(group))}'
               for path in package_modules() for group in import_groups(path)
               if not group & modules}
    assert not missing, 'imports without an exec_depend in package.xml:\n' + '\n'.join(
        sorted(missing))


def test_every_import_of_the_package_is_brought_by_requirements_txt():
    closure = requirements_closure(REPO / 'requirements.txt')
    missing = {f'{path.relative_to(REPO)}: {" or ".join(sorted(group))}'
               for path in sorted((REPO / PACKAGE).rglob('*.py'))
               for group in import_groups(path)
               if not group <= NOT_ON_PYPI
               and not any(provided_by(closure, module) for module in group)}
    assert not missing, 'imports requirements.txt does not install:\n' + '\n'.join(
        sorted(missing))


def install_requires():
    """Return setup.py's install_requires."""
    for node in ast.walk(ast.parse((REPO / 'setup.py').read_text())):
        if isinstance(node, ast.keyword) and node.arg == 'install_requires':
            return [element.value for element in node.value.elts]
    raise AssertionError('setup.py has no install_requires')


def test_every_import_but_ros_is_in_setup_py_install_requires():
    ros = {line for line in requirements_lines(REPO / 'requirements.txt')
           if line.startswith('ros-jazzy-')}
    closure = requirements_closure(lines=install_requires())
    ros_closure = requirements_closure(lines=ros)
    missing = {f'{path.relative_to(REPO)}: {" or ".join(sorted(group))}'
               for path in sorted((REPO / PACKAGE).rglob('*.py'))
               for group in import_groups(path)
               if not group <= NOT_ON_PYPI
               and not any(provided_by(closure, module) or provided_by(ros_closure, module)
                           for module in group)}
    assert not missing, 'imports setup.py does not require:\n' + '\n'.join(sorted(missing))


def first_party(path):
    """
    Return the top-level modules of this repository a test, benchmark or script can import.

    The packages at the root (benchmarks/, run as modules from there); those on the tests'
    path (pytest.ini; PYTHONPATH for the scripts that use the harness): test/'s modules and
    helper packages (harness/); and those beside the file, whose directory pytest (for a test)
    or Python (for a script) puts first on the path.
    """
    tests = REPO / 'test'
    return ({init.parent.name for init in [*REPO.glob('*/__init__.py'),
                                           *tests.glob('*/__init__.py')]} |
            {module.stem for module in [*tests.glob('*.py'), *path.parent.glob('*.py')]})


def test_tests_and_benchmarks_imports_are_brought_by_requirements_dev_txt():
    closure = requirements_closure(REPO / 'requirements-dev.txt')
    missing = {f'{path.relative_to(REPO)}: {" or ".join(sorted(group))}'
               for directory in ('test', 'benchmarks', 'scripts', 'doc')
               for path in sorted((REPO / directory).rglob('*.py'))
               for group in import_groups(path, first_party(path))
               if not group <= NOT_ON_PYPI
               and not any(provided_by(closure, module) for module in group)}
    assert not missing, 'imports requirements-dev.txt does not install:\n' + '\n'.join(
        sorted(missing))


# -- the Makefile's set-up ------------------------------------------------------------------

SETUP_FILES = ('Makefile', 'requirements.txt', 'requirements-dev.txt', 'constraints.txt',
               'setup.py', 'setup.cfg')
STAGES = {'venv': 'creating .venv', 'run': 'requirements.txt', 'dev': 'requirements-dev.txt',
          'package': '--editable .'}


@pytest.fixture
def checkout(tmp_path):
    """Return a directory with the Makefile and the files its set-up depends on."""
    for name in SETUP_FILES:
        (tmp_path / name).write_bytes((REPO / name).read_bytes())
    return tmp_path


def make(directory, *args):
    """
    Run make in `directory` as a user's shell would, not as a sub-make of `make test`.

    A make passes the variables of its command line to what it runs, in MAKEFLAGS and the
    environment (`make test-latest`: CONSTRAINTS= and VENV=.venv-latest); none reach this one.
    """
    flags = os.environ.get('MAKEFLAGS', '').split()
    given = flags[flags.index('--') + 1:] if '--' in flags else []
    calling_make = {'MAKEFLAGS', 'MAKELEVEL', 'MFLAGS', *(word.split('=')[0] for word in given)}
    env = {k: v for k, v in os.environ.items() if k not in calling_make}
    return subprocess.run(['make', *args], cwd=directory, env=env, capture_output=True,
                          text=True, timeout=60)


def planned_stages(directory, *args):
    """Return the set-up stages `make -n ARGS` would run in `directory`."""
    result = make(directory, '-n', *args)
    assert result.returncode == 0, result.stderr
    return {stage for stage, text in STAGES.items() if text in result.stdout}


def set_up(directory):
    """Make `directory` look set up as `make test` leaves it: the venv's Python and stamps."""
    python = directory / '.venv' / 'bin' / 'python'
    python.parent.mkdir(parents=True)
    python.symlink_to(sys.executable)
    for stamp in ('requirements', 'requirements-dev', 'package'):
        (directory / '.venv' / f'.installed-{stamp}').touch()


@pytest.mark.process
def test_the_first_make_demo_installs_what_running_needs_only(checkout):
    assert planned_stages(checkout, 'demo') == {'venv', 'run', 'package'}
    assert planned_stages(checkout, 'test') == {'venv', 'run', 'dev', 'package'}


@pytest.mark.process
@pytest.mark.parametrize('changed, target, stages', [
    (None, 'demo', set()), (None, 'test', set()),
    ('requirements.txt', 'demo', {'run'}), ('requirements.txt', 'test', {'run', 'dev'}),
    ('constraints.txt', 'demo', {'run'}), ('constraints.txt', 'test', {'run', 'dev'}),
    ('requirements-dev.txt', 'demo', set()), ('requirements-dev.txt', 'test', {'dev'}),
    ('setup.py', 'demo', {'package'}), ('setup.cfg', 'test', {'package'})])
def test_later_runs_install_only_what_a_changed_file_asks_for(
        checkout, changed, target, stages):
    set_up(checkout)
    assert planned_stages(checkout, *(['-W', changed] if changed else []), target) == stages


@pytest.mark.process
def test_without_python_make_says_what_to_install(checkout):
    result = make(checkout, 'demo', 'PYTHON=no-such-python3')
    assert result.returncode != 0
    assert result.stdout == ('make: no no-such-python3: install Python 3.11 or newer '
                             '(Debian/Ubuntu: sudo apt install python3 python3-venv)\n')
    assert not (checkout / '.venv').exists()


def pip_installs(directory, *args):
    """Return the `pip install -r` commands `make -n ARGS` would run in `directory`."""
    result = make(directory, '-n', *args)
    assert result.returncode == 0, result.stderr
    commands = re.findall(r'(\S+ -m pip install .* -r .*?)(?:&&|$)', result.stdout, re.MULTILINE)
    return [command.strip() for command in commands]


@pytest.mark.process
@pytest.mark.parametrize('target', ['demo', 'test'])
def test_make_installs_the_pinned_versions(checkout, target):
    installs = pip_installs(checkout, target)
    assert installs
    assert all(line.endswith('--constraint constraints.txt') for line in installs), installs


@pytest.mark.process
def test_make_test_latest_installs_the_newest_into_a_venv_of_its_own(checkout):
    installs = pip_installs(checkout, 'test-latest')
    assert installs
    assert all(line.startswith('.venv-latest/bin/python -m pip install') for line in installs)
    assert not any('--constraint' in line for line in installs), installs


@pytest.mark.process
def test_make_lock_pins_the_version_of_everything_the_requirements_install(checkout):
    venv = pathlib.Path(sys.prefix)
    stamps = [f'--old-file={venv}/.installed-{stamp}' for stamp in ('requirements-dev', 'package')]
    result = make(checkout, *stamps, 'lock', f'VENV={venv}')
    assert result.returncode == 0, result.stderr
    lines = (checkout / 'constraints.txt').read_text().splitlines()
    assert lines[0].startswith('# Made by `make lock`')
    pins = dict(line.split('==') for line in lines if not line.startswith('#'))
    assert {name: importlib.metadata.version(name) for name in pins} == pins
    pinned = {canonicalize_name(name) for name in pins}
    assert requirements_closure(REPO / 'requirements-dev.txt') - {'kraft-master-driver'} <= pinned
