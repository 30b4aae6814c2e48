"""`usb2rc record DEVICE [--seconds N] [--replay DIR]`: a device's reports, hid-recorder format.

DEVICE is a hidraw path (/dev/hidraw3), a vid:pid (044f:b10a) or, with --replay, a recording's
file stem. Writes the header (R:, N:, P:, I:) and then one E: line per report as it arrives to
stdout, flushed, until N seconds have passed or Ctrl-C.
"""

from __future__ import annotations

import argparse
import re
import sys
import time
from typing import TextIO

from usb2rc.commands.arguments import replay_dir
from usb2rc.commands.list_devices import make_backend
from usb2rc.hid.backend import Device, DeviceGone, DeviceInfo
from usb2rc.hid.recording import RecordedEvent, Recording, format_event, format_header

READ_TIMEOUT_S = 0.1
_VID_PID = re.compile(r"^([0-9a-fA-F]{1,4}):([0-9a-fA-F]{1,4})$")


def add_parser(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "record",
        help="record a device's input reports (hid-recorder format) to stdout",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("device", metavar="DEVICE", help="hidraw path, vid:pid or replay stem")
    parser.add_argument("--seconds", type=float, help="stop after this many seconds")
    parser.add_argument(
        "--replay", metavar="DIR", type=replay_dir, help="record from the recordings in DIR"
    )
    parser.set_defaults(func=run)


def matches(info: DeviceInfo, wanted: str) -> bool:
    m = _VID_PID.match(wanted)
    if m:
        return (info.vid, info.pid) == (int(m.group(1), 16), int(m.group(2), 16))
    return wanted in (info.path, info.hidraw, info.serial, info.port_path) and wanted != ""


def find_device(infos: list[DeviceInfo], wanted: str) -> DeviceInfo | None:
    usable = [i for i in infos if i.usable] + [i for i in infos if not i.usable]
    return next((i for i in usable if matches(i, wanted)), None)


def write_header(out: TextIO, info: DeviceInfo, device: Device) -> None:
    rec = Recording(device.report_descriptor(), info.product, info.port_path, 3, info.vid, info.pid)
    out.write(f"# usb2rc record {info.identity} ({info.path})\n")
    out.write("\n".join(format_header(rec)) + "\n")
    out.flush()


def record(out: TextIO, device: Device, seconds: float | None) -> None:
    start = time.monotonic()
    end = start + seconds if seconds is not None else float("inf")
    while (now := time.monotonic()) < end:
        report = device.read(min(READ_TIMEOUT_S, end - now))
        if report is not None:
            stamp = round(time.monotonic() - start, 6)
            out.write(format_event(RecordedEvent(stamp, report)) + "\n")
            out.flush()


def run(args: argparse.Namespace) -> int:
    backend = make_backend(args.replay)
    infos = backend.enumerate(all=True)
    info = find_device(infos, args.device)
    if info is None:
        present = ", ".join(f"{i.hidraw or i.serial} ({i.vid:04x}:{i.pid:04x})" for i in infos)
        print(
            f"usb2rc record: no device matches {args.device!r}; present: {present or 'none'}",
            file=sys.stderr,
        )
        return 1
    try:
        device = backend.open(info)
    except OSError as exc:
        print(f"usb2rc record: {exc.strerror or exc}", file=sys.stderr)
        return 1
    try:
        write_header(sys.stdout, info, device)
        record(sys.stdout, device, args.seconds)
    except KeyboardInterrupt:
        pass
    except DeviceGone:
        print(f"usb2rc record: {info.path} was unplugged", file=sys.stderr)
        return 1
    except BrokenPipeError:
        return 0
    except OSError as exc:
        print(f"usb2rc record: read failed: {exc.strerror or exc}", file=sys.stderr)
        return 1
    finally:
        device.close()
    return 0
