"""A umockdev testbed of USB HID joysticks, driven over stdin/stdout (JSON lines).

Run by Debian's python3 (it needs `gi` and the UMockdev typelib, which the project venv does
not have): `/usr/bin/python3 tests/umockdev_bed.py`. It prints `{"ok": true, "root": DIR}`
once the testbed exists; programs started with `UMOCKDEV_DIR=DIR` and
`LD_PRELOAD=libumockdev-preload.so.0` then see its /sys and /dev instead of the real ones.

Commands, one JSON object a line; each gets one JSON line back (`{"ok": false, "error": ...}`
on failure, never an exception that ends the bed):

    {"cmd": "add", "port": "1-1.2", "vid": 1103, "pid": 45322, "product": "T.16000M",
     "manufacturer": "Thrustmaster", "serial": "", "descriptor": "0501...", "mode": 0}
        -> {"ok": true, "hidraw": "/dev/hidraw0", "syspath": "/sys/devices/..."}
    {"cmd": "report", "hidraw": "/dev/hidraw0", "data": "0100..."}  -> {"ok": true, "t": T}
    {"cmd": "written", "hidraw": "/dev/hidraw0"}            -> {"ok": true, "data": "0201..."}
    {"cmd": "remove", "hidraw": "/dev/hidraw0"}          -> {"ok": true, "t": T, "closed": T2}
    {"cmd": "chmod", "hidraw": "/dev/hidraw0", "mode": 0}              -> {"ok": true}
    {"cmd": "quit"}

`written` returns what programs wrote to the node since the last `written` (output reports,
as hidapi's write() sends them: report ID first, 0 for a device without IDs), without
waiting: "" when nothing came. A pty keeps no boundaries: writes that queued come glued.

T is time.monotonic() (CLOCK_MONOTONIC, system-wide: comparable with the test's clock) taken
right after the report was written / just before the unplug began (its first uevent); T2
once the device is gone from sysfs and /dev and its pty master is closed.

What the kernel does and this copies:
- the sysfs chain PCI controller -> usbB root hub -> hubs -> the USB device at the port path
  (idVendor, idProduct, manufacturer, product, serial) -> interface :1.0 -> the hid device
  (HID_ID, HID_NAME, HID_PHYS, HID_UNIQ, binary report_descriptor) -> hidraw/hidrawN with a
  `device` link back to the hid device (hidapi reads the usage page through it, usb2rc the
  port path) and `dev` = major:minor;
- the node is a pty, as umockdev makes it for an emulated char device, but made here: it is
  set raw, so report bytes such as 0x03, 0x11, 0x13 or 0x16 reach the reader unchanged
  instead of being taken as signal, flow-control or literal-next characters by the tty line
  discipline, and it exists with its mode (`"mode"` in `add`) before sysfs lists the device;
- ioctl replies for HIDIOCGRDESCSIZE and HIDIOCGRDESC (hidapi's open_path needs the first,
  get_report_descriptor the second: the whole 4100-byte struct);
- uevents (seen by pyudev's netlink monitor in the preloaded process, so the daemon's
  hot-plug thread wakes on them as on a real system): "add" from umockdev itself when the
  chain is added, "remove" from here;
- unplug: remove uevents and sysfs removal bottom-up (hidraw, hid, interface, USB device),
  then the pty master is closed so a reader blocked in poll() wakes with POLLHUP, as a real
  hidraw reader wakes when the kernel marks the device gone;
- a node added later never reuses a minor number or name (a reader still holding the old
  node must never find a new device behind it).
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import struct
import sys
import tempfile
import time
import tty
from dataclasses import dataclass
from typing import Any

import gi

gi.require_version("UMockdev", "1.0")
from gi.repository import UMockdev  # noqa: E402

HIDRAW_MAJOR = 240
HID_MAX_DESCRIPTOR_SIZE = 4096
CONTROLLER = "/devices/pci0000:00/0000:00:14.0"


@dataclass
class Plugged:
    usb: str  # sysfs paths without /sys, top to bottom
    interface: str
    hid: str
    hidraw: str
    node: str  # /dev/hidrawN
    master: int  # the pty master: the device's side of the node
    pty: str  # the pty slave the node stands for: /dev/pts/N


def record(path: str, lines: list[str]) -> str:
    """One device in umockdev-record format (P: line, then properties/attributes)."""
    return "\n".join([f"P: {path}", *lines]) + "\n\n"


def ioctl_record(node: str, descriptor: bytes) -> str:
    size = struct.pack("<i", len(descriptor))
    desc = struct.pack("<I", len(descriptor)) + descriptor.ljust(HID_MAX_DESCRIPTOR_SIZE, b"\0")
    return f"@DEV {node}\nHIDIOCGRDESCSIZE 0 {size.hex()}\nHIDIOCGRDESC 0 {desc.hex()}\n"


ROOT_HUB = ["A: idVendor=1d6b", "A: idProduct=0002", "A: bDeviceClass=09"]
HUB = ["A: idVendor=05e3", "A: idProduct=0610", "A: product=USB2.0 Hub", "A: bDeviceClass=09"]


@dataclass(frozen=True)
class Stick:
    """What an `add` command plugs."""

    port: str
    vid: int
    pid: int
    product: str
    manufacturer: str
    serial: str
    descriptor: bytes

    @classmethod
    def from_command(cls, cmd: dict[str, Any]) -> Stick:
        return cls(
            port=cmd["port"],
            vid=int(cmd["vid"]),
            pid=int(cmd["pid"]),
            product=cmd.get("product", ""),
            manufacturer=cmd.get("manufacturer", ""),
            serial=cmd.get("serial", ""),
            descriptor=bytes.fromhex(cmd["descriptor"]),
        )


@dataclass(frozen=True)
class Chain:
    """The sysfs paths (without /sys) of one plugged stick, top to bottom, and its node."""

    usb: str
    interface: str
    hid: str
    hidraw: str
    node: str

    @classmethod
    def at(cls, hub: str, stick: Stick, minor: int, hid_no: int) -> Chain:
        usb = f"{hub}/{stick.port}"
        interface = f"{usb}/{stick.port}:1.0"
        hid = f"{interface}/0003:{stick.vid:04X}:{stick.pid:04X}.{hid_no:04X}"
        return cls(usb, interface, hid, f"{hid}/hidraw/hidraw{minor}", f"/dev/hidraw{minor}")

    def records(self, stick: Stick, minor: int) -> str:
        """The four devices in umockdev-record format."""
        bus, _, ports = stick.port.partition("-")
        usb = [
            "E: SUBSYSTEM=usb",
            "E: DEVTYPE=usb_device",
            f"A: busnum={bus}",
            f"A: devnum={100 + minor}",
            f"A: idVendor={stick.vid:04x}",
            f"A: idProduct={stick.pid:04x}",
        ]
        usb += [f"A: manufacturer={stick.manufacturer}"] if stick.manufacturer else []
        usb += [f"A: product={stick.product}"] if stick.product else []
        usb += [f"A: serial={stick.serial}"] if stick.serial else []  # none: no attribute
        interface = [
            "E: SUBSYSTEM=usb",
            "E: DEVTYPE=usb_interface",
            "E: INTERFACE=3/0/0",
            "A: bInterfaceNumber=00",
            "A: bInterfaceClass=03",
        ]
        hid = [
            "E: SUBSYSTEM=hid",
            f"E: HID_ID=0003:0000{stick.vid:04X}:0000{stick.pid:04X}",
            "E: HID_NAME=" + f"{stick.manufacturer} {stick.product}".strip(),
            f"E: HID_PHYS=usb-0000:00:14.0-{ports}/input0",
            f"E: HID_UNIQ={stick.serial}",
            f"H: report_descriptor={stick.descriptor.hex().upper()}",
        ]
        hidraw = [
            "L: device=../..",  # the kernel's link back to the hid device
            "E: SUBSYSTEM=hidraw",
            f"E: DEVNAME={self.node}",
            f"E: MAJOR={HIDRAW_MAJOR}",
            f"E: MINOR={minor}",
            f"A: dev={HIDRAW_MAJOR}:{minor}",
        ]
        return (
            record(self.usb, usb)
            + record(self.interface, interface)
            + record(self.hid, hid)
            + record(self.hidraw, hidraw)
        )


class Bed:
    def __init__(self) -> None:
        self.testbed = UMockdev.Testbed.new()
        self.root = self.testbed.get_root_dir()
        self.work = tempfile.mkdtemp(prefix="usb2rc-bed-")
        self.hubs: set[str] = set()  # sysfs paths of root hubs and hubs already made
        self.plugged: dict[str, Plugged] = {}
        self.next_minor = 0
        self.next_hid = 1

    # --- building the sysfs chain -------------------------------------------------------------

    def _add(self, text: str) -> None:
        self.testbed.add_from_string(text)

    def _uevent(self, syspath: str, action: str) -> None:
        self.testbed.uevent("/sys" + syspath, action)

    def _hub(self, path: str, lines: list[str]) -> None:
        if path not in self.hubs:
            self._add(record(path, ["E: SUBSYSTEM=usb", "E: DEVTYPE=usb_device", *lines]))
            self.hubs.add(path)

    def _hub_chain(self, port: str) -> str:
        """Make the root hub and the hubs above `port` ("1-1.2": usb1, 1-1); their path."""
        bus, _, ports = port.partition("-")
        parent = f"{CONTROLLER}/usb{bus}"
        self._hub(parent, [f"A: busnum={bus}", "A: devnum=1", *ROOT_HUB])
        steps = ports.split(".")
        for depth in range(1, len(steps)):
            path = f"{parent}/{bus}-{'.'.join(steps[:depth])}"
            self._hub(path, [f"A: busnum={bus}", f"A: devnum={10 + len(self.hubs)}", *HUB])
            parent = path
        return parent

    def add(self, cmd: dict[str, Any]) -> dict[str, Any]:
        stick = Stick.from_command(cmd)
        if any(p.usb.endswith(f"/{stick.port}") for p in self.plugged.values()):
            raise ValueError(f"port {stick.port} already has a device")
        minor, hid_no = self.next_minor, self.next_hid
        self.next_minor += 1
        self.next_hid += 1
        chain = Chain.at(self._hub_chain(stick.port), stick, minor, hid_no)
        ioctl_file = os.path.join(self.work, f"hidraw{minor}.ioctl")
        with open(ioctl_file, "w") as f:
            f.write(ioctl_record(chain.node, stick.descriptor))
        self.testbed.load_ioctl(chain.node, ioctl_file)
        master, pty = self._make_node(chain.node, minor, cmd.get("mode"))
        # add_from_string sends the "add" uevents itself (umockdev >= 0.13): none from here,
        # or every device would be announced twice
        self._add(chain.records(stick, minor))
        self.plugged[chain.node] = Plugged(
            chain.usb, chain.interface, chain.hid, chain.hidraw, chain.node, master, pty
        )
        return {"hidraw": chain.node, "syspath": "/sys" + chain.usb}

    def _make_node(self, node: str, minor: int, mode: int | None) -> tuple[int, str]:
        """The device node, made here rather than by umockdev (an `N:` line) so that it
        exists, with its final mode, before sysfs lists the device: a program that finds
        the device never finds its node missing or about to change its permissions."""
        master, slave = os.openpty()
        pty = os.ttyname(slave)
        os.close(slave)  # the device side is the master; the reader opens the slave
        tty.setraw(master)  # termios of the node: raw, no ISIG/IXON/IEXTEN on report bytes
        if mode is not None:
            os.chmod(pty, mode)
        # what umockdev's own node creation records: pty -> major:minor, for stat()
        ptymap = self._in_root("/dev/.ptymap")
        os.makedirs(ptymap, exist_ok=True)
        os.symlink(f"{HIDRAW_MAJOR}:{minor}", os.path.join(ptymap, pty.replace("/", "_")))
        tmp = self._in_root(node + ".new")
        os.symlink(pty, tmp)
        os.rename(tmp, self._in_root(node))  # appears whole
        return master, pty

    # --- what a device does -------------------------------------------------------------------

    def _plugged(self, cmd: dict[str, Any]) -> Plugged:
        node = cmd["hidraw"]
        if node not in self.plugged:
            raise KeyError(f"{node} is not plugged")
        return self.plugged[node]

    def report(self, cmd: dict[str, Any]) -> dict[str, Any]:
        dev = self._plugged(cmd)
        data = bytes.fromhex(cmd["data"])
        written = os.write(dev.master, data)
        if written != len(data):
            raise OSError(f"short write to {dev.node}: {written} of {len(data)} bytes")
        return {"t": time.monotonic()}

    def written(self, cmd: dict[str, Any]) -> dict[str, Any]:
        """What was written to the node (its pty slave) since the last call: the master's
        side, read without blocking."""
        dev = self._plugged(cmd)
        chunks = []
        os.set_blocking(dev.master, False)
        try:
            while chunk := os.read(dev.master, 4096):
                chunks.append(chunk)
        except BlockingIOError:
            pass  # nothing more queued
        except OSError as exc:  # EIO: no program has the node open (and nothing is queued)
            if exc.errno != errno.EIO:
                raise
        finally:
            os.set_blocking(dev.master, True)  # reports are written blocking
        return {"data": b"".join(chunks).hex()}

    def remove(self, cmd: dict[str, Any]) -> dict[str, Any]:
        dev = self.plugged.pop(cmd["hidraw"]) if cmd["hidraw"] in self.plugged else None
        if dev is None:
            raise KeyError(f"{cmd['hidraw']} is not plugged")
        yanked = time.monotonic()  # the unplug starts: a watcher of uevents may act at once
        for path in (dev.hidraw, dev.hid, dev.interface, dev.usb):  # children first
            self._uevent(path, "remove")  # remove_device sends none itself
            self.testbed.remove_device("/sys" + path)
        os.close(dev.master)  # readers blocked in poll() wake with POLLHUP
        closed = time.monotonic()
        # umockdev maps each pty to its node's major:minor in dev/.ptymap and asserts when a
        # new node gets a pty number it has seen: the closed pty's number is free again.
        stale = self._in_root("/dev/.ptymap/" + dev.pty.replace("/", "_"))
        if os.path.lexists(stale):
            os.unlink(stale)
        return {"t": yanked, "closed": closed}

    def chmod(self, cmd: dict[str, Any]) -> dict[str, Any]:
        dev = self._plugged(cmd)
        # /dev/hidrawN in the testbed is a symlink to the pty slave: chmod follows it
        os.chmod(self._in_root(dev.node), int(cmd["mode"]))
        return {}

    def _in_root(self, path: str) -> str:
        return os.path.join(self.root, path.lstrip("/"))

    def close(self) -> None:
        shutil.rmtree(self.root, ignore_errors=True)
        shutil.rmtree(self.work, ignore_errors=True)


def serve(bed: Bed) -> None:
    handlers = {
        "add": bed.add,
        "report": bed.report,
        "written": bed.written,
        "remove": bed.remove,
        "chmod": bed.chmod,
    }
    for line in sys.stdin:
        if not line.strip():
            continue
        try:
            cmd = json.loads(line)
            if cmd.get("cmd") == "quit":
                break
            reply: dict[str, Any] = {"ok": True, **handlers[cmd["cmd"]](cmd)}
        except Exception as exc:  # a bad command is answered, never fatal
            reply = {"ok": False, "error": f"{type(exc).__name__}: {exc}"}
        print(json.dumps(reply), flush=True)


def main() -> None:
    bed = Bed()
    print(json.dumps({"ok": True, "root": bed.root}), flush=True)
    try:
        serve(bed)
    finally:
        bed.close()
    sys.stdout.flush()
    # No Testbed destructor: it would close the pty masters closed at unplug a second time
    # (by then those numbers may belong to other files) and the root is already removed.
    os._exit(0)


if __name__ == "__main__":
    main()
