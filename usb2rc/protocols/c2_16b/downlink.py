"""The C2-16B downlink as a line hears it, sans-IO (docs/ICD.md "Downlink"): the far end's
`>` data frames, the newest per Node-ID.

A valid data frame from the far end with status `>` and Node-ID N is a downlink for node N:
its two button groups as 64 indicator bits (group 1 in bits 0-31, group 2 in bits 32-63) and
its 10 axes as int16 (`usb2rc.feedback.model.Downlink`). What to light and drive with them is
the feedback engine's business; nothing here reaches what the line sends up.

`Downlinks.take(frame)` keeps a read's frames, the newest per Node-ID; `publish(now)`, once
per read, makes `latest` the newest downlink of every Node-ID heard, sorted by Node-ID: one
tuple replaced whole (None before the first), which another thread reads without a lock.
Bounded whatever the far end sends: a frame costs one dict store, and a read rebuilds the
tuple once (at most 256 entries), so a flood of downlinks costs the reads O(bytes) and keeps
no more than one downlink per Node-ID.
"""

from __future__ import annotations

from collections import OrderedDict, deque
from typing import TypeGuard

from usb2rc.feedback.model import Downlink
from usb2rc.protocols.c2_16b import codec as c2_16b

GROUP_BITS = 32  # group 2's bits follow group 1's
# What the line sent lately, for the echo check: the bytes of the last ECHO_TICKS ticks (at
# 50 Hz ~1.3 s: an echo comes back within a few ms), decoded only when a `>` frame comes in,
# at most ECHO_FRAMES data frames kept.
ECHO_TICKS = 64
ECHO_FRAMES = 1024


def is_downlink(frame: c2_16b.Frame) -> TypeGuard[c2_16b.DataFrame]:
    """A `>` data frame from the far end: a downlink for its Node-ID."""
    return isinstance(frame, c2_16b.DataFrame) and frame.status == c2_16b.LIVE


def downlink_of(frame: c2_16b.DataFrame, at: float) -> Downlink:
    """A `>` frame as the downlink it carries, received at `at`."""
    indicators = frame.group1 | frame.group2 << GROUP_BITS
    return Downlink(frame.node_id, indicators, tuple(frame.axes), at)


class OwnFrames:
    """The data frames this line sent lately, to tell an echo of them (a loopback plug, a
    half-duplex wire that hears itself) from a downlink: a `>` frame equal to one of them
    (Node-ID, message code, axes, groups: the rolling code makes a far end's own frame
    equal to one of ours only if it copies it) is an echo. A tick costs one append; the
    sent bytes are decoded only when a `>` frame comes in, so a far end that sends none
    costs nothing."""

    def __init__(self) -> None:
        self._undecoded: deque[bytes] = deque(maxlen=ECHO_TICKS)
        self._decoder = c2_16b.Decoder()
        self._frames: OrderedDict[c2_16b.DataFrame, None] = OrderedDict()

    def sent(self, data: bytes) -> None:
        if data:
            self._undecoded.append(data)

    def is_echo(self, frame: c2_16b.DataFrame) -> bool:
        frames = self._frames
        while self._undecoded:
            for own in self._decoder.feed(self._undecoded.popleft()):
                if isinstance(own, c2_16b.DataFrame):
                    frames[own] = None
                    if len(frames) > ECHO_FRAMES:
                        frames.popitem(last=False)
        return frame in frames


class Downlinks:
    """The newest downlink per Node-ID (see the module docstring)."""

    def __init__(self) -> None:
        self.frames = 0  # downlink frames taken, every one counted
        # Written by the line's thread only (`publish`), read by the feedback worker: one
        # immutable value, assigned in one step.
        self.latest: tuple[Downlink, ...] | None = None  # None: no downlink yet
        self._by_node: dict[int, Downlink] = {}
        self._read: dict[int, c2_16b.DataFrame] = {}  # this read's newest frame per Node-ID

    def take(self, frame: c2_16b.DataFrame) -> None:
        self.frames += 1
        self._read[frame.node_id] = frame

    def publish(self, now: float) -> None:
        """This read's frames, received at `now`, become the published downlinks."""
        if not self._read:
            return
        for node_id, frame in self._read.items():
            self._by_node[node_id] = downlink_of(frame, now)
        self._read.clear()
        by_node = self._by_node
        self.latest = tuple(by_node[node_id] for node_id in sorted(by_node))
