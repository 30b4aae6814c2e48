"""The feedback thread on its own: what it reads (sessions' telemetry, the snapshot, the
devices) and what it posts to each device's reader; it sleeps while nothing rings it, and
its record shows what the page and `stats` show."""

from __future__ import annotations

import threading
import time
from typing import Any

from umockdev_harness import LED_STICK_DESCRIPTOR, wait_until

from usb2rc.feedback.engine import FeedbackEngine
from usb2rc.feedback.model import CrsfTelemetry, Downlink, Telemetry
from usb2rc.feedback.worker import FeedbackWorker, FeedDevice
from usb2rc.hid.backend import DeviceInfo
from usb2rc.hid.outputs import OutputDriver, OutputState
from usb2rc.nodes.table import NodeSnapshot
from usb2rc.runtime.stats_text import feedback_lines

WAIT_S = 10.0


class Session:
    def __init__(self, name: str) -> None:
        self.name = name
        self.telemetry: Telemetry = None


class Device:
    def report_descriptor(self) -> bytes:
        return LED_STICK_DESCRIPTOR


class Reader:
    """A device's reader as feedback sees it: posts are recorded."""

    def __init__(self, key: str) -> None:
        self.info = DeviceInfo(key, key, 0x1209, 0x0001, product="LED stick")
        self.device = Device()
        self.posts: list[OutputState] = []
        self._lock = threading.Lock()

    def post_output(self, driver: OutputDriver, state: OutputState) -> None:
        with self._lock:
            self.posts.append(state)

    def last(self) -> OutputState | None:
        with self._lock:
            return self.posts[-1] if self.posts else None


def make(devices: list[FeedDevice], sessions: list[Session], rules: Any = None) -> FeedbackWorker:
    return FeedbackWorker(FeedbackEngine(rules), sessions, lambda: NodeSnapshot(), lambda: devices)


def test_without_a_device_that_has_outputs_it_steps_only_when_rung() -> None:
    session = Session("c2")
    worker = make([], [session])
    worker.start()
    try:
        wait_until(lambda: worker.steps == 1, WAIT_S, "the first step")
        time.sleep(0.3)  # nothing rings it: it must not step (a flag that stays set would)
        assert worker.steps == 1
        session.telemetry = CrsfTelemetry(link_quality=80, at=time.monotonic())
        worker.ring()
        wait_until(lambda: worker.steps == 2, WAIT_S, "a step after the ring")
        time.sleep(0.3)  # and then sleeps again: a ring is used up by the step it caused
        assert worker.steps == 2
        assert worker.record(time.monotonic())["telemetry"]["crsf.link_quality"] == 80
    finally:
        worker.stop()
        worker.join(WAIT_S)


def test_a_downlink_is_posted_to_its_nodes_device_and_rest_after_it_goes_stale() -> None:
    session = Session("c2")
    reader = Reader("led")
    worker = make([FeedDevice(0, None, reader)], [session])
    worker.start()
    try:
        wait_until(lambda: reader.last() == OutputState(), WAIT_S, "rest at first")
        session.telemetry = (Downlink(0, 0b101, (0,) * 10, time.monotonic()),)
        worker.ring()
        wait_until(lambda: (s := reader.last()) and s.indicators == 0b101, WAIT_S, "lit")
        record = worker.record(time.monotonic())
        (shown,) = record["devices"]
        assert shown["lit"] == ["LED Num Lock", "LED Scroll Lock"]
        assert shown["indicators"] == 8
        assert any("lit LED Num Lock, LED Scroll Lock" in line for line in feedback_lines(record))
        # nobody rings: the engine's own next change (staleness) wakes it
        wait_until(lambda: (s := reader.last()) and s.indicators == 0, WAIT_S, "rest")
        worker.rest_all()
    finally:
        worker.stop()
        worker.join(WAIT_S)


def test_a_device_that_goes_is_forgotten_and_one_without_outputs_is_never_posted() -> None:
    session = Session("c2")
    led = Reader("led")
    plain = Reader("plain")
    plain.device.report_descriptor = lambda: bytes.fromhex(  # type: ignore[method-assign]
        "05010904a101850109300931150026ff0f751095028102c0"
    )
    devices = [FeedDevice(0, None, led), FeedDevice(0, None, plain)]
    worker = make(devices, [session])
    worker.step()
    assert led.posts and not plain.posts
    devices.pop(0)
    worker.step()
    assert worker.record(time.monotonic())["devices"] == []
