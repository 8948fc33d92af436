"""Write a stage's MCAP file (the record of truth of every oacli stage); read it with :mod:`oacli.io.mcap_read`.

The contract (topics, schemas, units, metadata, attachments) is documented in ``docs/mcap.md`` and its names
and JSON schemas live in :mod:`oacli.io.mcap_schema`.

Writing uses the Foxglove SDK's MCAP writer (``foxglove.open_mcap``) with one ``foxglove.Context`` per file, so
channels of one file never leak into another. It writes zstd-compressed chunks (level :data:`ZSTD_LEVEL`) of at most
:data:`DEFAULT_CHUNK_SIZE` bytes (uncompressed), chunk CRCs, the data-section CRC, the summary CRC and attachment
CRCs. The file is written under a temporary name and renamed into place only when the ``with`` block ends
without an exception (:func:`oacli.io.atomic.atomic_file`: an exclusive temporary file, never a
predictable name); a failed write names its cause (:class:`oacli.io.atomic.WriteError`).

Messages go to the file in time order (``log_time`` non-decreasing over the whole file, ties in call order) when
the writer is opened with ``time_ordered=True`` or inside a :meth:`StageMcapWriter.time_ordered` block: each
``write_*`` call is validated at once and queued as a lazy per-topic stream, and the streams are merged by time
(:func:`heapq.merge`) when the block ends or on :meth:`StageMcapWriter.flush`. Chunks are written as they fill,
so a file cut by a crash holds every complete chunk (all topics up to about the same time), which the ``mcap``
package's stream reader reads up to the cut.

The writer is split by record family: its machinery (time checks, spool file, channels, the time-ordered queue) in
:mod:`oacli.io.mcap_write_core`, oacli's JSON records in :mod:`oacli.io.mcap_write_records`, Foxglove messages in
:mod:`oacli.io.mcap_write_scene`; this module holds the file's life (open, finish, attachments, metadata).
"""

from __future__ import annotations

import contextlib
import sys
import time
from collections.abc import Iterator, Mapping
from datetime import UTC, datetime
from types import TracebackType
from typing import BinaryIO, cast

import foxglove
from foxglove.mcap import MCAPCompression, MCAPWriteOptions

import oacli
from oacli.io import mcap_memo
from oacli.io import mcap_schema as ms
from oacli.io.atomic import WriteError, atomic_file, describe_os_error
from oacli.io.mcap_write_core import (  # noqa: F401  # re-exported: names the stages and tests use
    _NS_PER_S,
    DEFAULT_CHUNK_SIZE,
    ZSTD_LEVEL,
    EncodedRows,
    _SpoolFile,
    _time_ns,
    _times_ns,
)
from oacli.io.mcap_write_records import RecordWrites
from oacli.io.mcap_write_scene import ROBOT_BODY_EDGE_M, ROBOT_BODY_RATE_HZ, SceneWrites
from oacli.signals import held

__all__ = ["DEFAULT_CHUNK_SIZE", "ROBOT_BODY_EDGE_M", "ROBOT_BODY_RATE_HZ", "ZSTD_LEVEL", "EncodedRows",
           "StageMcapWriter"]


class StageMcapWriter(RecordWrites, SceneWrites):
    """Context manager writing one stage's MCAP file atomically.

    On entering, the file is opened under an exclusive temporary name (``.<name>.<random>.partial`` beside
    ``path``), and the
    metadata record ``oacli`` and the attachment ``config.yaml`` are written first (so that even a file cut by a
    crash carries them). On leaving without an exception the file is finished (summary, CRCs), fsynced and
    renamed to ``path``; if an exception escapes the ``with`` block the temporary file is deleted and no file
    named ``path`` is created.

    All times are mission time ``t`` [s] since the start of the stage, ``t >= 0``; each message's MCAP
    ``log_time`` and ``publish_time`` are ``round(t * 1e9)`` [ns] and oacli's JSON records also hold the exact
    float ``t``. Sample topics (trajectories, wrenches, solver statistics, poses) must be written with strictly
    increasing times; a topic may be written in several calls (each continuing after the last time written).

    Parameters
    ----------
    path : Path
        Final file name (``*.mcap``). Its folder must exist.
    stage : str
        Stage name (``plan``, ``smooth``, ``track``, ...), stored in the ``oacli`` metadata.
    config_yaml : str
        The resolved configuration as YAML text, stored as the attachment ``config.yaml``.
    metadata : Mapping[str, object], optional
        Further entries of the ``oacli`` metadata record (``seed``, ``git_commit``, ...); values are converted
        with ``str``. They override the defaults ``version``, ``created_utc``, ``frame``, ``contract_version``;
        ``seed`` and ``git_commit`` default to ``"unknown"``.
    frame : str
        Name of the world frame (``frame_id`` of poses; channel metadata of sample topics).
    chunk_size : int
        Target uncompressed chunk size [bytes].
    overwrite : bool
        Replace an existing ``path`` (default: refuse with ``FileExistsError``).
    time_ordered : bool
        Queue every message and write them merged by time (see the module docstring) when the ``with`` block
        ends or on :meth:`flush`; otherwise each ``write_*`` call writes its messages at once.

    Examples
    --------
    ::

        with StageMcapWriter(run / "plan.mcap", stage="plan", config_yaml=text, metadata={"seed": 1}) as w:
            w.write_trajectory("/trajectory", plan)
            w.write_poses(plan.t, plan.x)
            w.write_scene(scene, {"plan": plan.x[:, :3]})
            w.write_log(0.0, "info", "plan found")
    """

    # -- context management ------------------------------------------------------------------------------

    def __enter__(self) -> StageMcapWriter:
        if self._state != "new":
            raise RuntimeError("a StageMcapWriter can be entered only once")
        if self.path.exists() and not self._overwrite:
            raise FileExistsError(f"{self.path} exists; refusing to overwrite it")
        if not self.path.parent.is_dir():
            raise FileNotFoundError(f"folder {self.path.parent} does not exist")
        self._atomic = atomic_file(self.path)
        self._file = _SpoolFile(self._atomic.__enter__())
        self._written = mcap_memo.Written() if mcap_memo.active() else None
        try:
            self._context = foxglove.Context()
            options = MCAPWriteOptions(
                compression=MCAPCompression.Zstd,
                compression_level=ZSTD_LEVEL,
                compression_threads=0,  # compressed in this thread (no pool of one thread per CPU)
                chunk_size=self._chunk_size,
                calculate_chunk_crcs=True,
                calculate_data_section_crc=True,
                calculate_summary_section_crc=True,
                calculate_attachment_crcs=True,
            )
            sink = cast(BinaryIO, self._file)  # our spool: write/flush/seek/tell as open_mcap needs
            with held():  # Ctrl-C inside the native writer's callbacks is raised after them (oacli.signals)
                self._writer = foxglove.open_mcap(sink, context=self._context, writer_options=options)
            self._state = "open"
            created = datetime.now(UTC).isoformat(timespec="seconds").replace("+00:00", "Z")
            info = {
                "version": oacli.__version__,
                "stage": self.stage,
                "seed": "unknown",
                "git_commit": "unknown",
                "created_utc": created,
                "frame": self.frame,
                "contract_version": ms.CONTRACT_VERSION,
                **self._extra_metadata,
            }
            self.write_metadata(ms.METADATA_NAME, info)
            self.attach(ms.CONFIG_ATTACHMENT, self._config_yaml.encode("utf-8"), ms.CONFIG_MEDIA_TYPE)
            with held():
                self._writer.flush()
            self._spill()  # the metadata and the config are on disk before any message
        except BaseException:
            self.__exit__(*sys.exc_info())
            raise
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if self._state == "closed":
            return
        with held():  # an interruption while closing is raised once the file is committed or removed
            self._close(exc)

    def _close(self, exc: BaseException | None) -> None:
        error = exc
        try:
            if error is None and self._writer is not None:
                self._drain()
        except BaseException as err:
            error = err
        self._state = "closed"
        self._queue = None
        try:
            if self._writer is not None:
                self._writer.close()
                if error is None:
                    self._spill()
        except BaseException as err:
            if error is None:
                error = err
            else:
                error.add_note(f"(closing the MCAP writer also failed: {err})")
        finally:
            self._writer = None
            for channel, _, _ in self._channels.values():
                channel.close()
            self._channels.clear()
            self._context = None
        if not isinstance(error, KeyboardInterrupt) and self._file is not None and self._file.error is not None:
            # The foxglove writer reports a failed write vaguely; name the cause (e.g. ENOSPC) and the path.
            if not isinstance(error, WriteError):
                cause = error
                error = WriteError(describe_os_error(self._file.error, self.path))
                error.__cause__ = cause
        if error is None:
            self._atomic.__exit__(None, None, None)
            if self._written is not None:
                mcap_memo.store(self.path, self._written)
            self._written = None
            return
        self._written = None
        self._atomic.__exit__(type(error), error, error.__traceback__)  # removes the temporary file
        if error is not exc:
            raise error

    # -- time order --------------------------------------------------------------------------------------------

    @contextlib.contextmanager
    def time_ordered(self) -> Iterator[StageMcapWriter]:
        """Within the block, queue every message; at its end write them all merged by time.

        Messages with equal times keep the order of the calls. Nothing queued is written if the block raises.
        """
        self._require_open()
        if self._queue is not None:
            yield self  # already queueing (nested block or a time-ordered writer)
            return
        self._queue = []
        try:
            yield self
        except BaseException:
            self._queue = None
            raise
        try:
            self._drain()
        finally:
            self._queue = None

    # -- attachments and metadata ----------------------------------------------------------------------------

    def attach(self, name: str, data: bytes, media_type: str, *, t: float = 0.0) -> None:
        """Store a file as an MCAP attachment (create time = now, log time = ``t`` [s] mission time).

        Parameters
        ----------
        name : str
            Attachment name (e.g. ``config.yaml``).
        data : bytes
            Content.
        media_type : str
            MIME type (e.g. ``application/yaml``).
        t : float
            Mission time [s] of the attachment.
        """
        self._require_open()
        _, ns = _times_ns(f"attachment {name}", t)
        with held():
            self._writer.attach(
                log_time=ns[0], create_time=time.time_ns(), name=str(name), media_type=str(media_type),
                data=bytes(data),
            )
        if self._written is not None:
            self._written.attachments[str(name)] = bytes(data)

    def write_metadata(self, name: str, data: Mapping[str, object]) -> None:
        """Write a metadata record (string keys and values; values converted with ``str``).

        Parameters
        ----------
        name : str
            Record name.
        data : Mapping[str, object]
            Entries; must not be empty.
        """
        self._require_open()
        if not data:
            raise ValueError(f"metadata record {name!r} is empty (MCAP writers drop empty records)")
        entries = {str(k): str(v) for k, v in data.items()}
        with held():
            self._writer.write_metadata(str(name), entries)
        if self._written is not None:
            self._written.metadata[str(name)] = dict(entries)

    def flush(self) -> None:
        """Write the queued messages (merged by time), finish the current chunk and flush it to disk.

        A time-ordered writer keeps queueing afterwards; later calls should continue after the times written.
        """
        self._require_open()
        if self._queue:
            self._drain()
        with held():
            self._writer.flush()
        self._spill()
