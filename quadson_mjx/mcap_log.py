"""Training metrics to MCAP, as JSON messages that Foxglove's plot panel reads.

Each topic has a JSON schema; every message is one evaluation's metrics, nested by the first path
segment of brax's metric names ("eval/episode_reward" -> {"eval": {"episode_reward": ...}}) so that
Foxglove message paths read `/train/metrics.eval.episode_reward`. Non-finite numbers are written as
null: JSON has no NaN, and JavaScript readers reject it. The writer flushes (finishes its chunk and
the file) after every message, so a killed run keeps everything logged before; `close()` writes the
summary section.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Mapping
from pathlib import Path

from mcap.writer import CompressionType, Writer

_NUMBER = {"type": ["number", "null"]}


def nest_metrics(metrics: Mapping[str, float]) -> dict:
    """{"eval/episode_reward/x": 1.0, "steps": 3} -> {"eval": {"episode_reward_x": 1.0}, "steps": 3}."""
    out: dict = {}
    for key, value in metrics.items():
        v = float(value)
        v = v if math.isfinite(v) else None
        head, _, rest = key.partition("/")
        if rest:
            out.setdefault(head, {})[rest.replace("/", "_")] = v
        else:
            out[head] = v
    return out


def _schema_of(message: Mapping) -> dict:
    def field(v):
        if isinstance(v, Mapping):
            return _schema_of(v)
        return {"type": "string"} if isinstance(v, str) else _NUMBER

    return {"type": "object", "properties": {k: field(v) for k, v in message.items()}}


class McapLog:
    """Append-only JSON-message MCAP file. Use as a context manager or call close()."""

    def __init__(self, path: str | Path, profile: str = "", append_ok: bool = False):
        self.path = Path(path)
        if self.path.exists() and not append_ok:
            raise FileExistsError(f"{self.path} exists; refusing to overwrite a log")
        self._file = open(self.path, "wb")  # noqa: SIM115 - closed in close()
        self._writer = Writer(self._file, compression=CompressionType.ZSTD)
        self._writer.start(profile=profile, library="quadson_mjx")
        self._channels: dict[str, int] = {}
        self._seq: dict[str, int] = {}
        self.closed = False

    def metadata(self, name: str, data: Mapping[str, str]) -> None:
        self._writer.add_metadata(name, {k: str(v) for k, v in data.items()})
        self._writer.flush()

    def attachment(self, name: str, data: bytes, media_type: str = "application/octet-stream") -> None:
        now = time.time_ns()
        self._writer.add_attachment(
            create_time=now, log_time=now, name=name, media_type=media_type, data=data
        )
        self._writer.flush()

    def log(self, topic: str, message: Mapping, log_time_ns: int) -> None:
        """Writes one JSON message; the first message of a topic fixes its schema."""
        if topic not in self._channels:
            schema = json.dumps(_schema_of(message)).encode()
            sid = self._writer.register_schema(
                name=topic.strip("/").replace("/", "."), encoding="jsonschema", data=schema
            )
            self._channels[topic] = self._writer.register_channel(
                topic=topic, message_encoding="json", schema_id=sid
            )
            self._seq[topic] = 0
        data = json.dumps(message, allow_nan=False).encode()
        self._writer.add_message(
            self._channels[topic],
            log_time=log_time_ns,
            data=data,
            publish_time=log_time_ns,
            sequence=self._seq[topic],
        )
        self._seq[topic] += 1
        self._writer.flush()

    def close(self) -> None:
        if not self.closed:
            self._writer.finish()
            self._file.close()
            self.closed = True

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
