"""CRSF telemetry (`CrsfSession.telemetry`): link statistics, battery and flight mode frames
from the module, built here byte by byte with the tests' own reference CRC
(tests/rc_reference.py, sharing no code with usb2rc.protocols), become the right
`CrsfTelemetry`; a frame with a bad CRC is counted and changes nothing."""

from __future__ import annotations

import pytest
from rc_reference import crc8_d5

from usb2rc.feedback.model import CrsfTelemetry
from usb2rc.protocols.channels import OutputChannels
from usb2rc.protocols.crsf import codec as crsf
from usb2rc.protocols.crsf import telemetry
from usb2rc.protocols.crsf.session import CrsfModule, CrsfSession
from usb2rc.protocols.rc11_channels import RC11_SCALE

HANDSET = 0xEA  # what a module addresses its telemetry to


def ref_frame(frame_type: int, payload: bytes, address: int = HANDSET) -> bytes:
    """A CRSF frame as the spec writes it: address, length (type + payload + CRC), type,
    payload, CRC-8/DVB-S2 over type and payload."""
    body = bytes([frame_type]) + payload
    return bytes([address, len(body) + 1]) + body + bytes([crc8_d5(body)])


def link_statistics(rssi_1: int, rssi_2: int, lq: int, snr: int) -> bytes:
    # uplink RSSI 1, 2 (-dBm), LQ, SNR (int8), antenna, RF mode, TX power, downlink RSSI,
    # LQ, SNR
    payload = bytes([rssi_1, rssi_2, lq, snr & 0xFF, 1, 7, 3, 80, 99, 5])
    return ref_frame(0x14, payload)


def battery(voltage_dv: int, current_da: int, capacity_mah: int, remaining: int) -> bytes:
    payload = (
        voltage_dv.to_bytes(2, "big")
        + current_da.to_bytes(2, "big")
        + capacity_mah.to_bytes(3, "big")
        + bytes([remaining])
    )
    return ref_frame(0x08, payload)


def session() -> CrsfSession:
    channels = OutputChannels.scaled([], RC11_SCALE, crsf.RC_FRAME_LEN)
    line = CrsfSession("crsf", channels, CrsfModule(0.004))
    line.line_opened()
    return line


@pytest.mark.parametrize(
    ("rssi_1", "rssi_2", "rssi_dbm"),
    [
        (70, 0, -70),  # no diversity: antenna 2 gives no reading
        (90, 61, -61),  # the better antenna
        (55, 80, -55),
        (0, 0, None),  # no reading at all: unknown, not 0 dBm
    ],
)
def test_link_statistics_give_uplink_lq_the_better_rssi_and_snr(
    rssi_1: int, rssi_2: int, rssi_dbm: int | None
) -> None:
    line = session()
    assert line.telemetry is None  # nothing heard yet
    line.received(link_statistics(rssi_1, rssi_2, lq=42, snr=-7), now=3.0)
    assert line.telemetry == CrsfTelemetry(42, rssi_dbm, -7, at=3.0)


def test_a_battery_frame_gives_voltage_and_remaining() -> None:
    line = session()
    line.received(battery(168, 123, 1234, 77), now=1.5)
    assert line.telemetry == CrsfTelemetry(battery_v=16.8, battery_remaining=77, at=1.5)
    (frame,) = crsf.CrsfDecoder().feed(battery(168, 123, 70000, 0))
    assert isinstance(frame, crsf.OtherFrame)  # the codec keeps it as it came
    sensor = telemetry.battery_of(frame)
    assert sensor == telemetry.BatterySensor(16.8, 12.3, 70000, 0)  # capacity: all 24 bits


def test_a_flight_mode_frame_gives_its_text_up_to_the_nul() -> None:
    line = session()
    line.received(ref_frame(0x21, b"ACRO\0"), now=2.0)
    assert line.telemetry == CrsfTelemetry(flight_mode="ACRO", at=2.0)
    line.received(ref_frame(0x21, b"!FS\0junk"), now=2.5)
    assert line.telemetry == CrsfTelemetry(flight_mode="!FS", at=2.5)
    line.received(ref_frame(0x21, b"AN\x07GLE\0"), now=3.0)  # a control character
    assert line.telemetry is not None and line.telemetry.flight_mode == "AN?GLE"


def test_reports_merge_into_one_value_whose_time_is_the_newest() -> None:
    line = session()
    stream = link_statistics(65, 0, 100, 9) + battery(252, 0, 0, 88)
    line.received(stream, now=10.0)
    line.received(ref_frame(0x21, b"HOR\0"), now=11.0)
    line.received(link_statistics(80, 95, 31, -2), now=12.0)
    assert line.telemetry == CrsfTelemetry(31, -80, -2, 25.2, 88, "HOR", at=12.0)
    stats = line.stats(12.0)
    assert stats["module_rx_link_statistics"] == 2
    assert stats["module_rx_battery"] == 1 and stats["module_rx_flight_mode"] == 1


def test_a_frame_with_a_bad_crc_is_counted_and_changes_nothing() -> None:
    line = session()
    line.received(link_statistics(60, 0, 90, 4), now=1.0)
    before = line.telemetry
    bad = bytearray(link_statistics(120, 0, 5, -10))
    bad[-1] ^= 0x55
    line.received(bytes(bad), now=2.0)
    assert line.telemetry == before
    stats = line.stats(2.0)
    assert stats["module_rx_crc_failures"] == 1 and stats["module_rx_link_statistics"] == 1


def test_a_battery_frame_too_short_for_its_fields_is_counted_and_ignored() -> None:
    line = session()
    line.received(ref_frame(0x08, bytes([0, 168, 0, 0])), now=1.0)
    assert line.telemetry is None
    assert line.stats(1.0)["module_rx_malformed"] == 1


def test_the_encoders_make_the_frames_the_spec_describes() -> None:
    assert telemetry.encode_battery(168, 123, 1234, 77) == battery(168, 123, 1234, 77)
    assert telemetry.encode_flight_mode("ACRO") == ref_frame(0x21, b"ACRO\0")
    stats = crsf.LinkStatistics(70, 0, 42, -7, 1, 7, 3, 80, 99, 5)
    assert crsf.encode_link_statistics(stats) == link_statistics(70, 0, 42, -7)
    with pytest.raises(ValueError, match="capacity"):
        telemetry.encode_battery(168, 0, 1 << 24, 0)
    with pytest.raises(ValueError, match="out of range"):
        telemetry.encode_battery(70000, 0, 0, 0)
