"""The encoders' precompiled packing (CRCs from position tables, one struct per frame), held
to the encoders it replaced (tests/legacy_encoders.py) byte for byte and error for error, and
to the shared vectors in tests/data/vectors."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import legacy_encoders as legacy
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from wrong_type import fail_alike

from usb2rc import compiled_path
from usb2rc.protocols import crc, rc11
from usb2rc.protocols.c2_16b import codec as c2_16b
from usb2rc.protocols.crsf import codec as crsf
from usb2rc.protocols.sbus import codec as sbus

VECTORS = Path(__file__).parent / "data" / "vectors"

statuses = st.sampled_from(sorted(c2_16b.DATA_STATUSES))
bytes_ = st.integers(0, 255)
axes = st.lists(st.integers(-32768, 65535), min_size=10, max_size=10)
groups = st.integers(0, 0xFFFFFFFF)
channels11 = st.lists(st.integers(0, rc11.VALUE_MAX), min_size=16, max_size=16)
# Values a caller might get wrong: each check's message must be the old one (where one is
# of the wrong type and the hot path compiled, both must fail: tests/wrong_type.py).
odd_values = st.one_of(
    st.integers(-70000, 70000),
    st.booleans(),
    st.floats(allow_nan=False, allow_infinity=False),
    st.none(),
    st.text(max_size=2),
)


def outcome(call: Any, *args: Any, **kwargs: Any) -> tuple[str, object]:
    """What a call did: its bytes, or its ValueError's message, or the other error's type."""
    try:
        return ("bytes", call(*args, **kwargs))
    except ValueError as exc:
        return ("ValueError", str(exc))
    except Exception as exc:  # the old code's TypeError must stay one too
        return ("error", type(exc).__name__)


# --- CRCs ----------------------------------------------------------------------------------


@given(st.binary(max_size=80), st.binary(max_size=40))
def test_crcs_match_the_old_ones_and_continue(first: bytes, second: bytes) -> None:
    whole = first + second
    assert crc.crc16_arc(whole) == legacy.crc16_arc(whole)
    assert crc.crc16_arc(second, crc.crc16_arc(first)) == legacy.crc16_arc(whole)
    assert crc.crc8_dvb_s2(whole) == legacy.crc8_dvb_s2(whole)
    assert crc.crc8_dvb_s2(second, crc.crc8_dvb_s2(first)) == legacy.crc8_dvb_s2(whole)


@given(st.integers(1, 40).flatmap(lambda n: st.tuples(st.binary(min_size=n, max_size=n))))
def test_a_messages_crc_is_the_xor_of_its_bytes_positions(message: tuple[bytes]) -> None:
    data = message[0]
    combined = 0
    for position, value in enumerate(data):
        combined ^= crc.arc_position_table(position, len(data))[value]
    assert combined == legacy.crc16_arc(data)


def test_position_table_refuses_a_position_outside_the_message() -> None:
    with pytest.raises(ValueError, match="position 5"):
        crc.arc_position_table(5, 5)


# --- C2-16B --------------------------------------------------------------------------------


@settings(max_examples=300)
@given(statuses, bytes_, bytes_, axes, groups, groups, st.booleans())
def test_encode_data_is_the_old_encoder(
    status: int, node: int, code: int, axes_: list[int], g1: int, g2: int, lf: bool
) -> None:
    new = c2_16b.encode_data(status, node, code, axes_, g1, g2, line_feed=lf)
    assert new == legacy.encode_data(status, node, code, axes_, g1, g2, line_feed=lf)


@settings(max_examples=300)
@given(
    st.one_of(statuses, odd_values),
    st.one_of(bytes_, odd_values),
    st.one_of(bytes_, odd_values),
    st.one_of(axes, st.lists(st.one_of(st.integers(-32768, 65535), odd_values), max_size=11)),
    st.one_of(groups, odd_values),
    st.one_of(groups, odd_values),
)
@example(c2_16b.LIVE, 1, 0, [0] * 10, 0, True)  # a bool: refused, or 0 or 1 where compiled
@example(c2_16b.LIVE, 1, 0, [0, True, *[0] * 8], 0, 0)  # in a list: refused on either path
def test_encode_data_fails_as_the_old_encoder(
    status: Any, node: Any, code: Any, axes_: Any, g1: Any, g2: Any
) -> None:
    args = (status, node, code, axes_, g1, g2)
    new = outcome(c2_16b.encode_data, *args)
    if compiled_path.compiled_active():
        # compiled, a single `int` argument takes a bool as 0 or 1 (tests/wrong_type.py)
        args = tuple(int(arg) if type(arg) is bool else arg for arg in args)
    old = outcome(legacy.encode_data, *args)
    assert fail_alike(new, old, *args), (new, old)


@given(
    st.sampled_from(list(c2_16b.Service)),
    bytes_,
    st.binary(max_size=28),
    st.booleans(),
    st.booleans(),
)
def test_service_frames_keep_their_crc(
    service: c2_16b.Service, node: int, payload: bytes, binary: bool, lf: bool
) -> None:
    frame = c2_16b.encode_service(service, node, payload, binary_status=binary, line_feed=lf)
    assert int.from_bytes(frame[33:35], "little") == legacy.crc16_arc(frame[:33])
    assert frame[:2] == b"H-" and len(frame) == 35 + lf


# --- the 11-bit block: SBUS and CRSF -------------------------------------------------------


@settings(max_examples=300)
@given(
    channels11,
    st.booleans(),
    st.booleans(),
    st.booleans(),
    st.booleans(),
    st.integers(0, 255),
)
def test_sbus_and_crsf_are_the_old_encoders(
    values: list[int], ch17: bool, ch18: bool, lost: bool, failsafe: bool, address: int
) -> None:
    flags = {"ch17": ch17, "ch18": ch18, "frame_lost": lost, "failsafe": failsafe}
    assert rc11.pack(values) == legacy.rc11_pack(values)
    assert sbus.encode_sbus(values, **flags) == legacy.encode_sbus(values, **flags)
    assert crsf.encode_rc_channels(values, address) == legacy.encode_rc_channels(values, address)


@given(
    st.lists(st.one_of(st.integers(0, rc11.VALUE_MAX), odd_values), min_size=14, max_size=18),
    st.one_of(st.integers(-2, 300), odd_values),
)
@example([0] * 15 + [False], 0)  # a bool is an int: its check must stay
def test_sbus_and_crsf_fail_as_the_old_encoders(values: list[Any], address: Any) -> None:
    new, old = outcome(rc11.pack, values), outcome(legacy.rc11_pack, values)
    assert fail_alike(new, old, values), (new, old)
    new, old = outcome(sbus.encode_sbus, values), outcome(legacy.encode_sbus, values)
    assert fail_alike(new, old, values), (new, old)
    new = outcome(crsf.encode_rc_channels, values, address)
    old = outcome(legacy.encode_rc_channels, values, address)
    assert fail_alike(new, old, values, address), (new, old)


def test_sbus_and_crsf_reproduce_the_published_frames() -> None:
    """Each published frame, decoded, encodes to its own bytes again."""
    published = json.loads((VECTORS / "crsf-sbus-published.json").read_text())
    for entry in published["sbus"]:
        wire = _wire(entry)
        [frame] = sbus.SbusDecoder().feed(wire)
        flags = {"ch17": frame.ch17, "ch18": frame.ch18}
        flags |= {"frame_lost": frame.frame_lost, "failsafe": frame.failsafe}
        published_frame = bytearray(wire[wire.index(sbus.HEADER) :][: sbus.FRAME_LEN])
        published_frame[sbus.FLAGS_AT] &= 0x0F  # some set the unused bits; usb2rc does not
        encoded = sbus.encode_sbus(frame.channels, **flags)
        assert encoded == published_frame, entry["source"]
    for entry in published["crsf"]:
        wire = _wire(entry)
        for rc in crsf.CrsfDecoder().feed(wire):
            if isinstance(rc, crsf.RcChannels):
                assert crsf.encode_rc_channels(rc.channels, rc.address) in wire, entry["source"]


def _wire(entry: dict[str, Any]) -> bytes:
    if "hex" in entry:
        return bytes.fromhex(entry["hex"].replace(" ", ""))
    return bytes(entry["bytes"])


C2_CONTENTS = st.tuples(
    st.lists(st.integers(-32768, 65535), min_size=10, max_size=10),
    st.integers(0, 0xFFFFFFFF),
    st.integers(0, 0xFFFFFFFF),
)
C2_FRAMES = st.tuples(
    st.sampled_from([0x3E, 0x21, 0x3C, 0x26, 0x25, 0x3E, 0x00]),  # a bad status too
    st.integers(0, 3),
    st.integers(0, 255),
    st.integers(0, 3),  # which of a few contents: most frames repeat one
)


def one_field_changed(content: tuple[list[int], int, int], k: int) -> tuple[list[int], int, int]:
    """`content` with field k changed: an axis (0-9), group 1 (10) or group 2 (11)."""
    axes, group1, group2 = list(content[0]), content[1], content[2]
    if k < 10:
        axes[k] = axes[k] + 1 if axes[k] < 65535 else 0
    elif k == 10:
        group1 ^= 1 << 31
    else:
        group2 ^= 1
    return axes, group1, group2


@settings(max_examples=300)
@given(
    C2_CONTENTS,
    st.lists(st.integers(0, 11), max_size=3),
    st.lists(C2_FRAMES, max_size=30),
)
def test_c2_data_frames_kept_bodies_encode_as_encode_data(
    base: tuple[list[int], int, int], changes: list[int], frames: list[tuple[int, int, int, int]]
) -> None:
    """A body kept while a node's content stays the same (one field apart is another
    content): every frame, and every error, as `encode_data` makes it (docs/ICD.md, "Data
    frame")."""
    contents = [base, *(one_field_changed(base, k) for k in changes)]
    for line_feed in (True, False):
        kept = c2_16b.DataFrames(line_feed)
        for status, node_id, code, which in frames:
            axes, group1, group2 = contents[which % len(contents)]
            want = outcome(
                c2_16b.encode_data, status, node_id, code, axes, group1, group2, line_feed=line_feed
            )
            assert outcome(kept.encode, status, node_id, code, axes, group1, group2) == want
