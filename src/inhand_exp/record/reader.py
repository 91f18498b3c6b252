"""Read a run log back: every CRC-checked chunk of a complete, killed or damaged MCAP file."""

from __future__ import annotations

import errno
import io
import json
import os
import struct
import zlib
from collections import Counter
from collections.abc import Callable, Collection
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import lz4.frame
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.decoder import DecoderFactory
from mcap.exceptions import EndOfFile, McapError
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, ChunkIndex, Footer, McapRecord, Message, Schema
from mcap.stream_reader import CRCValidationError, breakup_chunk
from mcap.well_known import MessageEncoding
from mcap.writer import MCAP0_MAGIC

from inhand_exp.record.schemas import TOPIC_SCHEMAS

DEFAULT_RECORD_SIZE_LIMIT = 1 << 30  # bytes; no record or uncompressed chunk may claim more
_HEADER = struct.Struct("<BQ")  # record opcode and body length
_FOOTER_SIZE = _HEADER.size + 20  # footer record: summary_start, summary_offset_start, crc
_KNOWN_OPCODES = frozenset(int(op) for op in Opcode)
_CHUNK_OPCODE = bytes([Opcode.CHUNK])
# Everything that damaged or cut bytes can make parsing raise; never shown to the caller.
_DECODE_ERRORS = (McapError, ValueError, struct.error, zstandard.ZstdError, RuntimeError,
                  OverflowError, IndexError, MemoryError)


class LogError(Exception):
    """The file is not an MCAP run log at all."""


@dataclass(slots=True)
class LogMessage:
    """One message: its topic, log time (ns since the epoch), decoded data and sequence number."""

    topic: str
    log_time_ns: int
    data: dict[str, Any]
    sequence: int = 0


@dataclass
class Log:
    """What could be read from a run log, and what was wrong with it.

    ``messages`` are in file (= write) order. ``truncated``: the file has no footer, i.e. the
    writer never closed it (killed, crashed, still running). ``corrupt_chunks``: chunks whose
    bytes were damaged (CRC mismatch, undecodable, unframeable), so their messages were left
    out. ``problems``: one human-readable line per thing found wrong, with its byte offset.
    """

    path: Path
    messages: list[LogMessage] = field(default_factory=list)
    truncated: bool = False
    corrupt_chunks: int = 0
    problems: list[str] = field(default_factory=list)
    topics: frozenset[str] | None = None  # the topics read (None: all of them)

    def topic(self, name: str) -> list[dict[str, Any]]:
        """The data of every message on topic ``name``, in order (KeyError for a typo, or for
        a topic this read left out)."""
        if self.topics is not None and name not in self.topics:
            raise KeyError(f"{self.path} was read for topics {', '.join(sorted(self.topics))} "
                           f"only; read it with topics including {name!r}")
        found = [m.data for m in self.messages if m.topic == name]
        if not found and name not in TOPIC_SCHEMAS:
            topics = sorted(set(TOPIC_SCHEMAS) | {m.topic for m in self.messages})
            raise KeyError(f"no topic {name!r} in {self.path}; known topics: {', '.join(topics)}")
        return found


class JsonDecoderFactory(DecoderFactory):
    """Decoder for ``mcap.reader.make_reader``: messages with encoding ``json`` become dicts."""

    def decoder_for(
        self, message_encoding: str, schema: Schema | None
    ) -> Callable[[bytes], Any] | None:
        if message_encoding != MessageEncoding.JSON:
            return None
        return json.loads


class _StrictStream(ReadDataStream):
    """A ReadDataStream that raises EndOfFile on a short read instead of returning less."""

    def read(self, length: int) -> bytes:
        data = super().read(length)
        if len(data) != length:
            raise EndOfFile()
        return data


def _why(err: BaseException) -> str:
    return str(err) or type(err).__name__


def _parse(reader: Callable[[ReadDataStream], McapRecord], body: bytes) -> McapRecord:
    return reader(_StrictStream(io.BytesIO(body)))


def read_log(
    path: str | os.PathLike[str], *, topics: Collection[str] | None = None,
    record_size_limit: int = DEFAULT_RECORD_SIZE_LIMIT
) -> Log:
    """Read every intact message of the run log at ``path`` (of ``topics`` only, when given:
    the others are not decoded, which saves most of the time on an evaluation's log of
    ``/sim/state``).

    A file without footer (writer killed) gives the messages of every chunk completed before
    the cut, ``truncated=True``. A chunk with damaged bytes is left out and counted; reading
    goes on with the next intact chunk. Raises FileNotFoundError for a missing file and
    LogError for a file that is not MCAP; errors of the MCAP and decompression libraries never
    reach the caller. No record may claim more than ``record_size_limit`` bytes.
    """
    path = Path(path)
    try:
        with open(path, "rb") as f:
            data = f.read()
    except FileNotFoundError:
        raise FileNotFoundError(errno.ENOENT, "no such run log", str(path)) from None
    return _Reader(path, data, record_size_limit,
                   None if topics is None else frozenset(topics)).read()


class _Reader:
    """One pass over one file's bytes: data section in order, summary only as a fallback."""

    def __init__(self, path: Path, buf: bytes, record_size_limit: int,
                 topics: frozenset[str] | None = None) -> None:
        self.path = path
        self.buf = buf
        self.limit = record_size_limit
        self.log = Log(path, topics=topics)
        self.channels: dict[int, Channel] = {}
        self.raw: list[Message] = []
        self.good_chunks: dict[int, int] = {}  # offset -> body bytes used, chunks kept
        self.bad_chunks: set[int] = set()  # offsets of chunk records found damaged
        self.top_level_seen: set[int] = set()  # offsets of records outside chunks, read once
        self.lost_regions = 0  # stretches of broken framing skipped to the next good chunk
        self.unverified_chunks = 0

    def problem(self, text: str) -> None:
        self.log.problems.append(text)

    # --- top level ----------------------------------------------------------------------

    def read(self) -> Log:
        buf, log = self.buf, self.log
        if not buf.startswith(MCAP0_MAGIC):
            if MCAP0_MAGIC.startswith(buf):  # empty, or cut inside the magic
                log.truncated = True
                self.problem(f"file ends at byte {len(buf)}, before any record: the writer "
                             "stopped before writing the header")
                return log
            raise LogError(f"{self.path} is not an MCAP file (starts with {buf[:8]!r})")
        footer_at, footer = self.find_footer()
        log.truncated = footer is None
        if footer is None:
            self.problem(f"file ends at byte {len(buf)} without a footer: the log was not "
                         "closed (writer killed, crashed or still running)")
        summary_ok = footer is not None and self.summary_intact(footer_at, footer)
        # The data section ends at its DATA_END record, before the summary and the footer.
        self.scan(len(MCAP0_MAGIC), footer_at if footer is not None else len(buf),
                  complete=footer is not None)
        chunk_offsets: set[int] | None = None
        if summary_ok and footer is not None and footer.summary_start:
            chunk_offsets = self.read_summary(footer_at, footer)
        if chunk_offsets is not None:  # exact: every indexed chunk not read back is corrupt
            missing = chunk_offsets - self.good_chunks.keys()
            log.corrupt_chunks = len(missing)
            unnoticed = sorted(missing - self.bad_chunks)
            if unnoticed:
                self.problem(f"{len(unnoticed)} chunk(s) the summary lists were not found intact "
                             f"(at byte {', '.join(map(str, unnoticed))}); their messages "
                             "were dropped")
        else:
            log.corrupt_chunks = len(self.bad_chunks) + self.lost_regions
        if self.unverified_chunks:
            self.problem(f"{self.unverified_chunks} chunk(s) carry no CRC: their messages "
                         "could not be verified")
        self.decode()
        return log

    def find_footer(self) -> tuple[int, Footer | None]:
        """Offset and record of a footer + closing magic at the end of the file, if any."""
        buf = self.buf
        at = len(buf) - len(MCAP0_MAGIC) - _FOOTER_SIZE
        if at < len(MCAP0_MAGIC) or not buf.endswith(MCAP0_MAGIC):
            return at, None
        opcode, length = _HEADER.unpack_from(buf, at)
        if opcode != Opcode.FOOTER or length != _FOOTER_SIZE - _HEADER.size:
            return at, None
        return at, Footer.read(ReadDataStream(io.BytesIO(buf[at + _HEADER.size:])))

    def summary_intact(self, footer_at: int, footer: Footer) -> bool:
        """Whether the footer's pointers and the summary section pass the footer's CRC."""
        start = footer.summary_start or footer_at
        if not len(MCAP0_MAGIC) <= start <= footer_at or footer.summary_offset_start > footer_at:
            self.problem(f"footer at byte {footer_at} is damaged (points outside the file); "
                         "ignored the summary")
            return False
        if footer.summary_crc == 0:  # written without CRCs: pointers are plausible, use them
            return True
        crc = zlib.crc32(self.buf[start:footer_at + _HEADER.size + 16])
        if crc != footer.summary_crc:
            self.problem(f"summary section (bytes {start} to {footer_at + _FOOTER_SIZE}) is "
                         "damaged (CRC mismatch); ignored it")
            return False
        return True

    def scan(self, pos: int, end: int, *, complete: bool) -> None:
        """Process records in ``[pos, end)``; past broken framing, resume at the next chunk.

        Only CRC-checked chunks vouch for the framing: after a damaged record, the search for
        the next intact chunk starts where the last intact chunk ended, as the length of any
        record since then may have sent the scan astray.
        """
        buf = self.buf
        trusted = pos  # end of the last intact chunk
        while pos < end:
            reason, cut = self.framing_problem(pos, end)
            if reason is not None:
                found = self.next_chunk(trusted, end)
                if found is None:
                    self.stop(pos, end, reason, complete=complete, cut=cut)
                    return
                if found > pos:
                    self.lost_regions += 1
                    self.problem(f"byte {pos}: {reason}; skipped {found - pos} bytes to the "
                                 f"next intact chunk at byte {found}")
                else:
                    self.problem(f"byte {pos}: {reason}; went back to the intact chunk at "
                                 f"byte {found}")
                pos = found
                continue
            opcode, length = _HEADER.unpack_from(buf, pos)
            body_at = pos + _HEADER.size
            body, next_at = buf[body_at:body_at + length], body_at + length
            if opcode == Opcode.CHUNK:
                used = self.chunk(pos, body)
                if isinstance(used, str):
                    self.bad_chunks.add(pos)
                    self.problem(f"chunk at byte {pos}: {used}; its messages were dropped")
                    found = self.next_chunk(trusted, end)  # its length may be damaged too
                    if found is None:
                        return
                    next_at = found
                else:
                    trusted = body_at + used
            elif opcode == Opcode.DATA_END:
                return
            elif opcode == Opcode.FOOTER:
                self.problem(f"byte {pos}: footer inside the data section; stopped there")
                return
            elif opcode in (Opcode.CHANNEL, Opcode.MESSAGE):
                self.top_level(pos, opcode, body)
            pos = next_at

    def framing_problem(self, pos: int, end: int) -> tuple[str | None, bool]:
        """Why the record at ``pos`` cannot be framed (None if it can); True if cut by ``end``."""
        if end - pos < _HEADER.size:
            return f"only {end - pos} bytes of a record header", True
        opcode, length = _HEADER.unpack_from(self.buf, pos)
        if opcode not in _KNOWN_OPCODES:
            return f"unknown record type (opcode {opcode:#04x})", False
        name = Opcode(opcode).name
        if length > self.limit:
            return f"{name} record claims {length} bytes (limit {self.limit})", False
        left = end - pos - _HEADER.size
        if length > left:
            return f"{name} record needs {length} bytes, only {left} are left", True
        return None, False

    def stop(self, pos: int, end: int, reason: str, *, complete: bool, cut: bool) -> None:
        """Note why reading the data section ended at ``pos``, before ``end``."""
        if not complete and cut:
            self.problem(f"file ends mid-record at byte {end}: {reason} (record at byte {pos})")
        elif not complete:
            self.problem(f"byte {pos}: {reason}; no intact chunk follows up to the end of the "
                         f"file at byte {end}")
        else:
            self.lost_regions += 1
            self.problem(f"byte {pos}: {reason}; no intact chunk follows, skipped {end - pos} "
                         f"bytes up to the end of the data section at byte {end}")

    def next_chunk(self, start: int, end: int) -> int | None:
        """Offset of the first chunk record in ``[start, end)`` that parses and passes its CRC."""
        buf = self.buf
        at = buf.find(_CHUNK_OPCODE, start, end)
        while at != -1:
            reason, _ = self.framing_problem(at, end)
            if reason is None:
                length = _HEADER.unpack_from(buf, at)[1]
                body = buf[at + _HEADER.size:at + _HEADER.size + length]
                if not isinstance(self.unpack_chunk(body, require_crc=True), str):
                    return at
            at = buf.find(_CHUNK_OPCODE, at + 1, end)
        return None

    # --- records --------------------------------------------------------------------------

    def chunk(self, pos: int, body: bytes) -> int | str:
        """Keep the records of the chunk at ``pos`` and return the body bytes it used, or
        return what was wrong with it."""
        if pos in self.good_chunks:  # never keep a chunk's messages twice
            return self.good_chunks[pos]
        unpacked = self.unpack_chunk(body, require_crc=False)
        if isinstance(unpacked, str):
            return unpacked
        records, verified, used = unpacked
        self.unverified_chunks += not verified
        self.good_chunks[pos] = used
        for record in records:
            if isinstance(record, Message):
                self.raw.append(record)
            elif isinstance(record, Channel):
                self.channels.setdefault(record.id, record)
        return used

    def unpack_chunk(
        self, body: bytes, *, require_crc: bool
    ) -> tuple[list[Any], bool, int] | str:
        """(records, CRC-checked, body bytes used) of a chunk record, or why it is unreadable."""
        try:
            chunk = _parse(Chunk.read, body)
        except _DECODE_ERRORS as err:
            return f"unreadable chunk header ({_why(err)})"
        used = 8 + 8 + 8 + 4 + 4 + len(chunk.compression.encode()) + 8 + len(chunk.data)
        if chunk.uncompressed_size > self.limit:
            return f"claims {chunk.uncompressed_size} bytes uncompressed (limit {self.limit})"
        verified = chunk.uncompressed_crc != 0
        if require_crc and not verified:
            return "no CRC"
        kind = chunk.compression or "uncompressed"
        try:
            if chunk.compression == "zstd":
                declared = zstandard.frame_content_size(chunk.data)
                if declared not in (-1, chunk.uncompressed_size):
                    return (f"zstd frame holds {declared} bytes, chunk header says "
                            f"{chunk.uncompressed_size}")
            elif chunk.compression == "lz4":
                chunk = self.inflate_lz4(chunk)
            elif chunk.compression != "":
                return f"unknown compression {chunk.compression!r}"
            elif len(chunk.data) != chunk.uncompressed_size:
                return (f"holds {len(chunk.data)} bytes, chunk header says "
                        f"{chunk.uncompressed_size}")
            records: list[Any] = breakup_chunk(chunk, validate_crc=True)
        except CRCValidationError as err:
            return f"CRC mismatch (expected {err.expected:#010x}, computed {err.actual:#010x})"
        except _DECODE_ERRORS as err:
            return f"cannot decode {kind} data ({_why(err)})"
        return records, verified, used

    @staticmethod
    def inflate_lz4(chunk: Chunk) -> Chunk:
        """The chunk with its lz4 data decompressed, never inflating past the declared size."""
        decompressor = lz4.frame.LZ4FrameDecompressor()
        data = decompressor.decompress(chunk.data, max_length=chunk.uncompressed_size)
        if not decompressor.eof or len(data) != chunk.uncompressed_size:
            raise ValueError(f"lz4 data does not hold the declared {chunk.uncompressed_size} bytes")
        return Chunk(compression="", data=data, message_end_time=chunk.message_end_time,
                     message_start_time=chunk.message_start_time,
                     uncompressed_crc=chunk.uncompressed_crc,
                     uncompressed_size=chunk.uncompressed_size)

    def top_level(self, pos: int, opcode: int, body: bytes) -> None:
        """A channel or message outside any chunk (RunLog never writes these)."""
        if pos in self.top_level_seen:
            return
        self.top_level_seen.add(pos)
        try:
            if opcode == Opcode.CHANNEL:
                channel = _parse(Channel.read, body)
                self.channels.setdefault(channel.id, channel)
            else:
                self.raw.append(_parse(lambda s: Message.read(s, len(body)), body))
        except _DECODE_ERRORS as err:
            self.problem(f"byte {pos}: unreadable {Opcode(opcode).name} record "
                         f"({_why(err)}); skipped")

    def read_summary(self, footer_at: int, footer: Footer) -> set[int] | None:
        """Take channels the data section lacked (first chunk damaged) from the summary.

        Returns the offsets of all chunks the summary indexes, or None if it cannot be parsed.
        """
        buf = self.buf
        end = footer.summary_offset_start or footer_at
        offsets: set[int] = set()
        pos = footer.summary_start
        while pos + _HEADER.size <= end:
            opcode, length = _HEADER.unpack_from(buf, pos)
            body = buf[pos + _HEADER.size:pos + _HEADER.size + length]
            try:
                if opcode == Opcode.CHANNEL:
                    channel = _parse(Channel.read, body)
                    self.channels.setdefault(channel.id, channel)
                elif opcode == Opcode.CHUNK_INDEX:
                    offsets.add(_parse(ChunkIndex.read, body).chunk_start_offset)
            except _DECODE_ERRORS as err:
                self.problem(f"byte {pos}: unreadable summary record ({_why(err)}); "
                             "ignored the rest")
                return None
            pos += _HEADER.size + length
        return offsets or None  # no chunk index: count damaged chunks as found

    def decode(self) -> None:
        """Turn the kept raw messages into LogMessages; count what cannot be decoded."""
        dropped: Counter[str] = Counter()
        messages, wanted = self.log.messages, self.log.topics
        for raw in self.raw:
            channel = self.channels.get(raw.channel_id)
            if channel is None:
                dropped[f"channel id {raw.channel_id} has no channel record"] += 1
                continue
            if wanted is not None and channel.topic not in wanted:
                continue
            if channel.message_encoding != MessageEncoding.JSON:
                dropped[f"{channel.topic}: message encoding {channel.message_encoding!r}"] += 1
                continue
            try:
                data = json.loads(raw.data)
            except (ValueError, RecursionError):
                dropped[f"{channel.topic}: invalid JSON"] += 1
                continue
            if not isinstance(data, dict):
                dropped[f"{channel.topic}: JSON is not an object"] += 1
                continue
            messages.append(LogMessage(channel.topic, raw.log_time, data, raw.sequence))
        for reason, count in dropped.items():
            self.problem(f"dropped {count} message(s): {reason}")
