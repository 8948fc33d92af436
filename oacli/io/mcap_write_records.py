"""oacli's JSON records of :class:`oacli.io.mcap_write.StageMcapWriter`: sample records (``oacli.TrajectorySample``,
``oacli.Wrench``), solver statistics and stage-specific JSON records (``docs/mcap.md``), and the reuse of encoded
sample payloads by a second file (:class:`oacli.io.mcap_write_core.EncodedRows`).
"""

from __future__ import annotations

import itertools
import json
import math
from collections.abc import Iterator, Mapping, Sequence
from typing import Any

import numpy as np

from oacli.io import mcap_schema as ms
from oacli.io.jsonsafe import to_json_safe
from oacli.io.mcap_write_core import EncodedRows, WriterCore, _finite_array, _ms_or_none, _Pending, _time_ns
from oacli.types import INPUT_DIM, STATE_DIM, SolveInfo, Trajectory

#: The JSON encoder of :meth:`StageMcapWriter.write_json` (``json.dumps(..., allow_nan=False)`` builds one per call).
_JSON = json.JSONEncoder(allow_nan=False)

class RecordWrites(WriterCore):
    """The oacli record writers of :class:`oacli.io.mcap_write.StageMcapWriter`."""

    def keep_encoded(self) -> EncodedRows:
        """Keep the payloads of the sample records written from now on (for :meth:`reuse_encoded` by another
        writer).

        Returns
        -------
        EncodedRows
            Filled as the records are encoded.
        """
        if self._kept is None:
            self._kept = EncodedRows()
        return self._kept

    def reuse_encoded(self, encoded: EncodedRows | None) -> None:
        """Take the payloads of sample records from ``encoded`` when a topic's rows are exactly those it kept
        (:class:`EncodedRows`); other records are encoded as usual. None: encode everything.

        Parameters
        ----------
        encoded : EncodedRows or None
            Another writer's kept payloads (:meth:`keep_encoded`).
        """
        self._reuse = encoded

    def _log_rows(self, topic: str, channel: Any, template: str, rows: np.ndarray, ns: list[int]) -> None:
        emit = self._raw_emitter(channel)
        reused = None if self._reuse is None else self._reuse.payloads(topic, template, rows)
        if reused is not None:
            self._emit(list(zip(ns, itertools.repeat(emit, len(ns)), reused, strict=True)))
            return
        kept = None if self._kept is None else self._kept.keep(topic, template, rows)
        payloads = [(template % row).encode() for row in map(tuple, rows.tolist())]
        if kept is not None:
            kept.extend(payloads)
        self._emit(list(zip(ns, itertools.repeat(emit, len(ns)), payloads, strict=True)))

    # -- oacli records ---------------------------------------------------------------------------------------

    def write_states(
        self,
        topic: str,
        t: np.ndarray,
        x: np.ndarray,
        u: np.ndarray | None = None,
        *,
        name: str | None = None,
        frame: str | None = None,
    ) -> None:
        """Write state (and input) samples as ``oacli.TrajectorySample`` records on ``topic``.

        Parameters
        ----------
        topic : str
            Any topic name (``/state/true``, ``/reference``, ``/control/command``, ...).
        t : ndarray, shape (N,)
            Mission times [s], ``>= 0``, strictly increasing (and after the last time written on ``topic``).
        x : ndarray, shape (N, 13)
            States ``[r (m), v (m/s), q (x, y, z, w), omega (rad/s)]``.
        u : ndarray, shape (N, 6), optional
            Inputs ``[f (N, world), tau (N·m, body)]``; zeros when omitted.
        name : str, optional
            Trajectory name stored in the channel metadata (default: the topic without its leading ``/``).
        frame : str, optional
            World frame of the samples (default: the writer's frame); fixed per topic.
        """
        times, ns = self._sample_times(topic, t)
        n = times.shape[0]
        xs = _finite_array(f"{topic}: x", x, (n, STATE_DIM))
        us = np.zeros((n, INPUT_DIM)) if u is None else _finite_array(f"{topic}: u", u, (n, INPUT_DIM))
        meta = {"frame": self.frame if frame is None else str(frame), "name": name or topic.strip("/")}
        channel = self._json_channel(topic, ms.TRAJECTORY_SAMPLE, ms.TRAJECTORY_SAMPLE_SCHEMA, meta)
        if n:
            self._log_rows(topic, channel, ms.TRAJECTORY_SAMPLE_TEMPLATE, np.column_stack([times, xs, us]), ns)
            self._last_t[topic] = float(times[-1])

    def write_trajectory(self, topic: str, traj: Trajectory) -> None:
        """Write a :class:`~oacli.types.Trajectory` (its name and frame go to the channel metadata).

        Parameters
        ----------
        topic : str
            Topic name, ``/trajectory`` for a stage's output trajectory.
        traj : Trajectory
            Times [s] must be ``>= 0``.
        """
        self.write_states(topic, traj.t, traj.x, traj.u, name=traj.name, frame=traj.frame)

    def write_wrenches(self, topic: str, t: np.ndarray, wrench: np.ndarray) -> None:
        """Write force/torque samples as ``oacli.Wrench`` records (e.g. ``/disturbance``).

        Parameters
        ----------
        topic : str
            Topic name.
        t : ndarray, shape (N,)
            Mission times [s], strictly increasing.
        wrench : ndarray, shape (N, 6)
            ``[f (N, world), tau (N·m, body)]`` held from ``t[k]`` to ``t[k+1]``.
        """
        times, ns = self._sample_times(topic, t)
        w = _finite_array(f"{topic}: wrench", wrench, (times.shape[0], INPUT_DIM))
        channel = self._json_channel(topic, ms.WRENCH, ms.WRENCH_SCHEMA, {"frame": self.frame})
        if times.size:
            self._log_rows(topic, channel, ms.WRENCH_TEMPLATE, np.column_stack([times, w]), ns)
            self._last_t[topic] = float(times[-1])

    def write_solver_stats(self, t: np.ndarray, infos: Sequence[SolveInfo], topic: str = ms.TOPIC_SOLVER_STATS) -> None:
        """Write one ``oacli.SolverStats`` record per controller step.

        Parameters
        ----------
        t : ndarray, shape (K,)
            Controller step times [s], strictly increasing.
        infos : sequence of SolveInfo, length K
            Per-step outcome; NaN objective or times become JSON ``null``; times are written in ms.
        topic : str
            Topic name.
        """
        times, ns = self._sample_times(topic, t)
        if len(infos) != times.shape[0]:
            raise ValueError(f"{topic}: {times.shape[0]} times but {len(infos)} SolveInfo records")
        channel = self._json_channel(topic, ms.SOLVER_STATS, ms.SOLVER_STATS_SCHEMA, {})
        emit = self._raw_emitter(channel)
        infos = list(infos)

        def messages() -> Iterator[_Pending]:
            for ti, info, log_time in zip(times.tolist(), infos, ns, strict=True):
                objective = float(info.objective)
                record = {
                    "t": ti,
                    "status": str(info.status),
                    "success": bool(info.success),
                    "objective": objective if math.isfinite(objective) else None,
                    "iterations": int(info.iterations),
                    "solve_time_ms": _ms_or_none(info.solve_time_s),
                    "step_time_ms": _ms_or_none(info.step_time_s),
                }
                yield log_time, emit, json.dumps(record, allow_nan=False).encode()

        self._emit(messages())
        if times.size:
            self._last_t[topic] = float(times[-1])

    def write_json(
        self, topic: str, schema_name: str, schema: Mapping[str, Any], t: float, record: Mapping[str, Any]
    ) -> None:
        """Write one record of a stage-specific JSON schema (parameter estimates, events, ...).

        Parameters
        ----------
        topic : str
            Topic name; a topic carries one schema.
        schema_name : str
            Schema name, ``oacli.<Something>`` by convention (stored as the JSON schema's ``title``).
        schema : Mapping
            JSON Schema of an object (``{"type": "object", "properties": {...}}``); used on the first write.
        t : float
            Mission time [s], ``>= 0``; stored as the record's ``t`` field (inserted first).
        record : Mapping
            The record; numpy arrays and scalars are converted, NaN and infinities become ``null``.
        """
        t_s, log_time = _time_ns(topic, t)
        if "t" in record and float(record["t"]) != t_s:
            raise ValueError(f"{topic}: record t={record['t']!r} differs from t={t_s!r}")
        channel = self._json_channel(topic, schema_name, schema, {})
        body = to_json_safe({"t": t_s, **{k: v for k, v in record.items() if k != "t"}})
        self._emit([(log_time, self._raw_emitter(channel), _JSON.encode(body).encode())])

