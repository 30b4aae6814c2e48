"""`usb2rc init [--replay DIR] [-o FILE] [--port PORT] [--force]`: a starter config.

Writes a config with one entry per joystick-like device plugged in now (or each recording in
DIR): matched by vid/pid (and its serial, or USB port, when two devices are alike), its
Node-ID pinned as the automatic numbering gives it now, and its axes, buttons and first hat
written out as the default layout maps them, each line commented with the HID usage and
logical range it comes from. One SERaero C2-16B output on PORT; without --port the line is
a comment (`# port: /dev/serial0`) and `usb2rc run --port PORT` gives the port. A PORT that
exists but cannot be a serial line (/dev/null, a regular file, a directory) is refused
(exit 2): the daemon would retry it forever. The text passes `usb2rc check` as written.
Without -o it goes to stdout; an existing FILE is only replaced with --force, keeping its
owner, group and mode (a symlink: the file it points to). Next: `usb2rc calibrate --config
FILE`.
"""

from __future__ import annotations

import argparse
import os
import stat
import sys

from usb2rc.commands.arguments import replay_dir
from usb2rc.commands.list_devices import UnreadableDevice, no_devices_hint, read_layout
from usb2rc.commands.starter import PluggedDevice, SkippedDevice, device_label, starter_config
from usb2rc.config.port_url import port_argument
from usb2rc.configfile import ConfigError, load_config_text
from usb2rc.hid.choose import choose_backend
from usb2rc.hid.hotplug import initial_devices
from usb2rc.runtime.textfile import write_atomically


def add_parser(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "init",
        help="write a starter config from the devices plugged in now",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--replay",
        metavar="DIR",
        type=replay_dir,
        help="take the devices from recordings in DIR",
    )
    parser.add_argument("-o", "--output", metavar="FILE", help="write here (default: stdout)")
    parser.add_argument(
        "--port",
        type=serial_port_argument,
        help="serial port or pyserial URL of the C2-16B output (default: none, a comment)",
    )
    parser.add_argument("--force", action="store_true", help="replace FILE if it exists")
    parser.set_defaults(func=run)


def not_a_serial_line(port: str) -> str | None:
    """Why an existing path cannot be a serial line, or None (a URL, a tty, or a path not
    there now: an unplugged adapter, which the daemon waits for). Opens nothing: opening a
    serial port raises DTR, which resets some boards."""
    if "://" in port:
        return None
    try:
        st = os.stat(port)
    except OSError:
        return None
    if not stat.S_ISCHR(st.st_mode):
        return "not a character device"
    major, minor = os.major(st.st_rdev), os.minor(st.st_rdev)
    subsystem = f"/sys/dev/char/{major}:{minor}/subsystem"
    if os.path.islink(subsystem):  # ptys have no sysfs entry: accepted
        driver = os.path.basename(os.readlink(subsystem))
        if driver != "tty":
            return f"a {driver} device, not a tty"
    return None


def serial_port_argument(value: str) -> str:
    """argparse `type=` for init's --port: pyserial can parse it and it can be a serial line."""
    port = port_argument(value)
    problem = not_a_serial_line(port)
    if problem is not None:
        raise argparse.ArgumentTypeError(
            f"{value!r} cannot be a serial line ({problem}); leave --port out to write the "
            "port as a comment and give it later (`usb2rc run --port PORT`)"
        )
    return port


def read_devices(replay: str | None) -> tuple[list[PluggedDevice], list[SkippedDevice]]:
    """The usable devices present, in USB port-path order, with the ones that cannot be read."""
    backend = choose_backend(replay)
    plugged, skipped = [], []
    for info in initial_devices(backend):
        try:
            plugged.append(PluggedDevice(info, read_layout(backend, info)))
        except UnreadableDevice as exc:
            skipped.append(SkippedDevice(info, str(exc)))
    return plugged, skipped


def run(args: argparse.Namespace) -> int:
    if args.output and os.path.exists(args.output) and not args.force:
        print(f"usb2rc init: {args.output} exists; --force replaces it", file=sys.stderr)
        return 2
    try:
        plugged, skipped = read_devices(args.replay)
    except OSError as exc:
        print(f"usb2rc init: cannot enumerate HID devices: {exc}", file=sys.stderr)
        return 1
    for skip in skipped:
        print(f"usb2rc init: skipped {device_label(skip.info)}: {skip.reason}", file=sys.stderr)
    if not plugged:
        print(f"usb2rc init: {no_devices_hint(args.replay)}", file=sys.stderr)
        return 1
    text = starter_config(plugged, args.port, skipped)
    try:  # what `check` would say: a starter config that does not pass is a bug here
        load_config_text(text, args.output or "<init>")
    except ConfigError as exc:
        print(
            "\n".join(["usb2rc init: internal error, the config fails:", *exc.errors]),
            file=sys.stderr,
        )
        return 1
    if not args.output:
        sys.stdout.write(text)
        return 0
    try:
        write_atomically(args.output, text)
    except OSError as exc:
        print(f"usb2rc init: cannot write {args.output}: {exc}", file=sys.stderr)
        return 1
    names = ", ".join(p.info.product or f"{p.info.vid:04x}:{p.info.pid:04x}" for p in plugged)
    print(f"wrote {args.output}: {len(plugged)} device(s): {names}", file=sys.stderr)
    print(f"next: usb2rc calibrate --config {args.output}", file=sys.stderr)
    return 0
