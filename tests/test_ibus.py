"""The iBus output: codec against a hand-computed frame and the reference decoder written from
the description (tests/ibus_reference.py), the session's failsafe silence, and the commands
(`decode`, `check`, `icd`) that take it from the registry alone."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from ibus_reference import RefIbusReader, microseconds

from usb2rc.lines.session import SILENT_TICK_PERIOD_S
from usb2rc.nodes.step import aligned
from usb2rc.protocols.channels import OutputChannels
from usb2rc.protocols.ibus import codec as ibus
from usb2rc.protocols.ibus.session import IbusSession

# 14 × 1500 µs (0x05DC): sum of bytes 0..29 = 0x20 + 0x40 + 14 × (0xDC + 0x05) = 0x0CAE,
# checksum 0xFFFF - 0x0CAE = 0xF351, little-endian.
CENTRED = bytes.fromhex("2040" + "dc05" * 14 + "51f3")


def test_centred_frame_is_the_hand_computed_one() -> None:
    assert ibus.encode_ibus([1500] * 14) == CENTRED
    assert ibus.IbusDecoder().feed(CENTRED) == [ibus.IbusFrame((1500,) * 14)]


@settings(max_examples=200, deadline=None)
@given(
    frames=st.lists(st.lists(st.integers(0, 0xFFFF), min_size=14, max_size=14), max_size=5),
    noise=st.lists(st.binary(max_size=40), min_size=6, max_size=6),
    flip=st.integers(0, 10_000),
)
def test_decoder_agrees_with_the_reference(
    frames: list[list[int]], noise: list[bytes], flip: int
) -> None:
    """Frames between noise, one bit flipped somewhere: both decoders find the same frames."""
    stream = bytearray(noise[0])
    for channels, gap in zip(frames, noise[1:], strict=False):
        stream += ibus.encode_ibus(channels) + gap
    if stream:
        stream[flip % len(stream)] ^= 1 << (flip % 8)
    ours = ibus.IbusDecoder()
    got = ours.feed(bytes(stream)) + ours.flush()
    want = RefIbusReader().feed(bytes(stream))
    assert [list(f.channels) for f in got] == [f.channels for f in want]
    assert ours.bytes_in == len(stream)


@pytest.mark.parametrize("value", [-32768, -32767, -1, 0, 1, 12345, 32766, 32767])
def test_axis_scaling_follows_the_documented_line(value: int) -> None:
    assert ibus.axis_to_ibus(value) == microseconds(value)


def test_scaling_ends_and_centre() -> None:
    assert [ibus.axis_to_ibus(v) for v in (-32768, 0, 32767)] == [1000, 1500, 2000]
    assert (ibus.button_to_ibus(False), ibus.button_to_ibus(True)) == (1000, 2000)


def test_encoder_refuses_a_wrong_count_or_value() -> None:
    with pytest.raises(ValueError, match="14 channels"):
        ibus.encode_ibus([1500] * 13)
    with pytest.raises(ValueError, match="channel 2"):
        ibus.encode_ibus([1500, 70000] + [1500] * 12)


def test_session_pads_and_is_silent_in_failsafe() -> None:
    session = IbusSession("ibus", OutputChannels([]), 100.0)
    frame = session.encode([1234, 2000], failsafe=False)
    assert RefIbusReader().feed(frame)[0].channels == [1234, 2000] + [1000] * 12
    assert session.encode([1234, 2000], failsafe=True) == b""
    assert session.withheld == 1


def test_session_ticks_on_the_20ms_grid_while_silent_but_not_while_the_line_stalls() -> None:
    """Silence in failsafe: the next tick is the 20 ms grid's; a tick with no frame for
    another reason (a stalled line) keeps the output's own rate, so it sees the drain."""
    session = IbusSession("ibus", OutputChannels([]), 1 / 0.007)
    session.line_opened()
    due = aligned(500.0, SILENT_TICK_PERIOD_S)
    assert session.frame([1500] * 4, True) == b""
    assert session.next_due(due, due) == pytest.approx(due + SILENT_TICK_PERIOD_S)
    assert session.frame([1500] * 4, False)
    assert session.next_due(due, due) == pytest.approx(due + 0.007)
    session.line.stall()
    assert session.frame([1500] * 4, True) == b""
    assert session.next_due(due, due) == pytest.approx(due + 0.007)


def _usb2rc(*args: str, stdin: bytes = b"") -> subprocess.CompletedProcess[bytes]:
    return subprocess.run(
        [sys.executable, "-m", "usb2rc", *args], input=stdin, capture_output=True, timeout=60
    )


def test_decode_prints_ibus_frames_from_the_registry() -> None:
    stream = b"\x00" + ibus.encode_ibus([1000 + i for i in range(14)]) + CENTRED[:5]
    done = _usb2rc("decode", "--protocol", "ibus", "--json", "-", stdin=stream)
    assert done.returncode == 0, done.stderr
    record = json.loads(done.stdout.decode().splitlines()[0])
    assert record == {"protocol": "ibus", "frame": "channels", "channels": list(range(1000, 1014))}
    assert b"bytes skipped 6" in done.stderr


def test_check_and_icd_describe_an_ibus_output(tmp_path: Path) -> None:
    master, slave = os.openpty()
    try:
        config = tmp_path / "ibus.yaml"
        listed = "[node0.x, node0.button1]"
        config.write_text(
            f"outputs:\n  - {{protocol: ibus, port: {os.ttyname(slave)}, channels: {listed}}}\n"
        )
        check = _usb2rc("check", "--config", str(config))
        assert check.returncode == 0, check.stderr
        assert b"ibus" in check.stdout and b"no frame is sent" in check.stdout
        icd = _usb2rc("icd", "--config", str(config))
        assert icd.returncode == 0, icd.stderr
        text = icd.stdout.decode()
        assert "## iBus output 1" in text
        assert "| 1 | node0.x | axis, signed | 1000..2000, centre 1500 |" in text
        assert "| 3..14 | (not listed) |  | 1000 |" in text
    finally:
        os.close(master)
        os.close(slave)
