"""Check a stage's MCAP against the contract's JSON schemas (:data:`oacli.io.mcap_schema.SCHEMAS`)."""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

from mcap.reader import make_reader

from oacli.io import mcap_schema as ms


def check_json_records(path: Path) -> Counter[str]:
    """Every JSON record of ``path`` against its schema; returns the number of records per schema name.

    Each channel's schema must be the contract's schema of that name (with its ``title``), each record must carry
    the schema's required fields and no field the schema does not declare.
    """
    counts: Counter[str] = Counter()
    with Path(path).open("rb") as f:
        reader = make_reader(f)
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            if channel.message_encoding != "json":
                continue
            assert schema is not None and schema.encoding == "jsonschema", channel.topic
            assert schema.name in ms.SCHEMAS, f"{channel.topic}: schema {schema.name} is not in mcap_schema.SCHEMAS"
            declared = json.loads(schema.data)
            expected = {"type": "object", **ms.SCHEMAS[schema.name], "title": schema.name}
            assert declared == expected, f"{channel.topic}: the file's {schema.name} differs from the contract's"
            record = json.loads(message.data)
            properties = set(declared["properties"])
            assert set(declared.get("required", ())) <= set(record), (channel.topic, sorted(record))
            assert set(record) <= properties, f"{channel.topic}: undeclared fields {sorted(set(record) - properties)}"
            counts[schema.name] += 1
    return counts


def scene_updates(path: Path) -> list[tuple[int, object]]:
    """The ``/scene`` messages of ``path`` as ``(log_time [ns], foxglove.SceneUpdate)``, decoded with the protobuf
    decoder (CRCs checked)."""
    from mcap_protobuf.decoder import DecoderFactory

    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True, decoder_factories=[DecoderFactory()])
        return [(m.log_time, proto) for _, _, m, proto in reader.iter_decoded_messages(topics=[ms.TOPIC_SCENE])]


def robot_body_samples(path: Path) -> tuple[list[int], list[list[float]], list[list[float]], list[float]]:
    """The robot body on ``/scene`` (entity ``robot``): log times [ns], positions [m], quaternions ``[x, y, z, w]``
    and cube edges [m], one per update; checks each update holds the robot entity alone, in one cube."""
    times, positions, quats, edges = [], [], [], []
    for log_time, update in scene_updates(path):
        robots = [e for e in update.entities if e.id == "robot"]
        if not robots:
            continue
        assert len(update.entities) == 1, "a robot body update carries only the robot entity"
        (entity,) = robots
        assert entity.timestamp.seconds * 10**9 + entity.timestamp.nanos == log_time
        (cube,) = entity.cubes
        p, q = cube.pose.position, cube.pose.orientation
        assert cube.size.x == cube.size.y == cube.size.z
        times.append(log_time)
        positions.append([p.x, p.y, p.z])
        quats.append([q.x, q.y, q.z, q.w])
        edges.append(cube.size.x)
    return times, positions, quats, edges
