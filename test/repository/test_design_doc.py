# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""doc/design/, the record of experiments: every page in the index, the tests it names exist."""
import re

from harness import REPO
from harness.doc_tables import undefined_tests
import pytest

DESIGN = sorted((REPO / 'doc' / 'design').glob('*.md'))
INDEX = (REPO / 'doc' / 'index.rst').read_text()


@pytest.mark.parametrize('page', DESIGN, ids=lambda p: p.name)
def test_every_design_page_is_in_the_index(page):
    assert f'design/{page.stem}' in re.findall(r'^   (design/[a-z-]+)$', INDEX, re.MULTILINE)


def test_every_test_the_passivity_record_names_exists():
    page = (REPO / 'doc' / 'design' / 'passivity-experiments.md').read_text()
    assert not undefined_tests(page, ('test_teleop_quality.py',))
