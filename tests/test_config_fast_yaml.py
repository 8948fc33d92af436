"""The libyaml fast path of the config loader (issue 34: ``oacli report`` parses a mission's stage configs) reads
every document exactly as the pure-Python strict loader does, and hands every document it should not decide (an
error, a size cap, a recursive alias) to that loader, whose one-line error is the one raised."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

import oacli.config as config
from oacli.config import ConfigError, parse_yaml_value
from oacli.config.sizes import MAX_CONFIG_LIST_ITEMS, MAX_CONFIG_NODES

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.skipif(config._CStrictSafeLoader is None, reason="PyYAML built without libyaml")


def both(text: str):
    """(fast, pure-Python) parses of ``text``."""
    return config._load_fast(text), yaml.load(text, Loader=config._StrictSafeLoader)


@pytest.mark.parametrize("path", sorted((ROOT / "configs").glob("*.yaml")), ids=lambda p: p.name)
def test_every_shipped_config_reads_the_same_through_libyaml(path):
    fast, slow = both(path.read_text())
    assert fast is not config._FAST_FAILED
    assert fast == slow and repr(fast) == repr(slow)  # repr: the same types (1 vs 1.0 vs True) and key order


@pytest.mark.parametrize("text", [
    "a: yes\nb: on\nc: 0777\nd: 1:30\ne: 1e3\nf: 1_000\ng: 2024-01-01\nh: 0x1F\ni: 0o17\nj: .inf\nk: -.5\n",
    "base: &b {x: 1, y: [1, 2]}\nother:\n  <<: *b\n  y: 3\n",
    "v: [1.0, -2, +3, .5e-2, TRUE, False, null, ~, '1', \"x\"]\n",
    "",
    "# only a comment\n",
])
def test_yaml_12_scalars_merges_and_empty_documents_read_the_same(text):
    fast, slow = both(text)
    assert fast is not config._FAST_FAILED and repr(fast) == repr(slow)
    assert parse_yaml_value(text, "t") == slow


@pytest.mark.parametrize(("text", "message"), [
    ("a: 1\nb: 2\na: 3\n", "found duplicate key 'a'"),
    ("a: [1, 2\n", "invalid YAML"),
    ("a: !!python/object:os.system x\n", "invalid YAML"),
    ("a: &x [*x]\n", None),  # recursive: the pure-Python loader decides (it builds the cycle)
    ("l: [" + ",".join(["0"] * (MAX_CONFIG_LIST_ITEMS + 1)) + "]\n", "MAX_CONFIG_LIST_ITEMS"),
    ("a: &a [" + ",".join(["0"] * 999) + "]\nb: [" + ",".join(["*a"] * 999) + "]\n", "MAX_CONFIG_NODES"),
])
def test_what_libyaml_must_not_decide_goes_to_the_strict_loader(text, message, monkeypatch):
    assert config._load_fast(text) is config._FAST_FAILED
    if message is None:
        data = config._parse_yaml(text, "t.yaml")
        assert data["a"][0] is data["a"]
        return
    with pytest.raises(ConfigError) as err:
        config._parse_yaml(text, "t.yaml")
    monkeypatch.setattr(config, "_load_fast", lambda text: config._FAST_FAILED)  # the loader before the fast path
    with pytest.raises(ConfigError) as before:
        config._parse_yaml(text, "t.yaml")
    assert str(err.value) == str(before.value) and type(err.value) is type(before.value)
    assert message in str(err.value) and str(err.value).startswith("t.yaml: ") and "\n" not in str(err.value)


def _nodes_document(extra: int) -> str:
    """A document of exactly ``MAX_CONFIG_NODES + extra`` nodes counted as the composer counts them (every alias
    repeats the 4 nodes of ``&a``), no list over its cap."""
    lines = ["a: &a [1, 2, 3]"]  # root 1 + key 1 + list 1 + items 3
    total = 6
    for i in range(24):
        lines.append(f"b{i}: [" + ",".join(["*a"] * 1000) + "]")  # key 1 + list 1 + 1000 x 4
        total += 2 + 4000
    rest = MAX_CONFIG_NODES + extra - total
    i = 0
    while rest > 0:
        m = min(rest - 2, 1000)
        lines.append(f"c{i}: [" + ",".join(["0"] * m) + "]")
        rest -= 2 + m
        i += 1
    assert rest == 0
    return "\n".join(lines) + "\n"


def test_the_node_count_counts_aliases_like_the_composer():
    """At the cap the composed document passes the check and the pure-Python loader loads it; one node over, the
    check fails and that loader refuses it (the same count)."""
    at_cap, over = _nodes_document(0), _nodes_document(1)
    compose = config._CStrictSafeLoader
    assert config._within_size_caps(yaml.compose(at_cap, Loader=compose)) is True
    assert config._within_size_caps(yaml.compose(over, Loader=compose)) is False
    assert config._parse_yaml(at_cap, "t.yaml") == yaml.load(at_cap, Loader=config._StrictSafeLoader)
    with pytest.raises(ConfigError, match="MAX_CONFIG_NODES"):
        config._parse_yaml(over, "t.yaml")


def test_a_huge_document_goes_straight_to_the_strict_loader():
    """More separators than FAST_PATH_MAX_SEPARATORS: libyaml does not compose it (the pure-Python loader refuses a
    half-million-item list after 1000 items instead of libyaml building it first)."""
    huge = "a: [" + ",".join(["0"] * 500_000) + "]\n"
    assert config._load_fast(huge) is config._FAST_FAILED
    small = "a: [" + ",".join(["0"] * 999) + "]\n"
    assert config._load_fast(small) == {"a": [0] * 999}
    with pytest.raises(ConfigError, match="MAX_CONFIG_LIST_ITEMS"):
        config._parse_yaml(huge, "t.yaml")


scalars = st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=8)
documents = st.recursive(scalars, lambda inner: st.lists(inner, max_size=4)
                         | st.dictionaries(st.text(max_size=6), inner, max_size=4), max_leaves=30)


@settings(max_examples=80, deadline=None)
@given(st.dictionaries(st.text(min_size=1, max_size=6), documents, max_size=5))
def test_any_dumped_document_reads_the_same(data):
    for dumper in config._DUMPERS:
        text = yaml.dump(data, Dumper=dumper, allow_unicode=True, sort_keys=False)
        fast, slow = both(text)
        assert fast is not config._FAST_FAILED and repr(fast) == repr(slow)
