"""The CRSF line session, sans-IO (no thread, no port, no clock: time is passed in).

- `CrsfSession` (a `lines.session.ChannelSession`: one frame a tick while the line is open
  and not stalled, 11-bit wire values in, `protocols.rc11_channels.RC11_SCALE`): an
  RC_CHANNELS_PACKED frame every tick while every listed channel is live (to the module's
  address 0xEE, or to a flight controller's 0xC8: `address`); while any is in failsafe it
  sends nothing, so the ExpressLRS transmitter module stops and the receiver's own failsafe
  fires (docs/ICD.md, "CRSF failsafe").
- `CrsfModule`: the module as the session hears it: what it sends back (`received(data,
  now)`: link statistics, and the timing-correction frames with which an ELRS module asks the
  handset to follow its packet rate and phase), and when the next frame is due
  (`next_send(due, now)`). Its link statistics, battery and flight mode frames are the
  session's `telemetry` (`crsf.telemetry.CrsfReports`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from usb2rc.feedback.model import CrsfTelemetry
from usb2rc.lines.session import ChannelSession, ChannelValues
from usb2rc.protocols.crsf import codec as crsf
from usb2rc.protocols.crsf.telemetry import CrsfReports
from usb2rc.protocols.rc11_channels import padded

# ELRS sends a timing correction every 200 ms while it hears the handset; after a second
# without one the line goes back to its configured rate.
SYNC_STALE_S = 1.0
MIN_INTERVAL_S = 0.001  # the module's rate is followed up to 1000 Hz, never faster
MAX_INTERVAL_S = 0.1  # ... and down to 10 Hz; anything else is implausible and ignored


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


class CrsfModule:
    """The transmitter module (or flight controller) as a CRSF line hears it: its telemetry
    and its timing."""

    def __init__(
        self,
        interval_s: float,
        *,
        follow_module: bool = True,
        min_interval_s: float = 0.0,
    ) -> None:
        """`interval_s`: the configured period; `min_interval_s`: the shortest the line
        carries (one frame a tick at the baud rate): a faster module rate is followed only
        down to it."""
        self.configured_interval_s = interval_s
        self.follow_module = follow_module
        self.min_interval_s = max(MIN_INTERVAL_S, min_interval_s)
        self.decoder = crsf.CrsfDecoder()
        # Written by the output thread only (`received`), read by the stats thread: one
        # immutable value, assigned in one step.
        self.link: ModuleLink | None = None
        self.timing: ModuleTiming | None = None
        self.reports = CrsfReports()
        self.timing_frames = 0
        self.timing_ignored = 0  # implausible or not followed
        self._shift_s = 0.0  # the phase correction still to apply to the next send

    # --- what the module sends back ------------------------------------------------------

    def received(self, data: bytes, now: float) -> None:
        """Bytes read from the module at clock `now`."""
        for frame in self.decoder.feed(data):
            if isinstance(frame, crsf.LinkStatistics):
                self.link = ModuleLink(frame, now)
            elif isinstance(frame, crsf.TimingSync):
                self._follow(frame, now)
            self.reports.take(frame, now)

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
        1 ms interval would send twice as many frames as the line carries."""
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


class CrsfSession(ChannelSession):
    """CRSF to a transmitter module (or a flight controller's receiver UART): RC frames on
    the module's timing while it sends corrections (`module`)."""

    # a module follows the handset's packet timing, and corrects its phase to the microsecond
    on_deadline = True

    def __init__(
        self,
        name: str,
        channels: ChannelValues,
        module: CrsfModule,
        address: int = crsf.ADDRESS_MODULE,
    ) -> None:
        """`address`: the RC frames' first byte (0xEE a module, 0xC8 a flight controller,
        which drops RC frames to any other address)."""
        super().__init__(name, channels, crsf.RC_FRAME_LEN, module.configured_interval_s)
        self.module = module
        self.address = address
        self.withheld = 0  # ticks without an RC frame because a channel is in failsafe

    def encode(self, values: Sequence[int], failsafe: bool) -> bytes:
        if failsafe:
            self.withheld += 1
            return b""
        return crsf.encode_rc_channels(padded(values), self.address)

    def received(self, data: bytes, now: float) -> None:
        self.module.received(data, now)

    def makes_ahead(self) -> bool:
        """While it sends: a module corrects the frames' phase to the microsecond, and at
        500 Hz a frame made on its deadline beside C2-16B's would move by the tick's work
        (docs/DESIGN.md, `lines/driver.LineDriver`). Silent (a channel's node in
        failsafe), it has no frame to time."""
        return not self._silent

    def frame_due(self, due: float, now: float) -> float:
        """The module's interval and phase while it sends timing corrections."""
        return self.module.next_send(due, now)

    def period(self, now: float) -> float:
        return self.module.interval_s(now)

    @property
    def telemetry(self) -> CrsfTelemetry | None:
        """The module's link statistics, battery and flight mode (None: none heard yet)."""
        return self.module.reports.value

    def stats(self, now: float) -> dict[str, Any]:
        """The module's link quality, timing and what was withheld."""
        module, decoder = self.module, self.module.decoder
        module_link = module.link  # one read: one report's figures
        link = None if module_link is None else module_link.stats
        return {
            **super().stats(now),
            "module": module.link_text(now),
            "link_quality_up": None if link is None else link.uplink_link_quality,
            "link_quality_down": None if link is None else link.downlink_link_quality,
            "frames_withheld": self.withheld,
            "module_rx_frames": decoder.frames,
            "module_rx_crc_failures": decoder.crc_failures,
            "module_rx_skipped": decoder.bytes_skipped,
            **module.reports.record(),
            "timing_corrections": module.timing_frames,
            "timing_corrections_ignored": module.timing_ignored,
        }
