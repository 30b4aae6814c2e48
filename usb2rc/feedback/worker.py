"""The feedback thread: judges what the far ends said and the nodes' states into each
device's wanted output state, and hands it to that device's reader thread, which writes it.

It wakes when a line session's telemetry changed (the driver rings `ring()` after it fed a
session the far end's bytes), when the devices changed (the lifecycle rings it), when the
engine said a state changes by itself (a blink, a pulse's end, a stale downlink), and every
NODE_POLL_S while a device has outputs (a node's failsafe and guard, which no one rings
for). With no device that has an output it sleeps until rung: an idle daemon pays nothing.

It only reads: the sessions' telemetry (each replaced whole by its session's thread), the
table's snapshot and its devices; the engine's history (edges, pulses) is its own. The
writes, their rate and their failures are each reader's (`DeviceReader.post_output`).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple, Protocol

from usb2rc.config.model import FeedbackRule
from usb2rc.feedback.drivers import output_driver
from usb2rc.feedback.engine import DeviceSlot, FeedbackEngine, FeedbackResult, NodeFacts, Sources
from usb2rc.feedback.model import CrsfTelemetry, Downlink, MavlinkTelemetry, Telemetry
from usb2rc.hid.backend import Device, DeviceInfo
from usb2rc.hid.outputs import REST, Capabilities, OutputDriver, OutputState
from usb2rc.nodes.table import NodeSnapshot
from usb2rc.runtime.worker import Worker

log = logging.getLogger("usb2rc.feedback")

NODE_POLL_S = 0.1  # a node's failsafe reaches its devices' outputs this late at most
# Steps at most this often, however often it is rung: a far end that floods the line with
# downlinks changes the telemetry at every tick of its output; 10 ms keeps a downlink
# within two 50 Hz ticks of the device.
MIN_STEP_S = 0.01
FAILURE_LOG_S = 60.0  # a step that keeps failing is logged this often, and counted
GAME_PAD = (0x01, 0x05)  # Generic Desktop / Game Pad: the zero-config rumble's devices


class TelemetrySource(Protocol):
    """A line session, as feedback sees it."""

    name: str

    @property
    def telemetry(self) -> Telemetry: ...


class OutputReader(Protocol):
    """A device's reader, as feedback sees it: the device (its descriptor), and the mailbox
    its thread writes the outputs from (`hid.reader.DeviceReader`)."""

    info: DeviceInfo
    device: Device

    def post_output(self, driver: OutputDriver, state: OutputState) -> None: ...


class FeedDevice(NamedTuple):
    """A present device, as the table holds it: its node, its config entry, its reader."""

    node_id: int
    entry: str | None
    reader: OutputReader


class _Known(NamedTuple):
    """A device feedback has met: its output driver (None: it has no output)."""

    reader: OutputReader
    driver: OutputDriver | None


class FeedbackStatus(NamedTuple):
    """What the thread did last, for monitor, stats and the page (replaced whole)."""

    telemetry: dict[str, object]
    actions: tuple[tuple[int, str, float], ...] = ()  # (rule index, what it did, when)
    devices: tuple[tuple[str, Capabilities, OutputState], ...] = ()  # product, can, shows
    at: float = 0.0


def shown_record(can: Capabilities, state: OutputState) -> dict[str, Any]:
    """What a device shows, by name: its lit indicators, analog outputs, text lines."""
    names = can.indicator_names
    lit = [
        names[k] if k < len(names) else str(k)
        for k in range(can.indicators)
        if state.indicators >> k & 1
    ]
    return {
        "indicators": can.indicators,
        "lit": lit,
        "analog": {name: round(value, 3) for name, value in state.analog},
        "texts": list(state.texts),
    }


def _where(rule: FeedbackRule) -> str:
    """The rule's place in its config file ("usb2rc.yaml:12"), or its kind (built in)."""
    where = rule.where
    return "built in" if where is None else f"{where.source}:{where.line}"


def gathered_sources(sessions: Sequence[TelemetrySource], snapshot: NodeSnapshot) -> Sources:
    """The sessions' telemetry and the nodes' facts, as the engine takes them. Two outputs of
    one kind: the newest telemetry wins; downlinks of a Node-ID: the newest frame."""
    downlinks: dict[int, Downlink] = {}
    crsf: CrsfTelemetry | None = None
    mavlink: MavlinkTelemetry | None = None
    for session in sessions:
        told = session.telemetry
        if isinstance(told, CrsfTelemetry):
            crsf = told if crsf is None or told.at >= crsf.at else crsf
        elif isinstance(told, MavlinkTelemetry):
            mavlink = told if mavlink is None or told.at >= mavlink.at else mavlink
        elif told:
            for frame in told:
                other = downlinks.get(frame.node_id)
                if other is None or frame.at >= other.at:
                    downlinks[frame.node_id] = frame
    nodes = tuple(
        NodeFacts(view.frame.node_id, view.frame.failsafe, bool(view.waiting_for))
        for view in snapshot.nodes
    )
    ordered = tuple(downlinks[node_id] for node_id in sorted(downlinks))
    return Sources(ordered, crsf, mavlink, nodes)


class FeedbackWorker(Worker):
    def __init__(
        self,
        engine: FeedbackEngine,
        sessions: Sequence[TelemetrySource],
        snapshot: Callable[[], NodeSnapshot],
        devices: Callable[[], Sequence[FeedDevice]],
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.engine = engine
        self._sessions = tuple(sessions)
        self._snapshot = snapshot
        self._devices = devices
        self._clock = clock
        self._known: dict[str, _Known] = {}  # by device key: this thread's only
        self._woken = threading.Event()  # rung: step again (cleared before each step)
        self.steps = 0
        self.failures = 0  # steps that raised (logged the first time, then once a minute)
        self._failure_logged_at = 0.0
        self.status = FeedbackStatus({})
        super().__init__("feedback")

    def reload(self, engine: FeedbackEngine) -> None:
        """New rules (a reload): judged from the next step on. Any thread."""
        self.engine = engine
        self._woken.set()

    def rest_all(self) -> None:
        """usb2rc stops (after this thread ended): every driven device back to rest, its
        reader's last write before it closes the device."""
        for known in self._known.values():
            if known.driver is not None and known.driver.capabilities.any:
                known.reader.post_output(known.driver, REST)

    def record(self, now: float) -> dict[str, Any]:
        """What it did last, as plain JSON for stats, `/api/status` and the page: the
        telemetry as the rules see it (None: unknown or stale; ages in seconds), each rule's
        last action, and what each driven device shows. Any thread (one value, read once)."""
        status = self.status
        rules = self.engine.rules
        return {
            "step_failures": self.failures,
            "telemetry": {
                name: round(value, 3) if isinstance(value, float) else value
                for name, value in status.telemetry.items()
            },
            "actions": [
                {
                    "rule": index + 1,
                    "where": _where(rules[index]) if index < len(rules) else "",
                    "did": text,
                    "ago_s": round(now - at, 3),
                }
                for index, text, at in status.actions
            ],
            "devices": [
                {"name": name, **shown_record(can, state)} for name, can, state in status.devices
            ],
        }

    def ring(self) -> None:
        """Something changed (telemetry, the devices): step soon. Any thread."""
        self._woken.set()

    def stop(self) -> None:
        super().stop()
        self._woken.set()

    def run(self) -> None:
        while not self.stopping:
            stepped_at = self._clock()
            self._woken.clear()  # a ring from here on steps again
            try:
                wait_s = self.step()
            except Exception:  # feedback must never take the daemon down: log, go on
                self.failures += 1
                if self.failures == 1 or stepped_at - self._failure_logged_at >= FAILURE_LOG_S:
                    self._failure_logged_at = stepped_at
                    log.exception("feedback step failed (%d so far)", self.failures)
                wait_s = NODE_POLL_S
            self._woken.wait(None if wait_s is None else max(0.0, wait_s))
            rest_s = stepped_at + MIN_STEP_S - self._clock()
            if rest_s > 0 and not self.stopping:
                self.sleep(rest_s)

    def step(self) -> float | None:
        """One judgement, posted to the devices; how long until the next is due by itself
        (None: only a ring brings one)."""
        now = self._clock()
        slots, readers = self._slots()
        sources = gathered_sources(self._sessions, self._snapshot())
        result = self.engine.step(now, sources, slots)
        self._post(result, readers)
        self.steps += 1
        self._publish(now, sources, slots, result)
        if not slots:
            return None
        wait_s = NODE_POLL_S
        if result.next_change_at is not None:
            wait_s = min(wait_s, result.next_change_at - now)
        return wait_s

    def _slots(self) -> tuple[tuple[DeviceSlot, ...], dict[str, _Known]]:
        """The present devices that have an output, in node order; forgets the gone."""
        present = {d.reader.info.key: d for d in self._devices()}
        gone = [
            k
            for k, known in self._known.items()
            if present.get(k, known).reader is not known.reader or k not in present
        ]
        for key in gone:
            del self._known[key]
        slots = []
        for key, device in present.items():
            known = self._known.get(key)
            if known is None:
                known = self._known[key] = _Known(device.reader, self._driver(device.reader))
            if known.driver is None or not known.driver.capabilities.any:
                continue
            info = device.reader.info
            gamepad = (info.usage_page, info.usage) == GAME_PAD
            slots.append(
                DeviceSlot(
                    key,
                    device.node_id,
                    device.entry,
                    info.vid,
                    info.pid,
                    gamepad,
                    known.driver.capabilities,
                )
            )
        return tuple(slots), self._known

    @staticmethod
    def _driver(reader: OutputReader) -> OutputDriver | None:
        try:
            descriptor = reader.device.report_descriptor()
        except Exception as exc:
            log.warning("%s: no outputs driven: its descriptor: %s", reader.info.product, exc)
            return None
        try:
            driver = output_driver(reader.info, descriptor)
        except Exception:  # a descriptor no driver understands: its input goes on regardless
            log.exception("%s: no outputs driven: its outputs are not understood", reader.info.path)
            return None
        if driver is not None and driver.capabilities.any:
            can = driver.capabilities
            log.info(
                "%s: feedback drives %d indicators%s%s",
                reader.info.product or reader.info.path,
                can.indicators,
                f", {', '.join(can.analog)}" if can.analog else "",
                f", {can.text_lines} text lines" if can.text_lines else "",
            )
        return driver

    @staticmethod
    def _post(result: FeedbackResult, known: dict[str, _Known]) -> None:
        for key, state in result.states:
            entry = known.get(key)
            if entry is not None and entry.driver is not None:
                entry.reader.post_output(entry.driver, state)

    def _publish(
        self,
        now: float,
        sources: Sources,
        slots: tuple[DeviceSlot, ...],
        result: FeedbackResult,
    ) -> None:
        states = dict(result.states)
        devices = tuple(
            (self._known[s.key].reader.info.product or s.key, s.capabilities, states[s.key])
            for s in slots
            if s.key in states
        )
        telemetry = self.engine.telemetry_values(now, sources)
        self.status = FeedbackStatus(telemetry, tuple(result.actions), devices, now)
