"""The DualShock 4's and DualSense's output reports against the byte layouts linux
drivers/hid/hid-playstation.c documents (v6.2+: `struct dualshock4_output_report_usb`,
`_bt`, `_common`; `struct dualsense_output_report_usb`, `_bt`, `_common`; the DS4_* and DS_*
report ids, sizes and flags), the Bluetooth CRC32 against a bit-by-bit CRC, and that any
state gives well-formed reports, written only when they change."""

from __future__ import annotations

import math
import zlib

import pytest
from hypothesis import given
from hypothesis import strategies as st

from usb2rc.feedback.vendor import ds4, dualsense
from usb2rc.hid.outputs import ANALOG_NAMES, REST, HidReport, OutputState

CHECK_INPUT = b"123456789"
CRC32_CHECK = 0xCBF43926  # CRC-32 (ISO-HDLC) of the check input


def crc32_bitwise(data: bytes) -> int:
    """The kernel's crc32_le(~0, data) then inverted: the reflected polynomial 0xEDB88320,
    one bit at a time (lib/crc32.c's definition), not through zlib."""
    crc = 0xFFFFFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ (0xEDB88320 if crc & 1 else 0)
    return crc ^ 0xFFFFFFFF


def test_the_bitwise_crc_is_crc32() -> None:
    assert crc32_bitwise(CHECK_INPUT) == CRC32_CHECK == zlib.crc32(CHECK_INPUT)


def assert_bt_crc(report: bytes) -> None:
    """hid-playstation: crc32_le(0xFFFFFFFF, &seed, 1), then ~crc32_le(crc, data, len - 4),
    stored little-endian in the last 4 bytes; seed PS_OUTPUT_CRC32_SEED = 0xA2."""
    expected = crc32_bitwise(bytes([0xA2]) + report[:-4])
    assert report[-4:] == expected.to_bytes(4, "little")
    assert zlib.crc32(bytes([0xA2]) + report[:-4]) == expected


def only_report(writes: tuple[object, ...]) -> bytes:
    (write,) = writes
    assert isinstance(write, HidReport)
    return write.data


FULL = OutputState(
    analog=(
        ("rumble_strong", 1.0),
        ("rumble_weak", 0.5),
        ("red", 1.0),
        ("green", 0.0),
        ("blue", 0.25),
    )
)
STRONG, WEAK, RED, GREEN, BLUE = 255, 128, 255, 0, 64  # round(x * 255)


def ds4_common(weak: int, strong: int, red: int, green: int, blue: int) -> bytes:
    """struct dualshock4_output_report_common: valid_flag0 (MOTOR 0x01 | LED 0x02, always
    together as dualshock4_output_worker sends them), valid_flag1, reserved, motor_right,
    motor_left, lightbar_red, _green, _blue, lightbar_blink_on, _off."""
    return bytes([0x03, 0, 0, weak, strong, red, green, blue, 0, 0])


def test_ds4_usb_report_is_the_kernels_layout() -> None:
    report = only_report(ds4.DualShock4Driver(bluetooth=False).writes(FULL, None))
    # struct dualshock4_output_report_usb: report_id 0x05, common, reserved[21]; 32 bytes
    assert report == b"\x05" + ds4_common(WEAK, STRONG, RED, GREEN, BLUE) + bytes(21)
    assert len(report) == 32


def test_ds4_bluetooth_report_is_the_kernels_layout_with_its_crc() -> None:
    report = only_report(ds4.DualShock4Driver(bluetooth=True).writes(FULL, None))
    # struct dualshock4_output_report_bt: report_id 0x11, hw_control (HID 0x80 | CRC32 0x40,
    # poll interval 4 ms in the low 6 bits), audio_control, common, reserved[61], crc32
    assert report[:-4] == b"\x11\xc4\x00" + ds4_common(WEAK, STRONG, RED, GREEN, BLUE) + bytes(61)
    assert len(report) == 78
    assert_bt_crc(report)


def test_brightness_scales_the_lightbar_not_the_rumble() -> None:
    dim = FULL._replace(analog=(*FULL.analog, ("brightness", 0.5)))
    report = only_report(ds4.DualShock4Driver(bluetooth=False).writes(dim, None))
    assert report[4:9] == bytes([WEAK, STRONG, 128, 0, 32])  # 255*0.5, 0.25*0.5*255


def dualsense_common(
    flag0: int, flag2: int, weak: int, strong: int, players: int, rgb: tuple[int, int, int]
) -> bytes:
    """struct dualsense_output_report_common (47 bytes): valid_flag0, valid_flag1 (LIGHTBAR
    0x04 | PLAYER_INDICATOR 0x10), motor_right, motor_left, reserved[4], mute_button_led,
    power_save_control, reserved2[28], valid_flag2, reserved3[2], lightbar_setup,
    led_brightness, player_leds, lightbar_red, _green, _blue."""
    return (
        bytes([flag0, 0x14, weak, strong])
        + bytes(4 + 1 + 1 + 28)
        + bytes([flag2, 0, 0, 0, 0, players])
        + bytes(rgb)
    )


PLAYERS = OutputState(indicators=0b1_0101 | 1 << 40, analog=FULL.analog)


@pytest.mark.parametrize(
    ("vibration_v2", "flag0", "flag2"),
    [
        # DualSense: HAPTICS_SELECT 0x02 | COMPATIBLE_VIBRATION 0x01
        (False, 0x03, 0x00),
        # DualSense Edge: HAPTICS_SELECT, and valid_flag2 COMPATIBLE_VIBRATION2 0x04
        (True, 0x02, 0x04),
    ],
)
def test_dualsense_usb_report_is_the_kernels_layout(
    vibration_v2: bool, flag0: int, flag2: int
) -> None:
    driver = dualsense.DualSenseDriver(bluetooth=False, vibration_v2=vibration_v2)
    report = only_report(driver.writes(PLAYERS, None))
    common = dualsense_common(flag0, flag2, WEAK, STRONG, 0b1_0101, (RED, GREEN, BLUE))
    # struct dualsense_output_report_usb: report_id 0x02, common, reserved[15]; 63 bytes
    assert report == b"\x02" + common + bytes(15)
    assert len(report) == 63


def test_dualsense_bluetooth_reports_count_their_sequence_and_carry_the_crc() -> None:
    driver = dualsense.DualSenseDriver(bluetooth=True, vibration_v2=False)
    common = dualsense_common(0x03, 0, WEAK, STRONG, 0b1_0101, (RED, GREEN, BLUE))
    states = [PLAYERS, REST] * 9
    reports = [only_report(driver.writes(state, None)) for state in states]
    for number, report in enumerate(reports):
        # struct dualsense_output_report_bt: report_id 0x31, seq_tag (sequence << 4),
        # tag 0x10 (DS_OUTPUT_TAG), common, reserved[24], crc32; 78 bytes
        assert report[:3] == bytes([0x31, (number % 16) << 4, 0x10])
        assert len(report) == 78
        assert report[-28:-4] == bytes(24)
        assert_bt_crc(report)
    assert reports[0][3:-28] == common


def test_the_sequence_moves_only_for_a_report_that_is_built() -> None:
    driver = dualsense.DualSenseDriver(bluetooth=True, vibration_v2=True)
    first = only_report(driver.writes(FULL, None))
    assert driver.writes(FULL, FULL) == ()
    second = only_report(driver.writes(REST, FULL))
    assert (first[1], second[1]) == (0x00, 0x10)


def test_capabilities() -> None:
    assert ds4.CAPABILITIES.indicators == 0
    assert dualsense.CAPABILITIES.indicator_names == tuple(f"player-{n}" for n in range(1, 6))
    for capabilities in (ds4.CAPABILITIES, dualsense.CAPABILITIES):
        assert set(capabilities.analog) == {
            "rumble_strong",
            "rumble_weak",
            "brightness",
            "red",
            "green",
            "blue",
        }
        assert capabilities.analog == tuple(n for n in ANALOG_NAMES if n in capabilities.analog)


def any_driver(kind: str) -> ds4.DualShock4Driver | dualsense.DualSenseDriver:
    family, bus = kind.split("/")
    if family == "ds4":
        return ds4.DualShock4Driver(bluetooth=bus == "bt")
    return dualsense.DualSenseDriver(bluetooth=bus == "bt", vibration_v2=family == "edge")


KINDS = ["ds4/usb", "ds4/bt", "dualsense/usb", "dualsense/bt", "edge/usb", "edge/bt"]
# kind -> (report id, length, where strong, weak, red, green, blue are)
LAYOUT = {
    "ds4/usb": (0x05, 32, (5, 4, 6, 7, 8)),
    "ds4/bt": (0x11, 78, (7, 6, 8, 9, 10)),
    "dualsense/usb": (0x02, 63, (4, 3, 45, 46, 47)),
    "dualsense/bt": (0x31, 78, (6, 5, 47, 48, 49)),
}
LAYOUT["edge/usb"] = LAYOUT["dualsense/usb"]
LAYOUT["edge/bt"] = LAYOUT["dualsense/bt"]

analog_values = st.lists(
    st.tuples(st.sampled_from([*ANALOG_NAMES, "unknown"]), st.floats()), max_size=10
).map(tuple)
states = st.builds(
    OutputState,
    indicators=st.integers(0, (1 << 64) - 1),
    analog=analog_values,
    texts=st.lists(st.text(max_size=5), max_size=2).map(tuple),
)


def unit(value: float) -> float:
    return 0.0 if math.isnan(value) else min(max(value, 0.0), 1.0)


@given(st.sampled_from(KINDS), states)
def test_any_state_gives_a_report_of_the_right_length_with_values_in_range(
    kind: str, state: OutputState
) -> None:
    report_id, length, (strong, weak, red, green, blue) = LAYOUT[kind]
    report = only_report(any_driver(kind).writes(state, None))
    assert (report[0], len(report)) == (report_id, length)
    if kind.endswith("/bt"):
        assert_bt_crc(report)
    scale = unit(dict(state.analog).get("brightness", 1.0))
    wanted = {
        strong: unit(state.value("rumble_strong")),
        weak: unit(state.value("rumble_weak")),
        red: unit(state.value("red") * scale),
        green: unit(state.value("green") * scale),
        blue: unit(state.value("blue") * scale),
    }
    for offset, value in wanted.items():
        assert abs(report[offset] - value * 255) <= 0.5


@given(st.sampled_from(KINDS), states, states)
def test_a_report_goes_only_when_what_it_shows_changed(
    kind: str, first: OutputState, second: OutputState
) -> None:
    driver = any_driver(kind)
    assert driver.writes(first, first) == ()
    full_first = only_report(any_driver(kind).writes(first, None))
    full_second = only_report(any_driver(kind).writes(second, None))
    changed = driver.writes(second, first)
    # a Bluetooth DualSense's sequence nibble and CRC differ from report to report
    payload = slice(3, -4) if kind in ("dualsense/bt", "edge/bt") else slice(None)
    assert (changed != ()) == (full_first[payload] != full_second[payload])
