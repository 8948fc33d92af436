"""Check an MCAP file (``oacli logs verify``) and rescue what a cut-off or damaged one holds (``oacli logs recover``).

Both walk the file linearly with the ``mcap`` package's :class:`~mcap.stream_reader.StreamReader` (it checks the
data-section CRC at ``DataEnd``) and keep only what it lacks: every chunk is decompressed under a bound
(:func:`oacli.io.mcap_read.decompressed_budget`, at most :data:`oacli.io.mcap_read.MAX_CHUNK_BYTES` per chunk)
before ``mcap``'s own chunk parser checks its CRC (``breakup_chunk(..., validate_crc=True)``); attachment CRCs and
the summary CRC are checked from the raw bytes; a message must name a known channel and a channel a known schema.

A file is *truncated* when a record runs past its end or it ends before the footer and closing magic; it is
*corrupt* when a CRC fails or a record cannot be parsed. Recovery rewrites every complete message (in the order of
the file), schema, channel, metadata record and attachment with the ``mcap`` package's writer (zstd chunks of
:data:`oacli.io.mcap_write.DEFAULT_CHUNK_SIZE`, all CRCs), atomically (:func:`oacli.io.atomic.atomic_file`). A chunk
that fails its CRC is skipped (its messages are lost) and the walk goes on; a record that cannot be parsed ends it.
"""

from __future__ import annotations

import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, cast

from mcap.records import Attachment, Channel, Chunk, DataEnd, Footer, Header, Message, Metadata, Schema
from mcap.stream_reader import CRCValidationError, StreamReader, breakup_chunk

from oacli.errors import InputError
from oacli.io.mcap_read import MAX_CHUNK_BYTES, _decompress_bounded, decompressed_budget

_MAGIC = b"\x89MCAP0\r\n"


@dataclass
class Problem:
    """What is wrong with a file and where.

    Attributes
    ----------
    kind : str
        ``truncated`` (the file ends early) or ``corrupt`` (a CRC or the structure is wrong).
    offset : int
        Byte offset of the record concerned.
    message : str
        One line naming the problem.
    """

    kind: str
    offset: int
    message: str


@dataclass
class ScanResult:
    """The outcome of a linear walk (see :func:`verify`)."""

    path: Path
    size_bytes: int
    messages: int = 0
    chunks: int = 0
    schemas: int = 0
    channels: int = 0
    metadata: int = 0
    attachments: int = 0
    problems: list[Problem] = field(default_factory=list)
    data_end: bool = False  # reached the DataEnd record: every message the writer wrote was seen
    complete: bool = False  # reached the footer and the closing magic

    @property
    def ok(self) -> bool:
        """No problem found and the file is complete."""
        return not self.problems and self.complete


class _Stop(Exception):
    """End of the walk (the problem is recorded)."""


class _Walker:
    """One linear walk over a file, calling ``sink`` with every inner record (Header, Schema, Channel, Message,
    Metadata, Attachment) of the data section."""

    def __init__(self, path: Path, sink: Any = None, keep_going: bool = False) -> None:
        self.path = Path(path)
        self.sink = sink
        self.keep_going = keep_going  # skip a chunk that fails its CRC instead of stopping
        try:
            self.data = self.path.read_bytes()
        except FileNotFoundError:
            raise InputError(f"{self.path}: file not found") from None
        except IsADirectoryError:
            raise InputError(f"{self.path}: is a folder, not an MCAP file") from None
        except OSError as exc:
            raise InputError(f"{self.path}: cannot read the file ({exc.strerror or exc})") from None
        if self.data[: len(_MAGIC)] != _MAGIC:
            raise InputError(f"{self.path}: not an MCAP file (it does not start with the MCAP magic bytes)")
        self.result = ScanResult(self.path, len(self.data))
        self.budget = decompressed_budget(len(self.data))
        self.decompressed = 0
        self.schemas: set[int] = set()
        self.channels: set[int] = set()
        self.footer_seen = False

    def problem(self, kind: str, offset: int, message: str) -> None:
        self.result.problems.append(Problem(kind, offset, f"{self.path}: {message}"))

    def _header_at(self, offset: int) -> str:
        """Classify the failure of the record starting at ``offset``: truncated when it runs past the end."""
        size = len(self.data)
        if self.footer_seen:
            return f"truncated at byte {size}: the closing magic after the footer is cut"
        if offset + 9 > size:
            if offset >= size:
                return (f"truncated at byte {size}: the file ends after its last complete record, before the "
                        f"{'footer' if self.result.data_end else 'data end record'}")
            return f"truncated at byte {size}: the record header at byte {offset} is cut"
        opcode = self.data[offset]
        length = int.from_bytes(self.data[offset + 1 : offset + 9], "little")
        if offset + 9 + length > size:
            return (f"truncated at byte {size}: the {_opcode_name(opcode)} record at byte {offset} needs "
                    f"{9 + length} bytes, {size - offset} remain")
        return ""

    def run(self) -> ScanResult:
        reader = _PositionedStream(self.data)
        stream = StreamReader(cast(IO[bytes], reader), emit_chunks=True, validate_crcs=True,
                              record_size_limit=len(self.data))
        records = stream.records
        start = len(_MAGIC)  # offset of the next record
        while True:
            try:
                record = next(records)
            except StopIteration:
                self.result.complete = True
                return self.result
            except Exception as exc:  # the mcap reader raises struct.error, EndOfFile, ValueError, ...
                self._failed(exc, start)
                return self.result
            end = reader.tell()
            try:
                self._record(record, start, end)
            except _Stop:
                return self.result
            start = end

    def _failed(self, exc: BaseException, offset: int) -> None:
        if isinstance(exc, CRCValidationError) and isinstance(exc.record, DataEnd):
            self.problem("corrupt", offset, f"data section CRC mismatch at the data end record (byte {offset}): "
                                            f"stored {exc.expected:#010x}, computed {exc.actual:#010x}")
            return
        truncated = self._header_at(offset)
        if truncated:
            self.problem("truncated", offset, truncated)
        else:
            reason = str(exc) or type(exc).__name__
            self.problem("corrupt", offset, f"corrupt record ({_opcode_name(self.data[offset])}) at byte {offset}: "
                                            f"{reason}")

    def _record(self, record: Any, start: int, end: int) -> None:
        if isinstance(record, Chunk):
            self._chunk(record, start)
        elif isinstance(record, Attachment):
            stored = int.from_bytes(self.data[end - 4 : end], "little")
            actual = zlib.crc32(self.data[start + 9 : end - 4])
            if stored != 0 and stored != actual:
                self.problem("corrupt", start, f"attachment {record.name!r} at byte {start} failed its CRC check "
                                               f"(stored {stored:#010x}, computed {actual:#010x})")
                if not self.keep_going:
                    raise _Stop
                return
            self.result.attachments += 1
            self._emit(record)
        elif isinstance(record, DataEnd):
            self.result.data_end = True
        elif isinstance(record, Footer):
            self.footer_seen = True
            self._footer(record, start)
        elif isinstance(record, (Header, Metadata, Schema, Channel, Message)):
            self._inner(record, start)
        # summary records (indexes, statistics, repeated schemas/channels) are rebuilt by a writer

    def _footer(self, footer: Footer, start: int) -> None:
        if footer.summary_crc == 0 or footer.summary_start == 0:
            return
        actual = zlib.crc32(self.data[footer.summary_start : start + 1 + 8 + 8 + 8])
        if actual != footer.summary_crc:
            self.problem("corrupt", footer.summary_start,
                         f"summary section CRC mismatch (summary at byte {footer.summary_start}: stored "
                         f"{footer.summary_crc:#010x}, computed {actual:#010x})")

    def _chunk(self, chunk: Chunk, start: int) -> None:
        declared = int(chunk.uncompressed_size)
        limit = min(MAX_CHUNK_BYTES, self.budget - self.decompressed)
        if declared > limit:
            self.problem("corrupt", start, f"chunk at byte {start} declares {declared} decompressed bytes, more "
                                           f"than the {limit} allowed (a decompression bomb or a corrupt file)")
            raise _Stop
        try:
            data = _decompress_bounded(chunk, declared)
            if len(data) != declared:
                raise ValueError(f"it decompresses to {len(data)} bytes, not the {declared} it declares")
            plain = Chunk(compression="", data=data, message_start_time=chunk.message_start_time,
                          message_end_time=chunk.message_end_time, uncompressed_crc=chunk.uncompressed_crc,
                          uncompressed_size=declared)
            records = breakup_chunk(plain, validate_crc=True)
        except CRCValidationError as exc:
            self._bad_chunk(start, f"chunk at byte {start} failed its CRC check (stored {exc.expected:#010x}, "
                                   f"computed {exc.actual:#010x})")
            return
        except Exception as exc:
            self._bad_chunk(start, f"chunk at byte {start} failed its CRC check: its {chunk.compression or 'plain'} "
                                   f"data are corrupt ({exc or type(exc).__name__}), so no CRC can match")
            return
        self.decompressed += declared
        self.result.chunks += 1
        for inner in records:
            self._inner(inner, start)

    def _bad_chunk(self, start: int, message: str) -> None:
        self.problem("corrupt", start, message)
        if not self.keep_going:
            raise _Stop

    def _inner(self, record: Any, start: int) -> None:
        if isinstance(record, Message):
            if record.channel_id not in self.channels:
                self.problem("corrupt", start, f"message at byte {start} is on unknown channel id {record.channel_id}")
                raise _Stop
            self.result.messages += 1
        elif isinstance(record, Schema):
            if record.id in self.schemas:
                return  # repeated
            self.schemas.add(record.id)
            self.result.schemas += 1
        elif isinstance(record, Channel):
            if record.id in self.channels:
                return
            if record.schema_id and record.schema_id not in self.schemas:
                self.problem("corrupt", start, f"channel {record.topic!r} at byte {start} refers to unknown schema "
                                               f"id {record.schema_id}")
                raise _Stop
            self.channels.add(record.id)
            self.result.channels += 1
        elif isinstance(record, Metadata):
            self.result.metadata += 1
        self._emit(record)

    def _emit(self, record: Any) -> None:
        if self.sink is not None:
            self.sink(record)


class _PositionedStream:
    """A read-only byte stream over the file's bytes whose position is the offset of the next record."""

    def __init__(self, data: bytes) -> None:
        self._view = memoryview(data)
        self._pos = 0

    def read(self, n: int = -1) -> bytes:
        end = len(self._view) if n is None or n < 0 else min(len(self._view), self._pos + n)
        out = bytes(self._view[self._pos : end])
        self._pos = end
        return out

    def tell(self) -> int:
        return self._pos


def _opcode_name(opcode: int) -> str:
    from mcap.opcode import Opcode

    try:
        return Opcode(opcode).name.lower()
    except ValueError:
        return f"unknown opcode {opcode:#04x}"


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
    return _Walker(path).run()


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


def recover(path: Path, out: Path) -> RecoverResult:
    """Rescan a cut-off or damaged MCAP file into a valid one holding every complete message.

    Messages keep the order and times of the input; schemas, channels (with their metadata), metadata records and
    attachments are copied; the header's profile is kept. The output is written atomically (an existing ``out``
    is replaced only when the new file is complete).

    Parameters
    ----------
    path : Path
        The damaged (or sound) ``.mcap``.
    out : Path
        The file to write.

    Returns
    -------
    RecoverResult

    Raises
    ------
    InputError
        ``path`` is missing or not an MCAP file, or ``out`` is ``path`` itself.
    """
    from mcap.writer import CompressionType, Writer

    from oacli.io.atomic import atomic_file
    from oacli.io.mcap_write import DEFAULT_CHUNK_SIZE

    path, out = Path(path), Path(out)
    if out.exists() and path.exists() and out.resolve() == path.resolve():
        raise InputError(f"{out}: the output must not be the input file")
    if not out.parent.is_dir():
        raise InputError(f"{out}: folder {out.parent} does not exist")
    records: list[Any] = []
    walker = _Walker(path, sink=records.append, keep_going=True)
    scan = walker.run()
    written = 0
    with atomic_file(out) as handle:
        writer = Writer(handle, chunk_size=DEFAULT_CHUNK_SIZE, compression=CompressionType.ZSTD,
                        enable_crcs=True, enable_data_crcs=True)
        header = next((r for r in records if isinstance(r, Header)), None)
        writer.start(profile=header.profile if header else "", library=header.library if header else "oacli")
        schema_ids: dict[int, int] = {}
        channel_ids: dict[int, int] = {}
        for record in _body(records):
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
        writer.finish()
    # A cut in the summary section (after DataEnd) loses nothing: a writer rebuilds the summary.
    lost = not scan.data_end or any(p.kind == "corrupt" for p in scan.problems)
    return RecoverResult(scan=scan, messages=written, lost=lost)


def _body(records: list[Any]) -> Iterator[Any]:
    for record in records:
        if not isinstance(record, Header):
            yield record


def describe(scan: ScanResult) -> str:
    """One line: ``ok`` with the counts, or the first problem."""
    if scan.problems:
        return scan.problems[0].message
    if not scan.complete:
        return f"{scan.path}: truncated at byte {scan.size_bytes}: no footer"
    return (f"{scan.path}: ok ({scan.messages} messages in {scan.chunks} chunks, {scan.channels} channels, "
            f"{scan.metadata} metadata records, {scan.attachments} attachments; all CRCs match)")


__all__ = ["Problem", "RecoverResult", "ScanResult", "describe", "recover", "verify"]
