"""The MAVLink output: node frames → RC_CHANNELS_OVERRIDE or MANUAL_CONTROL, and a GCS
HEARTBEAT, through pymavlink (docs/ICD.md, "MAVLink output").

Two pieces, both sans-IO (no thread, no socket, no clock: `now` is passed in):

- `MavlinkChannels`: the configured channels (named as SUMD names them, `nodeN.<slot>` /
  `nodeN.buttonK`) evaluated once a tick from the NodeTable's frames into the message's
  fields, with the scalings of `protocols.mavlink.codec` (`axis_to_pwm`, `button_to_pwm`,
  `axis_to_manual`, `axis_to_manual_z`), and whether any channel's node is in failsafe.
- `MavlinkEngine`: what goes on the line each tick: a HEARTBEAT (MAV_TYPE_GCS,
  MAV_AUTOPILOT_INVALID) when one is due (the first tick of a line, then once a second), and
  the control message. MAVLink has no failsafe flag, so a failsafe is told by what is
  (not) sent:
  - rc_channels_override: every channel is released back to the vehicle's RC radio (0 on
    channels 1-8, UINT16_MAX-1 on 9-18) for `RELEASE_S`, then nothing but heartbeats until
    every node is live again: the vehicle's radio, or its own radio failsafe, has it;
  - manual_control: no MANUAL_CONTROL at all, so the autopilot's manual-control-lost
    failsafe fires (PX4 COM_RC_LOSS_T; ArduPilot's RC_OVERRIDE_TIME).
  What the far end sends is parsed with a second pymavlink instance
  (`protocols.mavlink.codec.MavlinkDecoder`, `received`): its heartbeats are counted for the
  stats, and the vehicle's HEARTBEAT, SYS_STATUS and BATTERY_STATUS are the session's
  `telemetry` (`protocols.mavlink.telemetry.VehicleTelemetry`: armed, mode, battery, failsafe).
- With a signing key (`signing_key_file`) every message is signed (MAVLink 2 signing, link
  id 0, timestamps from the wall clock passed to `tick`), and only messages signed with the
  key count from the far end.
- `VehicleCall`: whether a datagram to a udpin port is the vehicle calling (a HEARTBEAT
  from `target_system`, signed when signing is on): `lines.udp_link.UdpLink` locks to the
  first sender that calls.

- `MavlinkSession`: the engine on the one session interface (`usb2rc.lines.session`): a
  tick's messages in one write (one datagram on UDP: MAVLink receivers parse the packets of
  a datagram back to back, docs/ICD.md "MAVLink output").

pymavlink packs every byte (`message.pack(mav)`); nothing here writes MAVLink by hand.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

from pymavlink.dialects.v20 import common as mavlink2

from usb2rc.config.channel_ref import ChannelRef
from usb2rc.config.controls_model import ActionConfig
from usb2rc.config.mavlink import (
    MANUAL_AXES,
    MESSAGES,
    OVERRIDE_MAX_CHANNELS,
    RC_CHANNELS_OVERRIDE,
    MavlinkOptions,
)
from usb2rc.feedback.model import MavlinkTelemetry
from usb2rc.lines.session import Backpressure, Delivered, EngineSession, LineState
from usb2rc.nodes.mapping import ChannelSource
from usb2rc.nodes.scaling import node_button_bit
from usb2rc.nodes.table import NodeFrame, NodeSnapshot
from usb2rc.protocols.channels import int16_value, nodes_read
from usb2rc.protocols.mavlink.actions import ActionRunner
from usb2rc.protocols.mavlink.codec import (
    MANUAL_MAX,
    MANUAL_MIN,
    MANUAL_Z_MAX,
    MANUAL_Z_MIN,
    MavlinkDecoder,
    axis_to_manual,
    axis_to_manual_z,
    axis_to_pwm,
    button_to_pwm,
    set_up_signing,
    signing_timestamp,
)
from usb2rc.protocols.mavlink.telemetry import VehicleTelemetry

OVERRIDE_FIRST_CHANNELS = 8  # channels 1-8: 0 releases; 9-18 (MAVLink 2 extensions): 65534
RELEASE_LOW, RELEASE_HIGH = 0, 65534  # common.xml: 0 / UINT16_MAX-1 "release to the RC radio"
IGNORE = 65535  # common.xml: UINT16_MAX "ignore this field" (channels not configured)
HEARTBEAT_S = 1.0  # MAVLink's heartbeat rate: 1 Hz
RELEASE_S = 1.0  # how long the release is repeated (datagrams get lost) before silence

Nodes = Mapping[int, NodeFrame]
Channel = ChannelRef | ChannelSource
Reading = Callable[[Nodes], tuple[int, bool]]  # -> (int16 axis, or 1 pressed, failsafe)
Trigger = tuple[ChannelSource, int | None]  # an action's button (None) or switch and its value


def channel_reading(source: Channel) -> Reading:
    """One channel's node value each tick: an axis as int16 (a uint16 slot, as the frame's
    `unsigned_slots` says, shifted down by 32768; a slot nobody feeds is the centre), a
    button as 1 pressed or 0 not (`is_button` says which a channel is: never the value's
    type, which a compiled module does not keep); and whether its node is failsafe (or
    absent: centre / released, failsafe). Never raises on a tick."""
    node_id, index = source.node_id, source.index
    if isinstance(source, ChannelSource) and source.kind in ("switch", "mix"):
        return int16_value(source)  # a switch or mix (nodes/curves.py): an int16, as an axis
    if source.kind == "button":
        group, bit = node_button_bit(index)

        def button(nodes: Nodes) -> tuple[int, bool]:
            frame = nodes.get(node_id)
            if frame is None:
                return 0, True
            word = frame.group2 if group else frame.group1
            return word >> bit & 1, frame.failsafe

        return button

    def axis(nodes: Nodes) -> tuple[int, bool]:
        frame = nodes.get(node_id)
        if frame is None:
            return 0, True
        value = frame.axes[index]
        unsigned = frame.unsigned_slots >> index & 1
        if value is None:
            return 0, frame.failsafe
        return (value - 32768 if unsigned else value), frame.failsafe

    return axis


def is_button(source: Channel) -> bool:
    """Whether `channel_reading(source)` reads a button (1 pressed, 0 not)."""
    if isinstance(source, ChannelSource) and source.kind in ("switch", "mix"):
        return False
    return source.kind == "button"


def _pwm(value: int, button: bool) -> int:
    return button_to_pwm(value != 0) if button else axis_to_pwm(value)


def _manual(value: int, button: bool, field_name: str) -> int:
    """A MANUAL_CONTROL axis field; a button there is the field's ends."""
    if field_name == "z":
        if button:
            return MANUAL_Z_MAX if value else MANUAL_Z_MIN
        return axis_to_manual_z(value)
    if button:
        return MANUAL_MAX if value else MANUAL_MIN
    return axis_to_manual(value)


@dataclass(frozen=True)
class ControlValues:
    """One tick's message fields: `channels` (µs, RC_CHANNELS_OVERRIDE) or `axes`
    (x, y, z, r) and `buttons` (32 bits, MANUAL_CONTROL); `failsafe`: a channel's node is."""

    failsafe: bool
    channels: tuple[int, ...] = ()
    axes: tuple[int, int, int, int] = (0, 0, 0, 0)
    buttons: int = 0
    # MAVLink actions (protocols/mavlink/actions.py): each trigger active in this frame,
    # and whether a trigger's node is in failsafe
    triggers: tuple[bool, ...] = ()
    triggers_failsafe: bool = False


class MavlinkChannels:
    """One MAVLink output's channels: `evaluate(frames)` once a tick."""

    def __init__(
        self,
        sources: Iterable[Channel],
        message: str = RC_CHANNELS_OVERRIDE,
        triggers: Sequence[Trigger] = (),
    ) -> None:
        if message not in MESSAGES:
            raise ValueError(f"unknown MAVLink message {message!r}")
        self.sources = tuple(sources)
        self.message = message
        self.readings = tuple(channel_reading(source) for source in self.sources)
        self.buttons = tuple(is_button(source) for source in self.sources)
        self.triggers = tuple(trigger_value(source, target) for source, target in triggers)
        # the nodes the channels and the actions' buttons and switches read (None: any)
        self.node_ids = nodes_read([*self.sources, *(source for source, _ in triggers)])
        # the last frames evaluated and what they gave: every reading and trigger is a
        # function of the node frames alone, so equal frames (nodes in failsafe, sticks
        # at rest) give the same (immutable) values without reading them again
        self._last: tuple[list[NodeFrame], ControlValues] | None = None

    def __len__(self) -> int:
        return len(self.readings)

    def evaluate(self, frames: Iterable[NodeFrame]) -> ControlValues:
        frames = list(frames)
        last = self._last
        if last is not None and last[0] == frames:
            return last[1]
        nodes = {frame.node_id: frame for frame in frames}
        values = self._values(nodes)
        if self.triggers:
            values = replace(values, **self._triggers(nodes))
        self._last = (frames, values)
        return values

    def _triggers(self, nodes: Nodes) -> dict[str, Any]:
        """Each action's trigger (usb2rc.protocols.mavlink.actions), and whether a trigger's
        node is in failsafe."""
        active, failsafe = [], False
        for trigger in self.triggers:
            is_active, node_failsafe = trigger(nodes)
            active.append(is_active)
            failsafe = failsafe or node_failsafe
        return {"triggers": tuple(active), "triggers_failsafe": failsafe}

    def _values(self, nodes: Nodes) -> ControlValues:
        values: list[int] = []
        failsafe = False
        for reading in self.readings:
            value, channel_failsafe = reading(nodes)
            values.append(value)
            failsafe = failsafe or channel_failsafe
        kinds = self.buttons
        if self.message == RC_CHANNELS_OVERRIDE:
            return ControlValues(failsafe, channels=tuple(map(_pwm, values, kinds)))
        axes = [_manual(*field) for field in zip(values, kinds, MANUAL_AXES, strict=False)]
        axes += [0] * (len(MANUAL_AXES) - len(axes))
        buttons = 0
        extra = len(MANUAL_AXES)
        for bit, (value, button) in enumerate(zip(values[extra:], kinds[extra:], strict=True)):
            pressed = value != 0 if button else value > 0  # an axis: past centre
            buttons |= int(pressed) << bit
        return ControlValues(failsafe, axes=(axes[0], axes[1], axes[2], axes[3]), buttons=buttons)


TriggerValue = Callable[[Nodes], tuple[bool, bool]]  # the frames -> (active, failsafe)


def trigger_value(source: ChannelSource, target: int | None) -> TriggerValue:
    """An action's trigger: a node button pressed while its node was live (target None), or
    a switch that such a press moved to the position of int16 value `target`. A button held
    since before its node went live is never active (docs/ICD.md, "A held button is not a
    press"), though its channels show it held."""
    node_id = source.node_id
    if target is None:
        group, bit = node_button_bit(source.index)

        def button(nodes: Nodes) -> tuple[bool, bool]:
            frame = nodes.get(node_id)
            if frame is None:
                return False, True
            return bool(frame.pressed[group] >> bit & 1), frame.failsafe

        return button
    value, name = int16_value(source), source.name.removeprefix("switch.")

    def switch(nodes: Nodes) -> tuple[bool, bool]:
        int16, failsafe = value(nodes)
        frame = nodes.get(node_id)
        moved = frame is not None and name in frame.pressed_switches
        return moved and int16 == target, failsafe

    return switch


def release_channels(count: int = OVERRIDE_MAX_CHANNELS) -> list[int]:
    """RC_CHANNELS_OVERRIDE values that hand every channel back to the RC radio."""
    return [RELEASE_LOW if i < OVERRIDE_FIRST_CHANNELS else RELEASE_HIGH for i in range(count)]


@dataclass
class FarEnd:
    """What the far end sent, as pymavlink parsed it (for the stats line)."""

    decoder: MavlinkDecoder
    heartbeats: int = 0
    last_heartbeat_from: tuple[int, int] | None = None  # (system, component)


class MavlinkEngine:
    """The MAVLink line of one output, sans-IO: `tick(now, values)` → the messages to send,
    one `bytes` each (one datagram each on UDP), and `wrote(sent)` for each of them in
    order. The line events are `lines.session.Engine`'s; `line`: the line's state it moves
    (its session's; a new one when it runs alone). `key`: the signing key
    (`config.mavlink.read_signing_key`), `wall_time`: the wall clock at the start."""

    def __init__(
        self,
        settings: MavlinkOptions,
        key: bytes | None = None,
        wall_time: float = 0.0,
        actions: Sequence[ActionConfig] = (),
        line: LineState | None = None,
    ) -> None:
        self.settings = settings
        self.signed = key is not None
        self.mav = mavlink2.MAVLink(
            None, srcSystem=settings.system_id, srcComponent=settings.component_id
        )
        if key is not None:
            set_up_signing(self.mav, key, wall_time, sign_outgoing=True)
        self.line = LineState() if line is None else line
        self.heartbeats = 0
        self.controls = 0  # override / manual_control messages sent (live values)
        self.releases = 0  # override messages releasing every channel (failsafe)
        self.silent_ticks = 0  # ticks without a control message (failsafe)
        self.far_end = FarEnd(MavlinkDecoder(key, wall_time))
        self.vehicle = VehicleTelemetry(settings.target_system, settings.target_component)
        self._next_heartbeat: float | None = None
        self._failsafe_since: float | None = None
        self._pending: deque[int] = deque()
        self._stop_ticked = False  # stopping: a failsafe tick's messages were made
        # --- MAVLink actions (usb2rc.protocols.mavlink.actions): the runner, fed in tick/received
        target = (settings.target_system, settings.target_component)
        self.actions = ActionRunner(actions, self.mav, target) if actions else None

    def stopping(self) -> None:
        """usb2rc stops (docs/ICD.md, "Stop"): from the next tick on, the values count as
        failsafe (the release of every channel, or silence)."""
        self.line.stop()

    @property
    def stop_done(self) -> bool:
        """Stopping, and a failsafe tick's messages went out (or the line cannot take them)."""
        return self.line.stop_done(self._stop_ticked and not self._pending)

    # --- line events (as a channel output's) -------------------------------------------

    def line_opened(self) -> None:
        self.line.opened()
        self._next_heartbeat = None  # a new line starts with a heartbeat

    def line_lost(self) -> None:
        self.line.lost()
        self._pending.clear()

    def line_drained(self) -> None:
        self.line.resumed()

    def line_flushed(self) -> None:
        self.line.resumed()

    # --- ticks -------------------------------------------------------------------------------

    def tick(self, now: float, values: ControlValues, wall_time: float = 0.0) -> list[bytes]:
        """This tick's messages: a heartbeat when due, then the control message (or the
        release, or nothing, in failsafe). `wall_time` keeps signing timestamps on the wall
        clock (each message's is one more than the last's: they fall behind otherwise, and
        a vehicle that restarts refuses a stream more than a minute old)."""
        self._pending.clear()
        if not self.line.is_open or self.line.stalled:
            return []
        if self.signed:
            signing = self.mav.signing
            signing.timestamp = max(signing.timestamp, signing_timestamp(wall_time))
        if self.line.stopping:
            values = replace(values, failsafe=True)
            self._stop_ticked = True
        messages: list[bytes] = []
        if self._next_heartbeat is None or now >= self._next_heartbeat:
            messages.append(self._pack(self._heartbeat()))
            self.heartbeats += 1
            due = HEARTBEAT_S + (now if self._next_heartbeat is None else self._next_heartbeat)
            # on time: every HEARTBEAT_S; after a pause, a second from now (no burst)
            self._next_heartbeat = due if due > now else now + HEARTBEAT_S
        control = self._control(now, values)
        if control is not None:
            messages.append(self._pack(control))
        if self.actions is not None:  # --- MAVLink actions: after the control message
            failsafe = values.failsafe or values.triggers_failsafe
            commands = self.actions.tick(now, values.triggers, failsafe)
            messages += [self._pack(command) for command in commands]
        self._pending.extend(len(m) for m in messages)
        return messages

    def _control(self, now: float, values: ControlValues) -> mavlink2.MAVLink_message | None:
        if not values.failsafe:
            self._failsafe_since = None
            self.controls += 1
            return self._message(values)
        if self._failsafe_since is None:
            self._failsafe_since = now
        if self.settings.message == RC_CHANNELS_OVERRIDE and now - self._failsafe_since < RELEASE_S:
            self.releases += 1
            return self._override(release_channels())
        self.silent_ticks += 1
        return None

    def _message(self, values: ControlValues) -> mavlink2.MAVLink_message:
        if self.settings.message == RC_CHANNELS_OVERRIDE:
            channels = list(values.channels)
            return self._override(channels + [IGNORE] * (OVERRIDE_MAX_CHANNELS - len(channels)))
        x, y, z, r = values.axes
        return self.mav.manual_control_encode(
            self.settings.target_system,
            x,
            y,
            z,
            r,
            values.buttons & 0xFFFF,
            buttons2=values.buttons >> 16 & 0xFFFF,
        )

    def _override(self, channels: Sequence[int]) -> mavlink2.MAVLink_message:
        s = self.settings
        return self.mav.rc_channels_override_encode(s.target_system, s.target_component, *channels)

    def _heartbeat(self) -> mavlink2.MAVLink_message:
        return self.mav.heartbeat_encode(
            mavlink2.MAV_TYPE_GCS, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, mavlink2.MAV_STATE_ACTIVE
        )

    def _pack(self, message: mavlink2.MAVLink_message) -> bytes:
        data: bytes = message.pack(self.mav)
        self.mav.seq = (self.mav.seq + 1) % 256  # what MAVLink.send does after packing
        return data

    def wrote(self, sent: int, unsure: int = 0) -> Delivered:
        """One message of the last tick went out (`sent` bytes): a datagram or a message cut
        short stalls the line until it drains (the rest of the tick is not sent)."""
        length = self._pending.popleft() if self._pending else 0
        whole = length > 0 and sent >= length
        stalled = self.line.is_open and length > 0 and sent < length
        if stalled:
            self._pending.clear()
            self.line.stall()
        return Delivered(0, 1 if whole else 0, stalled)

    # --- the far end ---------------------------------------------------------------------

    def received(self, data: bytes, now: float = 0.0) -> None:
        """Bytes from the far end at `now` (the session's clock): parsed, heartbeats
        counted, the vehicle's state kept (`vehicle`)."""
        if not data:
            return
        far = self.far_end
        for message in far.decoder.feed(data):
            if self.actions is not None:  # --- MAVLink actions: the vehicle, its acks
                self.actions.received(message)
            if message.get_type() == "HEARTBEAT":
                far.heartbeats += 1
                far.last_heartbeat_from = (message.get_srcSystem(), message.get_srcComponent())
            self.vehicle.take(message, now)


class VehicleCall:
    """Whether one datagram to a udpin port is the vehicle calling: a valid HEARTBEAT from
    `target_system` (any system when 0) that is not a ground station's, signed with the
    key when signing is on. Each datagram is parsed on its own (no bytes of one sender
    joined to another's); signing timestamps seen are kept, so a replayed one is refused."""

    def __init__(self, target_system: int, key: bytes | None = None, wall_time: float = 0.0):
        self.target_system = target_system
        self.decoder = MavlinkDecoder(key, wall_time)

    def __call__(self, datagram: bytes) -> bool:
        return any(map(self._calls, self.decoder.feed_alone(datagram)))

    def _calls(self, message: Any) -> bool:
        if message.get_type() != "HEARTBEAT" or message.type == mavlink2.MAV_TYPE_GCS:
            return False
        return self.target_system in (0, message.get_srcSystem())


def stats_record(session: MavlinkEngine) -> dict[str, Any]:
    """The output's MAVLink counters, for the stats record (labels: `usb2rc.runtime.stats_text`)."""
    far = session.far_end
    record: dict[str, Any] = {
        "mavlink_message": session.settings.message,
        "control_messages": session.controls,
        "releases": session.releases,
        "silent_failsafe_ticks": session.silent_ticks,
        "heartbeats_sent": session.heartbeats,
        "far_end_messages": far.decoder.frames,
        "far_end_heartbeats": far.heartbeats,
    }
    if far.last_heartbeat_from is not None:
        record["far_end_heartbeat_from"] = "{}/{}".format(*far.last_heartbeat_from)
    record["far_end_skipped"] = far.decoder.bytes_skipped
    record.update(session.vehicle.record())
    if session.signed:
        record["far_end_bad_signatures"] = far.decoder.bad_signatures
    if session.actions is not None:
        record.update(session.actions.record())
    return record


def preview_text(channels: MavlinkChannels, values: ControlValues) -> str:
    """What the output sends for these values, in words (`usb2rc monitor`)."""
    if values.failsafe:
        if channels.message == RC_CHANNELS_OVERRIDE:
            return "FAILSAFE: releases every channel to the RC radio for 1 s, then heartbeats only"
        return "FAILSAFE: no MANUAL_CONTROL (manual control lost), heartbeats only"
    if channels.message == RC_CHANNELS_OVERRIDE:
        return "RC_CHANNELS_OVERRIDE µs " + " ".join(map(str, values.channels))
    x, y, z, r = values.axes
    return f"MANUAL_CONTROL x {x} y {y} z {z} r {r} buttons 0x{values.buttons:08X}"


def max_message_bytes(message: str) -> int:
    """Bytes of one control message on the wire at most (MAVLink 2, unsigned; pymavlink cuts
    the payload's trailing zeros): for `check`'s bandwidth sum."""
    mav = mavlink2.MAVLink(None)
    if message == RC_CHANNELS_OVERRIDE:
        full = mav.rc_channels_override_encode(1, 1, *([2000] * OVERRIDE_MAX_CHANNELS))
    else:
        full = mav.manual_control_encode(1, 1000, 1000, 1000, 1000, 0xFFFF, buttons2=0xFFFF)
    return len(full.pack(mav))


def heartbeat_bytes() -> int:
    mav = mavlink2.MAVLink(None)
    heartbeat = mav.heartbeat_encode(
        mavlink2.MAV_TYPE_GCS, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, mavlink2.MAV_STATE_ACTIVE
    )
    return len(heartbeat.pack(mav))


class MavlinkSession(EngineSession[MavlinkEngine]):
    """A MAVLink output's session: its channels evaluated each tick, its engine's messages in
    one write."""

    def __init__(
        self,
        name: str,
        channels: MavlinkChannels,
        engine: MavlinkEngine,
        tick_bytes: int,
        rate_hz: float,
        wall_clock: Callable[[], float] = time.time,
    ) -> None:
        super().__init__(name, engine, Backpressure(tick_bytes), 1.0 / rate_hz)
        self.channels = channels
        self.reads = channels.node_ids
        self.tick_bytes = tick_bytes
        self.wall_clock = wall_clock  # signing timestamps follow the wall clock
        self._lengths: list[int] = []  # the last tick's messages, in order

    def tick(self, now: float, snapshot: NodeSnapshot) -> bytes:
        self._lengths = []
        if not self.can_add(self.tick_bytes):
            return b""
        values = self.channels.evaluate(self.latch.frames(snapshot, self.reads))
        messages = self.engine.tick(now, values, self.wall_clock())
        self._lengths = [len(m) for m in messages]
        return b"".join(messages)

    def wrote(self, sent: int, unsure: int = 0) -> Delivered:
        """The engine hears of each message in turn: whole, or the one cut short (a stall:
        the rest of the tick is not sent)."""
        lengths, self._lengths = self._lengths, []
        data = 0
        stalled = False
        for length in lengths:
            delivered = self.engine.wrote(min(length, max(0, sent)))
            sent -= length
            data += delivered.data_frames
            if delivered.stalled or not self.line.is_open:
                stalled = delivered.stalled
                break
        return Delivered(0, data, stalled)

    def received(self, data: bytes, now: float) -> None:
        self.engine.received(data, now)

    @property
    def telemetry(self) -> MavlinkTelemetry | None:
        """The vehicle's armed state, mode, battery and failsafe (None: not heard yet)."""
        return self.engine.vehicle.value

    def stats(self, now: float) -> dict[str, Any]:
        return {**super().stats(now), **stats_record(self.engine)}
