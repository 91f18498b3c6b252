"""Run logs: MCAP files of JSON messages with JSON-Schema schemas, written and read back."""

from inhand_exp.record.reader import JsonDecoderFactory, Log, LogError, LogMessage, read_log
from inhand_exp.record.schemas import TOPIC_SCHEMAS
from inhand_exp.record.writer import RunLog

__all__ = [
    "TOPIC_SCHEMAS",
    "JsonDecoderFactory",
    "Log",
    "LogError",
    "LogMessage",
    "RunLog",
    "read_log",
]
