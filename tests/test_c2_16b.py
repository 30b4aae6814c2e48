"""C2-16B codec: the shared vectors both ways, round trips, encoder errors, streaming decoder."""

from __future__ import annotations

import itertools
import json
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st
from wrong_type import refused, rejected

from usb2rc import __version__, compiled_path
from usb2rc.protocols.c2_16b import codec as c2_16b
from usb2rc.protocols.c2_16b.codec import (
    FAILSAFE,
    FRAME_LEN,
    LIVE,
    DataFrame,
    Decoder,
    Service,
    ServiceFrame,
    encode,
    encode_data,
    encode_service,
)

VECTORS = Path(__file__).parent / "data" / "vectors"
DATA_VECTORS: list[dict[str, Any]] = json.loads((VECTORS / "c2-16b-data.json").read_text())
SERVICE_VECTORS: list[dict[str, Any]] = json.loads((VECTORS / "c2-16b-service.json").read_text())
ZERO_AXES = [0] * 10


def decode_all(data: bytes, chunk_size: int | None = None) -> tuple[list[c2_16b.Frame], Decoder]:
    decoder = Decoder()
    size = chunk_size or max(len(data), 1)
    frames = [f for i in range(0, len(data), size) for f in decoder.feed(data[i : i + size])]
    return frames, decoder


def live(node_id: int = 1, code: int = 0, **fields: Any) -> bytes:
    values: dict[str, Any] = {"axes": ZERO_AXES, "group1": 0, "group2": 0, **fields}
    return encode_data(LIVE, node_id, code, values.pop("axes"), **values)


# --- shared vectors ------------------------------------------------------------------------


def vector_data_frame(vector: dict[str, Any]) -> DataFrame:
    return DataFrame(
        vector["status"],
        vector["node_id"],
        vector["message_code"],
        tuple(vector["axes"]),
        vector["group1"],
        vector["group2"],
    )


def vector_service_frame(vector: dict[str, Any]) -> ServiceFrame:
    binary = vector["status"] < 0x30
    service = Service(vector["status"] if binary else vector["status"] - 0x30)
    return ServiceFrame(service, vector["node_id"], bytes.fromhex(vector["payload_hex"]), binary)


@pytest.mark.parametrize("vector", DATA_VECTORS, ids=lambda v: v["name"])
def test_data_vector_encodes(vector: dict[str, Any]) -> None:
    wire = encode_data(
        vector["status"],
        vector["node_id"],
        vector["message_code"],
        vector["axes"],
        vector["group1"],
        vector["group2"],
    )
    assert wire.hex() == vector["hex"]


@pytest.mark.parametrize("vector", DATA_VECTORS, ids=lambda v: v["name"])
def test_data_vector_decodes(vector: dict[str, Any]) -> None:
    frames, decoder = decode_all(bytes.fromhex(vector["hex"]))
    assert frames == [vector_data_frame(vector)]
    assert (decoder.bytes_skipped, decoder.crc_failures) == (0, 0)


@pytest.mark.parametrize("vector", SERVICE_VECTORS, ids=lambda v: v["name"])
def test_service_vector_encodes(vector: dict[str, Any]) -> None:
    assert encode(vector_service_frame(vector)).hex() == vector["hex"]


@pytest.mark.parametrize("vector", SERVICE_VECTORS, ids=lambda v: v["name"])
def test_service_vector_decodes(vector: dict[str, Any]) -> None:
    frames, decoder = decode_all(bytes.fromhex(vector["hex"]))
    assert frames == [vector_service_frame(vector)]
    assert frames[0].payload == bytes.fromhex(vector["payload_hex"]).ljust(28, b"\0")
    assert (decoder.bytes_skipped, decoder.crc_failures) == (0, 0)


def service_vector_hex(name: str) -> str:
    return next(v["hex"] for v in SERVICE_VECTORS if v["name"] == name)


def test_service_helpers_reproduce_the_vectors() -> None:
    assert c2_16b.startup("0.1.0").hex() == service_vector_hex("startup")
    assert c2_16b.connected(2).hex() == service_vector_hex("connected")
    assert c2_16b.disconnected(2).hex() == service_vector_hex("disconnected")
    assert c2_16b.vid_pid(2, 0x044F, 0xB10A).hex() == service_vector_hex("vid-pid")
    assert c2_16b.device_string(2, "T.16000M").hex() == service_vector_hex("device-string")
    assert c2_16b.device_type(2, "JOYSTICK").hex() == service_vector_hex("device-type")
    binary = c2_16b.connected(2, binary_status=True)
    assert binary.hex() == service_vector_hex("connected-binary")


def test_line_feed_false_sends_the_bare_35_bytes() -> None:
    with_lf = live()
    without_lf = live(line_feed=False)
    assert len(with_lf) == FRAME_LEN + 1 and with_lf[-1] == 0x0A
    assert without_lf == with_lf[:FRAME_LEN]
    assert c2_16b.connected(3, line_feed=False) == c2_16b.connected(3)[:FRAME_LEN]


# --- service frame fields ------------------------------------------------------------------


def decode_one(wire: bytes) -> c2_16b.Frame:
    frames, _ = decode_all(wire)
    assert len(frames) == 1
    return frames[0]


def test_service_frame_properties() -> None:
    ids = decode_one(c2_16b.vid_pid(2, 0x044F, 0xB10A))
    assert (ids.vid, ids.pid, ids.text, ids.error_code) == (0x044F, 0xB10A, None, None)
    name = decode_one(c2_16b.device_string(2, "T.16000M"))
    assert (name.text, name.vid) == ("T.16000M", None)
    assert decode_one(c2_16b.device_type(2, "GAMEPAD")).text == "GAMEPAD"
    assert decode_one(c2_16b.startup("0.1.0")).text == "usb2rc 0.1.0"
    error = decode_one(c2_16b.device_error(4, 0x02))
    assert (error.service, error.node_id, error.error_code) == (Service.ERROR, 4, 2)
    poll = decode_one(c2_16b.poll_request(7))
    assert (poll.service, poll.node_id, poll.payload) == (Service.POLL, 7, bytes(28))


def test_service_names() -> None:
    names = [service.service_name for service in Service]
    assert names == [
        "connected",
        "disconnected",
        "error",
        "poll",
        "device-string",
        "vid-pid",
        "device-type",
        "startup",
    ]


def test_startup_frame_layout() -> None:
    wire = c2_16b.startup(__version__)
    assert wire[2:5] == b"8\xff\x00"
    assert wire[5:17] == f"usb2rc {__version__}".encode().ljust(12, b"\0")
    assert wire[17:33] == bytes(16)


def test_device_text_is_ascii_at_most_12_bytes_nul_padded() -> None:
    wire = c2_16b.device_string(1, "Thrustmaster T.16000M")
    assert wire[5:33] == b"Thrustmaster" + bytes(16)
    wire = c2_16b.device_string(1, "Joystick Ä\x07\n")
    assert wire[5:33] == b"Joystick ???" + bytes(16)
    assert c2_16b.ascii_field("€uro") == b"?uro"


def test_decoded_text_replaces_unprintable_bytes() -> None:
    frame = ServiceFrame(Service.DEVICE_STRING, 1, b"AB\xc3\x84\x07C\0junk")
    assert frame.text == "AB???C"


def test_service_frame_normalises_payload_and_service() -> None:
    frame = ServiceFrame(Service.VID_PID, 1, b"\x01\x02")
    assert frame.payload == b"\x01\x02" + bytes(26)
    assert frame == ServiceFrame(Service.VID_PID, 1, b"\x01\x02" + bytes(26))
    # An int service and a bytearray payload are wrong types (the fields are annotated
    # Service and bytes): the compiled class refuses them at the call; the interpreted one
    # still makes them a Service and bytes.
    try:
        frame = ServiceFrame(6, 1, bytearray(b"\x01\x02"))  # type: ignore[arg-type]
    except TypeError:
        assert compiled_path.compiled_active()
    else:
        assert frame.service is Service.VID_PID
        assert frame.payload == b"\x01\x02" + bytes(26)
        assert frame == ServiceFrame(Service.VID_PID, 1, b"\x01\x02" + bytes(26))


def test_service_frame_rejects_bad_fields() -> None:
    with pytest.raises(ValueError, match="28"):
        ServiceFrame(Service.POLL, 1, bytes(29))
    with refused("service"):  # an int is not a Service (tests/wrong_type.py)
        ServiceFrame(9, 1)  # type: ignore[arg-type]


# --- round trips ---------------------------------------------------------------------------

node_ids = st.integers(0, 255)
int16 = st.integers(-32768, 32767)
uint32 = st.integers(0, 0xFFFFFFFF)
data_frames = st.builds(
    DataFrame,
    status=st.sampled_from(sorted(c2_16b.DATA_STATUSES)),
    node_id=node_ids,
    code=st.integers(0, 255),
    axes=st.tuples(*[int16] * 10),
    group1=uint32,
    group2=uint32,
)
service_frames = st.builds(
    ServiceFrame,
    service=st.sampled_from(list(Service)),
    node_id=node_ids,
    payload=st.binary(max_size=28),
    binary_status=st.booleans(),
)
frames_strategy = st.one_of(data_frames, service_frames)


@given(frames_strategy, st.booleans())
def test_round_trip(frame: c2_16b.Frame, line_feed: bool) -> None:
    wire = encode(frame, line_feed=line_feed)
    assert len(wire) == FRAME_LEN + line_feed
    assert decode_one(wire) == frame


@given(st.lists(st.integers(0, 65535), min_size=10, max_size=10))
def test_uint16_axes_decode_as_their_int16_bit_pattern(axes: list[int]) -> None:
    frame = decode_one(encode_data(LIVE, 0, 0, axes, 0, 0))
    assert isinstance(frame, DataFrame)
    assert [value & 0xFFFF for value in frame.axes] == axes
    assert all(-32768 <= value <= 32767 for value in frame.axes)


# --- encoder errors ------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"status": 0x31}, "encode_service"),
        ({"status": ord("x")}, "status"),
        ({"status": ">"}, "status"),  # a wrong type (tests/wrong_type.py)
        ({"node_id": 256}, "node_id"),
        ({"node_id": -1}, "node_id"),
        ({"code": 256}, "code"),
        ({"axes": [0] * 9}, "10 axes"),
        ({"axes": [0] * 11}, "10 axes"),
        ({"axes": [0, 0, 65536, *[0] * 7]}, "axis z"),
        ({"axes": [-32769, *[0] * 9]}, "axis x"),
        ({"axes": [0.5, *[0] * 9]}, "axis x"),  # a wrong type
        ({"group1": -1}, "group1"),
        ({"group2": 1 << 32}, "group2"),
        ({"group2": True}, "group2"),  # an int to the type system: a bad value, not a type
    ],
)
def test_encode_data_rejects_bad_input(change: dict[str, Any], message: str) -> None:
    fields: dict[str, Any] = {
        "status": LIVE,
        "node_id": 1,
        "code": 0,
        "axes": ZERO_AXES,
        "group1": 0,
        "group2": 0,
        **change,
    }
    if compiled_path.compiled_active() and any(type(v) is bool for v in change.values()):
        # compiled, an `int` argument takes a bool as 0 or 1 (tests/wrong_type.py)
        as_ints = {key: int(value) for key, value in change.items()}
        assert encode_data(**fields) == encode_data(**{**fields, **as_ints})
        return
    with rejected(message, *change.values()):  # tests/wrong_type.py
        encode_data(**fields)


def test_service_encoders_reject_bad_input() -> None:
    with pytest.raises(ValueError, match="service"):
        encode_service(0, 1)
    with pytest.raises(ValueError, match="service"):
        encode_service(9, 1)
    with pytest.raises(ValueError, match="node_id"):
        c2_16b.connected(300)
    with pytest.raises(ValueError, match="28"):
        encode_service(Service.ERROR, 1, bytes(29))
    with refused("bytes"):  # a wrong type (tests/wrong_type.py)
        encode_service(Service.ERROR, 1, "text")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="error code"):
        c2_16b.device_error(1, 256)
    with pytest.raises(ValueError, match="vid"):
        c2_16b.vid_pid(1, 0x10000, 1)
    with pytest.raises(ValueError, match="pid"):
        c2_16b.vid_pid(1, 1, -1)
    with refused("str"):
        c2_16b.device_string(1, b"bytes")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="12 bytes"):
        c2_16b.startup("10.20.30")
    with refused("not a C2-16B frame"):
        encode("frame")  # type: ignore[arg-type]


# --- streaming decoder ---------------------------------------------------------------------


def sample_stream() -> bytes:
    return b"".join(
        [
            c2_16b.startup("0.1.0"),
            c2_16b.connected(2, binary_status=True),
            live(2, 0, axes=[1, -2, 3, -4, 5, -6, 7, -8, 9, -10], group1=0xFF000001),
            live(2, 1, line_feed=False),
            c2_16b.disconnected(2, line_feed=False),
            encode_data(FAILSAFE, 2, 2, ZERO_AXES, 0, 0),
        ]
    )


def test_any_chunking_gives_the_same_frames() -> None:
    stream = sample_stream()
    expected, _ = decode_all(stream)
    assert len(expected) == 6
    for size in (1, 2, 3, 7, 34, 35, 36, 37, 100):
        frames, decoder = decode_all(stream, size)
        assert frames == expected, size
        assert (decoder.frames, decoder.bytes_skipped, decoder.crc_failures) == (6, 0, 0)
        assert decoder.bytes_in == len(stream)


def test_line_feed_after_a_frame_is_consumed_even_across_chunks() -> None:
    decoder = Decoder()
    assert len(decoder.feed(live(line_feed=False))) == 1
    assert decoder.feed(b"") == []
    assert decoder.feed(b"\n") == []
    assert decoder.bytes_skipped == 0


def test_stray_line_feeds_are_skipped() -> None:
    frames, decoder = decode_all(b"\n" + live() + b"\n" + live(line_feed=False))
    assert len(frames) == 2
    assert decoder.bytes_skipped == 2


def test_frame_inside_a_corrupted_region_is_found() -> None:
    good = live(5, 9, group1=0x1234)
    truncated = good[:20]  # a header whose 35 bytes end inside the next frame
    frames, decoder = decode_all(b"xx" + truncated + good + b"yy")
    assert frames == [decode_one(good)]
    assert decoder.crc_failures == 1
    assert decoder.bytes_skipped == 2 + 20 + 2


def test_flipped_bit_is_a_crc_failure_and_the_next_frame_survives() -> None:
    good = live(1, 1)
    corrupted = bytearray(live(1, 0))
    corrupted[10] ^= 0x10
    frames, decoder = decode_all(bytes(corrupted) + good, 1)
    assert frames == [decode_one(good)]
    assert decoder.crc_failures == 1
    assert decoder.bytes_skipped == len(corrupted)


def test_unknown_status_is_skipped_without_a_crc_failure() -> None:
    bogus = b"H-X" + bytes(40)
    frames, decoder = decode_all(bogus + live())
    assert len(frames) == 1
    assert (decoder.crc_failures, decoder.bytes_skipped) == (0, len(bogus))


@pytest.mark.parametrize("binary", [False, True])
def test_a_service_frame_with_a_service_code_is_decoded_with_it(binary: bool) -> None:
    """The ICD calls byte 4 "Message Code or Service Code" and leaves the service codes
    TBD: a CRC-valid service frame is a frame whatever byte 4 holds (docs/ICD.md)."""
    wire = bytearray(c2_16b.poll_request(7, binary_status=binary, line_feed=False))
    wire[4] = 0x9C
    wire[33:35] = c2_16b.crc16_arc(bytes(wire[:33])).to_bytes(2, "little")
    frames, decoder = decode_all(bytes(wire))
    assert frames == [ServiceFrame(Service.POLL, 7, b"", binary, 0x9C)]
    assert (decoder.crc_failures, decoder.bytes_skipped) == (0, 0)
    assert encode(frames[0], line_feed=False) == bytes(wire)


def test_the_service_code_is_range_checked_when_encoding() -> None:
    with pytest.raises(ValueError, match="service code"):
        encode_service(Service.CONNECTED, 1, code=256)


def test_header_split_over_chunks() -> None:
    decoder = Decoder()
    wire = live()
    assert decoder.feed(b"zzH") == []
    assert decoder.feed(wire[1:]) == [decode_one(wire)]
    assert decoder.bytes_skipped == 2


def test_flush_counts_an_incomplete_frame_as_skipped() -> None:
    decoder = Decoder()
    assert decoder.feed(live()[:20]) == []
    assert decoder.flush() == []
    assert decoder.bytes_skipped == 20
    assert decoder.feed(live()) != []


def test_buffer_stays_bounded() -> None:
    decoder = Decoder()
    junk = (b"H->" + bytes(10)) * 50 + b"H"
    for _ in range(200):
        decoder.feed(junk)
        assert len(decoder._buffer) < FRAME_LEN
    assert decoder.crc_failures > 0


# --- properties ----------------------------------------------------------------------------

garbage_without_header_start = st.binary(max_size=60).map(lambda b: b.replace(b"H", b""))


@st.composite
def chunked(draw: st.DrawFn, data: bytes) -> list[bytes]:
    cuts = sorted(draw(st.lists(st.integers(0, len(data)), max_size=12)))
    edges = [0, *cuts, len(data)]
    return [data[a:b] for a, b in itertools.pairwise(edges)]


@given(
    st.lists(st.tuples(garbage_without_header_start, frames_strategy, st.booleans()), max_size=8),
    garbage_without_header_start,
    st.data(),
)
def test_finds_every_frame_embedded_in_garbage(
    items: list[tuple[bytes, c2_16b.Frame, bool]], tail: bytes, data: st.DataObject
) -> None:
    stream = b"".join(garbage + encode(f, line_feed=lf) for garbage, f, lf in items) + tail
    decoder = Decoder()
    found = [f for chunk in data.draw(chunked(stream)) for f in decoder.feed(chunk)]
    assert found == [frame for _, frame, _ in items]
    assert decoder.crc_failures == 0


@given(st.binary(max_size=400), st.data())
def test_never_raises_and_accounts_for_every_byte(noise: bytes, data: st.DataObject) -> None:
    decoder = Decoder()
    frames = [f for chunk in data.draw(chunked(noise)) for f in decoder.feed(chunk)]
    decoder.flush()
    assert decoder.frames == len(frames)
    assert decoder.bytes_in == len(noise)
    assert decoder.bytes_skipped <= len(noise) - FRAME_LEN * len(frames)
