"""`usb2rc decode` end to end, against streams built by an encoder written here.

The acceptance streams are built with struct and bitwise CRCs in this file, not with
usb2rc.protocols, so a bug shared by encoder and decoder cannot hide.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import random
import re
import select
import signal
import struct
import subprocess
import sys
import time
import tty
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest

from usb2rc.commands import decode

REPO = Path(__file__).resolve().parent.parent
SAMPLES = REPO / "usb2rc" / "data" / "samples"
GUARD_TIMEOUT_S = 20.0  # only a bound for a hung subprocess; never waited for on success


# --- an independent encoder ----------------------------------------------------------------


def crc16_arc_bitwise(data: bytes) -> int:
    crc = 0
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc


def crc16_xmodem_bitwise(data: bytes) -> int:
    crc = 0
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc


SERVICE_NAMES = {
    1: "connected",
    2: "disconnected",
    3: "error",
    4: "poll",
    5: "device-string",
    6: "vid-pid",
    7: "device-type",
    8: "startup",
}
PRINTABLE = bytes(range(0x20, 0x7F))


@dataclass
class Built:
    wire: bytes  # without LF
    record: dict[str, Any]  # what `--json` must print for it


def c2_frame(status: int, node_id: int, code: int, body: bytes) -> bytes:
    head = b"H-" + bytes([status, node_id, code]) + body
    return head + struct.pack("<H", crc16_arc_bitwise(head))


def random_data_frame(rng: random.Random) -> Built:
    status = rng.choice(b"><!&%")
    node_id, code = rng.randrange(256), rng.randrange(256)
    axes = [rng.randrange(-32768, 32768) for _ in range(10)]
    groups = [rng.getrandbits(32), rng.getrandbits(32)]
    wire = c2_frame(status, node_id, code, struct.pack("<10h2I", *axes, *groups))
    record = {
        "protocol": "c2-16b",
        "status": chr(status),
        "node_id": node_id,
        "code": code,
        "axes": axes,
        "group1": groups[0],
        "group2": groups[1],
    }
    if status == ord("&"):
        record["destination"] = code  # byte 4 of a handover is the destination ID
    return Built(wire, record)


def random_service_payload(rng: random.Random, service: int) -> tuple[bytes, dict[str, Any]]:
    if service == 3:
        code = rng.randrange(256)
        return bytes([code]), {"error_code": code}
    if service == 6:
        vid, pid = rng.randrange(65536), rng.randrange(65536)
        return struct.pack("<HH", vid, pid), {"vid": vid, "pid": pid}
    if service in (5, 7, 8):
        text = bytes(rng.choice(PRINTABLE) for _ in range(rng.randint(1, 12)))
        return text, {"text": text.decode("ascii")}
    return b"", {}


def random_service_frame(rng: random.Random) -> Built:
    service = rng.randint(1, 8)
    binary = rng.random() < 0.5
    node_id = rng.randrange(256)
    code = 0 if rng.random() < 0.5 else rng.randrange(256)  # a service code: ICD, TBD
    payload, fields = random_service_payload(rng, service)
    status = service if binary else 0x30 + service
    wire = c2_frame(status, node_id, code, payload.ljust(28, b"\0"))
    record = {
        "protocol": "c2-16b",
        "status": str(service),
        "status_encoding": "binary" if binary else "ascii",
        "node_id": node_id,
        "code": code,
        "service": SERVICE_NAMES[service],
        "payload_hex": payload.rstrip(b"\0").hex(),
        **fields,
    }
    return Built(wire, record)


def random_sumd_frame(rng: random.Random) -> Built:
    failsafe = rng.random() < 0.3
    channels = [rng.randrange(65536) for _ in range(rng.randint(2, 32))]
    head = struct.pack(
        f">BBB{len(channels)}H", 0xA8, 0x81 if failsafe else 0x01, len(channels), *channels
    )
    wire = head + struct.pack(">H", crc16_xmodem_bitwise(head))
    return Built(wire, {"protocol": "sumd", "failsafe": failsafe, "channels": channels})


# Headers must appear only where a frame starts: frames with a header-like byte pair inside
# are redrawn, garbage has no header bytes at all, and a flipped bit never creates one. C2
# garbage has no LF either: an LF right after a frame is part of that frame.
C2_GARBAGE = bytes(b for b in range(256) if b not in b"H-\n")
SUMD_GARBAGE = bytes(b for b in range(256) if b != 0xA8)


def c2_clean(wire: bytes) -> bool:
    return wire.find(b"H-", 1) < 0


def sumd_clean(wire: bytes) -> bool:
    return wire.find(b"\xa8", 1) < 0


def flip_one_bit(rng: random.Random, wire: bytes, first: int, clean: Any) -> bytes:
    while True:
        corrupted = bytearray(wire)
        corrupted[rng.randrange(first, len(wire))] ^= 1 << rng.randrange(8)
        if clean(bytes(corrupted)):
            return bytes(corrupted)


@dataclass
class Stream:
    data: bytes
    records: list[dict[str, Any]]
    corrupted: int  # frames with a flipped bit or cut short: each one CRC failure
    skipped: int  # bytes outside valid frames and their LFs


def build_stream(rng: random.Random, make: Any, clean: Any, garbage: bytes, **kw: Any) -> Stream:
    """Frames, corrupted frames and garbage, interleaved.

    A corrupted frame has one bit flipped past its header, or is cut short inside its body
    (then the next frame starts inside the corrupted candidate's 35 bytes). Either way the
    header stays plausible, so each counts as exactly one CRC failure. The stream ends with
    garbage long enough to complete any candidate.
    """
    parts: list[bytes] = []
    records: list[dict[str, Any]] = []
    corrupted = skipped = 0
    for _ in range(kw["count"]):
        filler = bytes(rng.choice(garbage) for _ in range(rng.choice((0, 0, 1, 5, 40))))
        built = make(rng)
        while not clean(built.wire):
            built = make(rng)
        damage = rng.random()
        damaged = damage < 0.18
        if damage < 0.12:
            wire = flip_one_bit(rng, built.wire, kw["first_payload_byte"], clean)
        elif damage < 0.18:
            wire = built.wire[: rng.randrange(kw["first_payload_byte"], len(built.wire))]
        else:
            wire = built.wire
            records.append(built.record)
        line_feed = b"\n" if kw["line_feeds"] and rng.random() < 0.5 else b""
        parts += [filler, wire, line_feed]
        skipped += len(filler)
        if damaged:
            corrupted += 1
            skipped += len(wire) + len(line_feed)
    tail = bytes(rng.choice(garbage) for _ in range(80))
    return Stream(b"".join([*parts, tail]), records, corrupted, skipped + len(tail))


def random_c2_frame(rng: random.Random) -> Built:
    return random_data_frame(rng) if rng.random() < 0.7 else random_service_frame(rng)


def c2_stream(seed: int, count: int) -> Stream:
    return build_stream(
        random.Random(seed),
        random_c2_frame,
        c2_clean,
        C2_GARBAGE,
        count=count,
        first_payload_byte=5,  # status and code stay plausible: a CRC failure, not a skip
        line_feeds=True,
    )


def sumd_stream(seed: int, count: int) -> Stream:
    return build_stream(
        random.Random(seed),
        random_sumd_frame,
        sumd_clean,
        SUMD_GARBAGE,
        count=count,
        first_payload_byte=3,
        line_feeds=False,
    )


# --- running the command -------------------------------------------------------------------


def usb2rc_decode(*args: str, **kw: Any) -> subprocess.CompletedProcess[bytes]:
    command = [sys.executable, "-m", "usb2rc", "decode", *args]
    return subprocess.run(command, capture_output=True, timeout=GUARD_TIMEOUT_S, cwd=REPO, **kw)


def json_records(stdout: bytes) -> list[dict[str, Any]]:
    return [json.loads(line) for line in stdout.decode().splitlines()]


def summary_number(stderr: bytes, label: str) -> int:
    match = re.search(rf"{label} (\d+)", stderr.decode())
    assert match, stderr
    return int(match.group(1))


@pytest.mark.parametrize(
    ("protocol", "make_stream"), [("c2-16b", c2_stream), ("sumd", sumd_stream)]
)
def test_acceptance_random_stream_with_garbage_and_corruption(
    tmp_path: Path, protocol: str, make_stream: Any
) -> None:
    stream = make_stream(seed=16, count=400)
    assert stream.corrupted > 20 and len(stream.records) > 300
    capture = tmp_path / "capture.bin"
    capture.write_bytes(stream.data)
    result = usb2rc_decode("--protocol", protocol, "--json", str(capture))
    assert result.returncode == 0, result.stderr
    assert json_records(result.stdout) == stream.records
    assert summary_number(result.stderr, "CRC failures") == stream.corrupted
    assert summary_number(result.stderr, "frames") == len(stream.records)
    assert summary_number(result.stderr, "bytes skipped") == stream.skipped
    assert summary_number(result.stderr, "bytes read") == len(stream.data)


def test_stdin_source() -> None:
    stream = c2_stream(seed=7, count=40)
    result = usb2rc_decode("--json", "-", input=stream.data)
    assert result.returncode == 0, result.stderr
    assert json_records(result.stdout) == stream.records
    assert summary_number(result.stderr, "CRC failures") == stream.corrupted


def test_missing_source_is_a_clear_error() -> None:
    result = usb2rc_decode("/nonexistent/capture.bin")
    assert result.returncode == 1
    assert result.stdout == b""
    assert b"/nonexistent/capture.bin" in result.stderr
    assert b"no such file or port" in result.stderr


def read_until(fd: int, done: Any, buffer: bytearray) -> bytes:
    """Read fd until done(buffer) holds; the deadline only bounds a hung child."""
    deadline = time.monotonic() + GUARD_TIMEOUT_S
    while not done(buffer):
        remaining = deadline - time.monotonic()
        ready, _, _ = select.select([fd], [], [], max(remaining, 0))
        assert ready, f"no output from usb2rc decode; so far: {bytes(buffer)!r}"
        chunk = os.read(fd, 65536)
        assert chunk, f"usb2rc decode closed its output; so far: {bytes(buffer)!r}"
        buffer += chunk
    return bytes(buffer)


def restore_default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)  # a child of a background job may ignore it


def test_pseudo_terminal_source_until_ctrl_c() -> None:
    master, slave = os.openpty()
    tty.setraw(slave)  # no line discipline between the test and the decoder
    stream = c2_stream(seed=3, count=60)
    process = subprocess.Popen(
        [sys.executable, "-m", "usb2rc", "decode", "--json", os.ttyname(slave)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        cwd=REPO,
        preexec_fn=restore_default_sigint,
    )
    try:
        stderr = bytearray()
        read_until(process.stderr.fileno(), lambda b: b"Ctrl-C" in b, stderr)  # port is open
        os.write(master, stream.data)
        expected_lines = len(stream.records)
        stdout = read_until(
            process.stdout.fileno(), lambda b: b.count(b"\n") >= expected_lines, bytearray()
        )
        process.send_signal(signal.SIGINT)
        rest_out, rest_err = process.communicate(timeout=GUARD_TIMEOUT_S)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
        os.close(master)
        os.close(slave)
    assert process.returncode == 0, bytes(stderr) + rest_err
    assert json_records(stdout + rest_out) == stream.records
    summary = bytes(stderr) + rest_err
    assert summary_number(summary, "frames") == len(stream.records)
    assert summary_number(summary, "CRC failures") == stream.corrupted


def test_importing_the_command_has_no_side_effects() -> None:
    code = (
        "import sys; import usb2rc.commands.decode; "
        "assert 'serial' not in sys.modules, 'pyserial imported eagerly'"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, timeout=GUARD_TIMEOUT_S
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout == b""


# --- the shipped samples and the human-readable output (in process) ------------------------


def load_generator() -> ModuleType:
    spec = importlib.util.spec_from_file_location(
        "make_sample_capture", Path(__file__).parent / "make_sample_capture.py"
    )
    assert spec and spec.loader
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_shipped_samples_equal_the_generator_output() -> None:
    generator = load_generator()
    assert (SAMPLES / "c2-16b-sample.bin").read_bytes() == generator.c2_16b_sample()
    assert (SAMPLES / "sumd-sample.bin").read_bytes() == generator.sumd_sample()


def run_in_process(*argv: str) -> int:
    parser = argparse.ArgumentParser()
    decode.add_parser(parser.add_subparsers())
    args = parser.parse_args(["decode", *argv])
    return args.func(args)


def test_human_readable_sample(capsys: pytest.CaptureFixture[str]) -> None:
    assert run_in_process(str(SAMPLES / "c2-16b-sample.bin")) == 0
    out, err = capsys.readouterr()
    lines = out.splitlines()
    assert lines[:5] == [
        'service startup node 255 "usb2rc 0.1.0"',
        "service connected node 0",
        "service vid-pid node 0 vid 0x044F pid 0xB10A",
        'service device-string node 0 "T.16000M"',
        'service device-type node 0 "JOYSTICK"',
    ]
    assert lines[5] == (
        "> node 0 code 0 axes [-32768, -1, -32768, 32767, 0, 0, -1, 0, 0, 0]"
        " g1 0x00000000 g2 0x00000000"
    )
    assert lines[105] == "service disconnected node 0"
    assert all(line.startswith("! node 0 code ") for line in lines[106:])
    assert len(lines) == 116
    assert "frames 116 (live 100, failsafe 10, connected 1," in err
    assert "CRC failures 0" in err


def test_human_readable_sumd_sample(capsys: pytest.CaptureFixture[str]) -> None:
    assert run_in_process("--protocol", "sumd", str(SAMPLES / "sumd-sample.bin")) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 110
    assert lines[0].startswith("sumd live 8ch [8800, ")
    assert lines[-1].startswith("sumd failsafe 8ch [")


def test_text_lines_for_other_services(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    capture = tmp_path / "services.bin"
    error = c2_frame(0x03, 4, 0, b"\x02".ljust(28, b"\0"))
    poll = c2_frame(ord("4"), 9, 0, b"\x01\x02".ljust(28, b"\0"))
    capture.write_bytes(error + b"\n" + poll)
    assert run_in_process(str(capture)) == 0
    assert capsys.readouterr().out.splitlines() == [
        "service error node 4 error 0x02 (binary status)",
        "service poll node 9 payload 0102",
    ]


def test_service_codes_and_handover_destinations(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Byte 4 of a CRC-valid service frame may be anything (the ICD's service codes are TBD):
    the frame is shown with its code, never skipped; a `&` shows byte 4 as its destination."""
    capture = tmp_path / "codes.bin"
    poll = c2_frame(ord("4"), 9, 0x41, bytes(28))
    startup = c2_frame(0x08, 0xFF, 0xFF, b"other 2.0".ljust(28, b"\0"))
    handover = c2_frame(ord("&"), 1, 7, struct.pack("<10h2I", *([0] * 10), 1, 0))
    capture.write_bytes(poll + b"\n" + startup + handover)
    assert run_in_process(str(capture)) == 0
    out, err = capsys.readouterr()
    assert out.splitlines() == [
        "service poll node 9 code 65",
        'service startup node 255 code 255 "other 2.0" (binary status)',
        "& node 1 to 7 axes [0, 0, 0, 0, 0, 0, 0, 0, 0, 0] g1 0x00000001 g2 0x00000000",
    ]
    assert "frames 3 (" in err and "bytes skipped 0" in err
    assert run_in_process("--json", str(capture)) == 0
    records = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [(r["status"], r["code"]) for r in records] == [("4", 0x41), ("8", 0xFF), ("&", 7)]
    assert records[0]["service"] == "poll" and records[1]["text"] == "other 2.0"
    assert records[2]["destination"] == 7
