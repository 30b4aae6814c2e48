"""Whether pyserial can parse a port name: a usage error, told apart from a missing cable.

`serial_for_url` fails the same way (an exception at open) for `foo://bar`, which can never
work, and for `/dev/ttyUSB0` while the adapter is unplugged, which the daemon retries every
second. This checks the first kind without opening anything, so the command line and the
config can refuse it at start (exit 2). So is a device's bare name (`ttyUSB0`): pyserial
opens it as a file in the current folder, which is never the adapter; it gets a
did-you-mean `/dev/ttyUSB0` (unless the folder has a file of that name).
"""

from __future__ import annotations

import importlib
import os
import re
import sys
from typing import Any

import serial

# URL handlers whose `from_url` only parses the text. Others do more: `spy://` opens its log
# file, `hwgrep://` searches the ports present (no match is a missing cable, not a typo).
PARSE_ONLY_HANDLERS = ("socket", "rfc2217", "loop")
# How the kernel names serial devices under /dev (a bare name like these is a slip).
SERIAL_DEVICE_NAME = re.compile(r"^(tty|cu\.|serial|rfcomm)")
UDP_SCHEMES = ("udpout:", "udpin:")  # MAVLink's UDP addresses (config/udp_url.py)


def url_problem(url: str) -> str | None:
    """None if pyserial can parse `url`, else why not (one line). Opens nothing."""
    scheme, sep, _rest = url.partition("://")
    if not sep:
        return None  # a device path (/dev/ttyUSB0, COM3): absent or not, it is a port name
    if not _has_handler(scheme.lower()):
        return f"invalid URL, protocol {scheme!r} not known"
    if scheme.lower() not in PARSE_ONLY_HANDLERS:
        return None
    try:
        port: Any = serial.serial_for_url(url, do_not_open=True)  # the handler's own class
        port.from_url(url)
    except Exception as exc:  # socket://host without a port raises TypeError (pyserial)
        return _reason(exc)
    return None


def _has_handler(scheme: str) -> bool:
    """As serial_for_url looks a protocol up, without its `serial_class_for_url` (which
    for hwgrep:// already searches the ports)."""
    for package in serial.protocol_handler_packages:
        try:
            importlib.import_module(f"{package}.protocol_{scheme}")
        except ImportError:
            continue
        return True
    return False


def _reason(exc: Exception) -> str:
    if isinstance(exc, KeyError):  # an unknown ?option or value
        return f"unknown option or value {exc}"
    if isinstance(exc, TypeError):
        return "expected host:port"
    return str(exc) or type(exc).__name__


def port_name_problem(port: str) -> str | None:
    """Why `port` can never be a port (the whole message), or None. Opens nothing."""
    problem = url_problem(port)
    if problem is not None:
        return f"{port!r} is not a port pyserial can open: {problem}"
    device = bare_device_name(port)
    if device is not None:
        return f"{port!r} is a name, not a path: did you mean {device}?"
    return None


def bare_device_name(port: str) -> str | None:
    """`/dev/ttyUSB0` for `ttyUSB0`: a device's name given without its folder, which no
    file of that name in the current folder explains; None otherwise."""
    if sys.platform == "win32" or "/" in port or port.startswith(UDP_SCHEMES):
        return None
    if os.path.exists(port):
        return None  # a file of that name here (a link to the port, say): meant as it is
    device = f"/dev/{port}"
    if os.path.exists(device) or SERIAL_DEVICE_NAME.match(port):
        return device
    return None


def port_argument(value: str) -> str:
    """argparse `type=` for --port: a name that can never be a port is a usage error."""
    import argparse

    problem = port_name_problem(value)
    if problem is not None:
        raise argparse.ArgumentTypeError(problem)
    return value
