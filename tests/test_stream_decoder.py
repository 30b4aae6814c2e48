"""The decoders on `usb2rc.protocols.stream.StreamDecoder` decode exactly as the four loops they
replaced (kept in tests/legacy_decoders.py): the same frames from every chunk and the same
counters after every chunk and after `flush()`, on random, mixed and mutated streams."""

from __future__ import annotations

import itertools
from collections.abc import Callable
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from legacy_decoders import OldC2Decoder, OldCrsfDecoder, OldSbusDecoder, OldSumdDecoder

from usb2rc.protocols.c2_16b import codec as c2_16b
from usb2rc.protocols.crsf import codec as crsf
from usb2rc.protocols.sbus import codec as sbus
from usb2rc.protocols.sumd import codec as sumd

COUNTERS = ("frames", "bytes_in", "bytes_skipped", "crc_failures")


def _c2_frames(draw: st.DrawFn) -> bytes:
    if draw(st.booleans()):
        axes = draw(st.lists(st.integers(-32768, 32767), min_size=10, max_size=10))
        return c2_16b.encode_data(
            draw(st.sampled_from(sorted(c2_16b.DATA_STATUSES))),
            draw(st.integers(0, 255)),
            draw(st.integers(0, 255)),
            axes,
            draw(st.integers(0, 0xFFFFFFFF)),
            draw(st.integers(0, 0xFFFFFFFF)),
            line_feed=draw(st.booleans()),
        )
    return c2_16b.device_string(
        draw(st.integers(0, 254)), "stick", binary_status=draw(st.booleans())
    )


def _sumd_frames(draw: st.DrawFn) -> bytes:
    channels = draw(st.lists(st.integers(0, 0xFFFF), min_size=2, max_size=32))
    return sumd.encode_sumd(channels, failsafe=draw(st.booleans()))


def _rc11(draw: st.DrawFn) -> list[int]:
    return draw(st.lists(st.integers(0, 2047), min_size=16, max_size=16))


def _crsf_frames(draw: st.DrawFn) -> bytes:
    kind = draw(st.integers(0, 2))
    if kind == 0:
        return crsf.encode_rc_channels(_rc11(draw), draw(st.sampled_from(sorted(crsf.ADDRESSES))))
    if kind == 1:
        return crsf.encode_timing_sync(draw(st.integers(0, 2**32 - 1)), draw(st.integers(-5, 5)))
    payload = draw(st.binary(max_size=60))
    return crsf.encode_frame(draw(st.sampled_from(sorted(crsf.ADDRESSES))), 0x7F, payload)


def _sbus_frames(draw: st.DrawFn) -> bytes:
    return sbus.encode_sbus(_rc11(draw), failsafe=draw(st.booleans()))


PAIRS: dict[str, tuple[Callable[[], Any], Callable[[], Any], Callable[[st.DrawFn], bytes]]] = {
    "c2-16b": (c2_16b.Decoder, OldC2Decoder, _c2_frames),
    "sumd": (sumd.SumdDecoder, OldSumdDecoder, _sumd_frames),
    "crsf": (crsf.CrsfDecoder, OldCrsfDecoder, _crsf_frames),
    "sbus": (sbus.SbusDecoder, OldSbusDecoder, _sbus_frames),
}


@st.composite
def streams(draw: st.DrawFn, make_frame: Callable[[st.DrawFn], bytes]) -> bytes:
    """Valid frames, truncated and bit-flipped ones, and noise, in any order."""
    parts: list[bytes] = []
    for _ in range(draw(st.integers(0, 8))):
        kind = draw(st.sampled_from(("frame", "frame", "cut", "flip", "noise")))
        if kind == "noise":
            parts.append(draw(st.binary(max_size=40)))
            continue
        frame = bytearray(make_frame(draw))
        if kind == "cut":
            frame = frame[: draw(st.integers(0, len(frame) - 1))]
        elif kind == "flip":
            at = draw(st.integers(0, len(frame) - 1))
            frame[at] ^= 1 << draw(st.integers(0, 7))
        parts.append(bytes(frame))
    return b"".join(parts)


def _chunked(data: bytes, cuts: list[int]) -> list[bytes]:
    points = sorted({0, len(data), *(cut % (len(data) + 1) for cut in cuts)})
    return [data[a:b] for a, b in itertools.pairwise(points)]


def _counters(decoder: Any) -> tuple[int, ...]:
    return tuple(getattr(decoder, name) for name in COUNTERS)


def _assert_same(name: str, data: bytes, cuts: list[int]) -> None:
    new_type, old_type, _ = PAIRS[name]
    new, old = new_type(), old_type()
    for chunk in _chunked(data, cuts):
        assert new.feed(chunk) == old.feed(chunk)
        assert _counters(new) == _counters(old)
    assert new.flush() == old.flush()
    assert _counters(new) == _counters(old)


@pytest.mark.parametrize("name", sorted(PAIRS))
@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data(), cuts=st.lists(st.integers(0, 4000), max_size=12))
def test_same_frames_and_counters_as_the_old_loops(
    name: str, data: st.DataObject, cuts: list[int]
) -> None:
    stream = data.draw(streams(PAIRS[name][2]))
    _assert_same(name, stream, cuts)


@pytest.mark.parametrize("name", sorted(PAIRS))
@settings(max_examples=200, deadline=None)
@given(stream=st.binary(max_size=300), cuts=st.lists(st.integers(0, 400), max_size=8))
def test_same_on_random_bytes(name: str, stream: bytes, cuts: list[int]) -> None:
    _assert_same(name, stream, cuts)


@pytest.mark.parametrize("name", sorted(PAIRS))
def test_one_byte_at_a_time_matches(name: str) -> None:
    """Every header byte of every protocol, valid frames, then a cut-off tail."""
    frames = b"".join(
        (
            c2_16b.encode_data(c2_16b.LIVE, 1, 0, [0] * 10, 0, 0),
            sumd.encode_sumd([0x2EE0] * 8),
            crsf.encode_rc_channels([992] * 16),
            sbus.encode_sbus([992] * 16),
        )
    )
    stream = frames + b"\x0fH-\xa8\x01\x08\xee\x18"
    _assert_same(name, stream, list(range(len(stream))))
