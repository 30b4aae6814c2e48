"""SUMD codec: shared vectors both ways, scaling helpers, encoder errors, streaming decoder."""

from __future__ import annotations

import itertools
import json
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st
from wrong_type import rejected

from usb2rc.protocols.sumd.codec import (
    SumdDecoder,
    SumdFrame,
    axis_to_sumd,
    button_to_sumd,
    encode_sumd,
    frame_length,
)

VECTORS: list[dict[str, Any]] = json.loads(
    (Path(__file__).parent / "data" / "vectors" / "sumd.json").read_text()
)
NEUTRAL_8 = [0x2EE0] * 8


def decode_all(data: bytes, chunk_size: int | None = None) -> tuple[list[SumdFrame], SumdDecoder]:
    decoder = SumdDecoder()
    size = chunk_size or max(len(data), 1)
    frames = [f for i in range(0, len(data), size) for f in decoder.feed(data[i : i + size])]
    return frames + decoder.flush(), decoder


@pytest.mark.parametrize("vector", VECTORS, ids=lambda v: v["name"])
def test_vector_encodes(vector: dict[str, Any]) -> None:
    assert encode_sumd(vector["values"], failsafe=vector["failsafe"]).hex() == vector["hex"]


@pytest.mark.parametrize("vector", VECTORS, ids=lambda v: v["name"])
def test_vector_decodes(vector: dict[str, Any]) -> None:
    frames, decoder = decode_all(bytes.fromhex(vector["hex"]), chunk_size=1)
    assert frames == [SumdFrame(vector["failsafe"], tuple(vector["values"]))]
    assert (decoder.bytes_skipped, decoder.crc_failures) == (0, 0)


def test_frame_layout() -> None:
    wire = encode_sumd([0x1234, 0xABCD], failsafe=True)
    assert wire[:7] == bytes([0xA8, 0x81, 0x02, 0x12, 0x34, 0xAB, 0xCD])
    assert len(wire) == frame_length(2) == 9


# --- scaling -------------------------------------------------------------------------------


def test_axis_scaling_ends_and_centre_are_exact() -> None:
    assert [axis_to_sumd(v) for v in (-32768, 0, 32767)] == [0x2260, 0x2EE0, 0x3B60]
    extended = [axis_to_sumd(v, extended=True) for v in (-32768, 0, 32767)]
    assert extended == [0x1C20, 0x2EE0, 0x41A0]


@pytest.mark.parametrize(("extended", "low", "high"), [(False, 8800, 15200), (True, 7200, 16800)])
def test_axis_scaling_is_the_rounded_straight_line(extended: bool, low: int, high: int) -> None:
    previous = low
    for value in range(-32768, 32768):
        scaled = axis_to_sumd(value, extended)
        assert scaled == low + round((value + 32768) * (high - low) / 65535)
        assert previous <= scaled <= previous + 1
        previous = scaled


@pytest.mark.parametrize("value", [-32769, 32768, 65535, 1.0])
def test_axis_scaling_rejects_non_int16(value: Any) -> None:
    with rejected("int16", value):  # 1.0 is a wrong type (tests/wrong_type.py)
        axis_to_sumd(value)


def test_button_scaling() -> None:
    assert (button_to_sumd(True), button_to_sumd(False)) == (0x3B60, 0x2260)


# --- encoder errors ------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("channels", "message"),
    [
        ([0x2EE0], "2..32 channels"),
        ([0x2EE0] * 33, "2..32 channels"),
        ([0x2EE0, -1], "channel 2"),
        ([65536, 0], "channel 1"),
        ([0x2EE0, 1.5], "channel 2"),  # a wrong type (tests/wrong_type.py)
    ],
)
def test_encoder_rejects_bad_channels(channels: list[Any], message: str) -> None:
    with rejected(message, channels):
        encode_sumd(channels)


# --- streaming decoder ---------------------------------------------------------------------


def test_chunking_does_not_matter() -> None:
    stream = b"".join(bytes.fromhex(v["hex"]) for v in VECTORS)
    expected, _ = decode_all(stream)
    assert len(expected) == len(VECTORS)
    for size in (1, 2, 3, 5, 21, 68, 69, 70):
        frames, decoder = decode_all(stream, size)
        assert frames == expected
        assert (decoder.frames, decoder.bytes_skipped, decoder.bytes_in) == (5, 0, len(stream))


def test_flipped_bit_is_a_crc_failure_and_the_next_frame_survives() -> None:
    corrupted = bytearray(encode_sumd(NEUTRAL_8))
    corrupted[5] ^= 0x01
    good = encode_sumd([0x2260, 0x3B60])
    frames, decoder = decode_all(b"\x00" + bytes(corrupted) + good, 1)
    assert frames == [SumdFrame(False, (0x2260, 0x3B60))]
    assert decoder.crc_failures == 1
    assert decoder.bytes_skipped == 1 + len(corrupted)


def test_implausible_headers_are_skipped_without_crc_failures() -> None:
    noise = bytes([0xA8, 0x02, 0x08, 0xA8, 0x01, 0x01, 0xA8, 0x81, 0x21])
    frames, decoder = decode_all(noise + encode_sumd(NEUTRAL_8))
    assert frames == [SumdFrame(False, tuple(NEUTRAL_8))]
    assert (decoder.crc_failures, decoder.bytes_skipped) == (0, len(noise))


def test_flush_finds_a_frame_behind_a_long_plausible_header() -> None:
    decoder = SumdDecoder()
    wire = encode_sumd(NEUTRAL_8)
    assert decoder.feed(bytes([0xA8, 0x01, 0x20]) + wire) == []  # waits for 69 bytes
    assert decoder.flush() == [SumdFrame(False, tuple(NEUTRAL_8))]
    assert decoder.bytes_skipped == 3
    assert decoder.feed(wire) == [SumdFrame(False, tuple(NEUTRAL_8))]


def test_buffer_stays_bounded() -> None:
    decoder = SumdDecoder()
    junk = bytes([0xA8, 0x01, 0x20]) * 40
    for _ in range(100):
        decoder.feed(junk)
        assert len(decoder._buffer) < frame_length(32)


# --- properties ----------------------------------------------------------------------------

sumd_frames = st.builds(
    SumdFrame,
    failsafe=st.booleans(),
    channels=st.lists(st.integers(0, 0xFFFF), min_size=2, max_size=32).map(tuple),
)
garbage_without_vendor_id = st.binary(max_size=60).map(lambda b: b.replace(b"\xa8", b""))


@st.composite
def chunked(draw: st.DrawFn, data: bytes) -> list[bytes]:
    cuts = sorted(draw(st.lists(st.integers(0, len(data)), max_size=12)))
    return [data[a:b] for a, b in itertools.pairwise([0, *cuts, len(data)])]


@given(sumd_frames)
def test_round_trip(frame: SumdFrame) -> None:
    frames, _ = decode_all(encode_sumd(frame.channels, frame.failsafe))
    assert frames == [frame]


@given(
    st.lists(st.tuples(garbage_without_vendor_id, sumd_frames), max_size=8),
    garbage_without_vendor_id,
    st.data(),
)
def test_finds_every_frame_embedded_in_garbage(
    items: list[tuple[bytes, SumdFrame]], tail: bytes, data: st.DataObject
) -> None:
    stream = b"".join(g + encode_sumd(f.channels, f.failsafe) for g, f in items) + tail
    decoder = SumdDecoder()
    found = [f for chunk in data.draw(chunked(stream)) for f in decoder.feed(chunk)]
    found += decoder.flush()
    assert found == [frame for _, frame in items]
    assert decoder.crc_failures == 0


@given(st.binary(max_size=400), st.data())
def test_never_raises_and_accounts_for_every_byte(noise: bytes, data: st.DataObject) -> None:
    decoder = SumdDecoder()
    frames = [f for chunk in data.draw(chunked(noise)) for f in decoder.feed(chunk)]
    frames += decoder.flush()
    used = sum(frame_length(len(frame.channels)) for frame in frames)
    assert decoder.frames == len(frames)
    assert decoder.bytes_in == len(noise)
    assert decoder.bytes_skipped + used == len(noise)
