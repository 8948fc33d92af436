"""Check an MCAP file (``oacli logs verify``) and rescue what a cut-off or damaged one holds (``oacli logs recover``).

Both read the file mapped into memory (:func:`oacli.io.mcap_walk.map_file`: pages the system can drop, one chunk
decompressed at a time, so memory stays bounded whatever the file's size), refuse a FIFO, a device or a folder
(exit 2, without blocking), and walk the file linearly with :class:`oacli.io.mcap_walk.McapWalk`: the ``mcap`` package's
:class:`~mcap.stream_reader.StreamReader` (it checks the data-section CRC at ``DataEnd``), every chunk decompressed
under a bound and its CRC checked before its records are read, attachment CRCs and the summary CRC checked from the
raw bytes, a message on a known channel and a channel of a known schema, at most as many messages and channels as
oacli reads (:mod:`oacli.config.sizes`).

A file is *truncated* when a record runs past its end or it ends before the footer and closing magic; it is
*corrupt* when a CRC fails or a record cannot be parsed; *too large* when a chunk would decompress beyond the bound
or the file holds more messages or channels than allowed. Recovery rewrites every complete message (in the order of
the file), schema, channel, metadata record and attachment with the ``mcap`` package's writer (zstd chunks of
:data:`oacli.io.mcap_write.DEFAULT_CHUNK_SIZE`, all CRCs) as the walk yields them (nothing is collected),
atomically (:func:`oacli.io.atomic.atomic_file`); an existing output is refused unless ``force``. A chunk
that fails its CRC is skipped (its messages are lost) and the walk goes on; a record that cannot be parsed ends it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mcap.records import Attachment, Channel, Header, Message, Metadata, Schema

from oacli.errors import InputError
from oacli.io.mcap_walk import McapWalk, Problem, ScanResult, map_file


def verify(path: Path) -> ScanResult:
    """Check an MCAP file: structure, every chunk CRC, attachment CRCs, the data-section and summary CRCs.

    Parameters
    ----------
    path : Path
        The ``.mcap`` file.

    Returns
    -------
    ScanResult
        ``ok`` when the file is complete and sound; otherwise ``problems[0]`` names the first problem and where.

    Raises
    ------
    InputError
        The file is missing, unreadable or not an MCAP file at all.
    """
    return McapWalk(path, data=map_file(path)).run()


@dataclass
class RecoverResult:
    """What :func:`recover` saved.

    Attributes
    ----------
    scan : ScanResult
        The walk of the input (its problems: what was lost and where).
    messages : int
        Messages written to the output.
    lost : bool
        Data were (or may have been) lost: the input ended before its data end record, or a chunk or record
        had to be skipped.
    """

    scan: ScanResult
    messages: int
    lost: bool


def recover(path: Path, out: Path, *, force: bool = False) -> RecoverResult:
    """Rescan a cut-off or damaged MCAP file into a valid one holding every complete message.

    Messages keep the order and times of the input; schemas, channels (with their metadata), metadata records and
    attachments are copied; the header's profile is kept. Each record is written as the walk yields it (memory
    bounded by one chunk); the output is written atomically (never a symlink, never half-written).

    Parameters
    ----------
    path : Path
        The damaged (or sound) ``.mcap``.
    out : Path
        The file to write.
    force : bool
        Replace an existing regular file ``out`` (default: refuse it).

    Returns
    -------
    RecoverResult

    Raises
    ------
    InputError
        ``path`` is missing, not a regular file or not an MCAP file; ``out`` is ``path`` itself, exists (without
        ``force``) or is not a regular file, or its folder is missing.
    """
    import os
    import stat

    from mcap.writer import CompressionType, Writer

    from oacli.io.atomic import atomic_file
    from oacli.io.mcap_write import DEFAULT_CHUNK_SIZE

    path, out = Path(path), Path(out)
    data = map_file(path)
    try:
        st = os.stat(out)
    except FileNotFoundError:
        st = None
    except OSError as exc:
        raise InputError(f"{out}: cannot use it as the output ({exc.strerror or exc})") from None
    if st is not None:
        if os.path.samefile(out, path):
            raise InputError(f"{out}: the output must not be the input file")
        if not stat.S_ISREG(st.st_mode):
            raise InputError(f"{out}: exists and is not a regular file; give the path of a new .mcap file")
        if not force:
            raise InputError(f"{out}: exists; give a new path, or add --force to replace it")
    if out.is_symlink() and not force:
        raise InputError(f"{out}: is a symlink; give a new path, or add --force to replace the link by the file")
    if not out.parent.is_dir():
        raise InputError(f"{out}: folder {out.parent} does not exist")
    written = 0
    with atomic_file(out) as handle:
        writer = Writer(handle, chunk_size=DEFAULT_CHUNK_SIZE, compression=CompressionType.ZSTD,
                        enable_crcs=True, enable_data_crcs=True)
        started = False
        schema_ids: dict[int, int] = {}
        channel_ids: dict[int, int] = {}

        def start(header: Header | None) -> None:
            nonlocal started
            if not started:
                started = True
                writer.start(profile=header.profile if header else "", library=header.library if header else "oacli")

        def sink(record: Any) -> None:
            nonlocal written
            if isinstance(record, Header):
                start(record)
                return
            start(None)
            if isinstance(record, Message):
                writer.add_message(channel_ids[record.channel_id], record.log_time, record.data,
                                   record.publish_time, record.sequence)
                written += 1
            elif isinstance(record, Schema):
                schema_ids[record.id] = writer.register_schema(record.name, record.encoding, record.data)
            elif isinstance(record, Channel):
                channel_ids[record.id] = writer.register_channel(
                    record.topic, record.message_encoding, schema_ids.get(record.schema_id, 0),
                    dict(record.metadata))
            elif isinstance(record, Metadata):
                writer.add_metadata(record.name, dict(record.metadata))
            elif isinstance(record, Attachment):
                writer.add_attachment(record.create_time, record.log_time, record.name, record.media_type,
                                      record.data)

        scan = McapWalk(path, sink=sink, keep_going=True, data=data).run()
        start(None)
        writer.finish()
    # A cut in the summary section (after DataEnd) loses nothing: a writer rebuilds the summary.
    lost = not scan.data_end or any(p.kind != "truncated" for p in scan.problems)
    return RecoverResult(scan=scan, messages=written, lost=lost)


def describe(scan: ScanResult) -> str:
    """One line: ``ok`` with the counts, or the first problem."""
    if scan.problems:
        return scan.problems[0].message
    if not scan.complete:
        return f"{scan.path}: truncated at byte {scan.size_bytes}: no footer"
    return (f"{scan.path}: ok ({scan.messages} messages in {scan.chunks} chunks, {scan.channels} channels, "
            f"{scan.metadata} metadata records, {scan.attachments} attachments; all CRCs match)")


__all__ = ["Problem", "RecoverResult", "ScanResult", "describe", "recover", "verify"]
