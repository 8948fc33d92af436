"""The MCAP writer's short paths write what the general ones did: the time-ordered merge by a stable sort,
``write_json``'s scalar time and prebuilt encoder, and :func:`oacli.io.jsonsafe.to_json_safe`'s plain-type path."""

from __future__ import annotations

import heapq
import json
import math
from collections import OrderedDict
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader

from oacli.io import mcap_write
from oacli.io.jsonsafe import to_json_safe
from oacli.io.mcap_write import StageMcapWriter

SCHEMA = {"type": "object", "properties": {"t": {"type": "number"}, "k": {"type": "integer"}}}


def reference_json_safe(value):
    """The general conversion (the former ``to_json_safe``), the reference of the short path."""
    if isinstance(value, np.ndarray):
        return reference_json_safe(value.tolist())
    if isinstance(value, np.generic):
        return reference_json_safe(value.item())
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, Mapping):
        return {str(k): reference_json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [reference_json_safe(v) for v in value]
    return value


def messages(path: Path) -> list[tuple[str, int, bytes]]:
    with path.open("rb") as f:
        return [(ch.topic, m.log_time, bytes(m.data))
                for _, ch, m in make_reader(f).iter_messages(log_time_order=False)]


def writer(path: Path, **kwargs) -> StageMcapWriter:
    return StageMcapWriter(path, stage="plan", config_yaml="seed: 1\n", **kwargs)


_floats = st.floats(allow_nan=True, allow_infinity=True, width=64)
_leaf = st.one_of(
    st.none(), st.booleans(), st.integers(-10**20, 10**20), _floats, st.text(max_size=5),
    _floats.map(np.float64), st.floats(width=32).map(np.float32), st.integers(-1000, 1000).map(np.int64),
    st.lists(_floats, max_size=6).map(np.array),
    st.lists(st.integers(-5, 5), max_size=6).map(lambda v: np.array(v, dtype=np.int32)),
    st.lists(st.booleans(), max_size=4).map(np.array),
    st.lists(_floats, min_size=4, max_size=4).map(lambda v: np.array(v).reshape(2, 2)),
)
_values = st.recursive(
    _leaf,
    lambda inner: st.one_of(
        st.lists(inner, max_size=4), st.lists(inner, max_size=4).map(tuple),
        st.dictionaries(st.one_of(st.text(max_size=4), st.integers(0, 9)), inner, max_size=4),
        st.dictionaries(st.text(max_size=4), inner, max_size=3).map(OrderedDict),
    ),
    max_leaves=20,
)


@settings(max_examples=300, deadline=None)
@given(_values)
def test_json_safe_short_path_gives_the_general_result(value):
    fast, ref = to_json_safe(value), reference_json_safe(value)
    # the same JSON text, and the same Python types (a float stays a float, an int an int)
    assert json.dumps(fast, allow_nan=False) == json.dumps(ref, allow_nan=False)
    assert repr(fast) == repr(ref)


def test_json_safe_keeps_negative_zero_and_nonfinite_array_entries():
    value = {"a": np.array([-0.0, np.nan, np.inf, 1.5]), 3: (np.float32(0.25), -np.inf)}
    assert to_json_safe(value) == {"a": [-0.0, None, None, 1.5], "3": [0.25, None]}
    assert math.copysign(1.0, to_json_safe(value)["a"][0]) == -1.0


@pytest.mark.parametrize("t", [0.0, 1.25, 7, 2.5e-9, 3.5e-9, 1e6 + 0.4999999e-9, np.float64(0.1), np.array([2.0])])
def test_write_json_times_round_as_the_array_path(tmp_path, t):
    path = tmp_path / "t.mcap"
    with writer(path) as w:
        w.write_json("/events", "oacli.Event", SCHEMA, t, {"k": 1})
    ((_, log_time, data),) = messages(path)
    _, ns = mcap_write._times_ns("x", t)
    assert log_time == ns[0]
    assert json.loads(data) == {"t": float(np.asarray(t).reshape(-1)[0]), "k": 1}


@pytest.mark.parametrize("t", [-1.0, math.nan, math.inf])
def test_write_json_refuses_a_bad_scalar_time(tmp_path, t):
    with writer(tmp_path / "bad.mcap") as w, pytest.raises(ValueError, match="/events"):
        w.write_json("/events", "oacli.Event", SCHEMA, t, {"k": 1})


def test_write_json_payload_is_json_dumps_of_the_record(tmp_path):
    path = tmp_path / "p.mcap"
    record = {"k": 3, "v": np.array([1.0, np.nan]), "s": "é", "n": {"x": (1, 2.5)}}
    with writer(path) as w:
        w.write_json("/events", "oacli.Event", SCHEMA, 0.5, record)
    ((_, _, data),) = messages(path)
    body = reference_json_safe({"t": 0.5, **record})
    assert data == json.dumps(body, allow_nan=False).encode()


def test_time_ordered_file_is_the_stable_merge_of_the_calls(tmp_path, rng):
    """Messages leave in time order, equal times in the order of the calls, as ``heapq.merge`` of the calls gives
    them; several topics, several calls per topic, events written out of time order."""
    path = tmp_path / "merged.mcap"
    calls: list[list[tuple[int, str, int]]] = []  # per call: (log_time, topic, index within the call)
    t_states = np.round(np.cumsum(rng.uniform(0.05, 0.3, 40)), 1)  # rounded: equal times with the events
    x = rng.normal(size=(40, 13))
    with writer(path, time_ordered=True) as w:
        w.write_states("/a", t_states[:20], x[:20])
        calls.append([(round(t * 1e9), "/a", i) for i, t in enumerate(t_states[:20])])
        for k, t in enumerate([3.0, 1.0, 1.0, 0.0, float(t_states[5])]):
            w.write_json("/events", "oacli.Event", SCHEMA, t, {"k": k})
            calls.append([(round(t * 1e9), "/events", k)])
        w.write_states("/b", t_states[::2], x[::2])
        calls.append([(round(t * 1e9), "/b", i) for i, t in enumerate(t_states[::2])])
        w.write_states("/a", t_states[20:], x[20:])
        calls.append([(round(t * 1e9), "/a", 20 + i) for i, t in enumerate(t_states[20:])])
    expected = [(topic, ns) for ns, topic, _ in heapq.merge(*calls, key=lambda m: m[0])]
    got = messages(path)
    assert [(topic, ns) for topic, ns, _ in got] == expected
    events = [json.loads(d)["k"] for topic, _, d in got if topic == "/events"]
    assert events == [3, 1, 2, 4, 0]  # by time; the two at 1.0 s in call order


def test_an_out_of_order_stream_is_merged_as_before(tmp_path):
    """A queued stream whose times decrease (no write_* call makes one) is merged by ``heapq.merge``, not sorted."""
    path = tmp_path / "raw.mcap"
    with writer(path, time_ordered=True) as w:
        channel = w._json_channel("/raw", "oacli.Event", SCHEMA, {})
        emit = w._raw_emitter(channel)
        first = [(5, emit, b'{"k":0}'), (2, emit, b'{"k":1}')]
        second = [(3, emit, b'{"k":2}')]
        w._emit(first)
        w._emit(second)
    expected = [m[2] for m in heapq.merge(first, second, key=lambda m: m[0])]
    assert [d for _, _, d in messages(path)] == expected

