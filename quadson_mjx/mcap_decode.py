"""A recorded MCAP message as a dict: JSON channels, and protobuf channels of Foxglove's schemas (their
descriptors travel in the file). Needs the `protobuf` package for the latter."""

from __future__ import annotations

import json


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
