"""A device that falls silent fails safe (docs/ICD.md, "A device that falls silent").

A Bluetooth pad out of range stays plugged for the 20-30 s Linux takes to notice, and a
device whose firmware hangs stays plugged for ever: its node would stay live on its last
values. A device that has been *streaming* (sending reports whether or not anything
changed) and then sends none for more than max(MIN_SILENCE_S, SILENCE_INTERVALS × its usual
interval) puts its node in failsafe, though it is still present; when its reports come
back it goes live through the neutral guard, as a re-plugged device does.

Which kind a device is, is learned from its reports: one that sent STREAMING_AFTER reports
byte for byte the same as the report before (`ReaderRecord.repeats`) streams; one that
reports only on change never sends the same report twice in a row, so it is never judged
by silence (a stick held still sends nothing, and that is no fault). A device whose sensor
jitters differs in every report and is not learned as streaming either: no watchdog for it,
never a false `!`. The config entry's `reports: streaming | on_change` says it instead of
learning. The usual interval is the reports' mean interval over the last RATE_WINDOW_S.
"""

from __future__ import annotations

from dataclasses import dataclass

from usb2rc.hid.reader import ReaderRecord

STREAMING_AFTER = 20  # repeated reports that show a device streams
MIN_SILENCE_S = 0.1
SILENCE_INTERVALS = 10
RATE_WINDOW_S = 1.0


@dataclass
class SilenceWatch:
    """One attached device's watch (the node table's, stepped under its lock)."""

    kind: str = "auto"  # the entry's `reports:`: auto, streaming or on_change
    streaming: bool = False
    interval_s: float = 0.0  # the usual interval between two reports, once measured
    window: tuple[float, int] | None = None  # (time, reports) where the rate window began
    seen_reports: int = 0  # the report count at the last check

    def limit_s(self) -> float:
        """How long the device may be silent."""
        return max(MIN_SILENCE_S, SILENCE_INTERVALS * self.interval_s)

    def silent(self, record: ReaderRecord, now: float) -> bool:
        """Whether the device, which published `record`, is silent at `now`."""
        if self.kind == "on_change" or record.reports == 0 or record.at is None:
            return False
        if record.refused_in_a_row:  # it sends, refused: its bad reports are another fault
            return False
        if not self.streaming:
            self.streaming = self.kind == "streaming" or record.repeats >= STREAMING_AFTER
        self._learn(record.at, record.reports)
        fresh, self.seen_reports = record.reports != self.seen_reports, record.reports
        # A step whose pull found reports is never silent, however late it ran: only a
        # check that finds none since the last one, that long after the last, is.
        return self.streaming and not fresh and now - record.at > self.limit_s()

    def _learn(self, at: float, reports: int) -> None:
        if self.window is None:
            self.window = (at, reports)
            return
        began, counted = self.window
        if at - began >= RATE_WINDOW_S and reports > counted:
            self.interval_s = (at - began) / (reports - counted)
            self.window = (at, reports)
