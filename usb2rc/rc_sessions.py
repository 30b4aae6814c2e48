"""The CRSF, SBUS and iBus line sessions, sans-IO (no thread, no port, no clock: time is passed in).

Both are `session.FrameLineSession`s: one frame a tick while the line is open and not
stalled, channel values in (11-bit wire values, `outputs.channels.RC11_SCALE`), bytes out.

- `SbusSession`: a 25-byte frame every tick; while any listed channel's node is in failsafe
  the frame carries the frame-lost and failsafe flags (docs/ICD.md, "SBUS output").
- `IbusSession`: a 32-byte frame of 14 channels (µs, `outputs.channels.IBUS_SCALE`) every
  tick while every listed channel is live; while any is in failsafe it sends nothing, as
  CRSF does: iBus has no failsafe flag, the receiver's own failsafe fires on the silence
  (docs/ICD.md, "iBus output").
- `CrsfSession`: an RC_CHANNELS_PACKED frame every tick while every listed channel is live
  (to the module's address 0xEE, or to a flight controller's 0xC8: `address`);
  while any is in failsafe it sends nothing, so the ExpressLRS transmitter module stops and
  the receiver's own failsafe fires (docs/ICD.md, "CRSF failsafe"). It decodes what the module
  sends back (`received(data, now)`): link statistics, and the timing-correction frames with
  which an ELRS module asks the handset to follow its packet rate and phase; the scheduler
  asks `next_send(due, now)` when the next frame is due.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from usb2rc.nodes.scaling import RC11_CENTRE, RC11_LOW
from usb2rc.protocols import rc11
from usb2rc.protocols.crsf import codec as crsf
from usb2rc.protocols.ibus import codec as ibus
from usb2rc.protocols.sbus import codec as sbus
from usb2rc.session import FrameLineSession

# ELRS sends a timing correction every 200 ms while it hears the handset; after a second
# without one the session goes back to the configured rate.
SYNC_STALE_S = 1.0
MIN_INTERVAL_S = 0.001  # the module's rate is followed up to 1000 Hz, never faster
MAX_INTERVAL_S = 0.1  # ... and down to 10 Hz; anything else is implausible and ignored
UNLISTED = RC11_LOW  # channels past the list: 988 µs ("off" for a switch channel)


def padded(channels: Sequence[int], count: int = rc11.CHANNELS) -> list[int]:
    """The listed channels, then UNLISTED up to `count`."""
    return [*channels[:count], *([UNLISTED] * (count - len(channels)))]


class SbusSession(FrameLineSession):
    """SBUS: channels 1..16 analogue, 17 and 18 digital (on above the centre)."""

    def frame(self, channels: Sequence[int], failsafe: bool) -> bytes:
        digital = channels[rc11.CHANNELS :]
        return sbus.encode_sbus(
            padded(channels),
            ch17=len(digital) > 0 and digital[0] > RC11_CENTRE,
            ch18=len(digital) > 1 and digital[1] > RC11_CENTRE,
            frame_lost=failsafe,
            failsafe=failsafe,
        )


class IbusSession(FrameLineSession):
    """iBus: channels 1..14 in µs; channels past the list at 1000 µs ("off" for a switch)."""

    def __init__(self) -> None:
        super().__init__()
        self.withheld = 0  # ticks without a frame because a channel is in failsafe

    def frame(self, channels: Sequence[int], failsafe: bool) -> bytes:
        if failsafe:
            self.withheld += 1
            return b""
        unlisted = [ibus.PULSE_LOW] * (ibus.CHANNELS - len(channels))
        return ibus.encode_ibus([*channels[: ibus.CHANNELS], *unlisted])


@dataclass(frozen=True)
class ModuleLink:
    """The module's last link statistics and when they came (clock of the session's
    caller): one value, replaced whole, so a stats thread never reads one report's
    figures with another's time."""

    stats: crsf.LinkStatistics
    at: float


@dataclass(frozen=True)
class ModuleTiming:
    """The module's last timing correction, as followed: when it came (clock of the
    session's caller), its packet interval and the offset it asked for (seconds)."""

    at: float
    interval_s: float
    offset_s: float


class CrsfSession(FrameLineSession):
    """CRSF to a transmitter module (or a flight controller's receiver UART): RC frames, the
    module's telemetry, its timing."""

    def __init__(
        self,
        interval_s: float,
        *,
        follow_module: bool = True,
        min_interval_s: float = 0.0,
        address: int = crsf.ADDRESS_MODULE,
    ) -> None:
        """`interval_s`: the configured period; `min_interval_s`: the shortest the line
        carries (one frame a tick at the baud rate): a faster module rate is followed only
        down to it; `address`: the RC frames' first byte (0xEE a module, 0xC8 a flight
        controller, which drops RC frames to any other address)."""
        super().__init__()
        self.configured_interval_s = interval_s
        self.address = address
        self.follow_module = follow_module
        self.min_interval_s = max(MIN_INTERVAL_S, min_interval_s)
        self.decoder = crsf.CrsfDecoder()
        # Written by the output thread only (`received`), read by the stats thread: one
        # immutable value, assigned in one step.
        self.link: ModuleLink | None = None
        self.timing: ModuleTiming | None = None
        self.withheld = 0  # ticks without an RC frame because a channel is in failsafe
        self.timing_frames = 0
        self.timing_ignored = 0  # implausible or not followed
        self.other_frames = 0
        self._shift_s = 0.0  # the phase correction still to apply to the next send

    def frame(self, channels: Sequence[int], failsafe: bool) -> bytes:
        if failsafe:
            self.withheld += 1
            return b""
        return crsf.encode_rc_channels(padded(channels), self.address)

    # --- what the module sends back ------------------------------------------------------

    def received(self, data: bytes, now: float) -> None:
        """Bytes read from the module at clock `now`."""
        for frame in self.decoder.feed(data):
            if isinstance(frame, crsf.LinkStatistics):
                self.link = ModuleLink(frame, now)
            elif isinstance(frame, crsf.TimingSync):
                self._follow(frame, now)
            else:
                self.other_frames += 1

    def _follow(self, sync: crsf.TimingSync, now: float) -> None:
        self.timing_frames += 1
        interval = sync.interval_s
        if not self.follow_module or not MIN_INTERVAL_S <= interval <= MAX_INTERVAL_S:
            self.timing_ignored += 1
            return
        interval = max(interval, self.min_interval_s)
        # The offset says how long before the module needs it a frame arrives (beyond the
        # module's margin): send that much later (earlier when negative), at most half a
        # period at a time so one odd measurement cannot skip or double a frame.
        half = interval / 2
        self._shift_s = max(-half, min(half, sync.offset_s))
        self.timing = ModuleTiming(now, interval, sync.offset_s)

    # --- when to send ----------------------------------------------------------------------

    def following(self, now: float) -> bool:
        """Whether the module's timing is followed now (a correction in the last second)."""
        return self.timing is not None and now - self.timing.at <= SYNC_STALE_S

    def interval_s(self, now: float) -> float:
        if self.timing is not None and self.following(now):
            return self.timing.interval_s
        return self.configured_interval_s

    def next_send(self, due: float, now: float) -> float:
        """When the frame after the one due at `due` is due: one interval later (the
        module's while it sends timing corrections), shifted once by its last offset.

        The shifted period stays within what following allows (MIN_INTERVAL_S, and a
        frame's time on the line, up to MAX_INTERVAL_S): a module that sends a correction
        before every frame could otherwise shift every period, and a -0.5 ms offset on a
        1 ms interval sent twice as many frames as the line carries."""
        shift, self._shift_s = self._shift_s, 0.0
        if not self.following(now):
            return due + self.configured_interval_s  # a stale correction says nothing
        period = self.interval_s(now) + shift
        return due + max(self.min_interval_s, min(MAX_INTERVAL_S, period))

    def link_text(self, now: float) -> str:
        """Link quality and timing for `stats` and `monitor`."""
        parts = []
        module_link = self.link  # one read: the figures and their time belong together
        if module_link is None:
            parts.append("no link statistics from the module")
        else:
            link = module_link.stats
            parts.append(
                f"link quality {link.uplink_link_quality}% up / "
                f"{link.downlink_link_quality}% down, RSSI -{link.uplink_rssi_1} dBm, "
                f"SNR {link.uplink_snr} dB ({now - module_link.at:.1f} s ago)"
            )
        if self.timing is not None and self.following(now):
            parts.append(
                f"following the module: {1 / self.timing.interval_s:.0f} Hz, "
                f"offset {self.timing.offset_s * 1e6:+.1f} µs"
            )
        else:
            parts.append(f"own rate {1 / self.configured_interval_s:.0f} Hz")
        return ", ".join(parts)
