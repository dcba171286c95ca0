"""Validate an MCAP file, or recover the readable part of a damaged or truncated one.

    python -m quadson_mjx.mcap_check FILE [--expect-topic /tf ...] [--rollout] [--recover OUT]

The file is walked record by record (opcode, length, body), and each record is parsed on its own by
the mcap library: a record that fails (a chunk whose CRC does not match or that does not
decompress, an attachment whose CRC does not match, a record cut short) is reported with its byte
offset and skipped, and reading goes on with the next record, so messages after a damaged chunk
are kept. The walk goes on at a damaged record's declared end where the record there and the one
after it parse; where a damaged length field leaves that end out of step, it resumes at the next
place where two consecutive records parse (a footer only where the closing magic follows it).
CRCs checked: every chunk's, every attachment's, the summary section's and the data section's
(where the writer stored them; 0 means none). Records without a CRC (metadata, a chunk's
uncompressed bytes' framing) are checked only in that they parse.

A file is complete when nothing was damaged and its summary (written by a writer that finished) is
present and agrees with the messages read. The report names the topics, schemas, message counts,
time range, metadata, attachments and every damaged record. `--recover OUT` writes a new, complete
file with every readable message (schemas and channels kept), metadata record and intact attachment;
OUT must not exist and is written whole or not at all. `--rollout` expects every topic of a rollout
file (quadson_mjx.foxglove_mcap). quadson_mjx.mcap_decode turns a message (JSON or Foxglove protobuf) into a dict.
A file that ends before its summary (a writer killed mid-write, e.g. an interrupted rollout) is
reported as "truncated at byte N: ...; K complete messages recovered"; `--recover OUT` writes those
K messages into a complete file.
Exit status: 0 valid, 1 readable only in part (damaged or truncated), 2 unreadable, missing an
expected topic, or a usage error (one line on stderr: a missing input or a folder, an OUT that
exists, is a folder or lies in a missing or read-only folder); a usage error writes nothing.
"""

from __future__ import annotations

import json
import struct
import sys
import zlib
from collections import Counter
from dataclasses import dataclass, field
from io import BytesIO
from pathlib import Path

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import (
    Attachment,
    AttachmentIndex,
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    Message,
    MessageIndex,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)
from mcap.stream_reader import breakup_chunk
from mcap.writer import Writer

from quadson_mjx import errors
from quadson_mjx.errors import UsageError
from quadson_mjx.mcap_decode import decode

ROLLOUT_TOPICS = ("/tf", "/scene", "/joint_states", "/odom", "/imu", "/rollout/step", "/log")


MAGIC = b"\x89MCAP0\r\n"
_RECORD_HEADER = 9  # opcode (1 byte) + length (uint64)


@dataclass
class Contents:
    """Everything readable in a file, in file order (see `read_contents`)."""

    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    messages: list[Message] = field(default_factory=list)
    metadata: list[Metadata] = field(default_factory=list)
    attachments: list[Attachment] = field(default_factory=list)
    damaged: list[str] = field(default_factory=list)  # "offset N: RECORD: why", in file order
    truncated_at: int | None = None  # the file's length when it ends before its summary (killed writer)
    statistics: Statistics | None = None
    footer: Footer | None = None
    profile: str = ""


def _parse(opcode: int, body: bytes):
    """One top-level record's body -> list of records (a chunk's inner records); raises if damaged."""
    stream = ReadDataStream(BytesIO(body))
    if opcode == Opcode.CHUNK:
        return breakup_chunk(Chunk.read(stream), validate_crc=True)
    if opcode == Opcode.ATTACHMENT:
        record = Attachment.read(stream)
        (crc,) = struct.unpack_from("<I", body, len(body) - 4)
        if crc != 0 and zlib.crc32(body[:-4]) != crc:
            raise ValueError(f"attachment {record.name!r}: CRC mismatch (stored {crc:#010x})")
        return [record]
    reader = {
        Opcode.HEADER: Header.read,
        Opcode.FOOTER: Footer.read,
        Opcode.SCHEMA: Schema.read,
        Opcode.CHANNEL: Channel.read,
        Opcode.MESSAGE: lambda st: Message.read(st, len(body)),
        Opcode.MESSAGE_INDEX: MessageIndex.read,
        Opcode.CHUNK_INDEX: ChunkIndex.read,
        Opcode.ATTACHMENT_INDEX: AttachmentIndex.read,
        Opcode.STATISTICS: Statistics.read,
        Opcode.METADATA: Metadata.read,
        Opcode.METADATA_INDEX: MetadataIndex.read,
        Opcode.SUMMARY_OFFSET: SummaryOffset.read,
        Opcode.DATA_END: DataEnd.read,
    }.get(opcode)
    if reader is None:
        raise ValueError(f"unknown opcode {opcode:#04x}")
    return [reader(stream)]


class _CutShort(ValueError):
    """A record that runs past the end of the file."""


# A streaming writer (foxglove's, which RolloutWriter uses) writes a chunk's header with this length
# and fills it in when the chunk is finished: a file ending in it was killed while writing the chunk.
_UNFINISHED_LENGTH = 2**64 - 1


def _record_at(data: bytes, pos: int):
    """(opcode, body, records) of the record at `pos`; raises ValueError if it is not a whole,
    parseable record (_CutShort if it runs past the end of the file)."""
    if pos + _RECORD_HEADER > len(data):
        raise _CutShort(f"record header cut short: the file ends {len(data) - pos} bytes after it starts")
    opcode = data[pos]
    (length,) = struct.unpack_from("<Q", data, pos + 1)
    end = pos + _RECORD_HEADER + length
    name = _opcode_name(opcode)
    if end > len(data):
        if length == _UNFINISHED_LENGTH:
            raise _CutShort(
                f"{name} cut short: its length was never written (the writer was killed while writing "
                f"it); the file ends {len(data) - pos} bytes into it"
            )
        raise _CutShort(f"{name} of {length} bytes cut short: the file ends {len(data) - pos} bytes into it")
    body = data[pos + _RECORD_HEADER : end]
    try:
        return opcode, body, _parse(opcode, body)
    except Exception as e:  # the mcap library, zstandard and struct raise many types on bad bytes
        raise ValueError(f"{name}: {type(e).__name__}: {e}") from None


def _opcode_name(opcode: int) -> str:
    try:
        return Opcode(opcode).name
    except ValueError:
        return f"opcode {opcode:#04x}"


def _in_step(data: bytes, p: int) -> bool:
    """Whether a walk can go on at `p`: the record there parses, and so does the one after it, or
    the closing magic follows (a footer must be followed by it: the footer's body is 20 bytes that
    any bytes parse as)."""
    if p >= len(data) or data[p] not in _KNOWN_OPCODES:
        return False
    try:
        opcode, body, _ = _record_at(data, p)
        nxt = p + _RECORD_HEADER + len(body)
        if data[nxt:] == MAGIC:
            return True
        if opcode == Opcode.FOOTER:
            return False
        _record_at(data, nxt)
        return True
    except ValueError:
        return False


def _resync(data: bytes, pos: int) -> int | None:
    """Where the walk goes on after a damaged record at `pos`, or None. Its declared end first: a
    chunk whose CRC fails or that does not decompress still has its length. Only where that end is
    out of step (a damaged length) is the file searched, from `pos` on, for a place in step."""
    if pos + _RECORD_HEADER <= len(data):
        (length,) = struct.unpack_from("<Q", data, pos + 1)
        declared_end = pos + _RECORD_HEADER + length
        if declared_end < len(data) and _in_step(data, declared_end):
            return declared_end
    for p in range(pos + 1, len(data) - _RECORD_HEADER):
        if _in_step(data, p):
            return p
    return None


_KNOWN_OPCODES = {int(o) for o in Opcode}


def read_contents(path: str | Path) -> Contents:
    """Walks every record of `path` (see the module docstring); never raises on damaged bytes."""
    data = Path(path).read_bytes()
    out = Contents()
    if not data.startswith(MAGIC):
        out.damaged.append("offset 0: not an MCAP file (the magic bytes are missing)")
        return out
    pos, data_end = len(MAGIC), None
    while pos < len(data):
        try:
            opcode, body, records = _record_at(data, pos)
        except ValueError as e:
            out.damaged.append(f"offset {pos}: {e}")
            nxt = _resync(data, pos)
            if nxt is None:
                if isinstance(e, _CutShort):  # the last record never ended: a killed writer
                    out.truncated_at = len(data)
                break
            out.damaged[-1] += f"; {nxt - pos} bytes skipped"
            pos = nxt
            continue
        for r in records:
            if isinstance(r, Header):
                out.profile = r.profile
            elif isinstance(r, Schema):
                out.schemas[r.id] = r
            elif isinstance(r, Channel):
                out.channels[r.id] = r
            elif isinstance(r, Message):
                out.messages.append(r)
            elif isinstance(r, Metadata):
                out.metadata.append(r)
            elif isinstance(r, Attachment):
                out.attachments.append(r)
            elif isinstance(r, Statistics):
                out.statistics = r
            elif isinstance(r, DataEnd):
                data_end = r
                if r.data_section_crc and zlib.crc32(data[:pos]) != r.data_section_crc:
                    out.damaged.append(f"offset {pos}: DATA_END: data section CRC mismatch")
            elif isinstance(r, Footer):
                out.footer = r
                summary_crc_end = pos + _RECORD_HEADER + 16  # through summary_offset_start
                start = r.summary_start or pos
                if r.summary_crc and zlib.crc32(data[start:summary_crc_end]) != r.summary_crc:
                    out.damaged.append(f"offset {pos}: FOOTER: summary section CRC mismatch")
        pos += _RECORD_HEADER + len(body)
        if opcode == Opcode.FOOTER:
            if data[pos:] != MAGIC:
                out.damaged.append(f"offset {pos}: the closing magic bytes are missing or damaged")
            break
    if out.footer is None and data_end is None and not out.damaged:
        out.damaged.append(f"offset {len(data)}: the file ends without a summary (the writer did not finish)")
        out.truncated_at = len(data)
    return out


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
    complete: bool = False  # summary present, nothing damaged, every CRC valid
    counts: Counter = field(default_factory=Counter)
    schemas: dict[str, str] = field(default_factory=dict)  # topic -> schema name
    start_ns: int | None = None
    end_ns: int | None = None
    error: str | None = None  # the first problem found
    damaged: list[str] = field(default_factory=list)  # every problem found
    lost_messages: int = 0  # messages whose channel definition was in a damaged record
    metadata: list[str] = field(default_factory=list)
    attachments: list[str] = field(default_factory=list)
    truncated_at: int | None = None  # the file ends here, before its summary (a killed writer)

    def lines(self) -> list[str]:
        state = "complete" if self.complete else "TRUNCATED/DAMAGED (readable part only)"
        out = [f"{self.path}: {state}"]
        if self.truncated_at is not None:
            out.append(
                f"  truncated at byte {self.truncated_at}: the writer was killed (or has not finished); "
                f"{sum(self.counts.values())} complete messages recovered"
            )
        for problem in self.damaged[:20]:
            out.append(f"  damaged: {problem}")
        if len(self.damaged) > 20:
            out.append(f"  ... and {len(self.damaged) - 20} more damaged records")
        if self.error and not self.damaged:
            out.append(f"  stopped at: {self.error}")
        if self.lost_messages:
            out.append(
                f"  {self.lost_messages} messages unreadable: their channel was defined in a damaged record"
            )
        if self.start_ns is not None:
            out.append(f"  time: {self.start_ns / 1e9:.3f} .. {self.end_ns / 1e9:.3f} s")
        for topic in sorted(self.counts):
            out.append(f"  {topic:32s} {self.counts[topic]:8d} msgs  schema {self.schemas.get(topic, '?')}")
        if self.metadata:
            out.append(f"  metadata: {', '.join(self.metadata)}")
        if self.attachments:
            out.append(f"  attachments: {', '.join(self.attachments)}")
        return out


def _report(path, contents: Contents, sink=None) -> Report:
    report = Report(str(path), damaged=list(contents.damaged), truncated_at=contents.truncated_at)
    report.metadata = [m.name for m in contents.metadata]
    report.attachments = [a.name for a in contents.attachments]
    for message in contents.messages:
        channel = contents.channels.get(message.channel_id)
        if channel is None:
            report.lost_messages += 1
            continue
        schema = contents.schemas.get(channel.schema_id)
        report.counts[channel.topic] += 1
        report.schemas[channel.topic] = schema.name if schema else ""
        t = message.log_time
        report.start_ns = t if report.start_ns is None else min(report.start_ns, t)
        report.end_ns = t if report.end_ns is None else max(report.end_ns, t)
        if sink is not None:
            sink(schema, channel, message)
    stats = contents.statistics
    if stats is not None and not report.damaged:
        by_topic = {contents.channels[c].topic: n for c, n in stats.channel_message_counts.items() if n}
        if by_topic != dict(report.counts):
            report.damaged.append(f"summary counts {by_topic} differ from the messages read")
    if contents.footer is None and not report.damaged:
        report.damaged.append("no summary section (writer did not finish)")
    report.error = report.damaged[0] if report.damaged else None
    report.complete = not report.damaged and not report.lost_messages
    return report


def check(path: str | Path, sink=None) -> Report:
    """Reads every readable message of `path`; sink(schema, channel, message) sees each one."""
    path = Path(path)
    if not path.exists():
        return Report(str(path), error="file does not exist", damaged=["file does not exist"])
    return _report(path, read_contents(path), sink)


def recover_messages(path: str | Path) -> list[tuple[str, int, dict]]:
    """(topic, log_time_ns, decoded JSON message) of every readable JSON message of `path`."""
    out = []

    def sink(schema, channel, message):
        if channel.message_encoding == "json":
            out.append((channel.topic, message.log_time, json.loads(message.data)))

    check(path, sink)
    return out


def recover(path: str | Path, out_path: str | Path) -> Report:
    """Writes every readable message (schemas and channels kept), metadata record and intact
    attachment of `path` into a new, complete file `out_path`.

    Refuses (FileExistsError) an `out_path` that exists, the input included: recovery never
    overwrites. The input is read whole before anything is written, and the output goes to a
    temporary file renamed into place at the end, so an interrupted recovery leaves no half file.
    """
    path, out_path = Path(path), Path(out_path)
    if out_path.exists() or out_path.is_symlink():
        same = path.exists() and out_path.exists() and out_path.samefile(path)
        what = "is the input file" if same else "exists"
        raise FileExistsError(
            f"{out_path} {what}; --recover writes a new file: choose another name or remove it"
        )
    errors.check_readable(path, "input")  # a missing input leaves no (empty) output behind
    errors.check_writable(out_path, "--recover")
    contents = read_contents(path)
    with errors.atomic_write(out_path, "wb") as f:
        writer = Writer(f)
        writer.start(profile=contents.profile, library="quadson_mjx.mcap_check")
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

        report = _report(path, contents, sink)
        for m in contents.metadata:
            writer.add_metadata(m.name, dict(m.metadata))
        for a in contents.attachments:
            writer.add_attachment(a.create_time, a.log_time, a.name, a.media_type, a.data)
        writer.finish()
    return report


@errors.one_line_errors
def main(argv=None) -> int:
    p = errors.ArgumentParser(prog="python -m quadson_mjx.mcap_check", description=__doc__.split("\n\n")[0])
    p.add_argument("file")
    p.add_argument("--expect-topic", action="append", default=[], help="fail unless this topic has messages")
    p.add_argument("--rollout", action="store_true", help="expect every topic of a rollout file")
    p.add_argument("--recover", metavar="OUT", help="write the readable contents to OUT, a new complete file")
    args = p.parse_args(argv)
    if args.rollout:
        args.expect_topic += [t for t in ROLLOUT_TOPICS if t not in args.expect_topic]
    errors.check_readable(args.file, "input")
    if args.recover:
        try:
            report = recover(args.file, args.recover)
        except FileExistsError as e:
            raise UsageError(str(e)) from None
    else:
        report = check(args.file)
    print("\n".join(report.lines()))
    if args.recover:
        print(
            f"recovered into {args.recover}: {sum(report.counts.values())} messages, "
            f"{len(report.metadata)} metadata records, {len(report.attachments)} attachments"
        )
    missing = [t for t in args.expect_topic if report.counts.get(t, 0) == 0]
    if missing:
        print(f"missing expected topics: {', '.join(missing)}")
        return 2
    if not report.counts and report.error:
        return 2
    return 0 if report.complete else 1


if __name__ == "__main__":
    sys.exit(main())
