"""Run the daemon as a subprocess on real pseudo-terminals with replayed devices.

`PtyLine` is the far end of a serial line: a thread reads the pty master and decodes what
the daemon sends; tests wait on a condition (never a bare sleep) for what they expect.
A T.16000M report packer lives here too, written from the descriptor by hand, so the tests
do not compute expected frames with the code under test.
"""

from __future__ import annotations

import contextlib
import os
import re
import select
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Any, Protocol

from process_harness import logs, owned, stop_owned
from rc_reference import RefCrsfReader, RefSbusReader

from usb2rc.protocols.c2_16b import codec as c2_16b
from usb2rc.protocols.sumd import codec as sumd

ROOT = Path(__file__).resolve().parent.parent
# How long a wait for what a test expects may take before it fails: long, since a loaded host
# (CI runs the suite beside two CPU hogs) is slow; a wait that succeeds ends at once.
WAIT_S = 30.0

# Thrustmaster T.16000M (044f:b10a), from tests/data/real-devices.json: 16 buttons, hat
# 0..7 (4 bits, null) + 4 pad bits, X 14 bit + 2 pad, Y 14 bit + 2 pad, Rz 8 bit, Slider
# 8 bit, 55 constant bytes: 64-byte reports, no report ID.
T16000M_DESCRIPTOR = bytes.fromhex(
    "05010904a101050919012910150025013500450175019510810205010939150025073500463b0165147504"
    "9501814281010930150026ff3f350046ff3f6500750e950181027502950181010931750e95018102750295"
    "0181010935093615002"
    "6ff00350046ff0065007508950281027508953781010600ff27ffff0000090175089504b1a2c0"
)
HAT_NULL = 8

# A T.16000M pinned to node 4 with X inverted or not: `INVERT_X_CONFIG.format(invert="true")`
INVERT_X_CONFIG = """
devices:
  - name: stick
    match: {{vid: 0x044f, pid: 0xb10a}}
    node_id: 4
    axes:
      x: {{usage: X, invert: {invert}}}
"""
# The same with X not guarded (`arm: any`): a reload that inverts X shows at once, even
# deflected (with X guarded, the node waits for X to centre: docs/ICD.md "A reload and the
# live devices").
INVERT_UNGUARDED_X_CONFIG = INVERT_X_CONFIG.replace(
    "invert: {invert}}}", "invert: {invert}, arm: any}}"
)


@dataclass(frozen=True)
class StickState:
    x: int = 8192
    y: int = 8192
    rz: int = 128
    slider: int = 128
    buttons: int = 0  # HID button n -> bit n-1
    hat: int = HAT_NULL  # 0..7 or null

    def report(self) -> bytes:
        head = bytes(
            [
                self.buttons & 0xFF,
                self.buttons >> 8 & 0xFF,
                self.hat & 0x0F,
                self.x & 0xFF,
                self.x >> 8 & 0x3F,
                self.y & 0xFF,
                self.y >> 8 & 0x3F,
                self.rz,
                self.slider,
            ]
        )
        return head + bytes(55)


def scale(v: int, lo: int, hi: int) -> int:
    """round((v - min) * 65535 / (max - min)) - 32768, in exact integers
    (docs/ICD.md, "Axis scaling")."""
    return (2 * (v - lo) * 65535 + (hi - lo)) // (2 * (hi - lo)) - 32768


HAT_BITS = {n: 1 << (24 + n) for n in range(8)}  # UP, UP-RIGHT ... UP-LEFT -> group 1 24..31


def expected_frame(state: StickState) -> tuple[tuple[int, ...], int, int]:
    """The default layout of a T.16000M state: axes, group1, group2
    (docs/ICD.md, "Default axis layout" and "Default button layout")."""
    axes = [0] * 10
    axes[0] = scale(state.x, 0, 16383)
    axes[1] = scale(state.y, 0, 16383)
    axes[3] = scale(state.slider, 0, 255)
    axes[6] = scale(state.rz, 0, 255)
    group1 = (state.buttons & 0xFFFF) | HAT_BITS.get(state.hat, 0)
    return tuple(axes), group1, 0


# How long a recording holds its first state at least: the state the device is plugged in at.
# A node goes live only once the daemon has seen its stick at rest for the neutral guard's
# 0.05 s (one that moves before that stays in failsafe, as it should), and on a loaded host
# the daemon's first steps after a plug come late: a 0.1 s rest was missed there.
REST_S = 0.5


def recording(
    states: Sequence[StickState],
    hold_s: float = 0.1,
    name: str = "Thrustmaster T.16000M",
    extra: str = "",
    rest_s: float = REST_S,
) -> str:
    """A hid-recorder file: the first state for `rest_s` (at least `hold_s`), each next one
    for `hold_s`; the last one held until the file goes."""
    first = max(rest_s, hold_s)
    events = [(0.0, states[0]), *((first + i * hold_s, s) for i, s in enumerate(states[1:]))]
    return timed_recording(events, name, extra)


class Reporting(Protocol):
    def report(self) -> bytes: ...


def timed_recording(
    events: Sequence[tuple[float, Reporting]],
    name: str = "Thrustmaster T.16000M",
    extra: str = "",
    descriptor: bytes = T16000M_DESCRIPTOR,
    ids: str = "044f b10a",
) -> str:
    """A hid-recorder file: each (time in s, state) is one report at that time."""
    lines = [
        "# usb2rc test recording",
        f"R: {len(descriptor)} " + " ".join(f"{b:02x}" for b in descriptor),
        f"N: {name}",
        "P: usb-0000:00:14.0-1/input0",
        f"I: 3 {ids}",
    ]
    if extra:
        lines.append(extra)
    for at, state in events:
        report = state.report()
        lines.append(f"E: {at:.6f} {len(report)} " + " ".join(f"{b:02x}" for b in report))
    return "\n".join(lines) + "\n"


def real_device_recordings(
    count: int, seconds: float, rate_hz: float, rest_s: float = 0.0
) -> list[str]:
    """`count` recordings of real descriptors (tests/data/real-devices.json; no T.16000M, so
    each is another model), each with random reports of every input report ID at `rate_hz`;
    in the first `rest_s`, each device's reports at rest (`_rest_reports`)."""
    import random

    from usb2rc.hid.descriptor import parse_descriptor

    rng = random.Random(11)
    texts = []
    for device in _real_devices():
        layout = parse_descriptor(bytes.fromhex(device["hex"]))
        if not layout.inputs or device["name"].startswith("Thrustmaster T.16000M"):
            continue
        texts.append(random_report_recording(device, seconds, rate_hz, rng, rest_s))
        if len(texts) == count:
            break
    return texts


def live_device_recordings(count: int, seconds: float, rate_hz: float) -> list[str]:
    """As `real_device_recordings`, but each device rests for its first REST_LEAD_S (every
    guarded axis where its zero-config guard wants it, the others and the hats centred, no
    button), so its node goes live: random reports after that keep it live, as a pilot's
    sticks do in flight."""
    return real_device_recordings(count, seconds, rate_hz, REST_LEAD_S)


REST_LEAD_S = 1.0  # live_device_recordings: the rest before the random reports


def _rest_reports(device: dict[str, str]) -> dict[int, bytes]:
    """Each input report ID's report at rest: guarded axes at their zero-config rest point
    (the device database's, else by usage), the other values at their centre, hats null,
    no button."""
    from usb2rc.config.layout import AXIS_NAMES
    from usb2rc.hid.descriptor import parse_descriptor
    from usb2rc.hid.usages import GD_HAT_SWITCH
    from usb2rc.nodes import known_devices
    from usb2rc.nodes.binding import default_axis_fields, default_binding

    layout = parse_descriptor(bytes.fromhex(device["hex"]))
    known = known_devices.lookup(int(device["vid"], 16), int(device["pid"], 16))
    values = {
        f.index: f.null_value() if f.usage == GD_HAT_SWITCH else f.centre() for f in layout.inputs
    }
    slots = dict(default_axis_fields(layout))
    for axis in default_binding(layout, device["name"], known=known).guard.axes:
        f = slots[AXIS_NAMES[axis.slot]]
        values[f.index] = {"low": f.logical_min, "high": f.logical_max}.get(axis.arm, f.centre())
    id_bits = 8 if layout.uses_report_ids else 0
    reports = {}
    for rid, length in layout.input_report_lengths.items():
        word = rid if id_bits else 0
        for f in layout.inputs:
            if f.report_id == rid:
                raw = values[f.index] & ((1 << f.bit_size) - 1)
                word |= raw << (f.bit_offset + id_bits)
        reports[rid] = word.to_bytes(length + id_bits // 8, "little")
    return reports


# The four models of issue 22's bench of real descriptors (names as in real-devices.json).
BENCH_MODELS = (
    "Saitek/Logitech X52",
    "Thrustmaster T.16000M",
    "Thrustmaster TWCS",
    "Logitech WingMan",
)


def named_device_recordings(
    names: Sequence[str], seconds: float, rate_hz: float, seed: int = 22
) -> list[str]:
    """A recording of each real descriptor whose name starts with one of `names`, with
    random reports of every input report ID (in turn) at `rate_hz`."""
    import random

    rng = random.Random(seed)
    devices = _real_devices()
    return [
        random_report_recording(
            next(d for d in devices if d["name"].startswith(name)), seconds, rate_hz, rng
        )
        for name in names
    ]


def _real_devices() -> list[dict[str, str]]:
    import json

    devices: list[dict[str, str]] = json.loads(
        (ROOT / "tests" / "data" / "real-devices.json").read_text()
    )
    return devices


def random_report_recording(
    device: dict[str, str], seconds: float, rate_hz: float, rng: Any, rest_s: float = 0.0
) -> str:
    """A recording of one real-devices.json entry: random reports, `rate_hz` of them a
    second, of its input report IDs in turn; in the first `rest_s`, its reports at rest
    (`_rest_reports`)."""
    from usb2rc.hid.descriptor import parse_descriptor
    from usb2rc.hid.recording import RecordedEvent, Recording, format_recording

    descriptor = bytes.fromhex(device["hex"])
    layout = parse_descriptor(descriptor)
    ids = sorted(layout.input_report_lengths.items())
    at_rest = _rest_reports(device) if rest_s > 0 else {}
    events = []
    for i in range(int(seconds * rate_hz)):
        rid, length = ids[i % len(ids)]
        head = bytes([rid]) if layout.uses_report_ids else b""
        resting = i < rest_s * rate_hz
        report = at_rest[rid] if resting else head + rng.randbytes(length)
        events.append(RecordedEvent(i / rate_hz, report))
    vid, pid = int(device["vid"], 16), int(device["pid"], 16)
    rec = Recording(descriptor, device["name"], "", 3, vid, pid, tuple(events))
    return format_recording(rec)


def install(path: Path, text: str) -> None:
    """Plug: the file appears whole (written aside, then renamed)."""
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


class MavlinkStream:
    """The far end of a MAVLink line as a receiver parses it: pymavlink's own parser (not
    usb2rc's code), `feed(bytes) -> [message]`; bad data is counted, never returned."""

    def __init__(self) -> None:
        from pymavlink.dialects.v20 import common

        self.parser = common.MAVLink(None)
        self.parser.robust_parsing = True
        self.bad = 0

    def feed(self, data: bytes) -> list[Any]:
        messages = []
        for message in self.parser.parse_buffer(data) or []:
            if message.get_type() == "BAD_DATA":
                self.bad += 1
            else:
                messages.append(message)
        return messages


@dataclass(frozen=True)
class Seen:
    time: float
    frame: Any  # c2_16b.DataFrame | c2_16b.ServiceFrame | sumd.SumdFrame


# The far end's decoder per protocol: CRSF and SBUS are read with the tests' own decoder,
# written from the protocol descriptions (rc_reference.py), not with usb2rc's codecs.
DECODERS: dict[str, Callable[[], Any]] = {
    "sumd": sumd.SumdDecoder,
    "crsf": RefCrsfReader,
    "sbus": RefSbusReader,
    "mavlink": MavlinkStream,
}


class PtyLine:
    """A pty pair; the test holds the master (the far end), the daemon opens the slave."""

    def __init__(self, protocol: str = "c2-16b") -> None:
        self.master, self._slave = os.openpty()
        self.path = os.ttyname(self._slave)
        self.decoder: Any = DECODERS.get(protocol, c2_16b.Decoder)()
        self.seen: list[Seen] = []
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"pty {self.path}")
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            if not self._reading():
                continue
            try:
                ready, _, _ = select.select([self.master], [], [], 0.05)
            except (OSError, ValueError):
                return
            if not ready or not self._reading():
                continue
            try:
                data = os.read(self.master, 65536)
            except OSError:
                continue
            now = time.monotonic()
            frames = self.decoder.feed(data)
            with self._cond:
                self._received(now, data, frames)
                self._cond.notify_all()

    def _reading(self) -> bool:
        """Whether the far end reads now (a subclass may stall it; it waits here then)."""
        return True

    def _received(self, now: float, data: bytes, frames: list[Any]) -> None:
        """Every read, under the condition's lock: the bytes and what they decoded to."""
        if frames:
            self._record(now, frames)

    def _record(self, now: float, frames: list[Any]) -> None:
        """Keep what arrived (under the condition's lock); subclasses check as they keep."""
        self.seen.extend(Seen(now, f) for f in frames)

    def send(self, data: bytes) -> None:
        os.write(self.master, data)

    def frames(self) -> list[Any]:
        with self._cond:
            return [s.frame for s in self.seen]

    def seen_now(self) -> list[Seen]:
        """What arrived so far, with arrival times (a copy)."""
        with self._cond:
            return list(self.seen)

    def wait_for(self, predicate: Callable[[list[Any]], Any], timeout: float = WAIT_S) -> Any:
        """Wait until predicate(frames) is truthy; return its value. Fails after timeout."""
        return self.wait_seen(lambda seen: predicate([s.frame for s in seen]), timeout)

    def wait_seen(self, predicate: Callable[[list[Seen]], Any], timeout: float = WAIT_S) -> Any:
        """wait_for with each frame's arrival time (`Seen`), for tests that time frames."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while True:
                result = predicate(self.seen)
                if result:
                    return result
                left = deadline - time.monotonic()
                if left <= 0:
                    raise AssertionError(
                        f"timed out after {timeout} s; saw {len(self.seen)} frames"
                    )
                self._cond.wait(left)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5)
        for fd in (self.master, self._slave):
            with contextlib.suppress(OSError):
                os.close(fd)

    def close_at_the_end(self) -> None:
        """A fixture's close, once its test is over: the harness's daemons still running stop
        first. One left running after its line went would open the path again, and a pty
        that another test opens next may get the same path."""
        stop_owned()
        self.close()


class DaemonProcess:
    """`python -m usb2rc run ...` as a subprocess; its log goes to a file the test can read."""

    def __init__(
        self,
        args: Sequence[str],
        log_path: Path,
        env: dict[str, str] | None = None,
        prefix: Sequence[str] = (),
    ) -> None:
        """`prefix`: a command that runs the daemon (e.g. setpriv dropping capabilities)."""
        self.log_path = log_path
        self._log = open(log_path, "wb")  # noqa: SIM115 - closed in stop()
        env = dict(os.environ, PYTHONUNBUFFERED="1", **(env or {}))
        self.proc = subprocess.Popen(
            [*prefix, sys.executable, "-m", "usb2rc", "run", "--log-level", "debug", *args],
            stdout=self._log,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            cwd=ROOT,
            env=env,
        )
        owned.add(self)  # stopped after the test if the test does not (tests/conftest.py)
        logs.append(log_path)  # shown if the test fails

    def log(self) -> str:
        return self.log_path.read_text(errors="replace")

    def signal(self, signum: int) -> None:
        self.proc.send_signal(signum)

    def stop(self, timeout: float = 10.0) -> int:
        owned.discard(self)
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        try:
            code = self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            code = self.proc.wait()
        self._log.close()
        return code


def run_daemon(
    tmp_path: Path, port: str, replay_dir: Path, *extra: str, env: dict[str, str] | None = None
) -> DaemonProcess:
    """The daemon on `port` with the replay folder, its log in tmp_path/daemon.log."""
    return DaemonProcess(
        ["--port", port, "--replay", str(replay_dir), *extra], tmp_path / "daemon.log", env
    )


def wait_until(condition: Callable[[], Any], what: str, timeout: float = WAIT_S) -> Any:
    """Poll `condition` until truthy (its value is returned); fail naming `what`."""
    deadline = time.monotonic() + timeout
    while not (result := condition()):
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.02)
    return result


def stats_until(daemon: DaemonProcess, pattern: str, timeout: float = WAIT_S) -> re.Match[str]:
    """Ask for the stats (SIGUSR1) until the log matches `pattern`; first wait until the
    daemon runs (before, SIGUSR1's default action would kill it)."""
    wait_until(lambda: " running" in daemon.log(), "the daemon to run (its signals handled)")

    def seen() -> re.Match[str] | None:
        daemon.signal(signal.SIGUSR1)
        time.sleep(0.05)
        return re.search(pattern, daemon.log())

    return wait_until(seen, f"a stats line matching {pattern!r}", timeout)  # type: ignore[no-any-return]


def data_frames(frames: list[Any], node_id: int | None = None) -> list[c2_16b.DataFrame]:
    return [
        f
        for f in frames
        if isinstance(f, c2_16b.DataFrame) and (node_id is None or f.node_id == node_id)
    ]


def service_frames(frames: list[Any], node_id: int | None = None) -> list[c2_16b.ServiceFrame]:
    return [
        f
        for f in frames
        if isinstance(f, c2_16b.ServiceFrame) and (node_id is None or f.node_id == node_id)
    ]


def services(frames: list[Any], node_id: int | None = None) -> list[str]:
    return [f.service.service_name for f in service_frames(frames, node_id)]


# --- MAVLink far ends (docs/ICD.md, "MAVLink output") ----------------------------------------

RELEASED = [0] * 8 + [65534] * 10  # channels 1-8: 0; 9-18: UINT16_MAX-1 (common.xml)


class UdpLine(PtyLine):
    """A UDP listener as the far end (a GCS / MAVLink router on udpin): what arrives is
    parsed by pymavlink (daemon_harness.MavlinkStream)."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.url = f"udpout:127.0.0.1:{self.sock.getsockname()[1]}"
        super().__init__("mavlink")

    def _run(self) -> None:
        while not self._stop.is_set():
            if not select.select([self.sock], [], [], 0.05)[0]:
                continue
            data = self.sock.recv(65535)
            messages = self.decoder.feed(data)
            with self._cond:
                self._received(time.monotonic(), data, messages)
                self._cond.notify_all()

    def close(self) -> None:
        super().close()
        self.sock.close()


def pwm_of_int16(value: int) -> int:
    """An int16 axis onto RC_CHANNELS_OVERRIDE's 1000..2000 µs, linear through both ends (the
    exact quotient is never a half: 65535 is odd)."""
    return 1000 + round(Fraction(value + 32768, 65535) * 1000)


def of_type(messages: list[Any], kind: str) -> list[Any]:
    return [m for m in messages if m.get_type() == kind]


def channels(message: Any) -> list[int]:
    """An RC_CHANNELS_OVERRIDE's 18 channels."""
    return [getattr(message, f"chan{i}_raw") for i in range(1, 19)]


@dataclass
class RecordSource:
    """Stands in for a DeviceReader in NodeTable tests: its published record."""

    record: Any  # usb2rc.hid.reader.ReaderRecord

    def pull(self) -> None:
        """The step's pull: a test sets the record itself."""


def stick_record(state: StickState, reports: int = 1) -> Any:
    """The record a T.16000M reader publishes after decoding `state`'s report."""
    from usb2rc.hid.descriptor import parse_descriptor
    from usb2rc.hid.reader import ReaderRecord

    decoder = parse_descriptor(T16000M_DESCRIPTOR).make_decoder()
    decoder.feed(state.report())
    return ReaderRecord(decoder.state(), reports)
