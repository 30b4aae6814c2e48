"""MAVLink 2 as a stream of messages, parsed by pymavlink (never by hand): the same shape as
the other decoders (`feed(chunk) -> [message]`, `flush()`, counters), for `usb2rc decode
--protocol mavlink` and the MAVLink output's view of its far end.

pymavlink's parser runs with `robust_parsing`: garbage and CRC failures come back as
BAD_DATA, which is counted here (`bytes_skipped`, `crc_failures`) and never raised. With a
signing key (MAVLink 2 signing, pymavlink's `MAVLink.signing`) only messages signed with
it are returned; unsigned ones, bad signatures and replayed timestamps are counted
(`bad_signatures`) and dropped.

The control messages' field values (docs/ICD.md, "MAVLink output"): an int16 axis or a
button as RC_CHANNELS_OVERRIDE's µs (`axis_to_pwm`, `button_to_pwm`), as MANUAL_CONTROL's
x, y, r (`axis_to_manual`) and z (`axis_to_manual_z`).
"""

from __future__ import annotations

import hashlib
from typing import Any

from pymavlink.dialects.v20 import common as mavlink2

from usb2rc.nodes.scaling import INT16_MAX, INT16_MIN, round_div

SIGNING_EPOCH = 1420070400  # MAVLink signing timestamps count from 2015-01-01 00:00 UTC
SIGNING_TICKS_PER_S = 100_000  # in units of 10 µs
PWM_MIN, PWM_MAX = 1000, 2000  # RC_CHANNELS_OVERRIDE, µs
MANUAL_MIN, MANUAL_MAX = -1000, 1000  # MANUAL_CONTROL x, y, r
MANUAL_Z_MIN, MANUAL_Z_MAX = 0, 1000  # MANUAL_CONTROL z: the range PX4 and ArduPilot read


def signing_timestamp(wall_time: float) -> int:
    """A wall-clock time (`time.time()`) as a MAVLink signing timestamp."""
    return int((wall_time - SIGNING_EPOCH) * SIGNING_TICKS_PER_S)


def set_up_signing(mav: Any, key: bytes, wall_time: float, sign_outgoing: bool) -> None:
    """What mavutil's `setup_signing` does, on a bare `MAVLink`: the key, link id 0, the
    timestamp from the wall clock (a receiver refuses a new stream more than a minute older
    than its own clock), and no unsigned message accepted. hashlib, which pymavlink signs
    with, is loaded now (it loads lazily: usb2rc/protocols/mavlink/__init__.py), not in the
    first tick that signs."""
    hashlib.new("sha256")
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


def _int16(value: int) -> int:
    return INT16_MIN if value < INT16_MIN else INT16_MAX if value > INT16_MAX else value


def axis_to_pwm(value: int) -> int:
    """An int16 axis onto 1000..2000 µs: -32768 → 1000, 0 → 1500, 32767 → 2000 (clamped)."""
    return PWM_MIN + round_div((_int16(value) - INT16_MIN) * (PWM_MAX - PWM_MIN), 65535)


def button_to_pwm(pressed: bool) -> int:
    """A button as an RC channel: 2000 µs pressed, 1000 µs released."""
    return PWM_MAX if pressed else PWM_MIN


def axis_to_manual(value: int) -> int:
    """An int16 axis onto MANUAL_CONTROL's -1000..1000: -32768 → -1000, 0 → 0, 32767 → 1000
    (each half scaled on its own, so both ends are reached and 0 stays 0)."""
    value = _int16(value)
    if value < 0:
        return round_div(value * MANUAL_MAX, -INT16_MIN)
    return round_div(value * MANUAL_MAX, INT16_MAX)


def axis_to_manual_z(value: int) -> int:
    """An int16 axis onto MANUAL_CONTROL z, 0..1000: -32768 → 0, 0 → 500, 32767 → 1000."""
    return round_div((_int16(value) - INT16_MIN) * MANUAL_Z_MAX, 65535)
