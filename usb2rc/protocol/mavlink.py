"""MAVLink 2 as a stream of messages, parsed by pymavlink (never by hand): the same shape as
the other decoders (`feed(chunk) -> [message]`, `flush()`, counters), for `usb2rc decode
--protocol mavlink` and the MAVLink output's view of its far end.

pymavlink's parser runs with `robust_parsing`: garbage and CRC failures come back as
BAD_DATA, which is counted here (`bytes_skipped`, `crc_failures`) and never raised.
"""

from __future__ import annotations

from typing import Any

from pymavlink.dialects.v20 import common as mavlink2


class MavlinkDecoder:
    def __init__(self) -> None:
        self.parser = mavlink2.MAVLink(None)
        self.parser.robust_parsing = True
        self.frames = 0
        self.bytes_skipped = 0
        self.crc_failures = 0
        self.bytes_in = 0

    def feed(self, chunk: bytes) -> list[Any]:
        """The whole messages in chunk (and what was left of earlier chunks)."""
        self.bytes_in += len(chunk)
        messages = []
        for message in self.parser.parse_buffer(chunk) or []:
            if message.get_type() == "BAD_DATA":
                self.bytes_skipped += len(message.get_msgbuf())
                if "CRC" in str(getattr(message, "reason", "")).upper():
                    self.crc_failures += 1
                continue
            self.frames += 1
            messages.append(message)
        return messages

    def flush(self) -> list[Any]:
        """End of stream: an incomplete message left in the buffer counts as skipped."""
        self.bytes_skipped += self.parser.buf_len()
        return []


def message_fields(message: Any) -> dict[str, Any]:
    """A message's fields by name, as pymavlink decoded them."""
    fields = dict(message.to_dict())
    fields.pop("mavpackettype", None)
    return fields
