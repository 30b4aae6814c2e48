"""What usb2rc makes of byte 4 on the receive side (docs/ICD.md, "UART receive"): the
receiver model of `demo` and the requests the RX thread hands to a C2-16B session."""

from __future__ import annotations

import pytest

from usb2rc.hid.backend import DeviceInfo
from usb2rc.nodes.table import EventKind, NodeFrame, ServiceEvent
from usb2rc.protocols.c2_16b import codec as c2_16b
from usb2rc.protocols.c2_16b.engine import C2Engine, C2Settings
from usb2rc.protocols.c2_16b.receiver import ReceiverModel
from usb2rc.protocols.c2_16b.session import is_request

AXES = (0,) * 10


def with_code(wire: bytes, code: int) -> bytes:
    """A frame usb2rc would send, with byte 4 set to `code` and its CRC made good again."""
    frame = bytearray(wire[: c2_16b.FRAME_LEN])
    frame[4] = code
    frame[33:35] = c2_16b.crc16_arc(bytes(frame[:33])).to_bytes(2, "little")
    return bytes(frame)


def test_handover_frames_carry_no_code_and_make_no_gap():
    model = ReceiverModel()
    data = lambda status, code: c2_16b.encode_data(status, 1, code, AXES, 0, 0)  # noqa: E731
    model.feed(data(c2_16b.LIVE, 10) + data(c2_16b.HANDOVER, 200) + data(c2_16b.LIVE, 11))
    node = model.nodes[1]
    assert (node.code, node.code_gaps, node.handover_to, node.frames) == (11, 0, 200, 3)
    model.feed(data(c2_16b.LIVE, 13))
    assert model.nodes[1].code_gaps == 1


def test_a_service_code_is_shown_with_the_event():
    model = ReceiverModel()
    model.feed(with_code(c2_16b.device_type(2, "GAMEPAD"), 0x21))
    assert model.events_since(0) == ["node 2: device-type GAMEPAD (service code 33)"]


@pytest.mark.parametrize("code", [0, 1, 0xFF])
@pytest.mark.parametrize("binary", [False, True])
def test_a_poll_is_a_poll_whatever_its_service_code(code, binary):
    """The RX thread hands it over and the session answers it like any `4`."""
    wire = with_code(c2_16b.poll_request(3, binary_status=binary), code)
    (frame,) = c2_16b.Decoder().feed(wire)
    assert is_request(frame)
    session = C2Engine(C2Settings(version="0.1.0"))
    session.line_opened()
    info = DeviceInfo(key="k", path="k", vid=1, pid=2, product="Pad")
    session.tick([ServiceEvent(EventKind.CONNECTED, 3, info, "GAMEPAD")], [])
    session.wrote(10**6)
    session.tick([], [NodeFrame(3, False, AXES, 0, 0)])
    session.wrote(10**6)
    assert session.received(frame)
    out = c2_16b.Decoder().feed(session.tick([], [NodeFrame(3, False, AXES, 0, 0)]))
    names = [f.service.service_name for f in out if isinstance(f, c2_16b.ServiceFrame)]
    assert names == ["connected", "vid-pid", "device-string", "device-type"]
