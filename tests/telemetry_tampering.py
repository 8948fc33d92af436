"""Make flight-like telemetry from a clean ``track.mcap``: swapped, dropped and duplicated messages, dropped control
steps, a file cut mid-write. Every random choice comes from the generator passed in."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
from mcap.reader import make_reader
from mcap.writer import Writer

MEASURED = "/state/measured"
CONTROLLER_TOPICS = ("/state/measured", "/reference", "/control/command", "/control/applied", "/disturbance",
                     "/solver/stats")

Message = tuple[str, int, bytes]  # topic, log time [ns], payload
Transform = Callable[[list[Message]], list[Message]]


def rewrite(src: Path, dst: Path, transform: Transform, *, chunk_size: int = 1024 * 1024,
            time_order: bool = False) -> Path:
    """Copy ``src`` to ``dst`` with its messages passed through ``transform`` (schemas, channels, metadata and
    attachments kept). ``time_order`` writes the messages interleaved by log time (as a flight recorder does)."""
    with open(src, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        messages = [(ch.topic, m.log_time, bytes(m.data)) for _, ch, m in reader.iter_messages(log_time_order=False)]
        attachments = list(reader.iter_attachments())
        metadata = list(reader.iter_metadata())
        schemas, channels = summary.schemas, summary.channels
    messages = transform(messages)
    if time_order:
        messages = sorted(messages, key=lambda m: m[1])
    with open(dst, "wb") as f:
        writer = Writer(f, chunk_size=chunk_size)
        writer.start(profile="", library="oacli tests")
        for a in attachments:  # first, as the stage writer does
            writer.add_attachment(a.create_time, a.log_time, a.name, a.media_type, a.data)
        for md in metadata:
            writer.add_metadata(md.name, md.metadata)
        ids = {}
        for sid, s in schemas.items():
            ids[sid] = writer.register_schema(s.name, s.encoding, s.data)
        channel_of = {}
        for ch in channels.values():
            channel_of[ch.topic] = writer.register_channel(ch.topic, ch.message_encoding,
                                                           ids.get(ch.schema_id, 0), ch.metadata)
        for seq, (topic, log_time, data) in enumerate(messages):
            writer.add_message(channel_of[topic], log_time, data, log_time, sequence=seq)
        writer.finish()
    return dst


def _stamp(data: bytes) -> float:
    return float(json.loads(data)["t"])


def swap_neighbours(fraction: float, rng: np.random.Generator, topic: str = MEASURED) -> Transform:
    """Swap ``fraction`` of the messages of ``topic`` with their successor in the file (true stamps kept)."""
    def transform(messages: list[Message]) -> list[Message]:
        pos = [i for i, m in enumerate(messages) if m[0] == topic]
        n = round(fraction * len(pos))
        starts = rng.choice(np.arange(1, len(pos) - 1, 2), size=n, replace=False)  # disjoint pairs
        out = list(messages)
        for s in starts:
            a, b = pos[s], pos[s + 1]
            out[a], out[b] = out[b], out[a]
        return out
    return transform


def drop_messages(fraction: float, rng: np.random.Generator, topic: str = MEASURED) -> Transform:
    """Drop ``fraction`` of the messages of ``topic`` (never the first)."""
    def transform(messages: list[Message]) -> list[Message]:
        pos = [i for i, m in enumerate(messages) if m[0] == topic]
        gone = set(rng.choice(pos[1:], size=round(fraction * len(pos)), replace=False).tolist())
        return [m for i, m in enumerate(messages) if i not in gone]
    return transform


def drop_control_steps(fraction: float, rng: np.random.Generator) -> tuple[Transform, list[float]]:
    """Drop ``fraction`` of the control steps from every controller-rate topic (the file stays consistent).

    Returns the transform and the dropped stamps (filled when the transform runs)."""
    dropped: list[float] = []

    def transform(messages: list[Message]) -> list[Message]:
        stamps = sorted({_stamp(m[2]) for m in messages if m[0] == MEASURED})
        chosen = rng.choice(np.arange(1, len(stamps) - 1), size=round(fraction * len(stamps)), replace=False)
        dropped.extend(stamps[i] for i in sorted(chosen))
        gone = set(dropped)
        return [m for m in messages if not (m[0] in CONTROLLER_TOPICS and _stamp(m[2]) in gone)]
    return transform, dropped


def duplicate_messages(fraction: float, rng: np.random.Generator, topic: str = MEASURED) -> Transform:
    """Log ``fraction`` of the messages of ``topic`` twice (the copy right after the original)."""
    def transform(messages: list[Message]) -> list[Message]:
        pos = [i for i, m in enumerate(messages) if m[0] == topic]
        twice = set(rng.choice(pos, size=round(fraction * len(pos)), replace=False).tolist())
        out: list[Message] = []
        for i, m in enumerate(messages):
            out.append(m)
            if i in twice:
                out.append(m)
        return out
    return transform


def cut(src: Path, dst: Path, fraction: float) -> Path:
    """The first ``fraction`` of ``src``'s bytes (a recorder that died mid-write)."""
    data = Path(src).read_bytes()
    Path(dst).write_bytes(data[: int(fraction * len(data))])
    return dst
