"""The CRSF line session: RC frames at the module's pace when it gives one, silence in
failsafe, and what the module sends back (link statistics, timing corrections)."""

from __future__ import annotations

from typing import Any

from usb2rc.lines.session import ChannelValues, FrameSession
from usb2rc.protocol import crsf
from usb2rc.rc_sessions import CrsfSession


class CrsfLine(FrameSession):
    engine: CrsfSession

    def __init__(self, name: str, channels: ChannelValues, engine: CrsfSession) -> None:
        super().__init__(name, engine, channels, crsf.RC_FRAME_LEN, engine.configured_interval_s)

    def received(self, data: bytes, now: float) -> None:
        self.engine.received(data, now)

    def next_due(self, due: float, now: float) -> float:
        """The module's interval and phase while it sends timing corrections."""
        return self.engine.next_send(due, now)

    def period(self, now: float) -> float:
        return self.engine.interval_s(now)

    def stats(self, now: float) -> dict[str, Any]:
        """The module's link quality, timing and what was withheld."""
        session, decoder = self.engine, self.engine.decoder
        module_link = session.link  # one read: one report's figures
        link = None if module_link is None else module_link.stats
        return {
            **super().stats(now),
            "module": session.link_text(now),
            "link_quality_up": None if link is None else link.uplink_link_quality,
            "link_quality_down": None if link is None else link.downlink_link_quality,
            "frames_withheld": session.withheld,
            "module_rx_frames": decoder.frames,
            "module_rx_crc_failures": decoder.crc_failures,
            "module_rx_skipped": decoder.bytes_skipped,
            "timing_corrections": session.timing_frames,
            "timing_corrections_ignored": session.timing_ignored,
        }
