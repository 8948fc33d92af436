"""The mission for Foxglove: one MCAP of every stage on the mission timeline (``mission.mcap``) and the shipped
layouts (``docs/foxglove/*.json``; issue 33 item 4).

``mission.mcap`` holds every message of every stage MCAP of the mission folder, unchanged (the same schemas,
encodings and bytes), on topic ``/<stage key><topic>`` (``/segment-3/track/state/true``) with its ``log_time`` and
``publish_time`` shifted by its segment's ``start_time_s`` (``summary.json``), so the stages follow one another on
one mission clock; every stage's ``/log`` goes to one ``/log`` topic. The fields inside the messages keep their
stage's clock (a JSON record's ``t``, a Foxglove message's ``timestamp``): the layouts plot against the log time.
Channel metadata gain ``stage`` (the stage key) and ``offset_s``; the metadata record ``oacli`` says ``stage:
mission``, the frame, the contract version and the offset of each stage; ``config.yaml`` (the mission's) is
attached. Written atomically (zstd chunks, CRCs) once the mission has finished.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Any

from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

import oacli
from oacli.io import mcap_schema as ms
from oacli.io.atomic import atomic_file
from oacli.io.foxglove_layouts import (
    FRAME,
    layout_file,
    plot_panel,
    split,
    stage_layouts,
    three_d_panel,
)
from oacli.mission.layout import ALL_STAGES, MISSION_STAGES, RECORDED_STAGES

#: Chunk size of ``mission.mcap`` [bytes, uncompressed], as the stage files'
#: (:data:`oacli.io.mcap_write.DEFAULT_CHUNK_SIZE`).
CHUNK_SIZE = 256 * 1024
MISSION_MCAP = "mission.mcap"
_XYZ = ("x", "y", "z")


def stage_offsets(summary: dict[str, Any]) -> dict[str, float]:
    """Mission time [s] at which each stage's clock starts: its segment's ``start_time_s``."""
    segments = summary.get("segments", {})
    return {s.key: float(segments.get(s.segment, {}).get("start_time_s", 0.0)) for s in ALL_STAGES}


def write_mission_mcap(mission_dir: Path, summary: dict[str, Any], path: Path | None = None) -> Path:
    """Write ``mission.mcap`` (module docstring) from the stage MCAPs of ``mission_dir``.

    Parameters
    ----------
    mission_dir : Path
        A finished mission folder.
    summary : dict
        The mission summary (segments' ``start_time_s``, ``name``, ``seed``).
    path : Path, optional
        Output file (default ``mission_dir/mission.mcap``).

    Returns
    -------
    Path
    """
    mission_dir = Path(mission_dir)
    out = mission_dir / MISSION_MCAP if path is None else Path(path)
    offsets = stage_offsets(summary)
    messages: list[tuple[int, int, int, bytes]] = []  # (log_time, order, channel key index, data)
    channels: list[tuple[str, str, tuple[str, str, bytes], dict[str, str]]] = []
    channel_index: dict[tuple[str, str], int] = {}
    publish: list[int] = []
    frame = FRAME
    for stage in RECORDED_STAGES:  # the unconstrained baseline too, when it flew
        source = stage.mcap(mission_dir)
        if not source.is_file():
            continue
        shift = round(offsets[stage.key] * 1e9)
        with source.open("rb") as f:
            reader = make_reader(f, validate_crcs=True)
            for meta in reader.iter_metadata():
                if meta.name == ms.METADATA_NAME:
                    frame = meta.metadata.get("frame", frame)
            for schema, channel, message in reader.iter_messages(log_time_order=False):
                topic = ms.TOPIC_LOG if channel.topic == ms.TOPIC_LOG else f"/{stage.key}{channel.topic}"
                key = (topic, stage.key if topic != ms.TOPIC_LOG else "")
                index = channel_index.get(key)
                if index is None:
                    index = channel_index[key] = len(channels)
                    schema_key = ("", "", b"") if schema is None else (schema.name, schema.encoding, bytes(schema.data))
                    extra = {"stage": stage.key, "offset_s": repr(offsets[stage.key])} if topic != ms.TOPIC_LOG else {
                        "stage": "every stage (mission clock)"}
                    channels.append((topic, channel.message_encoding, schema_key, {**channel.metadata, **extra}))
                messages.append((message.log_time + shift, len(messages), index, bytes(message.data)))
                publish.append(message.publish_time + shift)
    listed = {s.key for s in MISSION_STAGES} | {s.key for s in RECORDED_STAGES if s.mcap(mission_dir).is_file()}
    messages.sort(key=lambda m: (m[0], m[1]))
    config = (mission_dir / "config.yaml").read_bytes() if (mission_dir / "config.yaml").is_file() else b""
    with atomic_file(out) as handle:
        writer = Writer(handle, chunk_size=CHUNK_SIZE, compression=CompressionType.ZSTD, enable_data_crcs=True)
        writer.start(profile="", library=f"oacli {oacli.__version__}")
        schema_ids: dict[tuple[str, str, bytes], int] = {}
        channel_ids = []
        for topic, encoding, schema_key, metadata in channels:
            if schema_key not in schema_ids:
                schema_ids[schema_key] = (0 if not schema_key[0] else
                                          writer.register_schema(schema_key[0], schema_key[1], schema_key[2]))
            channel_ids.append(writer.register_channel(topic, encoding, schema_ids[schema_key], metadata))
        writer.add_metadata(ms.METADATA_NAME, {
            "version": oacli.__version__, "stage": "mission", "name": str(summary.get("name", "")),
            "seed": str(summary.get("seed", "unknown")), "frame": frame, "contract_version": str(ms.CONTRACT_VERSION),
            "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "offsets_s": json.dumps({k: v for k, v in offsets.items() if k in listed})})
        writer.add_attachment(create_time=time.time_ns(), log_time=0, name=ms.CONFIG_ATTACHMENT,
                              media_type=ms.CONFIG_MEDIA_TYPE, data=config)
        for log_time, order, index, data in messages:
            writer.add_message(channel_ids[index], log_time=log_time, data=data, publish_time=publish[order])
        writer.finish()
    return out


def mission_layout() -> dict[str, Any]:
    """The layout of ``mission.mcap``: every stage's ``/scene`` in one 3D panel, the flights' positions and forces,
    the two mass estimates and the merged log, on the mission clock. Every stage a mission may fly is named (the
    optional unconstrained baseline's series stay empty in a mission that did not fly it)."""
    scenes = [f"/{s.key}/scene" for s in RECORDED_STAGES]
    poses = [f"/{s.key}/robot/pose" for s in RECORDED_STAGES if s.command == "track"]
    flights = [s.key for s in RECORDED_STAGES if s.command == "track"]
    panels: dict[str, dict[str, Any]] = {
        "3D!mission": three_d_panel(scenes, poses),
        "Plot!position": plot_panel("true position [m] of every flight", [
            (f"/{key}/state/true.position[{i}]", f"{key} {a}") for key in flights for i, a in enumerate(_XYZ)]),
        "Plot!force": plot_panel("applied force [N] of every flight", [
            (f"/{key}/control/applied.force[{i}]", f"{key} f{a}") for key in flights for i, a in enumerate(_XYZ)]),
        "Plot!mass": plot_panel("mass estimate [kg]: batch and sequential", [
            ("/segment-2/estimate/estimate/params.mass_kg", "batch"),
            ("/segment-2/estimate-sequential/estimate/params.mass_kg", "sequential")]),
        "RosOut!mission": {"searchTerms": [], "minLogLevel": 1, "topicToRender": ms.TOPIC_LOG},
    }
    plots = split("Plot!position", split("Plot!force", "Plot!mass", "column", 50), "column", 34)
    return layout_file(panels, split(split("3D!mission", plots, "row", 50), "RosOut!mission", "column", 75))


def write_layouts(folder: Path) -> list[Path]:
    """Write every layout (the stages' and the mission's) as ``folder/<name>.json``.

    Parameters
    ----------
    folder : Path

    Returns
    -------
    list of Path
    """
    folder.mkdir(parents=True, exist_ok=True)
    written = []
    for name, layout in {**stage_layouts(), "mission": mission_layout()}.items():
        path = folder / f"{name}.json"
        path.write_text(json.dumps(layout, indent=2, ensure_ascii=False) + "\n", encoding="utf-8")
        written.append(path)
    return written


if __name__ == "__main__":
    for p in write_layouts(Path(sys.argv[1] if len(sys.argv) > 1 else "docs/foxglove")):
        print(p)
