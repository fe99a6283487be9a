# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""The README and doc/ say what the code does: parameters, operators, layout, links, build."""
import ast
import importlib.metadata
import re
import subprocess
import sys
import xml.etree.ElementTree as ET

from harness import PACKAGE, REPO
from kraft_master_driver.nodes.driver_parameters import PARAMETERS
from kraft_master_driver.simulation.master.operators import OPERATORS
import pytest
import yaml

DOC = REPO / 'doc'
README = (REPO / 'README.md').read_text()
INTERFACE = (DOC / 'ros-interface.md').read_text()
ROWS = {m.group(1): m.groups()[1:] for m in re.finditer(
    r'^\| `([a-z_.]+)` \| ([a-z\[\]0-9]+) \| ([^|]+) \| ([^|]*) \|', INTERFACE, re.MULTILINE)}
RUN_TIME = {m.group(1): m.group(2) for m in re.finditer(
    r'^\| `([a-z_.]+)` \| [a-z\[\]0-9]+ \| [^|]+ \| [^|]* \| (yes|no) \|', INTERFACE,
    re.MULTILINE)}


def number(value):
    """Return a number as the table writes it: integers as integers (1000000, not 1e+06)."""
    if isinstance(value, int) or float(value).is_integer() and abs(value) < 1e15:
        return str(int(value))
    return f'{value:g}'


def readme_default(value):
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, list):
        return '`[' + ', '.join(number(x) for x in value) + ']`'
    if isinstance(value, str):
        return f'`{value}`' if value else "`''`"
    return f'`{number(value)}`'


def readme_type(default):
    kind = type(default[0]) if isinstance(default, list) else type(default)
    name = {bool: 'bool', int: 'int', float: 'double', str: 'string'}[kind]
    return f'{name}[{len(default)}]' if isinstance(default, list) else name


def readme_range(spec):
    if spec.choices:
        return ', '.join(spec.choices)
    return '' if spec.low is None else f'{number(spec.low)} .. {number(spec.high)}'


@pytest.mark.parametrize('name', PARAMETERS)
def test_every_parameter_is_in_the_readme_table_with_its_default(name):
    assert name in ROWS, f'doc/ros-interface.md has no row for parameter {name}'
    spec = PARAMETERS[name]
    kind, default, bounds = (cell.strip() for cell in ROWS[name])
    assert (kind, default, bounds) == (
        readme_type(spec.default), readme_default(spec.default), readme_range(spec))


@pytest.mark.parametrize('name', PARAMETERS)
def test_the_run_time_column_says_whether_the_parameter_is_settable(name):
    assert RUN_TIME.get(name) == ('no' if PARAMETERS[name].read_only else 'yes')


def test_integers_show_as_integers():
    assert [cell.strip() for cell in ROWS['baud'][1:]] == ['`1000000`', '1200 .. 12000000']
    assert 'e+' not in ''.join(''.join(cells) for cells in ROWS.values())


def test_the_readme_table_has_no_stale_parameter():
    assert set(ROWS) <= set(PARAMETERS)


@pytest.mark.parametrize('command', ['make demo', 'make test'])
def test_readme_starts_with_the_two_commands(command):
    assert command in README[:1500]


def test_the_simulator_section_names_every_operator():
    section = (DOC / 'simulator.md').read_text()
    listed = re.search(r'\(`--operator ([^)]*)\)', section).group(1)
    assert re.findall(r'`?(\w+)`', listed) == list(OPERATORS)


# -- links ----------------------------------------------------------------------------------

PAGES = [REPO / 'README.md', REPO / 'CONTRIBUTING.md', *sorted(DOC.glob('*.md')),
         *sorted((DOC / 'design').glob('*.md'))]
LINK = re.compile(r'!?\[[^\]]*\]\(([^)\s]+)\)')


def anchors(page):
    """Return the anchors of a Markdown page's headings, as GitHub and MyST make them."""
    text = re.sub(r'^```.*?^```', '', page.read_text(), flags=re.MULTILINE | re.DOTALL)
    return {re.sub(r'[^\w\- ]', '', heading.strip().lower()).replace(' ', '-')
            for heading in re.findall(r'^#{1,6} (.*)$', text, re.MULTILINE)}


def relative_links(page):
    """Return the link targets of a Markdown page outside its code, other than URLs."""
    text = re.sub(r'^```.*?^```', '', page.read_text(), flags=re.MULTILINE | re.DOTALL)
    text = re.sub(r'`[^`\n]*`', '', text)
    return [target for target in LINK.findall(text)
            if not re.match(r'[a-z][a-z0-9+.-]*:', target)]


@pytest.mark.parametrize('page', PAGES, ids=lambda p: str(p.relative_to(REPO)))
def test_every_relative_link_points_to_a_file_and_heading_that_exist(page):
    for target in relative_links(page):
        path, _, fragment = target.partition('#')
        destination = (page.parent / path).resolve() if path else page
        assert destination.exists(), f'{page.name}: {target} points to nothing'
        if fragment:
            assert destination.suffix == '.md', f'{page.name}: {target}'
            assert fragment in anchors(destination), (
                f'{page.name}: {target}: no such heading in {destination.name}')


def test_every_page_of_doc_is_in_the_readme_and_the_index():
    pages = {p.name for p in DOC.glob('*.md')}
    index = (DOC / 'index.rst').read_text()
    toctree = {f'{name}.md' for name in re.findall(r'^   ([a-z-]+)$', index, re.MULTILINE)}
    assert pages == toctree, 'the toctree of doc/index.rst is not every page of doc/'
    assert {f'doc/{p}' for p in pages} <= {
        t.partition('#')[0] for t in relative_links(REPO / 'README.md')}


# -- the documentation's build --------------------------------------------------------------

@pytest.mark.process
def test_the_docs_build_with_sphinx_without_a_warning(tmp_path):
    """What `make docs` runs: every warning (a broken link or heading among them) fails."""
    pytest.importorskip('sphinx')
    pytest.importorskip('myst_parser')
    result = subprocess.run(
        [sys.executable, '-m', 'sphinx', '-W', '--keep-going', '-q', '-b', 'html',
         '-d', str(tmp_path / 'doctrees'), str(DOC), str(tmp_path / 'html')],
        capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    assert (tmp_path / 'html' / 'index.html').exists()


def test_the_docs_version_is_the_package_version():
    conf = ast.parse((DOC / 'conf.py').read_text())
    values = {target.id: node.value.value for node in conf.body if isinstance(node, ast.Assign)
              for target in node.targets if isinstance(target, ast.Name)
              and isinstance(node.value, ast.Constant)}
    version = ET.parse(REPO / 'package.xml').getroot().findtext('version')
    assert values['release'] == version


def test_rosdoc2_finds_the_sphinx_project():
    """rosdoc2.yaml as rosdoc2 parses it, named in package.xml, pointing at doc/conf.py."""
    exports = ET.parse(REPO / 'package.xml').getroot().find('export')
    config = REPO / exports.findtext('rosdoc2')
    attic, settings = yaml.safe_load_all(config.read_text())
    assert attic == {'type': 'rosdoc2 config', 'version': 1}
    assert (REPO / settings['settings']['python_source'] / '__init__.py').exists()
    (builder,) = settings['builders']
    assert set(builder) == {'sphinx'}
    assert (config.parent / builder['sphinx']['sphinx_sourcedir'] / 'conf.py').exists()


# -- the layout doc/architecture.md states ----------------------------------------------------

ARCHITECTURE = (DOC / 'architecture.md').read_text()


def ros_modules():
    """Return the top-level modules that ROS 2's distributions on PyPI (ros-*) provide."""
    return {module for module, dists in importlib.metadata.packages_distributions().items()
            if any(d.lower().startswith('ros-') for d in dists)}


def imports(path):
    """Return the top-level modules a Python file imports."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found.update(alias.name.split('.')[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0:
            found.add(node.module.split('.')[0])
    return found


def test_the_subpackages_that_import_no_ros_import_none():
    rows = dict(re.findall(r'^\| `(\w+)/` \| [^|]+ \| (no|yes|some) \|$', ARCHITECTURE,
                           re.MULTILINE))
    subpackages = {p.parent.name for p in (REPO / PACKAGE).glob('*/__init__.py')}
    assert set(rows) == subpackages
    ros = ros_modules()
    assert {'rclpy', 'geometry_msgs'} <= ros
    for subpackage, uses_ros in rows.items():
        users = {path.name for path in (REPO / PACKAGE / subpackage).rglob('*.py')
                 if imports(path) & ros}
        if uses_ros == 'no':
            assert not users, f'{subpackage}/ is said to import no ROS: {users} do'
        else:
            assert users, f'{subpackage}/ is said to import ROS and does not'


def test_each_console_script_is_in_the_subpackage_the_table_names():
    rows = dict(re.findall(r'^\| `(kraft_master_\w+)` \| `(\w+)/` \|$', ARCHITECTURE,
                           re.MULTILINE))
    entry_points = dict(re.findall(r"'(kraft_master_\w+) = ([\w.]+):\w+'",
                                   (REPO / 'setup.py').read_text()))
    assert entry_points and set(rows) == set(entry_points)
    for name, subpackage in rows.items():
        assert entry_points[name].startswith(f'{PACKAGE}.{subpackage}.'), name


def test_the_changelog_is_rest_with_the_ros_title():
    """CHANGELOG.rst as catkin_pkg and bloom read it: valid reST, the package's title."""
    core = pytest.importorskip('docutils.core')
    document = core.publish_doctree((REPO / 'CHANGELOG.rst').read_text(),
                                    settings_overrides={'halt_level': 2, 'report_level': 2})
    assert document.next_node().astext().startswith(f'Changelog for package {PACKAGE}')
    assert 'Forthcoming' in document.astext()
