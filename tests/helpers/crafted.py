"""Crafted logs: a real run log rewritten, for the tests that treat a log from outside as hostile.

`rewrite_log` copies a complete MCAP log record by record with the `mcap` library (not
with the code under test): every message on its channel and schema, every metadata
record with the given keys replaced, every attachment, plus the given extra attachments.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

from mcap.reader import make_reader
from mcap.writer import Writer


def rewrite_log(src: Path, dst: Path, *, metadata: dict[str, dict[str, str]] | None = None,
                attachments: dict[str, bytes] | None = None,
                keep: Callable[[str, bytes], bool] | None = None) -> Path:
    """Copy `src` to `dst` with `metadata` (record name -> keys to set) and extra `attachments` (name -> data);
    with `keep(topic, data)`, only the messages it keeps."""
    changes = metadata or {}
    with open(src, "rb") as f_in, open(dst, "wb") as f_out:
        reader = make_reader(f_in)
        writer = Writer(f_out)
        writer.start(profile="", library="tests/helpers/crafted.py")
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            if keep is not None and not keep(channel.topic, message.data):
                continue
            if channel.id not in channels:
                schema_id = 0
                if schema is not None:
                    if schema.id not in schemas:
                        schemas[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
                    schema_id = schemas[schema.id]
                channels[channel.id] = writer.register_channel(channel.topic, channel.message_encoding, schema_id,
                                                               dict(channel.metadata))
            writer.add_message(channels[channel.id], message.log_time, message.data, message.publish_time,
                               message.sequence)
        seen = set()
        for record in reader.iter_metadata():
            seen.add(record.name)
            writer.add_metadata(record.name, {**record.metadata, **changes.get(record.name, {})})
        for name in changes.keys() - seen:
            writer.add_metadata(name, dict(changes[name]))
        for attachment in reader.iter_attachments():
            writer.add_attachment(attachment.create_time, attachment.log_time, attachment.name,
                                  attachment.media_type, attachment.data)
        for name, data in (attachments or {}).items():
            writer.add_attachment(0, 0, name, "application/octet-stream", data)
        writer.finish()
    return dst
