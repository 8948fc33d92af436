"""The MCAP contract's JSON schemas (:mod:`oacli.io.mcap_schema`): well-formed, named, and documented.

The records the stages write are checked against these schemas in the CLI tests (``tests/mcap_checks.py``).
"""

from __future__ import annotations

import re

import pytest

from oacli.io import mcap_schema as ms
from tests.conftest import REPO


@pytest.mark.parametrize("name", sorted(ms.SCHEMAS))
def test_schema_is_an_object_with_t_and_declares_what_it_requires(name):
    schema = ms.SCHEMAS[name]
    assert re.fullmatch(r"oacli\.[A-Z][A-Za-z]+", name)
    assert schema.get("title", name) == name
    assert schema.get("type", "object") == "object"
    properties = schema["properties"]
    assert properties["t"]["type"] == "number"
    assert set(schema.get("required", ())) <= set(properties), set(schema.get("required", ())) - set(properties)
    for field, spec in properties.items():
        assert "type" in spec, f"{name}.{field} has no type"


def test_every_schema_is_in_docs_mcap_md():
    text = (REPO / "docs" / "mcap.md").read_text()
    missing = [name for name in ms.SCHEMAS if f"`{name}`" not in text]
    assert not missing, f"docs/mcap.md does not describe {missing}"


def test_topic_and_schema_names_are_unique():
    topics = [v for k, v in vars(ms).items() if k.startswith("TOPIC_")]
    assert len(topics) == len(set(topics))
    assert all(t.startswith("/") for t in topics)
    names = [v for k, v in vars(ms).items() if not k.startswith("_") and isinstance(v, str) and v.startswith("oacli.")]
    assert sorted(set(names)) == sorted(ms.SCHEMAS)
