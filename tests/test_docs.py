"""The documentation matches the code."""

import dataclasses
import os

from zsbfm.config import Config
from zsbfm.docs import configuration_markdown, field_docs

ROOT = os.path.join(os.path.dirname(__file__), "..")


def test_every_config_field_is_documented_once():
    docs = field_docs()
    assert [n for _, n, _ in docs] == [f.name for f in dataclasses.fields(Config)]
    assert not [n for _, n, text in docs if not text], "fields without a comment in config.py"


def test_configuration_reference_is_up_to_date():
    with open(os.path.join(ROOT, "docs", "configuration.md")) as f:
        committed = f.read()
    assert committed == configuration_markdown(), \
        "docs/configuration.md is stale: run `python -m zsbfm.docs > docs/configuration.md`"
