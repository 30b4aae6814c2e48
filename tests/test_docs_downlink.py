"""docs/ICD.md "Downlink": its example frame, as the far end would send it, read by the
C2-16B session and judged by the feedback engine for the test suite's LED stick: what the
ICD says it does is what it does."""

from __future__ import annotations

import re
from pathlib import Path

from umockdev_harness import LED_STICK_DESCRIPTOR

from usb2rc.feedback.engine import DeviceSlot, FeedbackEngine, NodeFacts, Sources
from usb2rc.feedback.hid_outputs import HidOutputDriver
from usb2rc.hid.outputs import Capabilities
from usb2rc.protocols.c2_16b.engine import C2Settings
from usb2rc.protocols.c2_16b.session import C2Session

ICD = Path(__file__).resolve().parent.parent / "docs" / "ICD.md"


def example_frame() -> bytes:
    section = ICD.read_text().split("\n## Downlink\n", 1)[1].split("\n## ", 1)[0]
    (block,) = re.findall(r"```\n(.*?)\n```", section, re.S)
    return bytes.fromhex(block)


def test_the_icds_downlink_example_lights_what_it_says() -> None:
    session = C2Session("c2", C2Settings())
    session.received(example_frame(), now=10.0)
    (downlink,) = session.telemetry or ()
    assert (downlink.node_id, downlink.indicators, downlink.axes[0]) == (0, 0b101, 32767)
    driver = HidOutputDriver.from_descriptor(LED_STICK_DESCRIPTOR)
    assert driver is not None
    can = driver.capabilities
    pad = Capabilities(analog=("rumble_strong", "rumble_weak"))
    slots = [
        DeviceSlot("stick", 0, None, 0x1209, 1, False, can),
        DeviceSlot("pad", 0, None, 0x054C, 0x09CC, True, pad),
    ]
    sources = Sources((downlink,), None, None, (NodeFacts(0, False, False),))
    states = dict(FeedbackEngine(()).step(10.0, sources, slots).states)
    lit = [
        can.indicator_names[k] for k in range(can.indicators) if states["stick"].indicators >> k & 1
    ]
    assert lit == ["LED Num Lock", "LED Scroll Lock"]
    assert states["pad"].value("rumble_strong") == 1.0
