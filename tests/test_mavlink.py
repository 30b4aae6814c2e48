"""The MAVLink output, sans-IO: scalings, channels, the session's heartbeat and failsafe
state machine, against pymavlink parsing the bytes as a receiver would; its config keys;
the UDP link on real sockets (docs/ICD.md, "MAVLink output"; docs/CONFIG.md, "MAVLink
outputs")."""

from __future__ import annotations

import hashlib
import logging
import socket
import time
from fractions import Fraction
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common

from usb2rc.config import mavlink as config_mavlink
from usb2rc.config.mavlink import MavlinkOptions
from usb2rc.config.model import ChannelRef
from usb2rc.configfile import ConfigError, load_config, load_config_text
from usb2rc.lines import udp_link as transport_udp
from usb2rc.lines.driver import DriverThread, LineDriver
from usb2rc.lines.link import LineEvent
from usb2rc.lines.serial_link import SerialLink
from usb2rc.lines.udp_link import UdpLink, parse_udp_url
from usb2rc.nodes.table import NodeFrame, NodeTable
from usb2rc.protocols.mavlink import session as mavlink
from usb2rc.protocols.mavlink.codec import axis_to_manual, axis_to_manual_z, axis_to_pwm
from usb2rc.protocols.mavlink.session import (
    HEARTBEAT_S,
    RELEASE_S,
    ControlValues,
    MavlinkChannels,
    MavlinkEngine,
    MavlinkSession,
    heartbeat_bytes,
    max_message_bytes,
)
from usb2rc.runtime.stats_text import output_line

INT16 = st.integers(-32768, 32767)


def parse(chunks: list[bytes]) -> list[Any]:
    """What a receiver makes of the bytes: pymavlink's parser, one message per chunk."""
    parser = common.MAVLink(None)
    out = []
    for chunk in chunks:
        messages = parser.parse_buffer(chunk) or []
        assert len(messages) == 1, "one message per write / datagram"
        out += messages
    return out


def open_session(**kw: Any) -> MavlinkEngine:
    session = MavlinkEngine(MavlinkOptions(**kw))
    session.line_opened()
    return session


def channels(message: Any) -> list[int]:
    return [getattr(message, f"chan{i}_raw") for i in range(1, 19)]


# --- scalings ------------------------------------------------------------------------------


def test_scaling_ends_and_centre() -> None:
    assert [axis_to_pwm(v) for v in (-32768, 0, 32767)] == [1000, 1500, 2000]
    assert [axis_to_manual(v) for v in (-32768, 0, 32767)] == [-1000, 0, 1000]
    assert [axis_to_manual_z(v) for v in (-32768, 0, 32767)] == [0, 500, 1000]
    assert axis_to_pwm(-99999) == 1000 and axis_to_pwm(99999) == 2000  # clamped, no raise


@given(INT16, INT16)
def test_scalings_are_monotonic_and_within_half_a_step(a: int, b: int) -> None:
    lo, hi = min(a, b), max(a, b)
    for scaling in (axis_to_pwm, axis_to_manual, axis_to_manual_z):
        assert scaling(lo) <= scaling(hi)
    exact = Fraction(a + 32768, 65535)
    assert abs(axis_to_pwm(a) - (1000 + exact * 1000)) <= Fraction(1, 2)
    assert abs(axis_to_manual_z(a) - exact * 1000) <= Fraction(1, 2)


# --- channels + session against pymavlink -----------------------------------------------

NODE = st.builds(
    NodeFrame,
    node_id=st.integers(0, 2),
    failsafe=st.booleans(),
    axes=st.tuples(*[st.integers(-32768, 65535)] * 10),  # int16 or uint16 slots
    group1=st.integers(0, 2**32 - 1),
    group2=st.integers(0, 2**32 - 1),
    unsigned_slots=st.integers(0, 1023),
    # the defaults given: a compiled NamedTuple's signature does not show them to hypothesis
    handover=st.none(),
    low_battery=st.just(False),
    switches=st.just(()),
    pressed=st.just((0, 0)),
    pressed_switches=st.just(()),
)
REF = st.one_of(
    st.builds(
        lambda n, s: ChannelRef(n, "axis", s, f"node{n}.{s}"), st.integers(0, 3), st.integers(0, 9)
    ),
    st.builds(
        lambda n, b: ChannelRef(n, "button", b, f"node{n}.button{b}"),
        st.integers(0, 3),
        st.integers(1, 56),
    ),
)


def node_value(ref: ChannelRef, nodes: dict[int, NodeFrame]) -> tuple[Any, bool]:
    """The test's own reading of a channel: int16 axis or pressed button, failsafe."""
    frame = nodes.get(ref.node_id)
    if frame is None:
        return (False if ref.kind == "button" else 0), True
    if ref.kind == "button":  # node buttons 1-24: group 1 bits 0-23; 25-56: group 2
        word, bit = (
            (frame.group1, ref.index - 1) if ref.index <= 24 else (frame.group2, ref.index - 25)
        )
        return bool(word >> bit & 1), frame.failsafe
    value = frame.axes[ref.index]
    if frame.unsigned_slots >> ref.index & 1:
        value -= 32768  # a uint16 slot
    return min(32767, max(-32768, value)), frame.failsafe  # out of range: clamped


@settings(max_examples=200)
@given(st.lists(NODE, max_size=3), st.lists(REF, min_size=1, max_size=18))
def test_override_values_as_pymavlink_decodes_them(
    frames: list[NodeFrame], refs: list[ChannelRef]
) -> None:
    nodes = {f.node_id: f for f in frames}
    values = MavlinkChannels(refs).evaluate(nodes.values())
    session = open_session(target_system=3, target_component=4)
    heartbeat, *rest = parse(session.tick(10.0, values))
    assert heartbeat.get_type() == "HEARTBEAT" and heartbeat.type == common.MAV_TYPE_GCS
    readings = [node_value(ref, nodes) for ref in refs]
    failsafe = any(fs for _, fs in readings)
    assert values.failsafe == failsafe
    (override,) = rest
    assert (override.target_system, override.target_component) == (3, 4)
    if failsafe:  # every channel back to the RC radio
        assert channels(override) == [0] * 8 + [65534] * 10
        return
    want = [
        (2000 if v else 1000) if ref.kind == "button" else 1000 + Fraction(v + 32768, 65535) * 1000
        for ref, (v, _) in zip(refs, readings, strict=True)
    ]
    got = channels(override)
    assert all(abs(g - w) <= Fraction(1, 2) for g, w in zip(got, want, strict=False))
    assert got[len(refs) :] == [65535] * (18 - len(refs))  # not configured: ignored


@settings(max_examples=200)
@given(
    st.lists(NODE, max_size=3),
    st.lists(REF, min_size=4, max_size=4),
    st.lists(st.integers(0, 3), max_size=32),
)
def test_manual_control_values_as_pymavlink_decodes_them(
    frames: list[NodeFrame], axes: list[ChannelRef], button_nodes: list[int]
) -> None:
    refs = axes + [ChannelRef(n, "button", i + 1, "b") for i, n in enumerate(button_nodes)]
    nodes = {f.node_id: f for f in frames}
    session = open_session(message="manual_control", target_system=9)
    messages = parse(session.tick(0.0, MavlinkChannels(refs, "manual_control").evaluate(frames)))
    readings = [node_value(ref, nodes) for ref in refs]
    if any(fs for _, fs in readings):
        assert [m.get_type() for m in messages] == ["HEARTBEAT"]  # silence: manual control lost
        return
    (control,) = messages[1:]
    assert control.target == 9
    for name, (v, _) in zip("xyzr", readings[:4], strict=True):
        if isinstance(v, bool):
            want = Fraction((1000 if v else 0) if name == "z" else (1000 if v else -1000))
        elif name == "z":
            want = Fraction(v + 32768, 65535) * 1000
        else:
            want = Fraction(v * 1000, 32768 if v < 0 else 32767)
        assert abs(getattr(control, name) - want) <= Fraction(1, 2)
    pressed = sum(int(v) << i for i, (v, _) in enumerate(readings[4:]))
    assert control.buttons | control.buttons2 << 16 == pressed


def test_heartbeat_once_a_second_and_no_burst_after_a_pause() -> None:
    session = open_session()
    live = ControlValues(False, channels=(1500,))
    kinds = []
    for i in range(151):  # 3 s at 50 Hz
        kinds.append([m.get_type() for m in parse(session.tick(i * 0.02, live))])
    beats = [i for i, k in enumerate(kinds) if "HEARTBEAT" in k]
    assert beats == [round(n * HEARTBEAT_S / 0.02) for n in range(4)]
    assert all(k[-1] == "RC_CHANNELS_OVERRIDE" for k in kinds)
    after_pause = [m.get_type() for m in parse(session.tick(60.0, live))]
    assert after_pause.count("HEARTBEAT") == 1
    assert "HEARTBEAT" not in [m.get_type() for m in parse(session.tick(60.5, live))]


def test_override_failsafe_releases_for_a_second_then_only_heartbeats_then_values() -> None:
    session = open_session()
    down, live = ControlValues(True, channels=(1500,)), ControlValues(False, channels=(1700,))
    t, seen = 0.0, []
    while t < 3.0:
        seen.append((t, parse(session.tick(t, down))))
        t += 0.02
    overrides = [(t, m) for t, ms in seen for m in ms if m.get_type() == "RC_CHANNELS_OVERRIDE"]
    assert overrides and all(channels(m) == [0] * 8 + [65534] * 10 for _, m in overrides)
    assert overrides[0][0] == 0.0 and overrides[-1][0] < RELEASE_S  # released at once, 1 s
    after = [m.get_type() for t, ms in seen if t >= RELEASE_S for m in ms]
    assert set(after) == {"HEARTBEAT"}  # then silence, but the heartbeat goes on
    (back,) = [m for m in parse(session.tick(3.0, live)) if m.get_type() == "RC_CHANNELS_OVERRIDE"]
    assert channels(back)[0] == 1700
    assert session.releases == len(overrides) and session.silent_ticks > 0


def test_sequence_numbers_count_every_message() -> None:
    session = open_session()
    messages = [
        m for i in range(300) for m in parse(session.tick(i * 0.02, ControlValues(False, (1500,))))
    ]
    assert [m.get_seq() for m in messages] == [i % 256 for i in range(len(messages))]


def test_a_short_write_stalls_until_drained_and_a_lost_line_sends_nothing() -> None:
    session = open_session()
    heartbeat, _control = session.tick(0.0, ControlValues(False, (1500,)))
    assert not session.wrote(len(heartbeat)).stalled
    assert session.wrote(3).stalled and session.line.stalled
    assert session.tick(0.02, ControlValues(False, (1500,))) == []
    session.line_drained()
    assert session.tick(0.04, ControlValues(False, (1500,)))
    session.line_lost()
    assert session.tick(0.06, ControlValues(False, (1500,))) == []


def test_the_far_end_is_parsed_and_garbage_is_counted() -> None:
    vehicle = common.MAVLink(None, srcSystem=1, srcComponent=1)
    beat = vehicle.heartbeat_encode(
        common.MAV_TYPE_QUADROTOR, common.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4
    )
    session = open_session()
    session.received(b"\x00garbage" + beat.pack(vehicle))
    assert session.far_end.heartbeats == 1 and session.far_end.last_heartbeat_from == (1, 1)
    assert session.far_end.decoder.bytes_skipped >= 1
    record = {"name": "mav", "url": "udpout:h:1", **mavlink.stats_record(session)}
    assert "far end: messages 1, heartbeats 1, (last from 1/1)" in output_line(record)


def test_the_bandwidth_check_counts_what_pymavlink_packs() -> None:
    for message in config_mavlink.MESSAGES:
        assert mavlink.max_message_bytes(message) == config_mavlink.MESSAGE_BYTES[message]
    assert mavlink.heartbeat_bytes() == config_mavlink.HEARTBEAT_BYTES


# --- config ----------------------------------------------------------------------------------


def errors(text: str) -> list[str]:
    with pytest.raises(ConfigError) as info:
        load_config_text(text, "m.yaml")
    return info.value.errors


def test_defaults() -> None:
    (out,) = load_config_text("outputs:\n  - protocol: mavlink\n    port: udpout:h:14550\n").outputs
    assert out.rate_hz == 50 and out.channels is None
    options = MavlinkOptions.of(out)
    assert options.message == "rc_channels_override"
    assert (options.system_id, options.component_id) == (255, 190)
    assert (options.target_system, options.target_component) == (1, 1)


@pytest.mark.parametrize(
    ("body", "want"),
    [
        (
            "message: manual_contrl",
            "m.yaml:4: outputs[0].message: 'manual_contrl' is not valid; "
            "did you mean 'manual_control'?",
        ),
        (
            "message: manual_control",
            "m.yaml:2: outputs[0].channels: missing: manual_control needs its channels",
        ),
        (
            "channels: [" + ", ".join(["node0.x"] * 19) + "]",
            "m.yaml:4: outputs[0].channels: 19 channels (allowed: 1..18)",
        ),
        (
            "message: manual_control\n    channels: [node0.x, node0.y, node0.z, node0.rz, node0.x]",
            "m.yaml:5: outputs[0].channels[4]: node0.x: "
            "manual_control channels after x, y, z, r are buttons",
        ),
        (
            "target_system: 256",
            "m.yaml:4: outputs[0].target_system: 256 is out of range (allowed: 0..255)",
        ),
        (
            "service_status: binary",
            "m.yaml:4: outputs[0].service_status: not an option of mavlink outputs",
        ),
        (
            "taget_system: 1",
            "m.yaml:4: outputs[0].taget_system: unknown key 'taget_system'; "
            "did you mean 'target_system'?",
        ),
    ],
)
def test_config_problems_name_file_line_and_key(body: str, want: str) -> None:
    text = f"outputs:\n  - protocol: mavlink\n    port: udpout:127.0.0.1:14550\n    {body}\n"
    assert any(e.startswith(want) for e in errors(text)), errors(text)


def test_a_bad_udp_address_names_the_port_line() -> None:
    (error,) = errors("outputs:\n  - protocol: mavlink\n    port: udpin:0.0.0.0:0\n")
    assert error.startswith(
        "m.yaml:3: outputs[0].port: 'udpin:0.0.0.0:0': expected udpin:HOST:PORT"
    )


def test_allow_is_for_udpin_and_takes_addresses_or_networks() -> None:
    (error,) = errors(
        "outputs:\n  - protocol: mavlink\n    port: udpout:127.0.0.1:14550\n"
        "    allow: [192.168.2.2]\n"
    )
    assert error.startswith("m.yaml:4: outputs[0].allow: only a udpin: port takes calls")
    (error,) = errors(
        "outputs:\n  - protocol: mavlink\n    port: udpin:127.0.0.1:14550\n"
        "    allow:\n      - 10.0.0.0/24\n      - vehicle\n"
    )
    assert error.startswith("m.yaml:6: outputs[0].allow[1]: 'vehicle' is not an address")
    text = (
        "outputs:\n  - protocol: mavlink\n    port: udpin:127.0.0.1:1\n    allow: [10.0.0.7/24]\n"
    )
    (out,) = load_config_text(text).outputs
    assert MavlinkOptions.of(out).allow == ("10.0.0.0/24",)


def test_a_signing_key_file_is_relative_to_the_config_and_signed_bytes_are_counted(
    tmp_path: Path,
) -> None:
    key = tmp_path / "keys" / "vehicle.key"
    key.parent.mkdir()
    key.write_text("  secret phrase \n")
    key.chmod(0o600)
    config = tmp_path / "m.yaml"
    text = (
        "outputs:\n  - protocol: mavlink\n    port: /dev/ttyUSB0\n    baudrate: {}\n"
        "    signing_key_file: keys/vehicle.key\n"
    )
    config.write_text(text.format(9600))
    with pytest.raises(ConfigError) as refused:  # (50 Hz x (50 + 13) + 21 + 13) x 10 bit
        load_config(str(config))
    assert "needs 31840 baud, more than the line's 9600; it carries at most 15 Hz" in str(
        refused.value
    )
    config.write_text(text.format(57600))
    (out,) = load_config(str(config)).outputs
    assert MavlinkOptions.of(out).signing_key_file == str(key)
    assert config_mavlink.read_signing_key(str(key)) == hashlib.sha256(b"secret phrase").digest()
    assert key.stat().st_mode & 0o777 == 0o600


def test_mavlink_keys_are_not_options_of_other_protocols() -> None:
    (error,) = errors(
        "outputs:\n  - protocol: sumd\n    port: /dev/null\n    message: manual_control\n"
    )
    assert "m.yaml:4: outputs[0].message: not an option of sumd outputs" in error


# --- UDP link ----------------------------------------------------------------------------------


def wait_until(condition: Any, timeout: float = 5.0) -> Any:
    deadline = time.monotonic() + timeout
    while not (result := condition()):
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.005)
    return result


def test_udpout_sends_each_write_as_one_datagram() -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as far:
        far.bind(("127.0.0.1", 0))
        link = UdpLink(f"udpout:127.0.0.1:{far.getsockname()[1]}")
        try:
            assert link.open_now() and link.line_event() is LineEvent.OPENED
            assert link.write(b"one").sent == 3 and link.write(b"two").sent == 3
            assert [far.recv(100), far.recv(100)] == [b"one", b"two"]
            far.sendto(b"reply", link._sock.getsockname())  # type: ignore[union-attr]
            assert link.line_event() is None  # told once; the tick's read is take_received
            received: list[bytes] = []

            def taken() -> list[bytes]:
                received.extend(d for d, _at in link.take_received())
                return received

            wait_until(taken)
            assert received == [b"reply"] and link.datagrams_received == 1
            assert link.take_received() == []
        finally:
            link.close()


def test_udpin_locks_to_the_first_caller_and_moves_only_after_its_silence() -> None:
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()
    clock = [100.0]
    link = UdpLink(
        f"udpin:127.0.0.1:{port}", lambda data: data.startswith(b"call"), clock=lambda: clock[0]
    )
    first = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    second = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    for sender in (first, second):
        sender.bind(("127.0.0.1", 0))
    try:
        assert not link.open_now() and link.line_event() is None  # nobody to talk to yet
        assert not link.is_open and "no vehicle has called yet" in link.last_error
        assert link.write(b"x").sent == 0
        first.sendto(b"noise", ("127.0.0.1", port))  # not a call: counted, still nobody
        wait_until(lambda: link.line_event() is None and link.datagrams_from_others == 1)
        first.sendto(b"call", ("127.0.0.1", port))
        assert wait_until(lambda: link.line_event()) is LineEvent.OPENED
        assert link.is_open and link.last_error == ""
        link.write(b"to-first")
        assert first.recv(100) == b"to-first"
        # once open, the tick's one read is take_received's (line_event reads no more)
        received: list[bytes] = []

        def taken() -> list[bytes]:
            received.extend(d for d, _at in link.take_received())
            return received

        second.sendto(b"call too", ("127.0.0.1", port))  # the peer talks: no redirect
        wait_until(lambda: taken() and link.datagrams_from_others == 2)
        assert link.line_event() is None
        assert link.peer == first.getsockname() and received == [b"call"]
        clock[0] += transport_udp.PEER_SILENT_S  # the first went silent: a new call is taken
        second.sendto(b"call again", ("127.0.0.1", port))
        wait_until(lambda: taken() and link.peer == second.getsockname())
        link.write(b"to-second")
        assert second.recv(100) == b"to-second"
        assert link.peer_locks == 2
    finally:
        link.close()
        first.close()
        second.close()


def test_udp_open_failures_retry_once_a_second_and_log_each_error_once(
    caplog: pytest.LogCaptureFixture,
) -> None:
    clock = [0.0]
    link = UdpLink("udpout:no-such-host.invalid:14550", clock=lambda: clock[0])
    with caplog.at_level(logging.DEBUG, logger="usb2rc.udp"):
        for _ in range(5):  # five ticks in the same second: one attempt
            assert not link.open_now()
        assert link._open_failures.attempts == 1
        for _ in range(59):
            clock[0] += transport_udp.REOPEN_INTERVAL_S
            link.open_now()
        errors = [r for r in caplog.records if r.levelno == logging.ERROR]
        assert len(errors) == 1 and "retrying every 1 s" in errors[0].getMessage()
        clock[0] += transport_udp.REOPEN_INTERVAL_S  # a minute later: one reminder
        link.open_now()
        errors = [r for r in caplog.records if r.levelno == logging.ERROR]
        assert len(errors) == 2 and "still failing (60 attempts" in errors[1].getMessage()


def test_udp_urls() -> None:
    assert parse_udp_url("udpout:127.0.0.1:14550").port == 14550
    assert parse_udp_url("udpin:[::1]:14550").host == "::1"
    for bad in ("udpout:14550", "udpin:host:", "udpout:host:70000", "tcp:h:1"):
        with pytest.raises(ValueError):
            parse_udp_url(bad)


def test_the_driver_writes_each_tick_whole_and_counts_one_period_per_tick() -> None:
    """A tick's messages go out in one write (one datagram on UDP: docs/ICD.md, "MAVLink
    output"), back to back; the far end parses them in order."""
    link = SerialLink("loop://", 115200)
    assert link.open_now()
    channels = MavlinkChannels([ChannelRef.axis(0, "x")])
    tick_bytes = heartbeat_bytes() + max_message_bytes("rc_channels_override")
    session = MavlinkSession("mav", channels, MavlinkEngine(MavlinkOptions()), tick_bytes, 50.0)
    out = LineDriver("mav", link, session, NodeTable().step_if_due, 0.02)
    try:
        out.tick()  # the line opens: a heartbeat, then (node 0 absent: failsafe) a release
        out.tick()
        assert out.stats.writes == 2 and len(out.stats.periods()) == 1
        received = bytearray()

        def three_messages() -> bool:
            received.extend(link.read())
            return len(parse_stream(bytes(received))) >= 3

        wait_until(three_messages)
        kinds = [(m.get_type(), channels_or_none(m)) for m in parse_stream(bytes(received))]
        released = [0] * 8 + [65534] * 10
        assert kinds == [
            ("HEARTBEAT", None),
            ("RC_CHANNELS_OVERRIDE", released),
            ("RC_CHANNELS_OVERRIDE", released),
        ]
    finally:
        link.close()


def parse_stream(data: bytes) -> list[Any]:
    return common.MAVLink(None).parse_buffer(data) or []


def channels_or_none(message: Any) -> list[int] | None:
    return channels(message) if message.get_type() == "RC_CHANNELS_OVERRIDE" else None


def test_the_registry_builds_a_serial_output_whose_far_end_is_read() -> None:
    """`mavlink` through the registry on a serial line: an RX thread hands what the far end
    sent to the session (loop:// echoes usb2rc's own heartbeats back, so it sees them)."""

    from usb2rc.lines.rx import LinkReader
    from usb2rc.nodes.mapping import compile_mapping
    from usb2rc.outputs import build
    from usb2rc.wiring import OutputContext

    config = load_config_text(
        "outputs:\n  - {protocol: mavlink, port: 'loop://', channels: [node0.x]}\n"
    )
    (out,) = config.outputs
    context = OutputContext("mav", out, compile_mapping(config), NodeTable())
    built = build(context)
    assert isinstance(built.driver, LineDriver) and isinstance(built.rx, LinkReader)
    assert built.link.open_now()
    thread = DriverThread("drivers", [built.driver])
    thread.start()
    built.rx.start()
    try:
        wait_until(lambda: built.driver.session.engine.far_end.heartbeats >= 1)
        assert built.driver.session.engine.far_end.last_heartbeat_from == (255, 190)
        stats = built.driver.protocol_stats()
        assert stats["far_end_heartbeats"] >= 1 and stats["releases"] >= 1  # node 0 absent
    finally:
        thread.stop()
        built.rx.stop()
        thread.join(5)
        built.rx.join(5)
        built.link.close()
