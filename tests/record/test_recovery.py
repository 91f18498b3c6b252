"""read_log on killed, cut and damaged files: whole intact chunks come back, never wrong data."""

from __future__ import annotations

import io
import json
import os
import struct
import subprocess
import sys
import textwrap
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from mcap.data_stream import ReadDataStream
from mcap.reader import make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import breakup_chunk

import inhand_exp
from inhand_exp.record import LogError, RunLog, read_log

N_MESSAGES = 400


@dataclass
class ChunkInfo:
    start: int  # byte offset of the chunk record
    end: int  # byte offset just past it
    data_at: int  # byte offset of its (compressed) payload
    data_size: int
    ids: list[int]  # the "n" of every message inside, in order (the config has none)


@dataclass
class Written:
    path: Path
    data: bytes
    messages: list[dict[str, Any]]  # as they read back, in write order
    chunks: list[ChunkInfo]
    footer_at: int


def message(n: int) -> tuple[str, dict[str, Any]]:
    """Message number ``n``: mostly actions, every fifth a sim state; ``n`` is a unique id."""
    if n % 5 == 4:
        return "/sim/state", {"n": n, "episode": n // 50, "sim_time_s": n * 0.25,
                              "object_pose": [0.0, 0.125, n * 0.5], "joint_q": [0.5] * 9}
    return "/episode/action", {"n": n, "episode": n // 50, "step": n % 50, "action": n % 7,
                               "name": f"primitive_{n % 7}", "valid": n % 11 != 0,
                               "pose_before": [0.0, 0.125, n * 0.5],
                               "pose_after": [0.0, 0.125, n * 0.5 + 0.25]}


def chunk_layout(path: Path) -> list[ChunkInfo]:
    """Where each chunk lies and which messages it holds, from the file's own chunk index."""
    data = path.read_bytes()
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    chunks = []
    for index in summary.chunk_indexes:
        start = index.chunk_start_offset
        body = data[start + 9:start + index.chunk_length]
        chunk = Chunk.read(ReadDataStream(io.BytesIO(body)))
        decoded = [json.loads(r.data) for r in breakup_chunk(chunk) if isinstance(r, Message)]
        ids = [d["n"] for d in decoded if "n" in d]
        data_at = start + 9 + 8 + 8 + 8 + 4 + 4 + len(index.compression) + 8
        chunks.append(ChunkInfo(start, start + index.chunk_length, data_at,
                                index.compressed_size, ids))
    return chunks


def write_log(path: Path, compression: str = "zstd", n: int = N_MESSAGES) -> Written:
    messages = []
    with RunLog(path, chunk_size=2048, compression=compression) as log:
        log.write("/run/config", {"config": {}, "versions": {}, "seed": 0})
        for i in range(n):
            topic, msg = message(i)
            log.write(topic, msg)
            messages.append(msg)
    data = path.read_bytes()
    chunks = chunk_layout(path)
    assert [i for c in chunks for i in c.ids] == list(range(n))
    assert len(chunks) >= 10
    return Written(path, data, messages, chunks, footer_at=len(data) - 8 - 29)


@pytest.fixture(scope="module")
def zstd_log(tmp_path_factory: pytest.TempPathFactory) -> Written:
    return write_log(tmp_path_factory.mktemp("zstd") / "run.mcap")


@pytest.fixture(scope="module")
def plain_log(tmp_path_factory: pytest.TempPathFactory) -> Written:
    return write_log(tmp_path_factory.mktemp("none") / "run.mcap", compression="none")


def ids(log: Any) -> list[int]:
    return [m.data["n"] for m in log.messages if "n" in m.data]


def damaged_copy(written: Written, tmp_path: Path, edits: dict[int, bytes]) -> Path:
    data = bytearray(written.data)
    for at, new in edits.items():
        data[at:at + len(new)] = new
    path = tmp_path / "damaged.mcap"
    path.write_bytes(bytes(data))
    return path


def flipped(written: Written, at: int) -> dict[int, bytes]:
    return {at: bytes([written.data[at] ^ 0xFF])}


def assert_only_written_data(log: Any, written: Written) -> None:
    """Every message read back equals one that was written, in write order."""
    remaining = iter(written.messages)
    for m in log.messages:
        if "n" in m.data:
            assert any(m.data == w for w in remaining), f"wrong or reordered message {m.data}"


# --- cut files (writer killed) -------------------------------------------------------------


def cut_offsets(w: Written) -> list[int]:
    third, last = w.chunks[3], w.chunks[-1]
    named = [0, 5, 8, 13, w.chunks[0].start + 20, third.start + (third.end - third.start) // 2,
             third.end, third.end - 1, last.end, w.footer_at - 1, w.footer_at, len(w.data) - 1]
    spaced = [len(w.data) * k // 11 for k in range(1, 11)]
    return sorted(set(named + spaced))


@pytest.mark.parametrize("fixture", ["zstd_log", "plain_log"])
def test_cut_file_returns_exactly_the_completed_chunks(
    fixture: str, request: pytest.FixtureRequest, tmp_path: Path
) -> None:
    w: Written = request.getfixturevalue(fixture)
    non_empty = 0
    for cut in cut_offsets(w):
        path = tmp_path / f"cut_{cut}.mcap"
        path.write_bytes(w.data[:cut])
        log = read_log(path)
        expected = [i for c in w.chunks if c.end <= cut for i in c.ids]
        assert ids(log) == expected, f"cut at byte {cut}"
        assert log.truncated, f"cut at byte {cut}"
        assert log.corrupt_chunks == 0, f"cut at byte {cut}: {log.problems}"
        assert any(str(cut) in p for p in log.problems), log.problems
        non_empty += bool(expected)
        path.unlink()
    assert non_empty >= 5


def test_sigkilled_writer_leaves_a_gap_free_prefix(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    script = textwrap.dedent("""
        import sys, time
        from inhand_exp.record import RunLog
        log = RunLog(sys.argv[1], chunk_size=1024, flush_every_s=0.05)
        step = 0
        while True:
            log.write("/episode/action", {"episode": 0, "step": step, "action": 1,
                                          "valid": True, "pose_before": [0.0, 0.1, 0.0],
                                          "pose_after": [0.0, 0.1, 0.5]})
            step += 1
            if step == 100:
                print("writing", flush=True)
            time.sleep(0.0002)
    """)
    src = str(Path(inhand_exp.__file__).resolve().parents[1])
    paths = [src, *filter(None, [os.environ.get("PYTHONPATH")])]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(paths)}
    proc = subprocess.Popen([sys.executable, "-c", script, str(path)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env)
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        assert line == "writing\n", proc.stderr.read() if proc.stderr else line
        time.sleep(1.0)
        proc.kill()  # SIGKILL on POSIX: no finally blocks, no close(), no footer
    finally:
        proc.kill()
        proc.wait(timeout=10)
    assert proc.returncode == -9 or sys.platform == "win32"
    log = read_log(path)
    steps = [m.data["step"] for m in log.messages]
    assert len(steps) >= 100
    assert steps == list(range(len(steps)))
    assert log.truncated and log.corrupt_chunks == 0


# --- damaged bytes -------------------------------------------------------------------------


@pytest.mark.parametrize("fixture", ["zstd_log", "plain_log"])
def test_flipped_byte_in_a_chunk_drops_only_that_chunk(
    fixture: str, request: pytest.FixtureRequest, tmp_path: Path
) -> None:
    w: Written = request.getfixturevalue(fixture)
    victim = w.chunks[len(w.chunks) // 2]
    path = damaged_copy(w, tmp_path, flipped(w, victim.data_at + victim.data_size // 2))
    log = read_log(path)
    assert ids(log) == [i for i in range(N_MESSAGES) if i not in victim.ids]
    assert_only_written_data(log, w)
    assert log.corrupt_chunks == 1 and not log.truncated
    assert any(f"chunk at byte {victim.start}" in p for p in log.problems), log.problems


@pytest.mark.parametrize("fixture", ["zstd_log", "plain_log"])
def test_damaged_first_chunk_keeps_topics_from_the_summary(
    fixture: str, request: pytest.FixtureRequest, tmp_path: Path
) -> None:
    """The first chunk also holds the schema and channel records; the summary repeats them."""
    w: Written = request.getfixturevalue(fixture)
    first = w.chunks[0]
    log = read_log(damaged_copy(w, tmp_path, flipped(w, first.data_at + first.data_size // 2)))
    assert ids(log) == [i for c in w.chunks[1:] for i in c.ids]
    assert {m.topic for m in log.messages} == {"/episode/action", "/sim/state"}
    assert log.corrupt_chunks == 1 and not log.truncated


@pytest.mark.parametrize("truncate", [False, True])
def test_damaged_length_field_resyncs_at_the_next_chunk(
    zstd_log: Written, tmp_path: Path, truncate: bool
) -> None:
    """A length of 2**62 must neither allocate nor lose the chunks after it."""
    w = zstd_log
    victim = w.chunks[4]
    path = damaged_copy(w, tmp_path, {victim.start + 1: struct.pack("<Q", 2**62)})
    if truncate:  # and the writer was killed: no footer to help
        path.write_bytes(path.read_bytes()[:w.chunks[-2].end])
    log = read_log(path)
    kept = w.chunks[1:-1] if truncate else w.chunks[1:]
    assert ids(log) == [i for c in kept if c is not victim for i in c.ids]
    assert log.corrupt_chunks == 1 and log.truncated == truncate
    assert any(f"byte {victim.start}" in p for p in log.problems), log.problems


@pytest.mark.parametrize("truncate", [False, True])
def test_damaged_header_length_goes_back_to_the_first_chunk(
    zstd_log: Written, tmp_path: Path, truncate: bool
) -> None:
    """A plausible but wrong length in an unchecked record jumps mid-file; nothing is lost."""
    w = zstd_log
    wrong = w.chunks[5].start + 40 - 8 - 9  # from the header at byte 8 into chunk 5's payload
    path = damaged_copy(w, tmp_path, {9: struct.pack("<Q", wrong)})
    if truncate:
        path.write_bytes(path.read_bytes()[:w.chunks[-1].end])
    log = read_log(path)
    assert ids(log) == list(range(N_MESSAGES))
    assert log.topic("/run/config") == [{"config": {}, "versions": {}, "seed": 0}]
    assert log.corrupt_chunks == 0 and log.truncated == truncate
    assert any("went back" in p for p in log.problems), log.problems


def test_damaged_opcode_resyncs_at_the_next_chunk(zstd_log: Written, tmp_path: Path) -> None:
    w = zstd_log
    victim = w.chunks[2]
    log = read_log(damaged_copy(w, tmp_path, {victim.start: b"\x66"}))
    assert ids(log) == [i for c in w.chunks[1:] if c is not victim for i in c.ids]
    assert log.corrupt_chunks == 1


def test_huge_uncompressed_size_is_refused_not_allocated(
    zstd_log: Written, tmp_path: Path
) -> None:
    w = zstd_log
    victim = w.chunks[3]
    size_at = victim.start + 9 + 16  # after the two time stamps
    log = read_log(damaged_copy(w, tmp_path, {size_at: struct.pack("<Q", 2**50)}))
    assert ids(log) == [i for c in w.chunks[1:] if c is not victim for i in c.ids]
    assert log.corrupt_chunks == 1


@pytest.mark.parametrize("fixture", ["zstd_log", "plain_log"])
def test_any_single_flipped_byte_never_yields_wrong_data(
    fixture: str, request: pytest.FixtureRequest, tmp_path: Path
) -> None:
    w: Written = request.getfixturevalue(fixture)
    for at in range(8, len(w.data), len(w.data) // 97):  # skip the leading magic
        log = read_log(damaged_copy(w, tmp_path, flipped(w, at)))
        assert_only_written_data(log, w)
        assert log.corrupt_chunks <= 1, (at, log.problems)
        lost = set(range(N_MESSAGES)) - set(ids(log))
        hit = [c for c in w.chunks if c.start <= at < c.end]
        assert lost <= set(hit[0].ids if hit else ()), f"flip at byte {at} lost {sorted(lost)}"
        assert not lost or (log.corrupt_chunks == 1 and log.problems), (at, log.problems)


# --- not a log -----------------------------------------------------------------------------


@pytest.mark.parametrize("content", [b"", b"\x89MCAP"])
def test_cut_inside_the_magic_is_an_empty_truncated_log(tmp_path: Path, content: bytes) -> None:
    path = tmp_path / "run.mcap"
    path.write_bytes(content)
    log = read_log(path)
    assert (log.messages, log.truncated, log.corrupt_chunks) == ([], True, 0)
    assert log.problems


@pytest.mark.parametrize("content", [b"abc", b"time,value\n0.0,1.0\n" * 10, b"\x89MCAP1\r\n" * 4])
def test_not_mcap_raises_log_error_naming_the_file(tmp_path: Path, content: bytes) -> None:
    path = tmp_path / "results.csv"
    path.write_bytes(content)
    with pytest.raises(LogError, match="results.csv"):
        read_log(path)


def test_missing_file_raises_file_not_found_naming_it(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="nothing_here.mcap"):
        read_log(tmp_path / "nothing_here.mcap")
