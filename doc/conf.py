# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Sphinx configuration of the package's documentation: Markdown pages read by MyST.

`make docs` runs Sphinx on this directory with warnings as errors; rosdoc2 finds it here too
(rosdoc2.yaml at the package root) and executes this file inside its own configuration, where
__file__ is not this file: nothing below depends on where it lies.
"""

project = 'kraft_master_driver'
author = 'kraft_master_driver contributors'
copyright = '2026, kraft_master_driver contributors'  # noqa: A001 (Sphinx's name)
# package.xml's version (test/repository/test_readme.py holds the two equal)
release = version = '0.1.0'

extensions = ['myst_parser']
source_suffix = {'.rst': 'restructuredtext', '.md': 'markdown'}
root_doc = 'index'
# doc/figures holds the scripts that draw the pictures and their data, not pages; rosdoc2
# copies this directory once more into user_docs/ beside these pages, not to be built twice.
exclude_patterns = ['_build', 'figures', 'user_docs']

# Links to a heading of another page ([text](page.md#heading)) resolve to GitHub's anchors,
# which these are, so a link reads the same on GitHub and in the built pages; a missing page
# or heading is a warning, which `make docs` turns into an error.
myst_heading_anchors = 4

# Sphinx's own theme here; rosdoc2 puts the theme of the ROS documentation in its place.
html_theme = 'alabaster'
html_title = 'kraft_master_driver'


def _add_python_api(app, docname, source):
    """List the Python API in the index where rosdoc2 had sphinx-apidoc write it."""
    if docname == 'index' and 'modules' in app.env.found_docs:
        source[0] += '\n.. toctree::\n   :caption: Python API\n\n   modules\n'


def setup(app):
    """Connect _add_python_api: `make docs` has no modules.rst, rosdoc2's build has one."""
    app.connect('source-read', _add_python_api)
