"""The C2-16B downlink (docs/ICD.md "Downlink"): `>` frames from the far end, built with the
project's own encoder, reach `C2Session.telemetry` as the newest `Downlink` per Node-ID, and
a flood of them changes nothing that goes up: neither the next ticks' bytes nor how the far
end's requests are answered."""

from __future__ import annotations

from usb2rc.feedback.model import Downlink
from usb2rc.hid.backend import DeviceInfo
from usb2rc.nodes.step import NodeView
from usb2rc.nodes.table import EventKind, EventLog, NodeFrame, NodeSnapshot, ServiceEvent
from usb2rc.protocols.c2_16b import codec as c2_16b
from usb2rc.protocols.c2_16b.engine import C2Settings
from usb2rc.protocols.c2_16b.session import REQUESTS_PER_TICK, C2Session

AXES = (-32768, 32767, -1, 0, 1, 12345, -12345, 256, -256, 7)


def downlink_frame(node_id: int, code: int = 0, g1: int = 0, g2: int = 0) -> bytes:
    """A `>` frame from the far end, by the project's own encoder."""
    return c2_16b.encode_data(c2_16b.LIVE, node_id, code, AXES, g1, g2)


def open_session() -> C2Session:
    session = C2Session("c2", C2Settings(version="0.1.0"))
    session.line_opened()
    return session


def test_a_downlink_frame_reaches_telemetry_with_its_bits_and_axes() -> None:
    session = open_session()
    assert session.telemetry is None  # nothing heard yet
    group1, group2 = 0x8000_0001, 0x8000_0003
    session.received(downlink_frame(7, 42, group1, group2), now=12.5)
    indicators = 1 | 1 << 31 | 1 << 32 | 1 << 33 | 1 << 63
    assert session.telemetry == (Downlink(7, indicators, AXES, 12.5),)
    assert session.stats(12.5)["rx_downlink_frames"] == 1


def test_only_the_newest_per_node_is_kept_sorted_by_node_id_whatever_the_chunks() -> None:
    session = open_session()
    stream = b"".join(
        [
            downlink_frame(9, g1=1),
            downlink_frame(3, g1=2),
            downlink_frame(9, g1=3),
            downlink_frame(200, g2=4),
        ]
    )
    for at, byte in enumerate(stream):  # one byte a read: frames complete across reads
        session.received(bytes([byte]), now=float(at))
    telemetry = session.telemetry
    assert telemetry is not None
    assert [(d.node_id, d.indicators) for d in telemetry] == [(3, 2), (9, 3), (200, 4 << 32)]
    third_frame_ends = 2 * (c2_16b.FRAME_LEN + 1) + c2_16b.FRAME_LEN - 1  # its CRC, not its LF
    assert telemetry[1].at == third_frame_ends  # node 9's newest came with that read
    session.received(downlink_frame(3, g1=5), now=1000.0)
    telemetry = session.telemetry
    assert telemetry is not None
    assert telemetry[0] == Downlink(3, 5, AXES, 1000.0)
    assert telemetry[1].at < 1000.0  # node 9's did not come again: its time says so
    assert session.stats(0.0)["rx_downlink_frames"] == 5


def test_other_statuses_and_bad_frames_from_the_far_end_are_not_downlinks() -> None:
    session = open_session()
    others = [
        c2_16b.encode_data(status, 4, 0, AXES, 1, 1)
        for status in (c2_16b.FAILSAFE, c2_16b.HANDOVER, c2_16b.LOW_BATTERY)
    ]
    corrupted = bytearray(downlink_frame(4, g1=1))
    corrupted[20] ^= 0xFF  # the CRC no longer matches
    session.received(b"".join(others) + bytes(corrupted), now=1.0)
    assert session.telemetry is None
    stats = session.stats(1.0)
    assert stats["rx_downlink_frames"] == 0 and stats["rx_crc_failures"] == 1


# --- a flood costs the uplink nothing --------------------------------------------------------


def snapshot(log: EventLog, tick: int) -> NodeSnapshot:
    """Nodes 0 and 1 live, their X axis moving with the tick."""
    views = tuple(
        NodeView(NodeFrame(node, False, (tick * 100 + node,) + (0,) * 9, tick, 0))
        for node in (0, 1)
    )
    return NodeSnapshot(period=tick, at=0.0, nodes=views, log=log)


def device_log() -> EventLog:
    log = EventLog()
    present: tuple[ServiceEvent, ...] = ()
    for node in (0, 1):
        info = DeviceInfo(key=f"d{node}", path="p", vid=0x044F, pid=0xB10A, product="T")
        event = ServiceEvent(EventKind.CONNECTED, node, info, "JOYSTICK")
        present = (*present, event)
        log = log.appended(event, present)
    return log


def requests() -> bytes:
    """More requests than a tick takes: a `<`, then polls for every Node-ID, twice."""
    polls = [c2_16b.poll_request(node) for node in range(256)] * 2
    asked = c2_16b.encode_data(c2_16b.CONFIG_REQUEST, 0, 0, (0,) * 10, 0, 0)
    return asked + b"".join(polls)


def test_a_flood_of_downlinks_changes_neither_the_ticks_nor_the_answers_to_requests() -> None:
    quiet, flooded = open_session(), open_session()
    log = device_log()
    sent: dict[str, list[bytes]] = {"quiet": [], "flooded": []}

    def tick(number: int) -> None:
        for name, session in (("quiet", quiet), ("flooded", flooded)):
            out = session.tick(float(number), snapshot(log, number))
            session.wrote(len(out))
            sent[name].append(out)

    for number in range(5):
        tick(number)
    # between two ticks: 2,000 downlinks, for the live nodes and others, with the requests
    # in the middle of them
    flood = [downlink_frame(n % 5, n % 256, g1=n) for n in range(2000)]
    stream = b"".join(flood[:1000]) + requests() + b"".join(flood[1000:])
    for start in range(0, len(stream), 4096):  # as a UART's reads would come
        flooded.received(stream[start : start + 4096], now=5.0)
    quiet.received(requests(), now=5.0)
    for number in range(5, 200):
        tick(number)
    assert sent["flooded"] == sent["quiet"]  # byte for byte, every tick
    quiet_stats, flooded_stats = quiet.stats(9.0), flooded.stats(9.0)
    for key in ("rx_requests", "rx_requests_dropped", "data_frames", "service_frames"):
        assert flooded_stats[key] == quiet_stats[key], key
    assert quiet_stats["rx_requests_dropped"] == 1 + 512 - REQUESTS_PER_TICK  # the limit held
    assert flooded_stats["rx_downlink_frames"] == 2000
    telemetry = flooded.telemetry
    assert telemetry is not None
    assert [d.node_id for d in telemetry] == [0, 1, 2, 3, 4]  # one each, the newest
    assert [d.indicators for d in telemetry] == [1995, 1996, 1997, 1998, 1999]


def test_its_own_frames_come_back_as_an_echo_not_a_downlink() -> None:
    """A loopback: every byte the line sent comes back. No downlink, each `>` an echo; a far
    end's own `>` frame among them is still a downlink."""
    session = open_session()
    log = device_log()
    sent = b""
    for tick in range(1, 40):
        out = session.tick(float(tick), snapshot(log, tick))
        session.wrote(len(out))
        sent += out
    own = [f for f in c2_16b.Decoder().feed(sent) if isinstance(f, c2_16b.DataFrame)]
    live = [f for f in own if f.status == c2_16b.LIVE]
    assert live
    session.received(sent, now=1.0)
    assert session.telemetry is None
    assert session.stats(1.0)["rx_echo_frames"] == len(live)
    session.received(downlink_frame(0, code=3, g1=0b101), now=2.0)
    assert session.telemetry == (Downlink(0, 0b101, AXES, 2.0),)
