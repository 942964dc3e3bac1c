"""Reading a recording back: every message, also from a file cut short by a kill.

`read_messages(path)` walks the records in file order with the `mcap` library's StreamReader,
so it needs neither the summary nor the footer; a record cut off at the end stops the walk
(`Recording.truncated`) and everything before it is kept. JSON messages are decoded; protobuf
messages keep their bytes (`foxglove` messages decode them where a test needs the fields).
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass, field
from pathlib import Path

from mcap.exceptions import McapError
from mcap.records import Channel, Message, Schema
from mcap.stream_reader import StreamReader


@dataclass(frozen=True)
class Msg:
    topic: str
    schema: str
    encoding: str
    log_time_ns: int
    data: bytes

    @property
    def t(self) -> float:
        return self.log_time_ns / 1e9

    def json(self):
        return json.loads(self.data)


@dataclass
class Recording:
    messages: list[Msg] = field(default_factory=list)
    truncated: bool = False  # the file ended inside a record (a kill, a full disk)
    complete: bool = False  # the footer was read: a file closed properly
    error: str = ""  # why the walk stopped early

    def counts(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for msg in self.messages:
            out[msg.topic] = out.get(msg.topic, 0) + 1
        return out

    def topic(self, name: str) -> list[Msg]:
        return [x for x in self.messages if x.topic == name]

    def schemas(self) -> dict[str, str]:
        """topic → schema name."""
        return {x.topic: x.schema for x in self.messages}


def read_messages(path: Path | str) -> Recording:
    rec = Recording()
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    with open(path, "rb") as f:
        try:
            for r in StreamReader(f, validate_crcs=True).records:
                if isinstance(r, Schema):
                    schemas[r.id] = r
                elif isinstance(r, Channel):
                    channels[r.id] = r
                elif isinstance(r, Message):
                    ch = channels[r.channel_id]
                    s = schemas.get(ch.schema_id)
                    rec.messages.append(
                        Msg(ch.topic, s.name if s else "", ch.message_encoding, r.log_time, r.data)
                    )
            rec.complete = True
        except (McapError, EOFError, ValueError, KeyError, OSError, struct.error) as e:
            # a record cut short: EndOfFile, or struct.error inside a length field; a bad CRC
            rec.truncated = True
            rec.error = f"{type(e).__name__}: {e}"
    return rec
