"""RunLog: a run's MCAP log of JSON messages, one JSON-Schema channel per topic."""

from __future__ import annotations

import errno
import json
import math
import operator
import os
import time
from collections.abc import Mapping
from pathlib import Path
from types import TracebackType
from typing import Any, Self

from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import LIBRARY_IDENTIFIER, CompressionType, Writer

from inhand_exp import __version__
from inhand_exp.record.schemas import TOPIC_SCHEMAS, check_required

COMPRESSIONS = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
                "none": CompressionType.NONE}
LIBRARY = f"inhand_exp/{__version__}; {LIBRARY_IDENTIFIER}"
_MAX_DEPTH = 64
_UINT32 = 2**32
_UINT64 = 2**64


def _json_default(obj: Any) -> Any:
    """json.dumps hook: numpy (and torch) scalars and arrays via ``tolist()``, paths as str."""
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    tolist = getattr(obj, "tolist", None)
    if callable(tolist):
        return tolist()
    raise TypeError(f"cannot log a value of type {type(obj).__name__} as JSON")


def _finite(obj: Any, depth: int = 0) -> Any:
    """``obj`` as plain JSON data with every NaN / +-inf float replaced by None."""
    if depth > _MAX_DEPTH:
        raise ValueError(f"message nested deeper than {_MAX_DEPTH} levels (or circular)")
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, str | int | bool) or obj is None:
        return obj
    if isinstance(obj, Mapping):
        return {key: _finite(value, depth + 1) for key, value in obj.items()}
    if isinstance(obj, list | tuple):
        return [_finite(value, depth + 1) for value in obj]
    return _finite(_json_default(obj), depth + 1)


def encode_message(message: Mapping[str, Any]) -> bytes:
    """Compact UTF-8 JSON of ``message``; numpy values become numbers/lists, NaN/inf null."""
    try:
        text = json.dumps(message, default=_json_default, allow_nan=False, separators=(",", ":"))
    except ValueError:  # a non-finite float somewhere: rare, so only then walk the message
        text = json.dumps(_finite(message), allow_nan=False, separators=(",", ":"))
    return text.encode()


class RunLog:
    """Append-only log of one run: ``with RunLog(run_dir / "run.mcap") as log: log.write(...)``.

    Every topic of :data:`TOPIC_SCHEMAS` gets a schema (encoding ``jsonschema``) and a channel
    (encoding ``json``) up front. Messages go into compressed chunks of about ``chunk_size``
    bytes (uncompressed); a chunk is also cut, and everything handed to the OS, on the first
    write more than ``flush_every_s`` seconds (wall time) after the last flush, so a killed run
    loses only what was written since then. ``close()`` writes the summary and footer.
    Not thread-safe: write from one thread.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        chunk_size: int = 32 * 1024,
        flush_every_s: float = 2.0,
        compression: str = "zstd",
    ) -> None:
        if chunk_size <= 0:
            raise ValueError(f"chunk_size must be > 0 bytes, got {chunk_size}")
        if not flush_every_s >= 0:
            raise ValueError(f"flush_every_s must be >= 0 s, got {flush_every_s}")
        if compression not in COMPRESSIONS:
            raise ValueError(f"compression must be one of {', '.join(COMPRESSIONS)}, "
                             f"got {compression!r}")
        self.path = Path(path)
        self.flush_every_s = float(flush_every_s)
        self._closed = True
        try:
            self._file = open(self.path, "xb")  # noqa: SIM115 - closed in close()
        except FileExistsError:
            raise FileExistsError(errno.EEXIST, "run log already exists, refusing to overwrite",
                                  str(self.path)) from None
        try:
            self._writer = Writer(self._file, chunk_size=chunk_size,
                                  compression=COMPRESSIONS[compression])
            self._writer.start(profile="", library=LIBRARY)
            self._channels: dict[str, int] = {}
            for topic, schema in TOPIC_SCHEMAS.items():
                schema_id = self._writer.register_schema(
                    name=schema["title"],
                    encoding=SchemaEncoding.JSONSchema,
                    data=json.dumps(schema, separators=(",", ":")).encode(),
                )
                self._channels[topic] = self._writer.register_channel(
                    topic=topic, message_encoding=MessageEncoding.JSON, schema_id=schema_id
                )
            self._sequence = dict.fromkeys(self._channels, 0)
            self._writer.flush()  # magic and header on disk: even an empty run reads back
        except BaseException:
            self._file.close()
            self.path.unlink(missing_ok=True)
            raise
        self._last_flush = time.monotonic()
        self._closed = False

    @property
    def closed(self) -> bool:
        return self._closed

    def write(
        self, topic: str, message: Mapping[str, Any], log_time_ns: int | None = None
    ) -> None:
        """Append ``message`` to ``topic``; ``log_time_ns`` defaults to now (ns since the epoch).

        Raises ValueError for an unknown topic or a missing required key, TypeError for a value
        JSON cannot hold; nothing is written then.
        """
        if self._closed:
            raise ValueError(f"run log {self.path} is closed")
        check_required(topic, message)
        try:
            data = encode_message(message)
        except (TypeError, ValueError) as err:
            raise type(err)(f"{topic} message: {err}") from err
        log_time = time.time_ns() if log_time_ns is None else operator.index(log_time_ns)
        if not 0 <= log_time < _UINT64:
            raise ValueError(f"log_time_ns must be in [0, 2**64), got {log_time}")
        sequence = self._sequence[topic]
        self._sequence[topic] = (sequence + 1) % _UINT32
        self._writer.add_message(channel_id=self._channels[topic], log_time=log_time,
                                 data=data, publish_time=log_time, sequence=sequence)
        if time.monotonic() - self._last_flush >= self.flush_every_s:
            self.flush()

    def flush(self) -> None:
        """Cut the current chunk and hand everything written so far to the OS (no fsync)."""
        if self._closed:
            return
        self._writer.flush()
        self._last_flush = time.monotonic()

    def close(self) -> None:
        """Write the summary and footer, fsync and close the file; later calls do nothing."""
        if self._closed:
            return
        self._closed = True
        try:
            self._writer.finish()
            self._file.flush()
            os.fsync(self._file.fileno())
        finally:
            self._file.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def __repr__(self) -> str:
        state = "closed" if self._closed else "open"
        return f"RunLog({str(self.path)!r}, {state})"
