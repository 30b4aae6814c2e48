"""MAVLink 2 as a stream of messages, parsed by pymavlink (never by hand): the same shape as
the other decoders (`feed(chunk) -> [message]`, `flush()`, counters), for `usb2rc decode
--protocol mavlink` and the MAVLink output's view of its far end.

pymavlink's parser runs with `robust_parsing`: garbage and CRC failures come back as
BAD_DATA, which is counted here (`bytes_skipped`, `crc_failures`) and never raised. With a
signing key (MAVLink 2 signing, pymavlink's `MAVLink.signing`) only messages signed with
it are returned; unsigned ones, bad signatures and replayed timestamps are counted
(`bad_signatures`) and dropped.
"""

from __future__ import annotations

from typing import Any

from pymavlink.dialects.v20 import common as mavlink2

SIGNING_EPOCH = 1420070400  # MAVLink signing timestamps count from 2015-01-01 00:00 UTC
SIGNING_TICKS_PER_S = 100_000  # in units of 10 µs


def signing_timestamp(wall_time: float) -> int:
    """A wall-clock time (`time.time()`) as a MAVLink signing timestamp."""
    return int((wall_time - SIGNING_EPOCH) * SIGNING_TICKS_PER_S)


def set_up_signing(mav: Any, key: bytes, wall_time: float, sign_outgoing: bool) -> None:
    """What mavutil's `setup_signing` does, on a bare `MAVLink`: the key, link id 0, the
    timestamp from the wall clock (a receiver refuses a new stream more than a minute older
    than its own clock), and no unsigned message accepted."""
    mav.signing.secret_key = key
    mav.signing.link_id = 0
    mav.signing.timestamp = signing_timestamp(wall_time)
    mav.signing.sign_outgoing = sign_outgoing
    mav.signing.allow_unsigned_callback = None


class MavlinkDecoder:
    def __init__(self, key: bytes | None = None, wall_time: float = 0.0) -> None:
        self.parser = mavlink2.MAVLink(None)
        self.parser.robust_parsing = True
        if key is not None:
            set_up_signing(self.parser, key, wall_time, sign_outgoing=False)
        self.frames = 0
        self.bytes_skipped = 0
        self.crc_failures = 0
        self.bad_signatures = 0  # with a key: unsigned, wrongly signed or replayed
        self.bytes_in = 0

    def feed(self, chunk: bytes) -> list[Any]:
        """The whole messages in chunk (and what was left of earlier chunks)."""
        self.bytes_in += len(chunk)
        messages = []
        for message in self.parser.parse_buffer(chunk) or []:
            if message.get_type() == "BAD_DATA":
                self.bytes_skipped += len(message.get_msgbuf())
                reason = str(getattr(message, "reason", "")).upper()
                self.crc_failures += "CRC" in reason
                self.bad_signatures += "SIGNATURE" in reason
                continue
            self.frames += 1
            messages.append(message)
        return messages

    def feed_alone(self, datagram: bytes) -> list[Any]:
        """The messages of one datagram on its own: nothing left of earlier datagrams (from
        other senders) is joined to it. The signing timestamps seen are kept (replays)."""
        self.parser.buf, self.parser.buf_index = bytearray(), 0
        self.parser.expected_length = mavlink2.HEADER_LEN_V1 + 2
        self.parser.have_prefix_error = False
        messages = self.feed(datagram)
        self.flush()
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
