"""CRSF and SBUS: codecs against published frames and a second decoder written from the
protocol descriptions (tests/rc_reference.py), the 11-bit scaling, and the sans-IO sessions
(CRSF's failsafe and timing follow, SBUS's flags)."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st
from rc_reference import (
    RefCrsfReader,
    RefSbusReader,
    channels11,
    crc8_d5,
    crsf_frame,
    parse_sbus,
    rc11,
)

from usb2rc.configfile import load_config_text
from usb2rc.lines.session import SILENT_TICK_PERIOD_S
from usb2rc.nodes.step import aligned
from usb2rc.protocols import rc11 as block
from usb2rc.protocols.channels import OutputChannels
from usb2rc.protocols.crc import crc8_dvb_s2
from usb2rc.protocols.crsf import codec as crsf
from usb2rc.protocols.crsf.session import SYNC_STALE_S, CrsfModule, CrsfSession, ModuleLink
from usb2rc.protocols.rc11 import axis_to_rc11, button_to_rc11
from usb2rc.protocols.sbus import codec as sbus
from usb2rc.protocols.sbus.session import SbusSession

VECTORS = json.loads(
    (Path(__file__).parent / "data" / "vectors" / "crsf-sbus-published.json").read_text()
)
CHANNELS = st.lists(st.integers(0, 2047), min_size=16, max_size=16)


def _bytes(entry: dict) -> bytes:
    return bytes.fromhex(entry["hex"].replace(" ", "")) if "hex" in entry else bytes(entry["bytes"])


# --- CRC and the 11-bit block ----------------------------------------------------------------


def test_crc8_check_value_and_reference() -> None:
    assert crc8_dvb_s2(b"123456789") == 0xBC == crc8_d5(b"123456789")


@given(st.binary(max_size=64))
def test_crc8_matches_the_bitwise_reference(data: bytes) -> None:
    assert crc8_dvb_s2(data) == crc8_d5(data)


@given(CHANNELS)
def test_block_round_trip_and_reference(values: list[int]) -> None:
    packed = block.pack(values)
    assert len(packed) == 22
    assert channels11(packed) == values
    assert list(block.unpack(packed)) == values


def test_block_rejects_bad_values() -> None:
    with pytest.raises(ValueError, match="16 channels"):
        block.pack([0] * 15)
    with pytest.raises(ValueError, match=r"0\.\.2047"):
        block.pack([0] * 15 + [2048])


# --- published frames ------------------------------------------------------------------------


@pytest.mark.parametrize("entry", VECTORS["sbus"], ids=lambda e: e["source"].split(",")[0])
def test_published_sbus_frames(entry: dict) -> None:
    data = _bytes(entry)
    frame_at = data.index(0x0F)
    [frame] = sbus.SbusDecoder().feed(data)
    assert list(frame.channels) == entry["channels"]
    assert (frame.ch17, frame.ch18) == (entry["ch17"], entry["ch18"])
    for flag in ("frame_lost", "failsafe"):
        if flag in entry:
            assert getattr(frame, flag) == entry[flag]
    reference = parse_sbus(data[frame_at : frame_at + 25])
    assert reference.channels == list(frame.channels)
    # and the encoder makes the same 22 channel bytes back
    again = sbus.encode_sbus(frame.channels, ch17=frame.ch17, ch18=frame.ch18)
    assert again[1:23] == data[frame_at + 1 : frame_at + 23]


@pytest.mark.parametrize("entry", VECTORS["crsf"], ids=lambda e: e["source"].split(",")[0])
def test_published_crsf_frames(entry: dict) -> None:
    data = _bytes(entry)
    decoder = crsf.CrsfDecoder()
    [frame] = decoder.feed(data)
    assert decoder.crc_failures == 0 and entry["crc_valid"]
    assert isinstance(frame, crsf.RcChannels)
    assert frame.address == entry["address"] and data[2] == entry["type"]
    [reference] = RefCrsfReader().feed(data)
    assert list(frame.channels) == reference.channels
    assert crsf.encode_rc_channels(frame.channels, address=frame.address) == data


# --- the codecs against the reference --------------------------------------------------------


@given(CHANNELS, st.booleans(), st.booleans(), st.booleans(), st.booleans())
def test_sbus_encoder_against_reference(
    values: list[int], ch17: bool, ch18: bool, lost: bool, failsafe: bool
) -> None:
    data = sbus.encode_sbus(values, ch17=ch17, ch18=ch18, frame_lost=lost, failsafe=failsafe)
    assert len(data) == 25 and data[0] == 0x0F and data[24] == 0
    [ref] = RefSbusReader().feed(data)
    assert (ref.channels, ref.ch17, ref.ch18, ref.frame_lost, ref.failsafe) == (
        values,
        ch17,
        ch18,
        lost,
        failsafe,
    )


@given(CHANNELS)
def test_crsf_encoder_against_reference(values: list[int]) -> None:
    data = crsf.encode_rc_channels(values)
    assert len(data) == crsf.RC_FRAME_LEN == 26
    assert data[:3] == bytes([0xEE, 24, 0x16])
    [ref] = RefCrsfReader().feed(data)
    assert ref.channels == values


@given(st.lists(CHANNELS, min_size=1, max_size=4), st.binary(max_size=30), st.integers(1, 9))
def test_crsf_decoder_resyncs_in_any_chunking(frames: list, junk: bytes, step: int) -> None:
    junk = bytes(b for b in junk if b not in crsf.ADDRESSES)  # no false start in the junk
    stream = junk + b"".join(crsf.encode_rc_channels(v) for v in frames) + junk
    decoder = crsf.CrsfDecoder()
    got = []
    for i in range(0, len(stream), step):
        got += decoder.feed(stream[i : i + step])
    got += decoder.flush()
    assert [list(f.channels) for f in got] == frames
    assert decoder.bytes_skipped == 2 * len(junk)


def test_crsf_decoder_counts_a_bad_crc_and_finds_the_next_frame() -> None:
    good = crsf.encode_rc_channels([992] * 16)
    bad = bytearray(good)
    bad[10] ^= 0x01
    decoder = crsf.CrsfDecoder()
    frames = decoder.feed(bytes(bad) + good)
    assert decoder.crc_failures >= 1
    assert [list(f.channels) for f in frames if isinstance(f, crsf.RcChannels)] == [[992] * 16]


def test_module_frames_from_the_description() -> None:
    """Link statistics (0x14) and the timing correction (0x3A / 0x10) as an ELRS module
    sends them, built here from the description, not with the codec's encoders."""
    link_payload = bytes([45, 50, 100, 9, 1, 7, 3, 60, 98]) + struct.pack(">b", -4)
    timing_payload = bytes([0xEA, 0xEE, 0x10]) + struct.pack(">Ii", 40000, -2500)
    stream = crsf_frame(0xEA, 0x14, link_payload) + crsf_frame(0xEA, 0x3A, timing_payload)
    link, timing = crsf.CrsfDecoder().feed(stream)
    assert link == crsf.LinkStatistics(45, 50, 100, 9, 1, 7, 3, 60, 98, -4)
    assert timing == crsf.TimingSync(40000, -2500)
    assert timing.interval_s == pytest.approx(0.004) and timing.offset_s == pytest.approx(-250e-6)
    assert crsf.encode_link_statistics(link) == stream[: len(stream) - 15]
    assert crsf.encode_timing_sync(40000, -2500) == stream[-15:]


# --- scaling ----------------------------------------------------------------------------------


def test_rc11_scaling_ends_centre_buttons() -> None:
    assert [axis_to_rc11(v) for v in (-32768, 0, 32767)] == [172, 992, 1811]
    assert (button_to_rc11(False), button_to_rc11(True)) == (172, 1811)
    with pytest.raises(ValueError):
        axis_to_rc11(32768)


@given(st.integers(-32768, 32767))
def test_rc11_scaling_matches_the_documented_formula(value: int) -> None:
    assert axis_to_rc11(value) == rc11(value)


# --- sessions -----------------------------------------------------------------------------------


NO_CHANNELS = OutputChannels([])  # the tests give the sessions their values themselves


def test_crsf_session_withholds_frames_in_failsafe_and_pads_with_low() -> None:
    session = CrsfSession("crsf", NO_CHANNELS, CrsfModule(0.004))
    session.line_opened()
    [ref] = RefCrsfReader().feed(session.frame([1811, 992], False))
    assert ref.channels == [1811, 992] + [172] * 14
    assert session.frame([1811, 992], True) == b""
    assert session.withheld == 1
    assert session.frame([172, 992], False)


@pytest.mark.parametrize("rate_hz", [250.0, 500.0, 150.0])
def test_crsf_session_ticks_on_the_20ms_grid_while_it_withholds(rate_hz: float) -> None:
    """In failsafe CRSF sends nothing, so it has no reason to tick at its own rate: the
    tick after a withheld one is the next on the 20 ms grid (where the other outputs' ticks
    fall); the tick after one that sent is one period later again."""
    period = 1.0 / rate_hz
    session = CrsfSession("crsf", NO_CHANNELS, CrsfModule(period))
    session.line_opened()
    due = aligned(1000.0, period)
    assert session.frame([992] * 4, True) == b""
    silent_due = session.next_due(due, due)
    assert silent_due == aligned(due + period, SILENT_TICK_PERIOD_S)
    assert due < silent_due <= due + period + SILENT_TICK_PERIOD_S
    assert session.frame([992] * 4, False)
    assert session.next_due(silent_due, silent_due) == pytest.approx(silent_due + period)


def test_crsf_session_follows_the_module_timing_then_falls_back() -> None:
    session = CrsfModule(0.004)
    assert session.next_send(10.0, 10.0) == pytest.approx(10.004)
    sync = crsf.encode_timing_sync(20000, 3000)  # 2 ms (500 Hz), send 300 µs later
    session.received(sync[:5], 10.001)
    session.received(sync[5:], 10.001)
    assert session.following(10.002)
    assert session.next_send(10.004, 10.002) == pytest.approx(10.004 + 0.002 + 0.0003)
    assert session.next_send(10.0063, 10.004) == pytest.approx(10.0083)  # shifted once only
    assert "following the module: 500 Hz" in session.link_text(10.005)
    later = 10.001 + SYNC_STALE_S + 0.01
    assert not session.following(later)
    assert session.next_send(later, later) == pytest.approx(later + 0.004)


def test_crsf_session_bounds_what_it_follows() -> None:
    session = CrsfModule(0.004, min_interval_s=0.0025)
    session.received(crsf.encode_timing_sync(10000, 0), 1.0)  # 1000 Hz: more than the line
    assert session.interval_s(1.0) == pytest.approx(0.0025)
    session.received(crsf.encode_timing_sync(40000, 10_000_000), 1.1)  # 1 s offset: a half
    assert session.next_send(2.0, 1.1) == pytest.approx(2.0 + 0.004 + 0.002)
    session.received(crsf.encode_timing_sync(5, 0), 1.2)  # 0.5 µs: implausible
    assert session.timing_ignored == 1
    off = CrsfModule(0.004, follow_module=False)
    off.received(crsf.encode_timing_sync(20000, 0), 1.0)
    assert off.interval_s(1.0) == pytest.approx(0.004) and off.timing_ignored == 1


def test_crsf_session_keeps_the_link_statistics() -> None:
    session = CrsfModule(0.004)
    stats = crsf.LinkStatistics(60, 61, 87, 7, 0, 5, 2, 70, 90, 3)
    session.received(crsf.encode_link_statistics(stats), 5.0)
    assert session.link == ModuleLink(stats, 5.0)  # one value: the figures with their time
    assert "link quality 87% up / 90% down, RSSI -60 dBm, SNR 7 dB" in session.link_text(5.5)


def test_sbus_session_flags_and_digital_channels() -> None:
    session = SbusSession("sbus", NO_CHANNELS, 100.0)
    session.line_opened()
    values = [172 + 100 * i for i in range(16)] + [1811, 172]
    [ref] = RefSbusReader().feed(session.frame(values, False))
    assert ref.channels == values[:16] and (ref.ch17, ref.ch18) == (True, False)
    assert not ref.frame_lost and not ref.failsafe
    [ref] = RefSbusReader().feed(session.frame([992, 992], True))
    assert ref.channels == [992, 992] + [172] * 14
    assert ref.frame_lost and ref.failsafe and not ref.ch17


# --- config ----------------------------------------------------------------------------------


def test_crsf_and_sbus_defaults() -> None:
    config = load_config_text(
        "outputs:\n"
        "  - {protocol: crsf, port: /dev/ttyUSB0, channels: [node0.x, node0.button1]}\n"
        "  - {protocol: sbus, port: /dev/ttyAMA0, channels: [node0.x]}\n"
    )
    crsf_out, sbus_out = config.outputs
    assert (crsf_out.baudrate, crsf_out.rate_hz, crsf_out.option("follow_module")) == (
        400000,
        250,
        True,
    )
    assert (sbus_out.baudrate, sbus_out.rate_hz) == (100000, 100)
    assert [c.name for c in crsf_out.channels or ()] == ["node0.x", "node0.button1"]


@given(st.lists(st.binary(max_size=80), max_size=8))
def test_decoders_never_raise_and_account_for_every_byte(chunks: list[bytes]) -> None:
    for decoder in (crsf.CrsfDecoder(), sbus.SbusDecoder()):
        frames = [f for chunk in chunks for f in decoder.feed(chunk)] + decoder.flush()
        size = crsf.RC_FRAME_LEN if isinstance(decoder, crsf.CrsfDecoder) else sbus.FRAME_LEN
        assert decoder.bytes_in == sum(map(len, chunks))
        if isinstance(decoder, sbus.SbusDecoder):
            assert decoder.bytes_skipped + size * len(frames) == decoder.bytes_in
        else:
            assert decoder.bytes_skipped <= decoder.bytes_in


# --- commands ----------------------------------------------------------------------------------

FOUR = """outputs:
  - {protocol: c2-16b, port: /dev/ttyUSB1}
  - {protocol: crsf, port: /dev/ttyUSB0, channels: [node0.x, node0.y, node0.button1]}
  - {protocol: sbus, port: /dev/ttyAMA0, channels: [node0.x, node0.y, node0.button1]}
"""


def test_check_and_icd_describe_crsf_and_sbus(tmp_path: Path, capsys) -> None:
    from usb2rc.cli import main

    path = tmp_path / "rc.yaml"
    path.write_text(FOUR)
    assert main(["check", "--config", str(path)]) == 0
    out = capsys.readouterr().out
    assert "crsf    /dev/ttyUSB0  400000 baud  250 Hz" in out
    assert "sbus    /dev/ttyAMA0  100000 baud  100 Hz  8E2" in out
    assert "3 channels: node0.x node0.y node0.button1" in out
    assert main(["icd", "--config", str(path)]) == 0
    out = capsys.readouterr().out
    assert "## CRSF output 2 (/dev/ttyUSB0)" in out and "## SBUS output 3 (/dev/ttyAMA0)" in out
    assert "| 3 | node0.button1 | button | 172 / 1811 (988 / 2012 µs) |" in out
    assert "| 4..16 | (not listed) |  | 172 (988 µs) |" in out


def test_decode_prints_crsf_and_sbus_frames(tmp_path: Path, capsys) -> None:
    from usb2rc.cli import main

    capture = tmp_path / "crsf.bin"
    capture.write_bytes(
        b"\x00" + crsf.encode_rc_channels([172] * 16) + crsf.encode_timing_sync(20000, -50)
    )
    assert main(["decode", "--protocol", "crsf", str(capture)]) == 0
    captured = capsys.readouterr()
    assert captured.out.splitlines() == [
        f"crsf rc-channels to 0xEE {[172] * 16}",
        "crsf timing-correction interval 2000.0 us (500 Hz) offset -5.0 us",
    ]
    assert "bytes skipped 1" in captured.err
    capture = tmp_path / "sbus.bin"
    capture.write_bytes(sbus.encode_sbus([992] * 16, ch18=True, frame_lost=True, failsafe=True))
    assert main(["decode", "--protocol", "sbus", "--json", str(capture)]) == 0
    record = json.loads(capsys.readouterr().out)
    assert record == {
        "protocol": "sbus",
        "channels": [992] * 16,
        "ch17": False,
        "ch18": True,
        "frame_lost": True,
        "failsafe": True,
    }


EVENTS = st.lists(
    st.one_of(
        st.tuples(st.just("tick"), st.booleans()),
        st.tuples(st.just("sync"), st.integers(0, 2_000_000), st.integers(-(2**31), 2**31 - 1)),
        st.tuples(st.just("wait"), st.floats(0.0, 2.0)),
        st.tuples(st.just("send")),
    ),
    max_size=40,
)


@given(EVENTS, st.floats(0.0, 0.01))
def test_crsf_session_timing_invariants(events: list, min_interval: float) -> None:
    """Whatever the module says and whenever: the next frame is always later than the one
    before (at least half an interval), the interval stays within what the line carries and
    100 ms, frames go out only while live, a stale correction is not followed, and a tick
    that withheld its frame is followed by one on the 20 ms grid, no later."""
    module = CrsfModule(0.004, min_interval_s=min_interval)
    session = CrsfSession("crsf", NO_CHANNELS, module)
    session.line_opened()
    now = due = 0.0
    withheld = False
    for event in events:
        if event[0] == "tick":
            frame = session.frame([992] * 4, event[1])
            assert bool(frame) == (not event[1])
            withheld = event[1]
        elif event[0] == "sync":
            session.received(crsf.encode_timing_sync(event[1], event[2]), now)
        elif event[0] == "wait":
            now += event[1]
        if event[0] != "send":
            continue
        interval = session.period(now)
        assert max(0.001, min_interval) <= interval <= 0.1 or interval == 0.004
        if module.timing is None or now - module.timing.at > SYNC_STALE_S:
            assert interval == 0.004
        following = module.following(now)
        nxt = session.next_due(due, now)
        assert nxt >= due + interval / 2 - 1e-12
        if withheld:
            assert aligned(nxt, SILENT_TICK_PERIOD_S) == nxt
            assert nxt < due + 0.1 + SILENT_TICK_PERIOD_S  # the frame's own due, then the grid
        else:
            assert following or nxt == pytest.approx(due + 0.004)
        due = nxt
