"""`usb2rc decode`: print the C2-16B, SUMD, CRSF, SBUS, iBus or MAVLink frames in a capture,
stdin, a port or (MAVLink) a UDP port. The decoder is the output registry's (`usb2rc.outputs`).

SOURCE is a file (read to its end), `-` for stdin, or a serial port: a character device
path or a pyserial URL (`socket://host:port`, `loop://`, ...), read until Ctrl-C; for
MAVLink also `udpin:HOST:PORT` (listen there, e.g. where usb2rc's `udpout:` sends). One line
per valid frame on stdout (`--json`: one JSON object per line); a summary on stderr at the end.
MAVLink is parsed by pymavlink: one line per message, its fields as pymavlink names them.
Exit 0 when it found a frame, 1 when none (it says so, and names the other protocol when
its frames are there), 2 for a port URL pyserial cannot parse.

Byte 4 is shown as it is: a data frame's message code (a `&` frame's destination ID, also
given as `destination`), a service frame's service code (`code`; usb2rc sends 0, another
implementation may not, docs/ICD.md "Service code").
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import shlex
import socket
import stat
import sys
from collections import Counter
from collections.abc import Callable, Generator, Iterable
from contextlib import closing
from typing import Any, BinaryIO, Protocol, TypeGuard, runtime_checkable

from usb2rc.config.udp_url import is_udp_url, parse_udp_url
from usb2rc.outputs import PROTOCOLS, protocol
from usb2rc.protocols.c2_16b.codec import (
    DATA_STATUS_NAMES,
    HANDOVER,
    DataFrame,
    ServiceFrame,
)
from usb2rc.protocols.crsf import codec as crsf
from usb2rc.protocols.sbus.codec import SbusFrame
from usb2rc.protocols.stream import StreamDecoder
from usb2rc.protocols.sumd.codec import SumdFrame


@runtime_checkable
class DescribedFrame(Protocol):
    """A frame that says how it prints (`protocols.ibus.codec.IbusFrame`): a protocol whose frames
    do needs no branch here, only its registry row."""

    def kind(self) -> str: ...

    def text(self) -> str: ...

    def record(self) -> dict[str, object]: ...


# Any: a pymavlink message (pymavlink is imported only for --protocol mavlink)
AnyFrame = DataFrame | ServiceFrame | SumdFrame | SbusFrame | crsf.CrsfFrame | Any
Formatter = Callable[[AnyFrame], str]
READ_SIZE = 65536
PORT_TIMEOUT_S = 0.5


def add_parser(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "decode",
        help="print the frames in a C2-16B / SUMD / CRSF / SBUS / MAVLink capture, stdin, "
        "port or UDP",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--protocol", choices=tuple(PROTOCOLS), default="c2-16b")
    parser.add_argument("--json", action="store_true", help="one JSON object per frame")
    parser.add_argument(
        "--baudrate",
        type=int,
        help="for ports (the protocol's default: 115200; crsf 400000; sbus 100000, 8E2)",
    )
    parser.add_argument("source", metavar="SOURCE", help="file, '-' (stdin), port or URL")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    entry = protocol(args.protocol)
    decoder = entry.decoder()
    # the other protocols' decoders, for the no-frame hint
    others = {name: PROTOCOLS[name].decoder() for name in PROTOCOLS if name != args.protocol}
    format_frame: Formatter = json_line if args.json else text_line
    baudrate = args.baudrate or entry.default_baudrate
    if problem := _port_url_problem(args.source):
        print(
            f"usb2rc decode: {args.source}: not a port pyserial can open: {problem}",
            file=sys.stderr,
        )
        return 2
    try:
        chunks = open_source(args.source, baudrate, even_parity=args.protocol == "sbus")
    except (OSError, ValueError) as exc:
        print(f"usb2rc decode: cannot open {args.source}: {_reason(exc)}", file=sys.stderr)
        return 1
    kinds: Counter[str] = Counter()
    status = 0
    try:
        with closing(chunks):
            for chunk in chunks:
                _print_frames(decoder.feed(chunk), format_frame, kinds)
                for other in others.values():
                    other.feed(chunk)
        _print_frames(decoder.flush(), format_frame, kinds)
        for other in others.values():
            other.flush()
    except KeyboardInterrupt:
        pass
    except BrokenPipeError:
        _silence_stdout()
    except OSError as exc:
        print(f"usb2rc decode: reading {args.source}: {_reason(exc)}", file=sys.stderr)
        status = 1
    print(summary(decoder, kinds), file=sys.stderr)
    if decoder.frames == 0:
        found = {name: other.frames for name, other in others.items()}
        print(no_frame_hint(args.protocol, args.source, found), file=sys.stderr)
        return status or 1
    return status


def no_frame_hint(protocol: str, source: str, found: dict[str, int]) -> str:
    """What to try when SOURCE held no frame of `protocol`: the protocol whose frames are
    there (the one with the most, when several decoders found some)."""
    line = f"usb2rc decode: no {_shown(protocol)} frame found in {source}"
    frames, best = max((count, name) for name, count in found.items())
    if frames == 0:
        return line + " (nor a frame of another protocol)"
    again = shlex.join(["usb2rc", "decode", "--protocol", best, source])
    return f"{line}, but {frames} {_shown(best)} frame(s): try `{again}`"


def _shown(protocol: str) -> str:
    return {"mavlink": "MAVLink"}.get(protocol, protocol.upper())


def _port_url_problem(source: str) -> str | None:
    if "://" not in source:
        return None
    from usb2rc.config.port_url import url_problem  # pyserial only when a port is named

    return url_problem(source)


# --- sources -------------------------------------------------------------------------------


def open_source(
    name: str, baudrate: int, *, even_parity: bool = False
) -> Generator[bytes, None, None]:
    """Open SOURCE now (so errors surface before reading) and return its chunks; a port
    with `even_parity` is opened 8E2 (SBUS)."""
    if name == "-":
        return _read_stream(sys.stdin.buffer, close=False)
    if is_udp_url(name):
        return _read_udp(name)
    if "://" in name or _is_character_device(name):
        return _read_port(_open_port(name, baudrate, even_parity))
    return _read_stream(open(name, "rb"), close=True)


def _is_character_device(path: str) -> bool:
    try:
        return stat.S_ISCHR(os.stat(path).st_mode)
    except OSError:
        return False


def _read_stream(stream: BinaryIO, close: bool) -> Generator[bytes, None, None]:
    try:
        while chunk := stream.read1(READ_SIZE):  # type: ignore[attr-defined]
            yield chunk
    finally:
        if close:
            stream.close()


def _open_port(name: str, baudrate: int, even_parity: bool = False) -> Any:
    import serial  # only ports need pyserial

    framing: dict[str, Any] = {}
    if even_parity:
        framing = {"parity": serial.PARITY_EVEN, "stopbits": serial.STOPBITS_TWO}
    port = serial.serial_for_url(name, baudrate=baudrate, timeout=PORT_TIMEOUT_S, **framing)
    print(f"usb2rc decode: reading {name} at {baudrate} baud, Ctrl-C to stop", file=sys.stderr)
    return port


def _read_port(port: Any) -> Generator[bytes, None, None]:
    try:
        while True:
            chunk = port.read(port.in_waiting or 1)
            if chunk:
                yield chunk
    finally:
        port.close()


def _read_udp(name: str) -> Generator[bytes, None, None]:
    """`udpin:HOST:PORT`: bind there now and yield each datagram (until Ctrl-C)."""
    address = parse_udp_url(name)
    if address.scheme != "udpin":
        raise ValueError(f"decode listens: give udpin:{address.host}:{address.port}")
    family = socket.AF_INET6 if ":" in address.host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_DGRAM)
    try:
        sock.bind((address.host, address.port))
    except OSError:
        sock.close()
        raise
    print(f"usb2rc decode: listening on {name}, Ctrl-C to stop", file=sys.stderr)

    def datagrams() -> Generator[bytes, None, None]:
        with sock:
            while True:
                yield sock.recv(65535)

    return datagrams()


def _reason(exc: BaseException) -> str:
    if isinstance(exc, FileNotFoundError):
        return "no such file or port"
    return getattr(exc, "strerror", None) or str(exc)


# --- output --------------------------------------------------------------------------------


def _print_frames(frames: list[Any], format_frame: Formatter, kinds: Counter[str]) -> None:
    if not frames:
        return
    kinds.update(frame_kind(frame) for frame in frames)
    sys.stdout.write("".join(f"{format_frame(frame)}\n" for frame in frames))
    sys.stdout.flush()


def _silence_stdout() -> None:
    """The reader went away (`| head`): drop what is still buffered for stdout."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    os.close(devnull)


def frame_kind(frame: AnyFrame) -> str:
    """`live`, `failsafe`, ... for data and SUMD frames; the service name for service frames."""
    if isinstance(frame, DescribedFrame):
        return frame.kind()
    if isinstance(frame, ServiceFrame):
        return frame.service.service_name
    if isinstance(frame, SumdFrame):
        return "failsafe" if frame.failsafe else "live"
    if isinstance(frame, SbusFrame):
        return "failsafe" if frame.failsafe else "frame-lost" if frame.frame_lost else "live"
    if isinstance(frame, DataFrame):
        return DATA_STATUS_NAMES[frame.status]
    if _is_mavlink(frame):
        return str(frame.get_type()).lower()
    return _CRSF_KINDS.get(type(frame), "other")


def _is_mavlink(frame: AnyFrame) -> TypeGuard[Any]:
    """A pymavlink message (told by its module: pymavlink is imported for mavlink only)."""
    return type(frame).__module__.startswith("pymavlink.")


_CRSF_KINDS: dict[type, str] = {
    crsf.RcChannels: "rc-channels",
    crsf.LinkStatistics: "link-statistics",
    crsf.TimingSync: "timing-correction",
}


def json_record(frame: AnyFrame) -> dict[str, Any]:
    if isinstance(frame, DescribedFrame):
        return frame.record()
    if isinstance(frame, DataFrame):
        return _data_record(frame)
    if isinstance(frame, ServiceFrame):
        return _service_record(frame)
    if isinstance(frame, SumdFrame):
        return {"protocol": "sumd", "failsafe": frame.failsafe, "channels": list(frame.channels)}
    if _is_mavlink(frame):
        return {"protocol": "mavlink", **_mavlink_header(frame), **_mavlink_fields(frame)}
    return _rc11_record(frame)


def _mavlink_header(message: Any) -> dict[str, Any]:
    return {
        "message": message.get_type(),  # not "type": HEARTBEAT has a field of that name
        "system": message.get_srcSystem(),
        "component": message.get_srcComponent(),
        "seq": message.get_seq(),
    }


def _mavlink_fields(message: Any) -> dict[str, Any]:
    from usb2rc.protocols.mavlink.codec import message_fields

    return message_fields(message)


def _rc11_record(frame: SbusFrame | crsf.CrsfFrame) -> dict[str, Any]:
    if isinstance(frame, SbusFrame):
        return {"protocol": "sbus", **dataclasses.asdict(frame), "channels": list(frame.channels)}
    record: dict[str, Any] = {"protocol": "crsf", "frame": frame_kind(frame)}
    if isinstance(frame, crsf.OtherFrame):
        return {
            **record,
            "address": frame.address,
            "type": frame.type,
            "payload_hex": frame.payload.hex(),
        }
    values = dataclasses.asdict(frame)
    if isinstance(frame, crsf.RcChannels):
        values["channels"] = list(frame.channels)
    return {**record, **values}


def _data_record(frame: DataFrame) -> dict[str, Any]:
    record: dict[str, Any] = {
        "protocol": "c2-16b",
        "status": chr(frame.status),
        "node_id": frame.node_id,
        "code": frame.code,
        "axes": list(frame.axes),
        "group1": frame.group1,
        "group2": frame.group2,
    }
    if frame.status == HANDOVER:
        record["destination"] = frame.code  # byte 4 of a `&` is the destination ID
    return record


def _service_record(frame: ServiceFrame) -> dict[str, Any]:
    record: dict[str, Any] = {
        "protocol": "c2-16b",
        "status": str(frame.service.value),
        "status_encoding": "binary" if frame.binary_status else "ascii",
        "node_id": frame.node_id,
        "code": frame.code,
        "service": frame.service.service_name,
        "payload_hex": frame.payload.rstrip(b"\0").hex(),
    }
    for field in ("vid", "pid", "text", "error_code"):
        value = getattr(frame, field)
        if value is not None:
            record[field] = value
    return record


def json_line(frame: AnyFrame) -> str:
    return json.dumps(json_record(frame), separators=(",", ":"))


def text_line(frame: AnyFrame) -> str:
    if isinstance(frame, DescribedFrame):
        return frame.text()
    if isinstance(frame, DataFrame):
        byte4 = f"to {frame.code}" if frame.status == HANDOVER else f"code {frame.code}"
        return (
            f"{chr(frame.status)} node {frame.node_id} {byte4} axes {list(frame.axes)}"
            f" g1 0x{frame.group1:08X} g2 0x{frame.group2:08X}"
        )
    if isinstance(frame, ServiceFrame):
        return _service_text(frame)
    if isinstance(frame, SumdFrame):
        state = "failsafe" if frame.failsafe else "live"
        return f"sumd {state} {len(frame.channels)}ch {list(frame.channels)}"
    if _is_mavlink(frame):
        head = _mavlink_header(frame)
        fields = " ".join(f"{k}={v}" for k, v in _mavlink_fields(frame).items())
        return (
            f"mavlink {head['message']} from {head['system']}/{head['component']} "
            f"seq {head['seq']}: {fields}"
        )
    if isinstance(frame, SbusFrame):
        flags = [n for n in ("ch17", "ch18", "frame_lost", "failsafe") if getattr(frame, n)]
        return f"sbus {frame_kind(frame)} {list(frame.channels)} flags {' '.join(flags) or '-'}"
    return _crsf_text(frame)


def _crsf_text(frame: crsf.CrsfFrame) -> str:
    if isinstance(frame, crsf.RcChannels):
        return f"crsf rc-channels to 0x{frame.address:02X} {list(frame.channels)}"
    if isinstance(frame, crsf.LinkStatistics):
        return (
            f"crsf link-statistics LQ {frame.uplink_link_quality}% up "
            f"{frame.downlink_link_quality}% down, RSSI -{frame.uplink_rssi_1}/"
            f"-{frame.uplink_rssi_2} dBm, SNR {frame.uplink_snr} dB, RF mode {frame.rf_mode}, "
            f"tx power {frame.uplink_tx_power}"
        )
    if isinstance(frame, crsf.TimingSync):
        return (
            f"crsf timing-correction interval {frame.rate / 10:.1f} us "
            f"({1 / frame.interval_s:.0f} Hz) offset {frame.offset / 10:+.1f} us"
        )
    return f"crsf type 0x{frame.type:02X} to 0x{frame.address:02X} payload {frame.payload.hex()}"


def _service_text(frame: ServiceFrame) -> str:
    line = f"service {frame.service.service_name} node {frame.node_id}"
    if frame.code:
        line += f" code {frame.code}"
    payload = frame.payload.rstrip(b"\0")
    if frame.vid is not None:
        line += f" vid 0x{frame.vid:04X} pid 0x{frame.pid:04X}"
    elif frame.text is not None:
        line += f" {json.dumps(frame.text)}"
    elif frame.error_code is not None:
        line += f" error 0x{frame.error_code:02X}"
    elif payload:
        line += f" payload {payload.hex()}"
    return line + (" (binary status)" if frame.binary_status else "")


def summary(decoder: StreamDecoder[Any] | Any, kinds: Counter[str]) -> str:
    by_kind = ", ".join(f"{kind} {count}" for kind, count in _ordered(kinds.items()))
    return (
        f"summary: frames {decoder.frames} ({by_kind or 'none'}), "
        f"bytes skipped {decoder.bytes_skipped}, CRC failures {decoder.crc_failures}, "
        f"bytes read {decoder.bytes_in}"
    )


def _ordered(items: Iterable[tuple[str, int]]) -> list[tuple[str, int]]:
    return sorted(items, key=lambda item: (-item[1], item[0]))
