# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Every test outside integration/ that starts a process is marked `process` (pytest.ini).

Read from the source: a test starts a process when it, a definition of its file, a fixture of
test/conftest.py or a definition it imports from harness/ calls one of PROCESS_CALLS, directly
or through another of these. integration/conftest.py marks every test under integration/.
"""
import ast

from harness import REPO
import pytest

TESTS = REPO / 'test'
PROCESS_CALLS = {'subprocess.Popen', 'subprocess.run', 'subprocess.call', 'subprocess.check_call',
                 'subprocess.check_output', 'os.system', 'os.popen', 'os.fork', 'os.forkpty',
                 'os.posix_spawn', 'os.posix_spawnp', 'pty.fork', 'multiprocessing.Process',
                 'multiprocessing.Pool'}


def used_names(node):
    """Return the names a definition uses: plain names, parameters and `module.attribute`s."""
    names = set()
    for sub in ast.walk(node):
        if isinstance(sub, ast.Name):
            names.add(sub.id)
        elif isinstance(sub, ast.arg):
            names.add(sub.arg)
        elif isinstance(sub, ast.Attribute) and isinstance(sub.value, ast.Name):
            names.add(f'{sub.value.id}.{sub.attr}')
    return names


def marks_process(nodes):
    """Whether these decorators or pytestmark values name pytest.mark.process."""
    return any(isinstance(sub, ast.Attribute) and sub.attr == 'process'
               for node in nodes for sub in ast.walk(node))


class Module:
    """One file's top-level definitions and what it imports from harness/."""

    def __init__(self, name, path):
        tree = ast.parse(path.read_text())
        self.name = name
        self.definitions = {node.name: node for node in tree.body if isinstance(
            node, (ast.FunctionDef, ast.ClassDef))}
        self.imported = {alias.asname or alias.name: f'{node.module}:{alias.name}'
                         for node in tree.body if isinstance(node, ast.ImportFrom)
                         and (node.module or '').split('.')[0] == 'harness'
                         for alias in node.names}
        self.marked = marks_process(node.value for node in tree.body if isinstance(
            node, ast.Assign) and 'pytestmark' in used_names(node))

    def key(self, name):
        """Return the definition `name` stands for in this file, or None."""
        if name in self.definitions:
            return f'{self.name}:{name}'
        if name in self.imported:
            return self.imported[name]
        return f'conftest:{name}' if name in FIXTURES.definitions else None


FIXTURES = Module('conftest', TESTS / 'conftest.py')


def checked_test_files():
    """Return the test files outside integration/, by name."""
    return {path.relative_to(TESTS).as_posix(): path for folder in ('unit', 'repository')
            for path in sorted((TESTS / folder).rglob('test_*.py'))}


def starting(modules):
    """Return the definitions of `modules` that start a process, as 'module:name'."""
    found = set()
    while True:
        more = {f'{module.name}:{name}' for module in modules
                for name, node in module.definitions.items()
                if any(used in PROCESS_CALLS or module.key(used) in found
                       for used in used_names(node))}
        if more <= found:
            return found
        found |= more


def test_every_test_that_starts_a_process_is_marked_process():
    harness = [Module('harness' if path.stem == '__init__' else f'harness.{path.stem}', path)
               for path in sorted((TESTS / 'harness').glob('*.py'))]
    tests = [Module(name, path) for name, path in checked_test_files().items()]
    found = starting([FIXTURES, *harness, *tests])
    assert 'conftest:install_prefix' in found and 'harness.driver:DriverProcess' in found
    unmarked = [f'{module.name}::{name}' for module in tests if not module.marked
                for name, node in module.definitions.items()
                if name.startswith('test_') and f'{module.name}:{name}' in found
                and not marks_process(node.decorator_list)]
    assert not unmarked, 'start a process, not marked process:\n' + '\n'.join(unmarked)


@pytest.mark.parametrize('source, starts', [
    ('def test_a():\n    subprocess.run(["true"])\n', True),
    ('def helper():\n    os.posix_spawn("x", [], {})\n\ndef test_a():\n    helper()\n', True),
    ('def test_a(install_prefix):\n    pass\n', True),
    ('from harness.driver import DriverProcess\n\ndef test_a():\n    DriverProcess()\n', True),
    ('def test_a():\n    subprocess.TimeoutExpired\n', False),
    ('def run():\n    pass\n\ndef test_a():\n    run()\n', False)])
def test_the_reading_finds_what_starts_a_process(tmp_path, source, starts):
    path = tmp_path / 'test_example.py'
    path.write_text(source)
    harness = Module('harness.driver', TESTS / 'harness' / 'driver.py')
    found = starting([FIXTURES, harness, Module('example', path)])
    assert ('example:test_a' in found) == starts
