"""One linear, bounded walk over an MCAP file with the ``mcap`` package's stream reader: what oacli's readers
(:mod:`oacli.io.mcap_read`) and ``oacli logs verify/recover`` (:mod:`oacli.io.mcap_recover`) share.

The ``mcap`` package's :class:`~mcap.stream_reader.StreamReader` (``validate_crcs=True``) parses the records and
checks the data-section CRC at ``DataEnd``; a file cut mid-write (a crash, a ``.partial`` leftover) makes it raise
at the cut, after every complete record. Kept here is only what it lacks:

* **bounded decompression**: a chunk may declare at most :data:`MAX_CHUNK_BYTES` decompressed bytes, a file at most
  :func:`decompressed_budget` in total (:data:`MAX_EXPANSION` × its size, at least :data:`MIN_DECOMPRESSED_BUDGET`,
  at most :data:`MAX_DECOMPRESSED_BYTES`), and the decompressor never produces more than declared (the package's
  ``breakup_chunk`` trusts the declared size for zstd and none at all for lz4). The chunk CRC is then checked and
  the chunk's records are parsed in place by struct-unpacking their headers (no list of millions of records; a
  message object is built only for the topics the caller wants, :class:`McapWalk` ``topics``);
* **counts**: at most :data:`oacli.config.sizes.MAX_MESSAGES_PER_TOPIC` messages on one topic,
  :data:`~oacli.config.sizes.MAX_MCAP_MESSAGES` in a file and :data:`~oacli.config.sizes.MAX_MCAP_CHANNELS`
  channels. A complete file whose summary statistics already say more is refused before any chunk is read; a file
  whose chunks could hold more is counted first by a scan of the chunks' record headers (one chunk in memory
  at a time), so millions of tiny messages are refused without parsing them;
* **attachment and summary CRCs** (the stream reader checks neither), a message on an unknown channel, a channel
  of an unknown schema;
* **where a problem is**: every problem is a :class:`Problem` (``truncated``, ``corrupt`` or ``too_large``) with
  the byte offset of the record concerned.
"""

from __future__ import annotations

import io
import mmap
import os
import struct
import zlib
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Attachment, Channel, Chunk, DataEnd, Footer, Header, Message, Metadata, Schema
from mcap.stream_reader import CRCValidationError, StreamReader

from oacli.config.sizes import MAX_MCAP_CHANNELS, MAX_MCAP_MESSAGES, MAX_MESSAGES_PER_TOPIC
from oacli.errors import InputError
from oacli.io.regular_files import open_regular, stream_of

MAGIC = b"\x89MCAP0\r\n"

MAX_CHUNK_BYTES = 64 * 1024 * 1024
"""Largest decompressed chunk accepted [bytes] (oacli writes chunks of 256 KiB)."""

MAX_EXPANSION = 100
"""Decompressed bytes allowed per byte of file (oacli's zstd chunks expand about 10 times)."""

MIN_DECOMPRESSED_BUDGET = 64 * 1024 * 1024
"""Decompressed bytes a small file may always expand to [bytes]."""

MAX_DECOMPRESSED_BYTES = 2 * 1024 * 1024 * 1024
"""Absolute cap on the decompressed bytes of one file [bytes]."""

IN_PLACE_CHUNKS = True
"""Parse a chunk's records in place (:meth:`McapWalk._chunk_records`); off: the former per-record
``StreamReader`` (for ``benchmarks/bench_mission_overhead.py`` only)."""


def decompressed_budget(file_bytes: int) -> int:
    """Decompressed bytes a file of ``file_bytes`` may expand to: ``MAX_EXPANSION`` × its size, at least
    :data:`MIN_DECOMPRESSED_BUDGET`, at most :data:`MAX_DECOMPRESSED_BYTES` (a decompression bomb is refused)."""
    return min(MAX_DECOMPRESSED_BYTES, max(MIN_DECOMPRESSED_BUDGET, MAX_EXPANSION * int(file_bytes)))


def decompress_bounded(chunk: Chunk, limit: int) -> bytes:
    """Decompress a chunk's records, producing at most ``limit + 1`` bytes whatever the data claim."""
    if chunk.compression == "":
        return bytes(chunk.data)
    if chunk.compression == "zstd":
        import zstandard

        reader = zstandard.ZstdDecompressor().stream_reader(io.BytesIO(chunk.data), read_across_frames=True)
        parts, total = [], 0
        while total <= limit:
            block = reader.read(min(1 << 20, limit + 1 - total))
            if not block:
                break
            parts.append(block)
            total += len(block)
        return b"".join(parts)
    if chunk.compression == "lz4":
        import lz4.frame

        return lz4.frame.LZ4FrameDecompressor().decompress(bytes(chunk.data), max_length=limit + 1)
    raise ValueError(f"unsupported compression {chunk.compression!r}")


@dataclass
class Problem:
    """What is wrong with a file and where.

    Attributes
    ----------
    kind : str
        ``truncated`` (the file ends early), ``corrupt`` (a CRC or the structure is wrong) or ``too_large``
        (a decompression bomb, or more messages or channels than oacli reads).
    offset : int
        Byte offset of the record concerned.
    message : str
        One line naming the problem (and the file).
    """

    kind: str
    offset: int
    message: str


@dataclass
class ScanResult:
    """The outcome of a linear walk (see :class:`McapWalk`)."""

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
    bytes_read: int = 0  # end of the last complete top-level record (the intact part of a cut file)

    @property
    def ok(self) -> bool:
        """No problem found and the file is complete."""
        return not self.problems and self.complete


class _Stop(Exception):
    """End of the walk (the problem is recorded)."""


_SKIPPED = frozenset({Opcode.MESSAGE_INDEX, Opcode.CHUNK_INDEX, Opcode.ATTACHMENT_INDEX, Opcode.METADATA_INDEX,
                      Opcode.STATISTICS, Opcode.SUMMARY_OFFSET})


class _Skipped:
    """An index or statistics record read past unparsed (yielded so that record offsets stay exact)."""

    __slots__ = ("opcode",)

    def __init__(self, opcode: int) -> None:
        self.opcode = opcode


class _StreamReader(StreamReader):
    """The ``mcap`` package's stream reader, skipping the index and statistics records instead of parsing them
    (oacli rebuilds none of them; a message index holds an entry per message). They still count in the
    data-section CRC."""

    def _read_record(self, opcode: int, length: int) -> Any:
        if opcode == 0:  # no MCAP record has opcode 0x00: zeros (a sparse or zero-filled file) are not skipped 9 bytes
            raise ValueError("opcode 0x00 is no MCAP record (zero bytes)")  # at a time, the walk stops here
        if opcode in _SKIPPED:
            self._stream.read(length)
            return _Skipped(opcode)
        return super()._read_record(opcode, length)


def opcode_name(opcode: int) -> str:
    """The record type's name (``chunk``, ``message``...) or ``unknown opcode 0x..``."""
    from mcap.opcode import Opcode

    try:
        return Opcode(opcode).name.lower()
    except ValueError:
        return f"unknown opcode {opcode:#04x}"


def read_file(path: Path) -> bytes:
    """The bytes of an MCAP file (InputError naming the file when missing, not a regular file -- a folder, a FIFO,
    a device --, unreadable or not MCAP)."""
    fd = open_regular(path)
    try:
        with os.fdopen(fd, "rb") as f:
            data = f.read()
    except OSError as exc:
        raise InputError(f"{path}: cannot read the file ({exc.strerror or exc})") from None
    if data[: len(MAGIC)] != MAGIC:
        raise InputError(f"{path}: not an MCAP file (it does not start with the MCAP magic bytes)")
    return data


def map_file(path: Path) -> Any:
    """The MCAP file mapped read-only (:class:`mmap.mmap`, bytes-like: the walk reads it in place with bounded memory
    whatever its size, :class:`McapWalk`); the checks and errors of :func:`read_file`."""
    fd = open_regular(path)
    try:
        size = os.fstat(fd).st_size
        if size < len(MAGIC):
            raise InputError(f"{path}: not an MCAP file (it does not start with the MCAP magic bytes)")
        try:
            mapped = mmap.mmap(fd, 0, access=mmap.ACCESS_READ)
        except (OSError, ValueError) as exc:
            raise InputError(f"{path}: cannot read the file ({exc})") from None
    finally:
        os.close(fd)
    if mapped[: len(MAGIC)] != MAGIC:
        raise InputError(f"{path}: not an MCAP file (it does not start with the MCAP magic bytes)")
    return mapped


_MIN_MESSAGE_RECORD = 9 + 22
"""Bytes of the smallest message record (opcode, length, channel id, sequence, log and publish times)."""

_RECORD_HEADER = struct.Struct("<BQ")
_MESSAGE_HEADER = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
_OP_MESSAGE, _OP_SCHEMA, _OP_CHANNEL = int(Opcode.MESSAGE), int(Opcode.SCHEMA), int(Opcode.CHANNEL)
_CHANNEL_ID = struct.Struct("<H")


def _count_messages(data: bytes, counts: dict[int, int], topics: dict[int, str]) -> None:
    """Add the messages per channel id of a decompressed chunk to ``counts`` (record headers only; the topic of
    each channel record to ``topics``)."""
    header, channel_id = _RECORD_HEADER.unpack_from, _CHANNEL_ID.unpack_from
    pos, end = 0, len(data)
    while pos + 9 <= end:
        opcode, length = header(data, pos)
        if opcode == Opcode.MESSAGE and pos + 11 <= end:
            cid = channel_id(data, pos + 9)[0]
            counts[cid] = counts.get(cid, 0) + 1
        elif opcode == Opcode.CHANNEL:
            try:
                channel = Channel.read(ReadDataStream(io.BytesIO(data[pos + 9 : pos + 9 + length])))
                topics.setdefault(channel.id, channel.topic)
            except Exception:
                pass  # the walk reports it
        pos += 9 + length


class McapWalk:
    """One linear walk over a file, calling ``sink`` with every inner record of the data section (Header, Schema,
    Channel, Message, Metadata, Attachment; a repeated schema or channel once).

    Parameters
    ----------
    path : Path
        The file.
    sink : callable, optional
        Called with each record.
    keep_going : bool
        Skip a chunk or attachment that fails its CRC and go on (recovery) instead of stopping.
    validate_crcs : bool
        Check chunk, attachment, data-section and summary CRCs.
    data : bytes, optional
        The file's bytes, when already read.
    topics : iterable of str, optional
        Pass to ``sink`` only the messages of these topics (all by default); every message is still counted
        against the caps and checked for a known channel, every chunk still decompressed and CRC-checked.
    """

    def __init__(self, path: Path, sink: Callable[[Any], None] | None = None, *, keep_going: bool = False,
                 validate_crcs: bool = True, data: bytes | None = None,
                 topics: Iterable[str] | None = None) -> None:
        self.path = Path(path)
        self.sink = sink
        self.keep_going = keep_going
        self.validate = validate_crcs
        self.data = read_file(self.path) if data is None else data
        self.result = ScanResult(self.path, len(self.data))
        self.budget = decompressed_budget(len(self.data))
        self.decompressed = 0
        self.schemas: set[int] = set()
        self.channels: dict[int, str] = {}
        self.per_channel: dict[int, int] = {}
        self.footer_seen = False
        self.topics = None if topics is None else frozenset(topics)
        self.wanted_channels: set[int] | None = None if topics is None else set()

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
            return (f"truncated at byte {size}: the {opcode_name(opcode)} record at byte {offset} needs "
                    f"{9 + length} bytes, {size - offset} remain")
        return ""

    def run(self) -> ScanResult:
        """Walk the file; returns the result (its ``problems`` name what is wrong and where)."""
        if self._statistics_too_large() or self._counted_too_large():
            return self.result
        reader = stream_of(self.data)
        stream = _StreamReader(reader, emit_chunks=True, validate_crcs=self.validate, record_size_limit=len(self.data))
        records = stream.records
        start = len(MAGIC)  # offset of the next record
        self.result.bytes_read = start
        while True:
            try:
                record = next(records)
            except StopIteration:
                self.result.complete = True
                self.result.bytes_read = len(self.data)
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
            if not self.footer_seen:
                self.result.bytes_read = end

    def _statistics_too_large(self) -> bool:
        """A complete file whose summary statistics count more messages or channels than allowed: refused before
        any chunk is read (the walk counts again: statistics can lie)."""
        data = self.data
        if len(data) < 2 * len(MAGIC) + 9 + 20 or data[-len(MAGIC) :] != MAGIC:
            return False
        try:
            from mcap.reader import SeekingReader

            summary = SeekingReader(stream_of(data), validate_crcs=False).get_summary()
        except Exception:
            return False
        if summary is None or summary.statistics is None:
            return False
        stats = summary.statistics
        topics = {cid: ch.topic for cid, ch in summary.channels.items()}
        for cid, count in stats.channel_message_counts.items():
            if count > MAX_MESSAGES_PER_TOPIC:
                self._too_many_on(topics.get(cid, f"of channel id {cid}"), count, 0)
                return True
        if stats.message_count > MAX_MCAP_MESSAGES:
            self.problem("too_large", 0, f"its summary counts {stats.message_count} messages, more than the "
                                         f"{MAX_MCAP_MESSAGES} oacli reads from one file "
                                         "(oacli.config.sizes.MAX_MCAP_MESSAGES)")
            return True
        if stats.channel_count > MAX_MCAP_CHANNELS:
            self.problem("too_large", 0, f"its summary counts {stats.channel_count} channels, more than the "
                                         f"{MAX_MCAP_CHANNELS} oacli reads from one file "
                                         "(oacli.config.sizes.MAX_MCAP_CHANNELS)")
            return True
        return False

    def _counted_too_large(self) -> bool:
        """Count the messages per channel before parsing any (a quick scan of each chunk's record headers), when
        the chunks could hold more than :data:`MAX_MESSAGES_PER_TOPIC`: a file of millions of tiny messages is then
        refused in about a second, not after parsing millions of them. Problems of structure are left to the walk."""
        declared, top = self._declared_sizes()
        if declared // _MIN_MESSAGE_RECORD + top <= min(MAX_MESSAGES_PER_TOPIC, MAX_MCAP_MESSAGES):
            return False  # cannot hold too many messages on a topic or in total
        counts: dict[int, int] = {}
        topics: dict[int, str] = {}
        used = 0
        for record in self._top_level():
            if isinstance(record, Chunk):
                size = int(record.uncompressed_size)
                if size > min(MAX_CHUNK_BYTES, self.budget - used):
                    return False  # a bomb: the walk refuses it
                try:
                    data = decompress_bounded(record, size)
                except Exception:
                    return False
                used += size
                _count_messages(data, counts, topics)
            elif isinstance(record, Message):
                counts[record.channel_id] = counts.get(record.channel_id, 0) + 1
            elif isinstance(record, Channel):
                topics.setdefault(record.id, record.topic)
            elif isinstance(record, DataEnd):
                break
            for cid, count in counts.items():
                if count > MAX_MESSAGES_PER_TOPIC:
                    self._too_many_on(topics.get(cid, f"of channel id {cid}"), None, 0)
                    return True
            if sum(counts.values()) > MAX_MCAP_MESSAGES:
                self.problem("too_large", 0, f"the file holds more than {MAX_MCAP_MESSAGES} messages, the most "
                                             "oacli reads from one file (oacli.config.sizes.MAX_MCAP_MESSAGES)")
                return True
        return False

    def _top_level(self) -> Any:
        """The top-level records up to the first problem (chunks not opened, no CRC checked)."""
        stream = _StreamReader(stream_of(self.data), emit_chunks=True, record_size_limit=len(self.data)).records
        while True:
            try:
                yield next(stream)
            except Exception:  # StopIteration, a cut or a corrupt record: the walk reports it
                return

    def _declared_sizes(self) -> tuple[int, int]:
        """Decompressed bytes the chunks declare, and the messages outside chunks."""
        declared = top = 0
        for record in self._top_level():
            if isinstance(record, Chunk):
                declared += int(record.uncompressed_size)
            elif isinstance(record, Message):
                top += 1
            elif isinstance(record, DataEnd):
                break
        return min(declared, self.budget), top

    def _too_many_on(self, topic: str, count: int | None, offset: int) -> None:
        held = f"its summary counts {count} messages" if count is not None else \
            f"more than {MAX_MESSAGES_PER_TOPIC} messages"
        self.problem("too_large", offset, f"topic {topic}: {held}; oacli reads at most {MAX_MESSAGES_PER_TOPIC} "
                                          "messages from one topic (oacli.config.sizes.MAX_MESSAGES_PER_TOPIC)")

    def _failed(self, exc: BaseException, offset: int) -> None:
        if isinstance(exc, CRCValidationError) and isinstance(exc.record, DataEnd):
            self.problem("corrupt", offset, f"data section CRC mismatch at the data end record (byte {offset}): "
                                            f"stored {exc.expected:#010x}, computed {exc.actual:#010x}: the file "
                                            "is corrupt")
            return
        truncated = self._header_at(offset)
        if truncated:
            self.problem("truncated", offset, truncated)
        else:
            reason = str(exc) or type(exc).__name__
            self.problem("corrupt", offset, f"corrupt record ({opcode_name(self.data[offset])}) at byte {offset}: "
                                            f"{reason}")

    def _record(self, record: Any, start: int, end: int) -> None:
        if isinstance(record, Chunk):
            self._chunk(record, start)
        elif isinstance(record, Attachment):
            stored = int.from_bytes(self.data[end - 4 : end], "little")
            if self.validate and stored != 0:
                actual = zlib.crc32(memoryview(self.data)[start + 9 : end - 4])
                if stored != actual:
                    self.problem("corrupt", start, f"attachment {record.name!r} at byte {start} failed its CRC "
                                                   f"check (stored {stored:#010x}, computed {actual:#010x}): the "
                                                   "file is corrupt")
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
            if self.result.data_end:
                return  # summary section: repeated schemas and channels
            self._inner(record, start)
        # summary records (indexes, statistics) are rebuilt by a writer

    def _footer(self, footer: Footer, start: int) -> None:
        if not self.validate or footer.summary_crc == 0 or footer.summary_start == 0:
            return
        actual = zlib.crc32(memoryview(self.data)[footer.summary_start : start + 1 + 8 + 8 + 8])
        if actual != footer.summary_crc:
            self.problem("corrupt", footer.summary_start,
                         f"summary section CRC mismatch (summary at byte {footer.summary_start}: stored "
                         f"{footer.summary_crc:#010x}, computed {actual:#010x})")

    def _chunk(self, chunk: Chunk, start: int) -> None:
        declared = int(chunk.uncompressed_size)
        limit = min(MAX_CHUNK_BYTES, self.budget - self.decompressed)
        if declared > limit:
            what = (f"more than the {MAX_CHUNK_BYTES} allowed per chunk" if declared > MAX_CHUNK_BYTES else
                    f"more than the {limit} left of the file's budget ({MAX_EXPANSION} × the file size, at least "
                    f"{MIN_DECOMPRESSED_BUDGET}, at most {MAX_DECOMPRESSED_BYTES})")
            self.problem("too_large", start, f"chunk at byte {start} declares {declared} decompressed bytes, {what}: "
                                             "refused as a decompression bomb (or a corrupt file)")
            raise _Stop
        try:
            data = decompress_bounded(chunk, declared)
        except Exception as exc:
            self._bad_chunk(start, f"chunk at byte {start} failed its CRC check: its {chunk.compression or 'plain'} "
                                   f"data are corrupt ({exc or type(exc).__name__}), so no CRC can match")
            return
        if len(data) > declared:  # a bomb: stopped one byte past what it declares, its CRC never computed
            self.problem("too_large", start, f"chunk at byte {start} decompresses to more than {declared} bytes, not "
                                             f"the {declared} it declares: refused as a decompression bomb (stopped "
                                             f"after {len(data)} bytes; its CRC is not checked)")
            raise _Stop
        if len(data) < declared:
            self._bad_chunk(start, f"chunk at byte {start} decompresses to {len(data)} bytes, not the {declared} it "
                                   f"declares: its {chunk.compression or 'plain'} data are cut or corrupt")
            return
        self.decompressed += declared
        if self.validate and chunk.uncompressed_crc != 0:
            actual = zlib.crc32(data)
            if actual != chunk.uncompressed_crc:
                self._bad_chunk(start, f"chunk at byte {start} failed its CRC check (stored "
                                       f"{chunk.uncompressed_crc:#010x}, computed {actual:#010x}): the file is "
                                       "corrupt")
                return
        self.result.chunks += 1
        if IN_PLACE_CHUNKS:
            self._chunk_records(data, start)
        else:
            self._chunk_recordsstream_of(data, start)

    def _chunk_recordsstream_of(self, data: bytes, start: int) -> None:
        """The former chunk parser (a second ``StreamReader`` over the decompressed bytes, a record object per
        record), kept for ``benchmarks/bench_mission_overhead.py`` (:data:`IN_PLACE_CHUNKS` off)."""
        inner = io.BytesIO(data)
        records = _StreamReader(inner, skip_magic=True, record_size_limit=len(data)).records
        while inner.tell() < len(data):
            try:
                record = next(records)
            except StopIteration:
                break
            except Exception as exc:
                self._bad_chunk(start, f"chunk at byte {start} holds a corrupt record at its byte {inner.tell()}: "
                                       f"{exc or type(exc).__name__}")
                return
            if isinstance(record, (Schema, Channel, Message)):
                self._inner(record, start)
        if inner.tell() != len(data):
            self._bad_chunk(start, f"chunk at byte {start} ends inside a record: the file is corrupt")

    def _chunk_records(self, data: bytes, start: int) -> None:
        """Parse a decompressed chunk's records in place (struct unpacking of the record headers; a message's
        payload is sliced out only when its channel is wanted, a schema or channel parsed by the ``mcap`` package).

        Raises :class:`_Stop` (via :meth:`_bad_chunk`) at a record that runs past the chunk's end or is malformed."""
        header, message_header = _RECORD_HEADER.unpack_from, _MESSAGE_HEADER.unpack_from
        channels, per_channel, wanted = self.channels, self.per_channel, self.wanted_channels
        emit = self.sink
        pos, end = 0, len(data)
        while pos < end:
            if pos + 9 > end:
                self._bad_chunk(start, f"chunk at byte {start} ends inside a record: the file is corrupt")
                return
            opcode, length = header(data, pos)
            body, nxt = pos + 9, pos + 9 + length
            if nxt > end:
                self._bad_chunk(start, f"chunk at byte {start} ends inside a record: the file is corrupt")
                return
            if opcode == _OP_MESSAGE:
                if length < 22:
                    self._bad_chunk(start, f"chunk at byte {start} holds a corrupt record at its byte {pos}: "
                                           f"a message record of {length} bytes (at least 22)")
                    return
                channel_id, sequence, log_time, publish_time = message_header(data, body)
                count = per_channel.get(channel_id)
                if count is None:
                    self.problem("corrupt", start, f"message at byte {start} is on unknown channel id {channel_id}")
                    raise _Stop
                per_channel[channel_id] = count = count + 1
                self.result.messages += 1
                if count > MAX_MESSAGES_PER_TOPIC:
                    self._too_many_on(channels[channel_id], None, start)
                    raise _Stop
                if self.result.messages > MAX_MCAP_MESSAGES:
                    self._too_many_messages(start)
                    raise _Stop
                if emit is not None and (wanted is None or channel_id in wanted):
                    emit(Message(channel_id=channel_id, sequence=sequence, log_time=log_time,
                                 publish_time=publish_time, data=data[body + 22 : nxt]))
            elif opcode in (_OP_SCHEMA, _OP_CHANNEL):
                try:
                    stream = ReadDataStream(io.BytesIO(data[body:nxt]))
                    record = Schema.read(stream) if opcode == _OP_SCHEMA else Channel.read(stream)
                except Exception as exc:
                    self._bad_chunk(start, f"chunk at byte {start} holds a corrupt record at its byte {pos}: "
                                           f"{exc or type(exc).__name__}")
                    return
                self._inner(record, start)
            pos = nxt

    def _bad_chunk(self, start: int, message: str) -> None:
        self.problem("corrupt", start, message)
        if not self.keep_going:
            raise _Stop

    def _inner(self, record: Any, start: int) -> None:
        if isinstance(record, Message):
            topic = self.channels.get(record.channel_id)
            if topic is None:
                self.problem("corrupt", start, f"message at byte {start} is on unknown channel id {record.channel_id}")
                raise _Stop
            count = self.per_channel[record.channel_id] = self.per_channel[record.channel_id] + 1
            self.result.messages += 1
            if count > MAX_MESSAGES_PER_TOPIC:
                self._too_many_on(topic, None, start)
                raise _Stop
            if self.result.messages > MAX_MCAP_MESSAGES:
                self._too_many_messages(start)
                raise _Stop
            if self.wanted_channels is not None and record.channel_id not in self.wanted_channels:
                return
        elif isinstance(record, Schema):
            if record.id in self.schemas:
                return  # repeated
            if len(self.schemas) >= MAX_MCAP_CHANNELS:
                self.problem("too_large", start, f"the file holds more than {MAX_MCAP_CHANNELS} schemas, the most "
                                                 "oacli reads from one file (oacli.config.sizes.MAX_MCAP_CHANNELS)")
                raise _Stop
            self.schemas.add(record.id)
            self.result.schemas += 1
        elif isinstance(record, Channel):
            if record.id in self.channels:
                return
            if record.schema_id and record.schema_id not in self.schemas:
                self.problem("corrupt", start, f"channel {record.topic!r} at byte {start} refers to unknown schema "
                                               f"id {record.schema_id}")
                raise _Stop
            if len(self.channels) >= MAX_MCAP_CHANNELS:
                self.problem("too_large", start, f"the file holds more than {MAX_MCAP_CHANNELS} channels, the most "
                                                 "oacli reads from one file (oacli.config.sizes.MAX_MCAP_CHANNELS)")
                raise _Stop
            self.channels[record.id] = record.topic
            self.per_channel[record.id] = 0
            if self.wanted_channels is not None and self.topics is not None and record.topic in self.topics:
                self.wanted_channels.add(record.id)
            self.result.channels += 1
        elif isinstance(record, Metadata):
            self.result.metadata += 1
        self._emit(record)

    def _too_many_messages(self, start: int) -> None:
        self.problem("too_large", start, f"the file holds more than {MAX_MCAP_MESSAGES} messages, the most "
                                         "oacli reads from one file (oacli.config.sizes.MAX_MCAP_MESSAGES)")

    def _emit(self, record: Any) -> None:
        if self.sink is not None:
            self.sink(record)


__all__ = [
    "MAX_CHUNK_BYTES",
    "MAX_DECOMPRESSED_BYTES",
    "MAX_EXPANSION",
    "MIN_DECOMPRESSED_BUDGET",
    "McapWalk",
    "Problem",
    "ScanResult",
    "decompress_bounded",
    "decompressed_budget",
    "map_file",
    "open_regular",
    "read_file",
]
