"""Reading Rerun recordings back (tests, and any tool that checks a recording's values).

Recordings are not byte-reproducible: compare the values these functions return, never files. A truncated ``.rrd``
cannot be read at all (:class:`oacli.errors.InputError`); the MCAP is the record of truth.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pyarrow as pa
from rerun.chunk import RrdReader

from oacli.errors import InputError
from oacli.io.rerun.writer import TIMELINE


def _reader(path: Path) -> RrdReader:
    """Open an ``.rrd`` and list its stores (which decodes every frame header: a truncated file fails here)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"Rerun recording {path} does not exist")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "no footer/manifest" on truncated or legacy files
            reader = RrdReader(path)
            reader.recordings()
    except Exception as exc:  # rerun raises plain RuntimeErrors for unreadable files
        raise InputError(f"cannot read Rerun recording {path}: {exc}") from exc
    return reader


def _entity(chunk_path: str) -> str:
    return chunk_path.lstrip("/")


def _arrow_values(arr: pa.Array) -> np.ndarray:
    """Arrow values as numpy: fixed-size lists become (n, size) arrays, lists object arrays of per-item arrays
    (e.g. the points of each line strip), strings object arrays, primitives plain arrays."""
    kind = arr.type
    if pa.types.is_fixed_size_list(kind):
        return _arrow_values(arr.flatten()).reshape(-1, kind.list_size)
    if pa.types.is_list(kind) or pa.types.is_large_list(kind):
        parts = _column_rows(arr)
        out = np.empty(len(parts), dtype=object)
        for i, part in enumerate(parts):
            out[i] = part
        return out
    if pa.types.is_string(kind) or pa.types.is_large_string(kind):
        return np.array(arr.to_pylist(), dtype=object)
    return arr.to_numpy(zero_copy_only=False)


def _column_rows(column: pa.Array) -> list[np.ndarray]:
    """Split a Rerun component column (a list array, one list per row) into one ndarray per row.

    A row of ``Vec3D`` becomes an array of shape (n, 3), a row of scalars shape (n,), a row of strings an object
    array, a row of line strips an object array of (n_i, 3) arrays. Null rows become empty arrays.
    """
    if isinstance(column, pa.ChunkedArray):
        column = column.combine_chunks()
    lengths = column.value_lengths().fill_null(0).to_numpy(zero_copy_only=False).astype(np.int64)
    flat = _arrow_values(column.flatten())
    return list(np.split(flat, np.cumsum(lengths)[:-1]))


def _index_seconds(batch: pa.RecordBatch, timeline: str) -> np.ndarray:
    col = batch.column(timeline)
    if pa.types.is_duration(col.type) or pa.types.is_timestamp(col.type):
        unit = col.type.unit
        scale = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}[unit]
        return col.cast(pa.int64()).to_numpy(zero_copy_only=False) * scale
    return col.to_numpy(zero_copy_only=False).astype(float)


def read_recording_entities(path: Path) -> set[str]:
    """Entity paths (without the leading ``/``) of the first recording store in an ``.rrd``.

    Rerun's reserved entities (``__properties`` ...) are left out.

    Parameters
    ----------
    path : Path
        The ``.rrd``.

    Returns
    -------
    set of str
        The entity paths.

    Raises
    ------
    oacli.errors.InputError
        The file is missing or not a readable recording.
    """
    reader = _reader(path)
    return {e for ch in reader.stream() if not (e := _entity(ch.entity_path)).startswith("__")}


def read_recording_component(
    path: Path, entity: str, component: str, *, timeline: str = TIMELINE
) -> tuple[np.ndarray | None, list[np.ndarray]]:
    """All values of one component of one entity, e.g. ``("world/keep_out", "Ellipsoids3D:half_sizes")``.

    Parameters
    ----------
    path : Path
        The ``.rrd``.
    entity : str
        Entity path (with or without the leading ``/``).
    component : str
        Component identifier ``"<Archetype>:<field>"`` as Rerun names it.
    timeline : str
        Timeline of temporal rows.

    Returns
    -------
    times_s : ndarray, shape (R,), or None
        Row times [s] sorted ascending (stable), or None when the component is static.
    rows : list of ndarray
        One array per row (see ``_column_rows``), in the order of ``times_s``.

    Raises
    ------
    KeyError
        The entity does not have the component.
    """
    want = _entity(entity)
    static_rows: list[np.ndarray] = []
    times: list[np.ndarray] = []
    rows: list[np.ndarray] = []
    for ch in _reader(path).stream().filter(content=f"/{want}", components=component):
        if _entity(ch.entity_path) != want:
            continue
        batch = ch.to_record_batch()
        if component not in batch.schema.names:
            continue
        values = _column_rows(batch.column(component))
        if ch.is_static:
            static_rows = values  # the latest static write wins, as in the viewer
        elif timeline in batch.schema.names:
            times.append(_index_seconds(batch, timeline))
            rows.extend(values)
    if rows:
        t = np.concatenate(times)
        order = np.argsort(t, kind="stable")
        return t[order], [rows[i] for i in order]
    if static_rows:
        return None, static_rows
    raise KeyError(f"{want} has no component {component} in {path}")


def read_recording_scalars(path: Path, *, timeline: str = TIMELINE) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Every temporal ``Scalars`` series of a recording.

    Parameters
    ----------
    path : Path
        The ``.rrd``.
    timeline : str
        Timeline to read the times from.

    Returns
    -------
    dict
        ``entity path -> (times_s (N,), values (N,) or (N, k))``, rows sorted by time (stable); ``k > 1`` when the
        entity holds several series (e.g. force x, y, z).
    """
    parts: dict[str, tuple[list[np.ndarray], list[np.ndarray]]] = {}
    stream = _reader(path).stream().filter(has_timeline=timeline, components="Scalars:scalars")
    for ch in stream:
        batch = ch.to_record_batch()
        if "Scalars:scalars" not in batch.schema.names:
            continue
        t_list, v_list = parts.setdefault(_entity(ch.entity_path), ([], []))
        t_list.append(_index_seconds(batch, timeline))
        v_list.extend(_column_rows(batch.column("Scalars:scalars")))
    out: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for entity, (t_list, v_list) in parts.items():
        t = np.concatenate(t_list)
        widths = {v.shape[0] for v in v_list}
        if len(widths) != 1:
            raise InputError(f"{entity}: scalar rows of different lengths {sorted(widths)} in {path}")
        v = np.stack(v_list).astype(float)
        order = np.argsort(t, kind="stable")
        v = v[order]
        out[entity] = (t[order], v[:, 0] if v.shape[1] == 1 else v)
    return out


def read_blueprint_views(path: Path) -> list[dict[str, str | None]]:
    """The views of the (first) blueprint stored in an ``.rrd``.

    Parameters
    ----------
    path : Path
        The ``.rrd``.

    Returns
    -------
    list of dict
        One ``{"class": "TimeSeries" | "3D" | "TextLog" ..., "origin": str, "name": str | None}`` per view;
        empty when the file holds no blueprint.
    """
    reader = _reader(path)
    blueprints = reader.blueprints()
    if not blueprints:
        return []
    views: dict[str, dict[str, str | None]] = {}
    for ch in reader.stream(store=blueprints[0]):
        entity = _entity(ch.entity_path)
        if not entity.startswith("view/") or entity.count("/") != 1:
            continue
        batch = ch.to_record_batch()
        view = views.setdefault(entity, {"class": None, "origin": None, "name": None})
        for key, component in (
            ("class", "ViewBlueprint:class_identifier"),
            ("origin", "ViewBlueprint:space_origin"),
            ("name", "ViewBlueprint:display_name"),
        ):
            if component in batch.schema.names:
                values = batch.column(component).to_pylist()
                if values and values[-1]:
                    view[key] = values[-1][0]
    return list(views.values())


def read_blueprint_timeline(path: Path) -> str | None:
    """The timeline the (first) blueprint of an ``.rrd`` makes active on open (its ``TimePanel``).

    Parameters
    ----------
    path : Path
        The ``.rrd``.

    Returns
    -------
    str or None
        The timeline name; None when the file holds no blueprint or the blueprint sets none.
    """
    reader = _reader(path)
    blueprints = reader.blueprints()
    if not blueprints:
        return None
    timeline = None
    for ch in reader.stream(store=blueprints[0]):
        if _entity(ch.entity_path) != "time_panel":
            continue
        batch = ch.to_record_batch()
        if "TimePanelBlueprint:timeline" in batch.schema.names:
            values = batch.column("TimePanelBlueprint:timeline").to_pylist()
            if values and values[-1]:
                timeline = values[-1][0]
    return timeline


def read_entities_shown_on(path: Path, timeline: str) -> set[str]:
    """Entities of an ``.rrd`` that hold data the viewer shows on ``timeline``: static rows or rows on it.

    Parameters
    ----------
    path : Path
        The ``.rrd``.
    timeline : str
        The active timeline.

    Returns
    -------
    set of str
        Entity paths without the leading ``/`` (Rerun's reserved ``__`` entities left out).
    """
    out: set[str] = set()
    for ch in _reader(path).stream():
        entity = _entity(ch.entity_path)
        if entity.startswith("__") or entity in out:
            continue
        if ch.is_static or timeline in ch.to_record_batch().schema.names:
            out.add(entity)
    return out


def read_application_id(path: Path) -> str:
    """The application id of the (first) recording of an ``.rrd``.

    Parameters
    ----------
    path : Path
        The ``.rrd``.

    Returns
    -------
    str
    """
    return _reader(path).recordings()[0].application_id


def empty_blueprint_views(path: Path) -> list[dict[str, str | None]]:
    """The blueprint views that would open empty: no entity at or below their origin has data on the
    blueprint's active timeline (nor static data). Time series views need ``Scalars`` on it.

    Parameters
    ----------
    path : Path
        The ``.rrd``.

    Returns
    -------
    list of dict
        The empty views (see :func:`read_blueprint_views`); every view when the blueprint sets no timeline.
    """
    views = read_blueprint_views(path)
    timeline = read_blueprint_timeline(path)
    if timeline is None:
        return views
    shown = read_entities_shown_on(path, timeline)
    scalars = set(read_recording_scalars(path, timeline=timeline))
    empty = []
    for view in views:
        origin = str(view["origin"] or "/").strip("/")
        pool = scalars if view["class"] == "TimeSeries" else shown
        if not any(origin == "" or e == origin or e.startswith(origin + "/") for e in pool):
            empty.append(view)
    return empty
