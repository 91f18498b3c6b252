"""RunLog then read_log (and the plain mcap reader) give back exactly what was written."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader

from inhand_exp.record import (
    TOPIC_SCHEMAS,
    JsonDecoderFactory,
    LogMessage,
    RunLog,
    read_log,
)

NAN, INF = float("nan"), float("inf")
Written = list[tuple[str, dict[str, Any], dict[str, Any]]]


def sample_messages() -> Written:
    """(topic, message as written, message as it must read back), several on every topic."""
    out: Written = [(
        "/run/config",
        {"config": {"seed": 7, "sim": {"dt_s": 0.001}}, "versions": {"mcap": "1.6.0"},
         "seed": np.int64(7), "mode": "train", "overrides": ("seed=7",), "git": None},
        {"config": {"seed": 7, "sim": {"dt_s": 0.001}}, "versions": {"mcap": "1.6.0"},
         "seed": 7, "mode": "train", "overrides": ["seed=7"], "git": None},
    )]
    for it in range(3):
        out.append((
            "/train/iteration",
            {"iteration": it, "frames": np.int64(1024 * (it + 1)), "wall_s": np.float64(1.5 * it),
             "losses": {"actor": np.float32(0.25), "critic": NAN}, "mean_return": -INF,
             "success_rate": np.float32(0.5), "drop_rate": 0.0},
            {"iteration": it, "frames": 1024 * (it + 1), "wall_s": 1.5 * it,
             "losses": {"actor": 0.25, "critic": None}, "mean_return": None,
             "success_rate": 0.5, "drop_rate": 0.0},
        ))
        for step in range(4):
            out.append((
                "/episode/action",
                {"episode": it, "step": step, "action": np.int32(step % 3),
                 "name": "rotate_ccw", "valid": np.bool_(step != 2), "outcome": "done",
                 "pose_before": np.array([0.5, -0.25, step]),
                 "pose_after": np.array([0.5, NAN, step + 0.125], dtype=np.float32),
                 "reward": np.float16(-0.5)},
                {"episode": it, "step": step, "action": step % 3,
                 "name": "rotate_ccw", "valid": step != 2, "outcome": "done",
                 "pose_before": [0.5, -0.25, float(step)],
                 "pose_after": [0.5, None, step + 0.125], "reward": -0.5},
            ))
            out.append((
                "/sim/state",
                {"episode": it, "sim_time_s": step * 0.25, "object_pose": [0.0, 0.125, 0.0],
                 "joint_q": np.arange(9) * 0.25, "joint_qd": np.zeros(9),
                 "contacts": [{"finger": np.int64(1), "position": np.array([0.5, 0.25]),
                               "normal_force_n": np.float64(2.5), "tangential_force_n": INF}]},
                {"episode": it, "sim_time_s": step * 0.25, "object_pose": [0.0, 0.125, 0.0],
                 "joint_q": [i * 0.25 for i in range(9)], "joint_qd": [0.0] * 9,
                 "contacts": [{"finger": 1, "position": [0.5, 0.25],
                               "normal_force_n": 2.5, "tangential_force_n": None}]},
            ))
        out.append((
            "/eval/episode",
            {"episode": it, "group": "train_objects", "success": it == 1, "dropped": False,
             "timeout": it == 2, "sim_time_s": 3.5, "n_actions": 4, "n_invalid": 1,
             "x0": [0.0, 0.1, 0.0], "xg": (0.0, 0.1, 1.5), "final_pose": np.array([0, 0.1, 1.5]),
             "object": "cube", "seed": 100 + it},
            {"episode": it, "group": "train_objects", "success": it == 1, "dropped": False,
             "timeout": it == 2, "sim_time_s": 3.5, "n_actions": 4, "n_invalid": 1,
             "x0": [0.0, 0.1, 0.0], "xg": [0.0, 0.1, 1.5], "final_pose": [0.0, 0.1, 1.5],
             "object": "cube", "seed": 100 + it},
        ))
    return out


def write_samples(path: Path, **kwargs: Any) -> Written:
    messages = sample_messages()
    with RunLog(path, **kwargs) as log:
        for topic, message, _ in messages:
            log.write(topic, message)
    return messages


@pytest.fixture
def written(tmp_path: Path) -> tuple[Path, Written]:
    path = tmp_path / "run.mcap"
    return path, write_samples(path, chunk_size=512)


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
def test_read_log_returns_every_message_equal_and_in_order(
    tmp_path: Path, compression: str
) -> None:
    path = tmp_path / "run.mcap"
    messages = write_samples(path, chunk_size=512, compression=compression)
    log = read_log(path)
    assert [(m.topic, m.data) for m in log.messages] == [(t, e) for t, _, e in messages]
    assert (log.truncated, log.corrupt_chunks, log.problems) == (False, 0, [])
    assert log.path == path


def test_plain_mcap_reader_decodes_the_same_dicts(written: tuple[Path, Written]) -> None:
    path, messages = written
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[JsonDecoderFactory()])
        decoded = [(channel.topic, data)
                   for _, channel, _, data in reader.iter_decoded_messages(log_time_order=False)]
    assert decoded == [(t, e) for t, _, e in messages]


def test_file_declares_jsonschema_schemas_and_json_channels(
    written: tuple[Path, Written],
) -> None:
    path, _ = written
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    channels = {c.topic: c for c in summary.channels.values()}
    assert set(channels) == set(TOPIC_SCHEMAS)
    for topic, channel in channels.items():
        schema = summary.schemas[channel.schema_id]
        assert channel.message_encoding == "json"
        assert schema.encoding == "jsonschema"
        assert schema.name == TOPIC_SCHEMAS[topic]["title"]
        assert json.loads(schema.data) == TOPIC_SCHEMAS[topic]
    assert summary.statistics is not None
    assert summary.statistics.message_count == len(written[1])
    assert summary.statistics.chunk_count > 3  # chunk_size=512 split the log


def test_sequence_numbers_count_per_topic(written: tuple[Path, Written]) -> None:
    path, messages = written
    log = read_log(path)
    for topic in TOPIC_SCHEMAS:
        count = sum(t == topic for t, _, _ in messages)
        assert [m.sequence for m in log.messages if m.topic == topic] == list(range(count))


def test_stored_json_is_strict_no_nan_tokens(written: tuple[Path, Written]) -> None:
    def refuse(token: str) -> None:
        raise AssertionError(f"non-standard JSON token {token}")

    path, messages = written
    with open(path, "rb") as f:
        raw = [m.data for _, _, m in make_reader(f).iter_messages(log_time_order=False)]
    assert len(raw) == len(messages)
    for data in raw:
        json.loads(data, parse_constant=refuse)


def test_log_times_default_to_now_and_can_be_given(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    before = time.time_ns()
    with RunLog(path) as log:
        log.write("/train/iteration", {"iteration": 0, "frames": 0})
        log.write("/train/iteration", {"iteration": 1, "frames": 10}, log_time_ns=np.int64(42))
        with pytest.raises(ValueError, match="log_time_ns"):
            log.write("/train/iteration", {"iteration": 2, "frames": 20}, log_time_ns=-1)
    after = time.time_ns()
    first, second = read_log(path).messages
    assert before <= first.log_time_ns <= after
    assert second == LogMessage("/train/iteration", 42, {"iteration": 1, "frames": 10}, 1)


def test_topic_helper_filters_and_catches_typos(written: tuple[Path, Written]) -> None:
    path, messages = written
    log = read_log(path)
    assert log.topic("/eval/episode") == [e for t, _, e in messages if t == "/eval/episode"]
    assert len(log.topic("/eval/episode")) == 3
    with pytest.raises(KeyError, match="/eval/episodes"):
        log.topic("/eval/episodes")


def test_a_read_of_some_topics_gives_exactly_theirs(written: tuple[Path, Written]) -> None:
    path, messages = written
    some = ("/eval/episode", "/run/config")
    log = read_log(path, topics=some)
    assert [(m.topic, m.data) for m in log.messages] == [
        (t, e) for t, _, e in messages if t in some]
    assert log.topic("/eval/episode") == read_log(path).topic("/eval/episode")
    with pytest.raises(KeyError, match="read it with topics including '/sim/state'"):
        log.topic("/sim/state")  # left out by this read: not silently empty


def test_empty_log_reads_back_complete(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    RunLog(path).close()
    log = read_log(path)
    assert (log.messages, log.truncated, log.corrupt_chunks, log.problems) == ([], False, 0, [])


def test_writer_refuses_to_overwrite(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    path.write_bytes(b"precious")
    with pytest.raises(FileExistsError, match="run.mcap"):
        RunLog(path)
    assert path.read_bytes() == b"precious"


def test_unknown_topic_is_named_with_the_known_ones(tmp_path: Path) -> None:
    with RunLog(tmp_path / "run.mcap") as log, pytest.raises(
        ValueError, match=r"'/train/iter'.*/run/config, /train/iteration"
    ):
        log.write("/train/iter", {"iteration": 0, "frames": 0})


def test_missing_required_key_is_named(tmp_path: Path) -> None:
    with RunLog(tmp_path / "run.mcap") as log, pytest.raises(
        ValueError, match=r"/episode/action.*pose_after"
    ):
        log.write("/episode/action", {"episode": 0, "step": 0, "action": 1, "valid": True,
                                      "pose_before": [0, 0, 0]})


def test_rejected_messages_leave_nothing_behind(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    with RunLog(path) as log:
        with pytest.raises(TypeError, match="/train/iteration message: .*object"):
            log.write("/train/iteration", {"iteration": 0, "frames": 0, "losses": object()})
        with pytest.raises(ValueError):
            log.write("/train/iteration", {"iteration": 0})
        log.write("/train/iteration", {"iteration": 1, "frames": 5})
    log_read = read_log(path)
    assert [(m.data, m.sequence) for m in log_read.messages] == [
        ({"iteration": 1, "frames": 5}, 0)
    ]


def test_close_is_idempotent_and_final(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    log = RunLog(path)
    log.write("/train/iteration", {"iteration": 0, "frames": 0})
    log.close()
    size = path.stat().st_size
    log.close()
    assert log.closed and path.stat().st_size == size
    with pytest.raises(ValueError, match="closed"):
        log.write("/train/iteration", {"iteration": 1, "frames": 0})
    assert not read_log(path).truncated


def test_exception_in_with_block_still_finishes_the_file(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    with pytest.raises(RuntimeError), RunLog(path) as log:
        log.write("/train/iteration", {"iteration": 0, "frames": 0})
        raise RuntimeError("learner diverged")
    log_read = read_log(path)
    assert not log_read.truncated and len(log_read.messages) == 1


def test_flush_policy_bounds_what_a_kill_loses(tmp_path: Path) -> None:
    message = {"iteration": 0, "frames": 0}
    lazy_path, eager_path = tmp_path / "lazy.mcap", tmp_path / "eager.mcap"
    with RunLog(lazy_path, flush_every_s=3600) as lazy, \
            RunLog(eager_path, flush_every_s=0.05) as eager:
        for log in (lazy, eager):
            log.write("/train/iteration", message)
        time.sleep(0.06)
        for log in (lazy, eager):
            log.write("/train/iteration", message)
        # Read the files while the writers are still open, as after a kill.
        assert read_log(lazy_path).messages == []
        on_disk = read_log(eager_path)
        assert on_disk.truncated and len(on_disk.messages) == 2
        lazy.flush()
        assert len(read_log(lazy_path).messages) == 2


def test_json_decoder_factory_only_claims_json() -> None:
    factory = JsonDecoderFactory()
    decode = factory.decoder_for("json", None)
    assert decode is not None and decode(b'{"a": [1, null]}') == {"a": [1, None]}
    assert factory.decoder_for("cdr", None) is None
