"""A real `HidapiDevice` without hidraw: its own fd is one end of a SOCK_SEQPACKET pair, which
gives one whole report a `read()` as a hidraw node does (/dev/uhid is not reachable here).
Used by tests/test_fd_pull.py and bench/bench_fd_pull.py."""

from __future__ import annotations

import socket
from collections.abc import Callable
from pathlib import Path
from typing import Any
from unittest import mock

from usb2rc.hid import hidapi_backend
from usb2rc.hid.backend import DeviceInfo
from usb2rc.hid.hidapi_backend import HidapiDevice


class SeqpacketDevice:
    """`device` reads what `sender` sends. `node`: a file standing for the hidraw node (there
    while plugged: `HidapiDevice._gone`); `handle(fd)`: the hidapi handle it is opened with,
    given the pair's reading end; `own_fd`: False, the device has no fd of its own (its
    reads go through the handle)."""

    def __init__(self, node: Path, handle: Callable[[int], Any], own_fd: bool = True) -> None:
        self.sender, self.theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        self.theirs.setblocking(False)
        fd = self.theirs.fileno()
        info = DeviceInfo(key=str(node), path=str(node), vid=1, pid=2, hidraw=str(node))
        with mock.patch.object(hidapi_backend, "open_read_fd", lambda info: fd if own_fd else None):
            self.device = HidapiDevice(info, handle(fd), None, node.parent)

    def close(self) -> None:
        self.device.read_fd = None  # the socket's own close closes it
        self.sender.close()
        self.theirs.close()
