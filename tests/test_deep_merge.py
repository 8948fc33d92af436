"""``deep_merge`` (the mission's per-segment overrides, campaign sets): mappings merge, the rest is replaced,
the inputs are never modified and the result shares no mutable value with them."""

from __future__ import annotations

import copy

from oacli.config.mission import deep_merge


def test_nested_mappings_merge_and_other_values_replace() -> None:
    base = {"a": {"b": 1, "c": [1, 2], "d": {"e": 3}}, "f": 4}
    override = {"a": {"c": [9], "d": {"g": 5}}, "f": {"h": 6}, "i": 7}
    assert deep_merge(base, override) == {"a": {"b": 1, "c": [9], "d": {"e": 3, "g": 5}}, "f": {"h": 6}, "i": 7}


def test_inputs_unchanged_and_nothing_shared() -> None:
    base = {"a": {"b": [1, 2], "d": {"e": [3]}}, "x": [[0]]}
    override = {"a": {"c": [4], "d": {"f": [5]}}}
    base_before, override_before = copy.deepcopy(base), copy.deepcopy(override)
    out = deep_merge(base, override)
    assert base == base_before and override == override_before
    out["a"]["b"].append(99)
    out["a"]["c"].append(99)
    out["a"]["d"]["e"].append(99)
    out["a"]["d"]["f"].append(99)
    out["x"][0].append(99)
    assert base == base_before and override == override_before
