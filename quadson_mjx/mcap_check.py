"""Validate an MCAP file, or recover the readable part of a truncated one.

    python -m quadson_mjx.mcap_check FILE [--expect-topic /tf ...] [--rollout] [--recover OUT]

A complete file is read through its summary (the seeking reader) and its chunk CRCs are checked; a
file whose writer was killed has no summary, so it is read front to back with the non-seeking reader,
which yields every message of every complete chunk and stops at the first damaged record. The
report names the topics, schemas, message counts and time range; `--recover OUT` writes the readable
messages into a new, complete file; `--rollout` expects every topic of a rollout file
(quadson_mjx.foxglove_mcap). `decode` turns a message (JSON or Foxglove protobuf) into a dict. Exit status: 0 valid, 1 readable only in part (truncated),
2 unreadable or missing an expected topic.
"""

from __future__ import annotations

import argparse
import json
import struct
import sys
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from mcap.exceptions import McapError
from mcap.reader import NonSeekingReader, make_reader
from mcap.writer import Writer

ROLLOUT_TOPICS = ("/tf", "/scene", "/joint_states", "/odom", "/imu", "/rollout/step", "/log")


def decode(schema, channel, message) -> dict:
    """A JSON or protobuf (Foxglove schema) message -> dict; protobuf needs the `protobuf` package.
    Protobuf fields keep their proto names (`child_frame_id`) and follow protobuf's JSON mapping
    (google.protobuf.Timestamp as RFC 3339 text, 64-bit integers as strings)."""
    if channel.message_encoding == "json":
        return json.loads(message.data)
    if channel.message_encoding != "protobuf":
        raise ValueError(f"cannot decode {channel.message_encoding!r} messages of {channel.topic}")
    return _to_dict(_protobuf_class(schema.name, schema.data).FromString(message.data))


_PROTO_CLASSES: dict = {}


def _protobuf_class(name: str, fds_bytes: bytes):
    key = (name, fds_bytes)
    if key not in _PROTO_CLASSES:
        from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

        fds = descriptor_pb2.FileDescriptorSet.FromString(fds_bytes)
        pool = descriptor_pool.DescriptorPool()
        for fd in fds.file:
            pool.Add(fd)
        _PROTO_CLASSES[key] = message_factory.GetMessageClass(pool.FindMessageTypeByName(name))
    return _PROTO_CLASSES[key]


def _to_dict(msg) -> dict:
    from google.protobuf.json_format import MessageToDict

    return MessageToDict(msg, preserving_proto_field_name=True, always_print_fields_with_no_presence=True)


def read_messages(path: str | Path, topics=None) -> list[tuple[str, int, dict]]:
    """(topic, log_time_ns, decoded message) of every readable message of `path` (of `topics`)."""
    out = []

    def sink(schema, channel, message):
        if topics is None or channel.topic in topics:
            out.append((channel.topic, message.log_time, decode(schema, channel, message)))

    check(path, sink)
    return out


@dataclass
class Report:
    path: str
    complete: bool = False  # summary present and every CRC valid
    counts: Counter = field(default_factory=Counter)
    schemas: dict[str, str] = field(default_factory=dict)  # topic -> schema name
    start_ns: int | None = None
    end_ns: int | None = None
    error: str | None = None
    metadata: list[str] = field(default_factory=list)
    attachments: list[str] = field(default_factory=list)

    def lines(self) -> list[str]:
        state = "complete" if self.complete else "TRUNCATED/DAMAGED (readable part only)"
        out = [f"{self.path}: {state}"]
        if self.error:
            out.append(f"  stopped at: {self.error}")
        if self.start_ns is not None:
            out.append(f"  time: {self.start_ns / 1e9:.3f} .. {self.end_ns / 1e9:.3f} s")
        for topic in sorted(self.counts):
            out.append(f"  {topic:32s} {self.counts[topic]:8d} msgs  schema {self.schemas.get(topic, '?')}")
        if self.metadata:
            out.append(f"  metadata: {', '.join(self.metadata)}")
        if self.attachments:
            out.append(f"  attachments: {', '.join(self.attachments)}")
        return out


def _scan(stream, report: Report, sink=None) -> None:
    reader = NonSeekingReader(stream, validate_crcs=True)
    for schema, channel, message in reader.iter_messages(log_time_order=False):
        report.counts[channel.topic] += 1
        report.schemas[channel.topic] = schema.name if schema else ""
        t = message.log_time
        report.start_ns = t if report.start_ns is None else min(report.start_ns, t)
        report.end_ns = t if report.end_ns is None else max(report.end_ns, t)
        if sink is not None:
            sink(schema, channel, message)


def check(path: str | Path, sink=None) -> Report:
    """Reads every readable message of `path`; sink(schema, channel, message) sees each one."""
    path = Path(path)
    report = Report(str(path))
    if not path.exists():
        report.error = "file does not exist"
        return report
    with open(path, "rb") as f:
        try:
            _scan(f, report, sink)
        except (McapError, EOFError, ValueError, OSError, struct.error) as e:
            report.error = f"{type(e).__name__}: {e}"
            return report
    with open(path, "rb") as f:
        try:
            reader = make_reader(f)
            summary = reader.get_summary()
            if summary is None:
                report.error = "no summary section (writer did not finish)"
                return report
            report.metadata = [m.name for m in reader.iter_metadata()]
            report.attachments = [a.name for a in reader.iter_attachments()]
            stats = summary.statistics
            if stats is not None:
                by_topic = {summary.channels[cid].topic: n for cid, n in stats.channel_message_counts.items()}
                if by_topic != dict(report.counts):
                    report.error = f"summary counts {by_topic} differ from the messages read"
                    return report
            report.complete = True
        except (McapError, EOFError, ValueError, OSError, struct.error) as e:
            report.error = f"{type(e).__name__}: {e}"
    return report


def recover_messages(path: str | Path) -> list[tuple[str, int, dict]]:
    """(topic, log_time_ns, decoded JSON message) of every readable JSON message of `path`."""
    out = []

    def sink(schema, channel, message):
        if channel.message_encoding == "json":
            out.append((channel.topic, message.log_time, json.loads(message.data)))

    check(path, sink)
    return out


def recover(path: str | Path, out_path: str | Path) -> Report:
    """Copies every readable message (any encoding, schemas kept) of `path` into a complete file."""
    with open(out_path, "wb") as f:
        writer = Writer(f)
        writer.start(profile="", library="quadson_mjx.mcap_check")
        schema_ids: dict[int, int] = {}
        channel_ids: dict[int, int] = {}

        def sink(schema, channel, message):
            if channel.id not in channel_ids:
                sid = 0
                if schema is not None:
                    if schema.id not in schema_ids:
                        schema_ids[schema.id] = writer.register_schema(
                            schema.name, schema.encoding, schema.data
                        )
                    sid = schema_ids[schema.id]
                channel_ids[channel.id] = writer.register_channel(
                    channel.topic, channel.message_encoding, sid, dict(channel.metadata)
                )
            writer.add_message(
                channel_ids[channel.id],
                message.log_time,
                message.data,
                message.publish_time,
                message.sequence,
            )

        report = check(path, sink)
        writer.finish()
    return report


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("file")
    p.add_argument("--expect-topic", action="append", default=[], help="fail unless this topic has messages")
    p.add_argument("--rollout", action="store_true", help="expect every topic of a rollout file")
    p.add_argument("--recover", metavar="OUT", help="write the readable messages to a new complete file")
    args = p.parse_args(argv)
    if args.rollout:
        args.expect_topic += [t for t in ROLLOUT_TOPICS if t not in args.expect_topic]
    report = recover(args.file, args.recover) if args.recover else check(args.file)
    print("\n".join(report.lines()))
    missing = [t for t in args.expect_topic if report.counts.get(t, 0) == 0]
    if missing:
        print(f"missing expected topics: {', '.join(missing)}")
        return 2
    if not report.counts and report.error:
        return 2
    return 0 if report.complete else 1


if __name__ == "__main__":
    sys.exit(main())
