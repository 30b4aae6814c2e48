"""Where `&` and `%` come from: a device's handover button and battery value, from the
descriptor (Battery Strength, Generic Device Controls page 0x06) through the binding to the
node table's frames (docs/CONFIG.md, "Handover and low battery")."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import pytest
from hid_encoder import decode as reference_decode
from hid_encoder import encode, ref_reports

from usb2rc.configfile import load_config_text
from usb2rc.hid.backend import DeviceInfo
from usb2rc.hid.descriptor import parse_descriptor
from usb2rc.hid.reader import ReaderRecord
from usb2rc.hid.usages import GDC_BATTERY_STRENGTH, usage_from_name, usage_name
from usb2rc.nodes.binding import MappingError, default_binding
from usb2rc.nodes.mapping import compile_mapping
from usb2rc.nodes.table import NodeTable

# A wireless pad, written by hand: 8 buttons, X and Y 0..255, Battery Strength 0..100
# (Usage Page 0x06, Usage 0x20) in the input report; 4-byte reports, no report ID.
PAD_DESCRIPTOR = bytes.fromhex(
    "05010905a101"  # Generic Desktop, Game Pad, Collection (Application)
    "05091901290815002501750195088102"  # 8 buttons
    "050109300931150026ff00750895028102"  # X, Y 0..255
    "0506092015002564750895018102"  # Generic Device Controls, Battery Strength 0..100
    "c0"
)
PAD = DeviceInfo(key="pad", path="pad", vid=0x045E, pid=0x0B13, product="Wireless Pad")


def pad_report(buttons: int = 0, x: int = 128, y: int = 128, battery: int = 80) -> bytes:
    return bytes([buttons, x, y, battery])


def test_the_descriptor_parser_decodes_battery_strength_as_hid_tools_does():
    layout = parse_descriptor(PAD_DESCRIPTOR)
    (battery,) = [f for f in layout.inputs if f.usage == GDC_BATTERY_STRENGTH]
    assert (battery.logical_min, battery.logical_max, battery.bit_size) == (0, 100, 8)
    assert usage_name(GDC_BATTERY_STRENGTH) == "BatteryStrength"
    assert usage_from_name("battery strength") == usage_from_name("Battery") == 0x00060020
    decoder = layout.make_decoder()
    report = pad_report(buttons=0x05, x=3, battery=17)
    assert decoder.feed(report)
    reference, _ = reference_decode(ref_reports(PAD_DESCRIPTOR)[0], report)
    assert decoder.state().values[battery.index] == reference[(GDC_BATTERY_STRENGTH, 0)] == 17


def bound(config_text: str = "defaults: true\n", report: bytes = pad_report()):
    layout = parse_descriptor(PAD_DESCRIPTOR)
    mapping = compile_mapping(load_config_text(config_text, "c.yaml"))
    binding = mapping.bind(PAD, layout)
    assert binding is not None
    decoder = layout.make_decoder()
    decoder.feed(report)
    return binding, binding.apply(decoder.state())


@pytest.mark.parametrize(("battery", "low"), [(0, True), (19, True), (20, False), (100, False)])
def test_zero_config_reads_battery_strength_below_20_percent(battery, low):
    binding, inputs = bound(report=pad_report(battery=battery))
    assert inputs.low_battery is low
    assert inputs.handover is False
    assert "  low battery: BatteryStrength below 20 % -> `%`" in binding.describe()


ENTRY = "devices:\n  - name: pad\n    match: {vid: 0x045e}\n"


def test_low_battery_false_turns_it_off():
    binding, inputs = bound(ENTRY + "    low_battery: false\n", pad_report(battery=0))
    assert binding.battery is None and inputs.low_battery is False


@pytest.mark.parametrize(("x", "low"), [(25, True), (26, False)])  # 10 % of 0..255 is 25.5
def test_an_axis_and_threshold_named_in_the_config(x, low):
    config = ENTRY + "    low_battery: {usage: X, below: 10}\n"
    _, inputs = bound(config, pad_report(x=x, battery=0))
    assert inputs.low_battery is low


def test_a_configured_battery_usage_the_device_lacks_names_the_line():
    with pytest.raises(MappingError, match=r"c\.yaml:4: devices\[0\]\.low_battery: .*Rz"):
        bound(ENTRY + "    low_battery: {usage: Rz}\n")


def test_the_handover_button_is_read_from_the_device_buttons():
    config = ENTRY + "    handover: {button: 3, destination: 7, frames: 5}\n"
    binding, released = bound(config, pad_report(buttons=0x03))
    _, pressed = bound(config, pad_report(buttons=0x04))
    assert (released.handover, pressed.handover) == (False, True)
    assert pressed.group1 == 0x04  # the default layout still maps the button: live values
    assert "  handover: HID button 3 -> `&` to 7 (5 frames a press)" in binding.describe()


def test_a_handover_button_the_device_lacks_names_the_line():
    with pytest.raises(MappingError, match=r"c\.yaml:4: devices\[0\]\.handover: .*button 9"):
        bound(ENTRY + "    handover: {button: 9, destination: 1}\n")


@dataclass
class Source:
    record: ReaderRecord

    def pull(self) -> None:
        """The step's pull: the test sets the record itself."""


def test_the_node_frame_carries_the_handover_and_the_battery():
    config = ENTRY + "    node_id: 3\n    handover: {button: 1, destination: 200}\n"
    layout = parse_descriptor(PAD_DESCRIPTOR)
    binding = compile_mapping(load_config_text(config, "c.yaml")).bind(PAD, layout)
    assert binding is not None
    decoder = layout.make_decoder()
    source = Source(ReaderRecord(decoder.state(), reports=0))
    table = NodeTable()
    table.add_device(3, PAD, binding, source, "GAMEPAD")
    (unknown,) = table.frames()  # no report yet: failsafe values, no buttons, no battery
    assert (unknown.failsafe, unknown.handover, unknown.low_battery) == (True, None, False)
    decoder.feed(pad_report(buttons=0x00, battery=5))
    source.record = ReaderRecord(decoder.state(), reports=1)
    (frame,) = table.frames()  # live: a press from now on asks for the handover
    assert frame.failsafe is False and frame.low_battery is True and frame.handover is None
    decoder.feed(pad_report(buttons=0x01, battery=5))
    source.record = ReaderRecord(decoder.state(), reports=2, presses=(0x01,), press_serial=1)
    (frame,) = table.frames()
    assert frame.handover is not None and frame.handover.destination == 200
    decoder.feed(pad_report(buttons=0x00, battery=50))
    source.record = ReaderRecord(decoder.state(), reports=3, presses=(0x01,), press_serial=1)
    (frame,) = table.frames()
    assert (frame.handover, frame.low_battery) == (None, False)


def test_a_real_wireless_pad_gets_low_battery_with_zero_config():
    """The Asus gamepad of hid-tools' test suite (tests/data/real-devices.json) reports
    Battery Strength 0..255 in an input report: the default binding reads it."""
    devices = json.loads((Path(__file__).parent / "data" / "real-devices.json").read_text())
    (asus,) = [d for d in devices if d["name"].startswith("Asus gamepad")]
    descriptor = bytes.fromhex(asus["hex"])
    layout = parse_descriptor(descriptor)
    (battery,) = [f for f in layout.inputs if f.usage == GDC_BATTERY_STRENGTH]
    binding = default_binding(layout, "asus")
    assert binding.battery is not None and binding.battery.index == battery.index
    assert (binding.battery.lo, binding.battery.hi, binding.battery.below) == (0, 255, 20)
    # written where hid-tools finds the field: 50 is 19.6 % of 0..255, 51 is 20 %
    key = (GDC_BATTERY_STRENGTH, 0)
    ref = next(r for r in ref_reports(descriptor).values() if key in r.values)
    for level, low in ((50, True), (51, False)):
        decoder = layout.make_decoder()
        assert decoder.feed(encode(ref, {key: level}))
        assert binding.apply(decoder.state()).low_battery is low
