"""MAVLink button actions, sans-IO (docs/CONFIG.md "MAVLink actions", docs/ICD.md "MAVLink
actions"): a MAVLink output's `actions:` turned into COMMAND_LONGs.

`ActionRunner.tick(now, triggers, failsafe)` takes, once a tick, whether each action's
trigger (its button down, or its switch at its position) is active in this frame, and
whether the output's nodes are in failsafe; it returns the messages to send (pymavlink
message objects: the session packs them). `received(message)` takes what the vehicle sent:
its HEARTBEAT (which autopilot and vehicle type: how a mode name is resolved) and
COMMAND_ACK (the result, logged and counted).

Decisions:
- edge-triggered: an action fires once when its trigger has been active for `hold` seconds
  (arm and disarm: 1 s by default); it fires again only after the trigger was released;
- never in failsafe, never before the vehicle's heartbeat: a hold completed then is
  refused (counted, logged) and not sent later, even if the vehicle appears while it is
  still held; a trigger active during a failsafe must be released and pressed again;
- every action is a COMMAND_LONG, retried (confirmation 1, 2) every RETRY_S until a
  COMMAND_ACK for its command comes or TRIES were sent; a newer action with the same
  command replaces a pending one;
- a mode by name: DO_SET_MODE. ArduPilot: param1 MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
  param2 the custom mode of pymavlink's mapping for the HEARTBEAT's vehicle type; PX4:
  param1..3 the base, main and sub mode of pymavlink's `px4_map` (as pymavlink's own
  `set_mode_px4` sends it). A name the vehicle's mapping lacks is refused (logged);
- rtl and land: the mode RTL / LAND when the vehicle's mapping has it, else
  MAV_CMD_NAV_RETURN_TO_LAUNCH / MAV_CMD_NAV_LAND.
"""

from __future__ import annotations

import logging
import os
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from pymavlink.dialects.v20 import common as mavlink2

from usb2rc.config.controls_model import ActionConfig

log = logging.getLogger(__name__)

NEEDS_MODE_MAPS = ("mode", "rtl", "land")  # action kinds that look up a mode by name


# What mavutil imports at its top in a try that lets it be missing, and usb2rc never uses:
# pymavlink's `all` dialect beside `common` (which usb2rc speaks; imported for pyinstaller's
# sake only), and curses (for `is_printable`, which has a fallback of its own).
UNUSED_MODULES = ("pymavlink.dialects.v10.all", "curses")


def mode_maps() -> Any:  # pymavlink has no types
    """pymavlink's `mavutil`, for its mode maps only: a MAVLink output imports it when it
    is built (its vehicle's mode is named by it, and actions that name a mode look it up),
    never in a tick or on a read. As it is, importing it loads the `all` dialect twice over
    (its own import of `v10.all`, and the dialect its environment names, `all` over MAVLink
    1 unless told): 9 MB of RSS, on a Pi that may have 512 MB, for messages usb2rc never
    parses; and curses with its terminal libraries (1.3 MB in the daemon). So the
    UNUSED_MODULES not loaded yet are kept out while it imports (a `None` in `sys.modules`:
    its tries let them be missing; a pymavlink whose import needs them imports them), and
    unless the user set them, mavutil is told MAVLink 2's `common`, which usb2rc already
    loaded: the mode maps are the same (they name autopilots and vehicle types by
    `common`'s constants). The environment and `sys.modules` are as they were after the
    import."""
    if "pymavlink.mavutil" in sys.modules:
        return sys.modules["pymavlink.mavutil"]
    told = {"MAVLINK20": "1", "MAVLINK_DIALECT": "common"}
    added = [key for key in told if key not in os.environ]
    os.environ.update({key: told[key] for key in added})
    blocked = [name for name in UNUSED_MODULES if name not in sys.modules]
    for name in blocked:
        sys.modules[name] = None  # type: ignore[assignment]
    try:
        try:
            from pymavlink import mavutil
        except ImportError:  # a pymavlink that needs them: load them after all
            for name in blocked:
                del sys.modules[name]
            blocked = []
            from pymavlink import mavutil
    finally:
        for name in blocked:
            sys.modules.pop(name, None)
        for key in added:
            os.environ.pop(key, None)
    return mavutil


TRIES = 3
RETRY_S = 1.0
ARDUPILOT = mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA
PX4 = mavlink2.MAV_AUTOPILOT_PX4
FALLBACK_COMMANDS = {
    "rtl": mavlink2.MAV_CMD_NAV_RETURN_TO_LAUNCH,
    "land": mavlink2.MAV_CMD_NAV_LAND,
}


@dataclass(frozen=True)
class Vehicle:
    """What the vehicle's HEARTBEAT said."""

    system: int
    component: int
    autopilot: int
    vehicle_type: int


@dataclass
class _Pending:
    command: int
    params: tuple[float, ...]
    label: str
    tries: int = 0
    next_at: float = 0.0


@dataclass
class _State:
    since: float | None = None  # the trigger active (live) since
    fired: bool = False  # fired (or refused) since it went active


@dataclass
class ActionStats:
    """Counters for the stats record and `monitor --outputs`."""

    fired: int = 0
    sent: int = 0  # COMMAND_LONGs, retries included
    acked: int = 0
    unanswered: int = 0  # no COMMAND_ACK after TRIES
    refused: int = 0  # not sent: failsafe, no vehicle, unknown mode
    last: str = ""  # the last result, in words
    results: dict[str, int] = field(default_factory=dict)  # MAV_RESULT name -> count


class ActionRunner:
    """One MAVLink output's actions (see the module docstring)."""

    def __init__(self, actions: Sequence[ActionConfig], mav: Any, target: tuple[int, int]):
        self.actions = tuple(actions)
        self.mav = mav  # pymavlink MAVLink: its *_encode builds the messages
        self.target = target
        self.vehicle: Vehicle | None = None
        self.stats = ActionStats()
        self._states = [_State() for _ in self.actions]
        self._pending: dict[int, _Pending] = {}
        if any(action.kind in NEEDS_MODE_MAPS for action in self.actions):
            mode_maps()

    def tick(self, now: float, triggers: Sequence[bool], failsafe: bool) -> list[Any]:
        """This tick's COMMAND_LONGs: actions whose hold completed, and retries due."""
        for action, state, active in zip(self.actions, self._states, triggers, strict=False):
            self._step(now, action, state, active, failsafe)
        return self._due(now, failsafe)

    def _step(
        self, now: float, action: ActionConfig, state: _State, active: bool, failsafe: bool
    ) -> None:
        if not active:
            state.since, state.fired = None, False
            return
        if failsafe:  # held through a failsafe: it must be released before it fires again
            state.since, state.fired = None, True
            return
        if state.fired:
            return
        if state.since is None:
            state.since = now
        if now - state.since >= action.hold:
            state.fired = True
            self._fire(now, action)

    def _fire(self, now: float, action: ActionConfig) -> None:
        text = action.describe()
        if self.vehicle is None:
            self._refuse(f"{text}: not sent, no vehicle heartbeat seen yet")
            return
        command = self._command(action, self.vehicle)
        if command is None:
            self._refuse(f"{text}: not sent, mode {action.mode!r} unknown to this vehicle")
            return
        self.stats.fired += 1
        log.info("MAVLink action %s", text)
        self._pending[command[0]] = _Pending(command[0], command[1], text, 0, now)

    def _refuse(self, text: str) -> None:
        self.stats.refused += 1
        self.stats.last = text
        log.warning("MAVLink action %s", text)

    def _due(self, now: float, failsafe: bool) -> list[Any]:
        messages = []
        for command, pending in list(self._pending.items()):
            if failsafe:  # never sent in failsafe: a retry is dropped too
                del self._pending[command]
                self._refuse(f"{pending.label}: retry dropped, the node is in failsafe")
                continue
            if now < pending.next_at:
                continue
            if pending.tries >= TRIES:
                del self._pending[command]
                self.stats.unanswered += 1
                self.stats.last = f"{pending.label}: no COMMAND_ACK after {TRIES} tries"
                log.warning("MAVLink action %s", self.stats.last)
                continue
            messages.append(self._command_long(pending))
            pending.tries += 1
            pending.next_at = now + RETRY_S
            self.stats.sent += 1
        return messages

    def _command_long(self, pending: _Pending) -> Any:
        params = list(pending.params) + [0.0] * (7 - len(pending.params))
        confirmation = pending.tries  # 0 first, then 1, 2 (MAVLink command protocol)
        return self.mav.command_long_encode(*self.target, pending.command, confirmation, *params)

    def _command(
        self, action: ActionConfig, vehicle: Vehicle
    ) -> tuple[int, tuple[float, ...]] | None:
        kind = action.kind
        if kind in ("arm", "disarm"):
            return mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, (1.0 if kind == "arm" else 0.0,)
        if kind == "command_long":
            return action.command, action.params
        if kind == "mode":
            assert action.mode is not None
            return set_mode(action.mode, vehicle)
        mode = set_mode(kind.upper(), vehicle)
        return mode if mode is not None else (FALLBACK_COMMANDS[kind], ())

    def received(self, message: Any) -> None:
        """A message from the vehicle: its HEARTBEAT, a COMMAND_ACK."""
        kind = message.get_type()
        if kind == "HEARTBEAT" and message.type != mavlink2.MAV_TYPE_GCS:
            self.vehicle = Vehicle(
                message.get_srcSystem(),
                message.get_srcComponent(),
                message.autopilot,
                message.type,
            )
        elif kind == "COMMAND_ACK":
            self._acked(message.command, message.result)

    def _acked(self, command: int, result: int) -> None:
        pending = self._pending.pop(command, None)
        if pending is None:
            return  # an ack for a command of someone else's, or a late duplicate
        name = (
            mavlink2.enums["MAV_RESULT"][result].name
            if result in mavlink2.enums["MAV_RESULT"]
            else str(result)
        )
        self.stats.acked += 1
        self.stats.results[name] = self.stats.results.get(name, 0) + 1
        self.stats.last = f"{pending.label}: {name}"
        level = logging.INFO if result == mavlink2.MAV_RESULT_ACCEPTED else logging.WARNING
        log.log(level, "MAVLink action %s", self.stats.last)

    def record(self) -> dict[str, Any]:
        """The stats record's fields."""
        s = self.stats
        record: dict[str, Any] = {
            "actions_fired": s.fired,
            "actions_sent": s.sent,
            "actions_acked": s.acked,
            "actions_unanswered": s.unanswered,
            "actions_refused": s.refused,
        }
        if s.last:
            record["actions_last"] = s.last
        return record


def set_mode(name: str, vehicle: Vehicle) -> tuple[int, tuple[float, ...]] | None:
    """DO_SET_MODE's command and params for a mode name on this vehicle, or None."""
    custom = float(mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED)
    mavutil = mode_maps()
    if vehicle.autopilot == PX4:
        px4 = mavutil.px4_map.get(name)
        if px4 is None:
            return None
        base, main, sub = px4
        return mavlink2.MAV_CMD_DO_SET_MODE, (float(base), float(main), float(sub))
    mapping = mavutil.mode_mapping_byname(vehicle.vehicle_type) or {}
    if name not in mapping:
        return None
    return mavlink2.MAV_CMD_DO_SET_MODE, (custom, float(mapping[name]))


def mode_names(autopilot: int, vehicle_type: int) -> list[str]:
    """The mode names a vehicle takes (for messages and `check`)."""
    mavutil = mode_maps()
    if autopilot == PX4:
        return sorted(mavutil.px4_map)
    return sorted(mavutil.mode_mapping_byname(vehicle_type) or {})
