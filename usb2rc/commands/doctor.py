"""`usb2rc doctor [--config FILE] [--port PORT] [--replay DIR] [--json]`: why it does not work.

One line per check: `ok` and what was found, or `FAIL`, the problem and its fix. In order:

- the config, as `usb2rc run` would take it (`commands.check.load_checked`: --port applied);
- each joystick's, gamepad's and multi-axis controller's hidraw node: whether this user
  can open it as hidapi does (read and write), and when not, what would let it: the udev
  rule (not installed, or installed but not applied to the node) or the group that owns
  the node. Other HID devices are not usb2rc's (the rule leaves keyboards alone on purpose).
  With --replay the replayed devices are the devices: a recording counts as readable;
- each output's port: that it exists, that this user may read and write it (the group
  that owns it, `dialout` as a rule), and which process holds it (`lines.port_holders`);
- the far end, through the port: C2-16B any byte within 1 s; CRSF a device ping answered
  by device info (the module's name and firmware), at the configured baud rate or else at
  each rate CRSF modules use; MAVLink a vehicle's HEARTBEAT within 3 s, usb2rc's GCS
  heartbeat sent meanwhile. Nothing else is sent: no RC frame ever leaves doctor. SUMD,
  SBUS and iBus far ends send nothing back, so there is nothing to ask them;
- on a Raspberry Pi with an output on its GPIO UART: `enable_uart=1` in config.txt, and no
  serial console on the UART in cmdline.txt;
- the usb2rc service: not installed is no failure when running by hand.

Exit 0 when every check passed, 1 otherwise, 2 for a usage error (a config's problems are
checks that failed: doctor goes on with the others). `--json`: the same as a list of records.
"""

from __future__ import annotations

import argparse
import grp
import json
import logging
import os
import pwd
import re
import shutil
import stat
import subprocess
import sys
import time
from collections.abc import Callable, Generator, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

from usb2rc.commands.arguments import replay_dir
from usb2rc.commands.check import load_checked
from usb2rc.commands.install_system import SERVICE_GROUP
from usb2rc.config.mavlink import MavlinkOptions, SigningKeyError, read_signing_key
from usb2rc.config.port_url import port_argument
from usb2rc.config.ports import UsedPort, used_ports
from usb2rc.config.udp_url import is_udp_url
from usb2rc.configfile import Config, ConfigError
from usb2rc.hid.backend import DeviceInfo
from usb2rc.hid.permissions import INSTALL_RULE, UDEV_RULES_INSTALLED
from usb2rc.lines.port_holders import Holder, command_line, lock_holders, port_holders
from usb2rc.lines.serial_link import device_path, is_held
from usb2rc.protocols.crsf import codec as crsf
from usb2rc.protocols.crsf.device_info import (
    TYPE_DEVICE_PING,
    device_info_of,
    encode_device_ping,
)
from usb2rc.protocols.crsf.device_info import DeviceInfo as CrsfDevice
from usb2rc.runtime.log_escape import escape

C2_16B_LISTEN_S = 1.0  # any byte within this long: the far end is alive
CRSF_LISTEN_S = 1.0  # per baud rate tried; a module answers a ping within milliseconds
CRSF_CONFIGURED_LISTEN_S = 2.0  # at the configured rate: a module still starting up
CRSF_PING_INTERVAL_S = 0.2  # a ping this often while listening (a handset pings as often)
# The baud rates CRSF transmitter modules use, most common first: 400000 (the handsets'
# default), 921600, 1870000, then 115200 (older firmware) and 3750000. A flight
# controller's 420000 is not tried: that rate is set on purpose, and `check` warns of it.
CRSF_BAUDRATES = (400000, 921600, 1870000, 115200, 3750000)
HEARTBEAT_LISTEN_S = 3.0  # MAVLink: a vehicle heartbeats at 1 Hz
HEARTBEAT_INTERVAL_S = 1.0  # usb2rc's own GCS heartbeat meanwhile (udpout peers need one)
UDP_POLL_S = 0.02  # UdpLink is polled: it keeps its socket to itself
SERVICE = "usb2rc.service"
RELOAD_RULES = "`sudo udevadm control --reload && sudo udevadm trigger --subsystem-match=hidraw`"
PORTS_LISTING = "`ls -l /dev/serial* /dev/ttyUSB* /dev/ttyACM*`"


def add_parser(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "doctor",
        help="why it does not work: devices, ports, far end, Pi UART, service (exit 0 all ok)",
        description="Check what usb2rc needs, one line each: ok, or the problem and the fix. "
        "Exit 0 when every check passes, 1 otherwise.",
    )
    parser.add_argument("--config", metavar="FILE", help="YAML config (default: zero config)")
    parser.add_argument(
        "--port",
        type=port_argument,
        help="the first output's port, as `usb2rc run --port` would give it",
    )
    parser.add_argument(
        "--replay",
        metavar="DIR",
        type=replay_dir,
        help="the devices are the hid-recorder files in DIR (they count as readable)",
    )
    parser.add_argument("--json", action="store_true", help="the checks as a list of records")
    # The system's files (the Pi's model and boot files, the installed udev rule) are read
    # under this folder: the tests give it a scratch tree.
    parser.add_argument("--root", metavar="DIR", default="/", help=argparse.SUPPRESS)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    # The links log their own open errors for the daemon; here each check says them.
    logging.getLogger("usb2rc").addHandler(logging.NullHandler())
    findings = []
    for finding in diagnose(args.config, args.port, args.replay, SystemFiles(args.root)):
        findings.append(finding)
        if not args.json:
            print(finding.line(), flush=True)
    if args.json:
        print(json.dumps([f.record() for f in findings], indent=2))
    failed = sum(not f.ok for f in findings)
    verdict = f"{failed} of {len(findings)} checks failed" if failed else "every check passed"
    print(f"usb2rc doctor: {verdict}", file=sys.stderr)
    return 1 if failed else 0


def diagnose(
    config_path: str | None, port: str | None, replay: str | None, files: SystemFiles
) -> Iterator[Finding]:
    """Every check's finding, as each is done (the far ends take seconds)."""
    config = yield from config_findings(config_path, port)
    yield from device_findings(replay, files)
    used = None if config is None else used_ports(config, port)
    for output in used or ():
        yield from output_findings(output)
    yield from pi_findings(files, used)
    yield service_finding()


# --------------------------------------------------------------------------- findings


@dataclass(frozen=True)
class Finding:
    """One check's result: `found` says what is (the problem when not ok), `fix` what to do."""

    check: str  # "config", "device", "port", "port access", "port holder", "far end", ...
    subject: str  # what was checked: a node, an output and its port, the service
    ok: bool
    found: str
    fix: str = ""
    facts: dict[str, Any] = field(default_factory=dict)  # for --json: the figures found

    def line(self) -> str:
        status = "ok" if self.ok else "FAIL"
        text = f"{status:<4}  {self.check}: {self.subject}: {self.found}"
        return f"{text}. Fix: {self.fix}" if self.fix else text

    def record(self) -> dict[str, Any]:
        record: dict[str, Any] = {
            "check": self.check,
            "subject": self.subject,
            "ok": self.ok,
            "found": self.found,
            "fix": self.fix,
        }
        if self.facts:
            record["facts"] = self.facts
        return record


@dataclass(frozen=True)
class SystemFiles:
    """Where the system's own files are read: under `root` (/ but in tests)."""

    root: str = "/"

    def path(self, absolute: str) -> str:
        return os.path.join(self.root, absolute.lstrip("/"))

    def first(self, candidates: Sequence[str]) -> str | None:
        """The first of `candidates` (absolute paths) that exists under the root."""
        return next((p for p in candidates if os.path.exists(self.path(p))), None)

    def read(self, absolute: str) -> str | None:
        try:
            with open(self.path(absolute), encoding="utf-8", errors="replace") as file:
                return file.read()
        except OSError:
            return None


# --------------------------------------------------------------------------- config


def config_findings(path: str | None, port: str | None) -> Generator[Finding, None, Config | None]:
    """The config's verdict (each problem a finding); returns the config, None when it has
    problems (then no output is checked: which port each has is not known for sure)."""
    source = path or "zero config"
    try:
        config = load_checked(path, port)
    except ConfigError as exc:
        for problem in exc.problems:
            yield Finding("config", source, False, str(problem))
        return None
    outputs = ", ".join(f"{u.output.protocol} on {u.port}" for u in used_ports(config, port))
    entries = f", {len(config.devices)} device entries" if config.devices else ""
    yield Finding("config", source, True, f"loads as `usb2rc run` takes it: {outputs}{entries}")
    return config


# --------------------------------------------------------------------------- devices


def device_findings(replay: str | None, files: SystemFiles) -> Iterator[Finding]:
    """The replayed devices, or each joystick's hidraw node and whether this user opens it."""
    if replay is not None:
        yield from replayed_findings(replay)
        return
    try:
        from usb2rc.hid.hidapi_backend import HidapiBackend

        infos = HidapiBackend().enumerate()
    except (ImportError, OSError) as exc:
        fix = "`pip install hidapi` in usb2rc's environment (it comes with usb2rc)"
        yield Finding("device", "hidapi", False, f"cannot list HID devices: {exc}", fix)
        return
    if not infos:
        found = "no joystick, gamepad or multi-axis controller found"
        fix = "plug one in; `usb2rc list --all` lists every HID device and what it is"
        yield Finding("device", "USB and Bluetooth", False, found, fix)
    for info in infos:
        yield node_finding(info, files)


def replayed_findings(directory: str) -> Iterator[Finding]:
    from usb2rc.hid.replay import ReplayBackend

    backend = ReplayBackend(directory)
    infos = backend.enumerate()
    for info in infos:
        found = f"replayed from {info.path}: a recording counts as readable"
        yield Finding("device", _device_name(info), True, found)
    for problem in backend.problems:
        yield Finding("device", directory, False, escape(problem))
    if not infos and not backend.problems:
        fix = "record a device into it: `usb2rc record VID:PID > DIR/stick.hid`"
        yield Finding("device", directory, False, "no recording in the folder", fix)


def _device_name(info: DeviceInfo) -> str:
    product = " ".join(p for p in (info.manufacturer, info.product) if p) or "no name"
    where = info.hidraw or info.port_path or info.path
    return escape(f"{where} ({product}, {info.vid:04x}:{info.pid:04x})")


def node_finding(info: DeviceInfo, files: SystemFiles) -> Finding:
    """Whether this user opens the device's node as hidapi does (read and write)."""
    subject = _device_name(info)
    node = info.hidraw
    if not node:  # not hidraw (another OS): hidapi opens what it names
        return Finding("device", subject, True, "listed by hidapi (not a hidraw node)")
    try:
        fd = os.open(node, os.O_RDWR | os.O_NONBLOCK | os.O_NOCTTY | os.O_CLOEXEC)
    except OSError as exc:
        return _node_refused(info, subject, exc, files)
    os.close(fd)
    return Finding("device", subject, True, f"user {user_name()} can read and write it")


def _node_refused(info: DeviceInfo, subject: str, exc: OSError, files: SystemFiles) -> Finding:
    try:
        node_stat = os.stat(info.hidraw)
    except FileNotFoundError:
        return Finding("device", subject, False, "unplugged while doctor looked", "plug it in")
    if isinstance(exc, PermissionError):
        found = f"user {user_name()} may not open it ({mode_text(node_stat)})"
        return Finding("device", subject, False, found, node_fix(info, node_stat, files))
    return Finding("device", subject, False, f"cannot open it: {exc.strerror or exc}")


def node_fix(info: DeviceInfo, node_stat: os.stat_result, files: SystemFiles) -> str:
    """What gives this user the node: the rule installed, applied, or the group it gives."""
    rule = UDEV_RULES_INSTALLED
    group = group_name(node_stat.st_gid)
    if not os.path.exists(files.path(rule)):
        fix = f"install the udev rule with {INSTALL_RULE}, then {RELOAD_RULES} (or re-plug it)"
        if _group_may_write(node_stat):
            fix += f"; or join group {group}, which may: {join_group_fix(group)}"
        return fix
    if group != SERVICE_GROUP:
        line = (
            f'SUBSYSTEM=="hidraw", ATTRS{{idVendor}}=="{info.vid:04x}", '
            f'ATTRS{{idProduct}}=="{info.pid:04x}", GROUP="{SERVICE_GROUP}", MODE="0660", '
            'TAG+="uaccess"'
        )
        return (
            f"{rule} is installed but did not apply to this node (its group is {group}, not "
            f"{SERVICE_GROUP}): {RELOAD_RULES}, or re-plug it. If it stays so, the rule does "
            f"not recognise this device's report descriptor: add the line `{line}` to {rule}"
        )
    return (
        f"join group {SERVICE_GROUP}: {join_group_fix(SERVICE_GROUP)}; or log in at the "
        "machine's own seat (the rule's uaccess gives that user the node), or run usb2rc "
        "as its service"
    )


def _group_may_write(node_stat: os.stat_result) -> bool:
    """The node's group (not root's) may read and write it."""
    both = stat.S_IRGRP | stat.S_IWGRP
    return node_stat.st_gid != 0 and node_stat.st_mode & both == both


# --------------------------------------------------------------------------- users and groups


def user_name() -> str:
    uid = os.geteuid()
    try:
        return pwd.getpwuid(uid).pw_name
    except KeyError:
        return f"uid {uid}"


def group_name(gid: int) -> str:
    try:
        return grp.getgrgid(gid).gr_name
    except KeyError:
        return str(gid)


def mode_text(node_stat: os.stat_result) -> str:
    """`crw------- root:root`, as `ls -l` shows it."""
    try:
        owner = pwd.getpwuid(node_stat.st_uid).pw_name
    except KeyError:
        owner = str(node_stat.st_uid)
    return f"{stat.filemode(node_stat.st_mode)} {owner}:{group_name(node_stat.st_gid)}"


def join_group_fix(group: str) -> str:
    """How this user comes to be in `group`: added, or only a new login when already in
    the group database (a session's groups are fixed at login)."""
    user = user_name()
    try:
        entry = pwd.getpwuid(os.geteuid())
        gid = grp.getgrnam(group).gr_gid
        listed = gid in os.getgrouplist(entry.pw_name, entry.pw_gid)
    except KeyError:
        listed = False
    if listed:
        return f"{user} is in it since this session began: log out and in again"
    return f"`sudo usermod -aG {group} {user}`, then log out and in again"


# --------------------------------------------------------------------------- ports


def output_findings(used: UsedPort) -> Iterator[Finding]:
    """The output's port, who holds it, then its far end (while the port allows it)."""
    assert used.port is not None  # load_runnable refuses an output without one
    url = used.port
    subject = f"{used.name} {url}"
    if not is_udp_url(url):
        device = device_path(url)
        if "://" not in device:
            blocking = [*local_port_findings(subject, device)]
            yield from blocking
            if not all(f.ok for f in blocking):
                return
    yield far_end_finding(used, subject)


def local_port_findings(subject: str, device: str) -> Iterator[Finding]:
    """A device path's presence, this user's access to it and its holders (each stops
    the next: a port that is not there has no access to check)."""
    if not os.path.exists(device):
        found = "not there" + (f" ({device} links to nothing)" if os.path.islink(device) else "")
        fix = f"plug the adapter in, or give its path: {PORTS_LISTING}"
        if is_pi_uart(device):
            fix += "; on a Pi the GPIO UART is there once enabled (the `pi uart` check below)"
        yield Finding("port", subject, False, found, fix)
        return
    if not os.access(device, os.R_OK | os.W_OK):
        port_stat = os.stat(device)
        found = f"user {user_name()} may not read and write it ({mode_text(port_stat)})"
        group = group_name(port_stat.st_gid)
        fix = f"join group {group}: {join_group_fix(group)}"
        if group == "dialout":
            fix += " (the usb2rc service has dialout already: SupplementaryGroups=dialout)"
        yield Finding("port access", subject, False, found, fix)
        return
    yield Finding("port access", subject, True, f"user {user_name()} can read and write it")
    holders = _holders(device)
    if holders:
        found = "in use by " + ", ".join(escape(str(h)) for h in holders)
        yield Finding("port holder", subject, False, found, _holder_fix(holders))
        return
    yield Finding("port holder", subject, True, "no other process has it open")


def _holders(device: str) -> list[Holder]:
    """Who locked the port, else who has it open (this process left out)."""
    own = os.getpid()
    locking = [Holder(pid, command_line(pid)) for pid in lock_holders(device) if pid != own]
    return locking or [h for h in port_holders(device) if h.pid != own]


def _holder_fix(holders: list[Holder]) -> str:
    if any("usb2rc" in h.command for h in holders):
        return (
            "a usb2rc has it (the service, if installed: `sudo systemctl stop usb2rc` frees "
            "it; while it runs, its log and `usb2rc web` show the line); one line carries "
            "one usb2rc"
        )
    if any(re.search(r"\bgetty\b|agetty", h.command) for h in holders):
        return "a login console runs on it: turn the serial console off (docs/PI.md, the UART)"
    return "stop that process, or give usb2rc another port"


# --------------------------------------------------------------------------- far ends


class Line(Protocol):
    """What a far-end check talks through: bytes out, bytes in until a time."""

    def send(self, data: bytes) -> None: ...

    def receive(self, until: float) -> bytes:
        """What arrived, once anything did; b"" at `until` (time.monotonic())."""
        ...

    def close(self) -> None: ...


class SerialLine:
    """A serial port (any pyserial URL), locked as usb2rc locks it: a running usb2rc's
    line is never shared."""

    def __init__(self, url: str, baudrate: int) -> None:
        import serial

        self.port = serial.serial_for_url(url, baudrate=baudrate, timeout=0, exclusive=True)

    def set_baudrate(self, baudrate: int) -> None:
        self.port.baudrate = baudrate
        self.port.reset_input_buffer()  # what came at another rate is noise at this one

    def send(self, data: bytes) -> None:
        self.port.write(data)

    def receive(self, until: float) -> bytes:
        left = until - time.monotonic()
        if left <= 0:
            return b""
        self.port.timeout = left
        first = bytes(self.port.read(1))
        return first + bytes(self.port.read(self.port.in_waiting)) if first else b""

    def close(self) -> None:
        self.port.close()


class UdpLine:
    """MAVLink's UDP address through the daemon's own `UdpLink`: a udpin port takes only a
    vehicle's call (`calls_us`), as the output does."""

    def __init__(self, url: str, calls_us: Callable[[bytes], bool]) -> None:
        from usb2rc.lines.udp_link import UdpLink

        self.link = UdpLink(url, calls_us)
        self.link.open_now()
        if self.link.stats.opens == 0:  # no socket: the address, or a port another has
            raise OSError(self.link.last_error)

    def send(self, data: bytes) -> None:
        self.link.write(data)  # a udpin port nobody has called yet sends nothing

    def receive(self, until: float) -> bytes:
        while True:
            chunks = self.link.take_received()
            if chunks:
                return b"".join(data for data, _ in chunks)
            left = until - time.monotonic()
            if left <= 0:
                return b""
            time.sleep(min(UDP_POLL_S, left))

    def close(self) -> None:
        self.link.close()


def far_end_finding(used: UsedPort, subject: str) -> Finding:
    """The far end's answer, through the output's port (opened here, closed after)."""
    probe = FAR_END_PROBES.get(used.output.protocol)
    if probe is None:
        found = (
            f"{used.output.protocol} far ends send nothing back, so there is nothing to ask "
            "(`usb2rc decode` on the far end's wires shows what arrives there)"
        )
        return Finding("far end", subject, True, found)
    try:
        return probe(used, subject)
    except OSError as exc:  # pyserial's SerialException is one
        return _open_failed(subject, used.port or "", exc)


def _open_failed(subject: str, url: str, exc: OSError) -> Finding:
    text = str(exc).strip() or type(exc).__name__
    if is_held(exc) or "Address already in use" in text:
        fix = "another process has it: a usb2rc service? `sudo systemctl stop usb2rc` frees it"
        return Finding("far end", subject, False, f"cannot open it: {text}", fix)
    fix = f"check the port's name ({PORTS_LISTING}) and the cable"
    return Finding("far end", subject, False, f"cannot open it: {text}", fix)


def _serial(used: UsedPort) -> SerialLine:
    assert used.port is not None
    return SerialLine(used.port, used.output.baudrate)


def probe_c2_16b(used: UsedPort, subject: str) -> Finding:
    """Any byte from the far end within C2_16B_LISTEN_S (it sends requests, `<` and `4`)."""
    baud = used.output.baudrate
    line = _serial(used)
    try:
        start = time.monotonic()
        data = line.receive(start + C2_16B_LISTEN_S)
        took = time.monotonic() - start
    finally:
        line.close()
    facts = {"baudrate": baud, "bytes": len(data)}
    if data:
        found = f"alive: {len(data)} bytes from it within {took:.1f} s at {baud} baud"
        return Finding("far end", subject, True, found, facts=facts)
    found = f"nothing from it in {C2_16B_LISTEN_S:.0f} s at {baud} baud"
    fix = (
        f"its TX to this port's RX, GND to GND, both ends at {baud} baud; a far end that "
        "sends no requests (`<`, `4`) is silent anyway: then `usb2rc decode` on its side "
        "shows whether usb2rc's frames arrive"
    )
    return Finding("far end", subject, False, found, fix, facts)


def probe_crsf(used: UsedPort, subject: str) -> Finding:
    """A device ping answered by device info: at the configured rate, else the others."""
    configured = used.output.baudrate
    rates = [configured, *(rate for rate in CRSF_BAUDRATES if rate != configured)]
    ping = encode_device_ping(int(used.output.option("address")))
    heard: dict[int, int] = {}  # rate -> CRSF frames from the far end, none a device info
    line = _serial(used)
    try:
        for rate in rates:
            try:
                line.set_baudrate(rate)
            except (OSError, ValueError):  # a rate the adapter cannot make
                continue
            listen_s = CRSF_CONFIGURED_LISTEN_S if rate == configured else CRSF_LISTEN_S
            device, frames = ping_at(line, ping, listen_s)
            if device is not None:
                return _crsf_answer(subject, device, rate, configured)
            heard[rate] = frames
    finally:
        line.close()
    return _crsf_silence(subject, heard)


def ping_at(line: Line, ping: bytes, listen_s: float) -> tuple[CrsfDevice | None, int]:
    """Ping for `listen_s`; the device info that answered first, and how many other CRSF
    frames came (the ping's own echo on a one-wire line left out)."""
    decoder = crsf.CrsfDecoder()
    deadline = time.monotonic() + listen_s
    next_ping = time.monotonic()
    others = 0
    while (now := time.monotonic()) < deadline:
        if now >= next_ping:
            line.send(ping)
            next_ping = now + CRSF_PING_INTERVAL_S
        for frame in decoder.feed(line.receive(min(next_ping, deadline))):
            device = device_info_of(frame)
            if device is not None:
                return device, others
            own_ping = isinstance(frame, crsf.OtherFrame) and frame.type == TYPE_DEVICE_PING
            others += not own_ping
    return None, others


def _crsf_answer(subject: str, device: CrsfDevice, rate: int, configured: int) -> Finding:
    who = escape(f"{device.name} ({device.maker} firmware {device.firmware})")
    facts = {
        "module": device.name,
        "firmware": device.firmware,
        "maker": device.maker,
        "baudrate": rate,
        "configured_baudrate": configured,
    }
    if rate == configured:
        return Finding("far end", subject, True, f"{who} answers at {rate} baud", facts=facts)
    found = f"{who} answers at {rate} baud, not at the configured {configured}"
    fix = f"set `baudrate: {rate}` for this output, or set the module to {configured} baud"
    return Finding("far end", subject, False, found, fix, facts)


def _crsf_silence(subject: str, heard: dict[int, int]) -> Finding:
    """No device info at any rate tried (the adapter's refused rates are not in `heard`)."""
    rates = ", ".join(map(str, heard)) or "no rate (the adapter took none)"
    talking = [rate for rate, frames in heard.items() if frames]
    if talking:
        found = (
            f"no device info at {rates} baud; CRSF frames came at {talking[0]} baud "
            f"({heard[talking[0]]}), but no answer to a device ping"
        )
        fix = f"set `baudrate: {talking[0]}`; a far end that never answers pings says no more"
    else:
        found = f"no answer to a device ping at {rates} baud"
        fix = (
            "power the module, cross TX and RX (its CRSF RX to this port's TX), GND to GND; "
            "a module on a one-wire S.Port pin needs a half-duplex adapter"
        )
    return Finding("far end", subject, False, found, fix, {"frames_by_baudrate": heard})


def probe_mavlink(used: UsedPort, subject: str) -> Finding:
    """A vehicle's HEARTBEAT within HEARTBEAT_LISTEN_S, usb2rc's GCS heartbeat sent
    meanwhile; signed both ways when the output signs."""
    from pymavlink.dialects.v20 import common as mavlink2

    from usb2rc.protocols.mavlink.codec import MavlinkDecoder, set_up_signing
    from usb2rc.protocols.mavlink.session import VehicleCall

    options = MavlinkOptions.of(used.output)
    try:
        key = read_signing_key(options.signing_key_file) if options.signing_key_file else None
    except SigningKeyError as exc:
        return Finding("far end", subject, False, f"cannot sign: {exc}")
    mav = mavlink2.MAVLink(None, srcSystem=options.system_id, srcComponent=options.component_id)
    if key is not None:
        set_up_signing(mav, key, time.time(), sign_outgoing=True)
    assert used.port is not None
    if is_udp_url(used.port):
        # any vehicle's call is taken (the output takes only target_system's): a vehicle of
        # another system id is then named, with the target_system that would take it
        line: Line = UdpLine(used.port, VehicleCall(0, key, time.time()))
    else:
        line = _serial(used)
    watch = HeartbeatWatch(options.target_system, MavlinkDecoder(key, time.time()))
    try:
        heartbeat = watch.listen(line, lambda: _gcs_heartbeat(mav))
    finally:
        line.close()
    return watch.finding(subject, heartbeat)


def _gcs_heartbeat(mav: Any) -> bytes:
    from pymavlink.dialects.v20 import common as mavlink2

    message = mav.heartbeat_encode(
        mavlink2.MAV_TYPE_GCS, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, mavlink2.MAV_STATE_ACTIVE
    )
    return bytes(message.pack(mav))


class HeartbeatWatch:
    """The far end's messages, looked through for a vehicle's HEARTBEAT (not a ground
    station's) from the target system (any system when 0)."""

    def __init__(self, target_system: int, decoder: Any) -> None:
        self.target_system = target_system
        self.decoder = decoder
        self.other_systems: set[int] = set()  # vehicles that are not the target

    def listen(self, line: Line, heartbeat: Callable[[], bytes]) -> Any:
        """The target's HEARTBEAT message, or None after HEARTBEAT_LISTEN_S."""
        deadline = time.monotonic() + HEARTBEAT_LISTEN_S
        next_heartbeat = time.monotonic()
        while (now := time.monotonic()) < deadline:
            if now >= next_heartbeat:
                line.send(heartbeat())
                next_heartbeat = now + HEARTBEAT_INTERVAL_S
            for message in self.decoder.feed(line.receive(min(next_heartbeat, deadline))):
                if self._is_target(message):
                    return message
        return None

    def _is_target(self, message: Any) -> bool:
        from pymavlink.dialects.v20 import common as mavlink2

        if message.get_type() != "HEARTBEAT" or message.type == mavlink2.MAV_TYPE_GCS:
            return False
        system = int(message.get_srcSystem())
        if self.target_system in (0, system):
            return True
        self.other_systems.add(system)
        return False

    def finding(self, subject: str, heartbeat: Any) -> Finding:
        if heartbeat is not None:
            return self._answered(subject, heartbeat)
        if self.other_systems:
            systems = ", ".join(map(str, sorted(self.other_systems)))
            found = (
                f"heartbeats from system {systems}, none from target_system {self.target_system}"
            )
            fix = f"set `target_system: {min(self.other_systems)}` for this output (0: any)"
            return Finding("far end", subject, False, found, fix)
        found = f"no vehicle HEARTBEAT in {HEARTBEAT_LISTEN_S:.0f} s"
        if self.decoder.bad_signatures:
            found += f" ({self.decoder.bad_signatures} messages not signed with the key)"
        fix = (
            "check the address and that the vehicle (or its router) sends there; on a serial "
            "line its TX to this port's RX, GND to GND and the same baud rate both ends"
        )
        return Finding("far end", subject, False, found, fix)

    def _answered(self, subject: str, heartbeat: Any) -> Finding:
        from pymavlink.dialects.v20 import common as mavlink2

        kind = _enum_name(mavlink2, "MAV_TYPE", int(heartbeat.type))
        autopilot = _enum_name(mavlink2, "MAV_AUTOPILOT", int(heartbeat.autopilot))
        system = int(heartbeat.get_srcSystem())
        found = f"vehicle system {system} heartbeats ({kind}, {autopilot})"
        facts = {"system": system, "type": kind, "autopilot": autopilot}
        return Finding("far end", subject, True, found, facts=facts)


def _enum_name(dialect: Any, enum: str, value: int) -> str:
    entry = dialect.enums.get(enum, {}).get(value)
    return str(entry.name) if entry is not None else str(value)


# Each protocol whose far end answers, and how it is asked.
FAR_END_PROBES: dict[str, Callable[[UsedPort, str], Finding]] = {
    "c2-16b": probe_c2_16b,
    "crsf": probe_crsf,
    "mavlink": probe_mavlink,
}


# --------------------------------------------------------------------------- Raspberry Pi

MODEL_FILES = ("/proc/device-tree/model", "/sys/firmware/devicetree/base/model")
CMDLINE_FILES = ("/boot/firmware/cmdline.txt", "/boot/cmdline.txt")
BOOT_CONFIG_FILES = ("/boot/firmware/config.txt", "/boot/config.txt")
PI_UART_LINKS = ("/dev/serial0", "/dev/serial1")
PI_UART = re.compile(r"^/dev/(ttyAMA\d+|ttyS\d+)$")
SERIAL_CONSOLE = re.compile(r"^console=(serial\d|ttyAMA\d+|ttyS\d+)(,|$)")
PI_SETUP = "docs/PI.md, the UART; or `sudo raspi-config`, Interface Options, Serial Port"


def pi_findings(files: SystemFiles, used: Sequence[UsedPort] | None) -> Iterator[Finding]:
    """On a Raspberry Pi whose GPIO UART an output uses (or any, when the config did not
    load): the UART enabled, and no serial console on it."""
    model = pi_model(files)
    if model is None:
        yield Finding("pi", "this machine", True, "not a Raspberry Pi: no UART to set up")
        return
    if used is not None and not any(u.port and is_pi_uart(u.port) for u in used):
        found = "no output uses the GPIO UART (/dev/serial0): its settings do not matter"
        yield Finding("pi", model, True, found)
        return
    yield uart_finding(files, model)
    yield console_finding(files, model)


def pi_model(files: SystemFiles) -> str | None:
    """The board's model when it is a Raspberry Pi (the device tree's model string)."""
    for path in MODEL_FILES:
        text = files.read(path)
        if text is not None and "Raspberry Pi" in text:
            return escape(text.strip("\0\n "))
    return None


def is_pi_uart(port: str) -> bool:
    return port in PI_UART_LINKS or bool(PI_UART.match(os.path.realpath(port)))


def uart_finding(files: SystemFiles, model: str) -> Finding:
    """`enable_uart=1` in config.txt (the last setting wins; section filters are not
    evaluated)."""
    path = files.first(BOOT_CONFIG_FILES)
    if path is None:
        found = f"no {' or '.join(BOOT_CONFIG_FILES)}: cannot tell whether the UART is on"
        return Finding("pi uart", model, False, found, f"mount the boot partition; {PI_SETUP}")
    settings = re.findall(r"(?m)^\s*enable_uart\s*=\s*(\d+)", files.read(path) or "")
    if settings and settings[-1] == "1":
        return Finding("pi uart", model, True, f"enable_uart=1 in {path}")
    said = f"enable_uart={settings[-1]}" if settings else "no enable_uart"
    fix = f"add `enable_uart=1` to {path} and reboot ({PI_SETUP})"
    return Finding("pi uart", model, False, f"the GPIO UART is off ({said} in {path})", fix)


def console_finding(files: SystemFiles, model: str) -> Finding:
    """No `console=serial0,...` (or the UART's own name) on the kernel's command line."""
    path = files.first(CMDLINE_FILES)
    if path is None:
        found = f"no {' or '.join(CMDLINE_FILES)}: cannot tell whether a console is on the UART"
        return Finding("pi console", model, False, found, f"mount the boot partition; {PI_SETUP}")
    consoles = [w for w in (files.read(path) or "").split() if SERIAL_CONSOLE.match(w)]
    if not consoles:
        return Finding("pi console", model, True, f"no serial console in {path}")
    found = f"a login console is on the UART ({' '.join(consoles)} in {path})"
    fix = f"remove {' '.join(consoles)} from {path} (keep the rest of its line), reboot"
    return Finding("pi console", model, False, found, f"{fix} ({PI_SETUP})")


# --------------------------------------------------------------------------- service


def service_finding() -> Finding:
    """The usb2rc service's state, from `systemctl show` (`is-active` says `inactive`
    alike for a unit that is not installed and one that is stopped)."""
    systemctl = shutil.which("systemctl")
    if systemctl is None:
        return Finding("service", SERVICE, True, "no systemd here: run by hand")
    properties = "--property=LoadState,ActiveState,SubState,UnitFileState"
    try:
        done = subprocess.run(
            [systemctl, "show", properties, SERVICE],
            capture_output=True,
            text=True,
            timeout=30,
            check=False,
        )
    except (OSError, subprocess.TimeoutExpired) as exc:
        return Finding("service", SERVICE, False, f"`systemctl show` failed: {exc}")
    if done.returncode != 0:
        why = (done.stderr.strip().splitlines() or ["no answer"])[0]
        return Finding(
            "service", SERVICE, True, f"systemd is not running here ({why}): not checked"
        )
    state = dict(line.split("=", 1) for line in done.stdout.splitlines() if "=" in line)
    return service_state_finding(state)


def service_state_finding(state: dict[str, str]) -> Finding:
    load, active = state.get("LoadState", ""), state.get("ActiveState", "")
    sub, enabled = state.get("SubState", ""), state.get("UnitFileState", "") or "?"
    facts = {"load": load, "active": active, "sub": sub, "enabled": enabled}
    if load == "not-found":
        found = (
            "not installed: fine when running by hand (`sudo usb2rc install-system` installs it)"
        )
        return Finding("service", SERVICE, True, found, facts=facts)
    journal = "`journalctl -u usb2rc -n 50` says why; after the fix `sudo systemctl restart usb2rc`"
    if active == "failed" or sub == "auto-restart":
        found = f"{active} ({sub}): it stopped on an error"
        return Finding("service", SERVICE, False, found, journal, facts)
    if active == "active":
        return Finding("service", SERVICE, True, f"active ({sub}), {enabled} at boot", facts=facts)
    found = f"{active} ({sub}), {enabled} at boot: fine when running by hand"
    if enabled != "enabled":
        found += "; `sudo systemctl enable --now usb2rc` runs it from now on and at boot"
    return Finding("service", SERVICE, True, found, facts=facts)
