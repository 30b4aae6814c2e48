"""The daemon's status socket: a read-only live view for `usb2rc web` and scripts.

An AF_UNIX stream socket (`/run/usb2rc/status.sock` under the service, 0660 so group usb2rc
can connect). Where it is by default, `usb2rc run` and `usb2rc web` work out the same way
(`default_path`): the runtime directory systemd or the login session gives, else root's
/run/usb2rc, else a folder of the user's own in /tmp that must stay private
(`check_private`). Each connected client gets one JSON object per line, about 10 a second:

    {"at": ..., "stats": <run --stats-format json's record>, "nodes": [...],
     "devices": [...], "events": [...], "check": {...}}

Read-only: whatever a client sends is read and thrown away; nothing here touches what an
output sends. The server has its own thread. Each period it reads the node table's immutable
snapshot (`NodeTable.snapshot()`, no lock), the devices' attachments (one short lock) and the
stats record, encodes one line, and queues it for every client. Writes are non-blocking: a
client that lets more than CLIENT_CAP_BYTES pile up is dropped (counted in `clients_dropped`,
one log line each), so a client that never reads costs a bounded buffer and never a tick.
"""

from __future__ import annotations

import contextlib
import errno
import json
import logging
import math
import os
import selectors
import socket
import stat
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from usb2rc.config.layout import AXIS_NAMES
from usb2rc.hid.backend import DeviceInfo
from usb2rc.lines.link import Link
from usb2rc.nodes.mapping import ChannelSource
from usb2rc.nodes.step import NodeView, TableSnapshot
from usb2rc.nodes.table import EventKind, NodeFrame, NodeTable, ServiceEvent
from usb2rc.protocols.c2_16b.receiver import NodeView as ReceivedNode
from usb2rc.protocols.channels import OutputChannels
from usb2rc.protocols.rc11_channels import RC11_SCALE
from usb2rc.runtime.worker import Worker

log = logging.getLogger("usb2rc.status")

PERIOD_S = 0.1  # one line per client each period: 10 Hz, under the page's 20 Hz ceiling
CLIENT_CAP_BYTES = 256 * 1024  # queued for one client beyond this: it is too slow, dropped
MAX_CLIENTS = 16  # connections beyond this are closed at once (counted)
EVENTS_KEPT = 50  # the service events each line carries (the latest)
SOCKET_MODE = 0o660  # owner and group usb2rc (docs/PI.md, "Phone access at the field")
SOCKET_NAME = "status.sock"
SERVICE_DIRECTORY = "/run/usb2rc"  # the unit's RuntimeDirectory=, and root's default
SERVICE_SOCKET = os.path.join(SERVICE_DIRECTORY, SOCKET_NAME)
PRIVATE_MODE = 0o700  # a user's own folder: nobody else may put a socket there or connect

Record = Callable[[], dict[str, Any]]


def default_path(environ: Mapping[str, str] | None = None, uid: int | None = None) -> str:
    """Where the socket is when no path is given, for `usb2rc run` and `usb2rc web` alike:
    the service's runtime directory (systemd sets RUNTIME_DIRECTORY for
    `RuntimeDirectory=usb2rc`), else the login session's ($XDG_RUNTIME_DIR/usb2rc), else
    root's /run/usb2rc, else the user's own `user_directory`. `uid`: the effective one."""
    env = os.environ if environ is None else environ
    if env.get("RUNTIME_DIRECTORY"):
        return os.path.join(env["RUNTIME_DIRECTORY"].split(":")[0], SOCKET_NAME)
    if env.get("XDG_RUNTIME_DIR"):
        return os.path.join(env["XDG_RUNTIME_DIR"], "usb2rc", SOCKET_NAME)
    uid = os.geteuid() if uid is None else uid
    return SERVICE_SOCKET if uid == 0 else os.path.join(user_directory(uid), SOCKET_NAME)


def user_directory(uid: int) -> str:
    """A user's folder for the socket without a runtime directory (sudo -u, cron, a
    container): in /tmp, not $TMPDIR, so that a daemon and a `web` started from different
    shells agree. Anyone may make a folder in /tmp: `check_private` guards it."""
    return f"/tmp/usb2rc-{uid}"


class SocketInUseError(OSError):
    """Another process answers on the socket path: a second daemon must not take it over."""


class NotPrivateError(OSError):
    """The user's socket folder is not theirs alone: refused, the message says the fix."""


def is_user_directory(directory: str) -> bool:
    return os.path.abspath(directory) == user_directory(os.geteuid())


def check_private(directory: str) -> None:
    """Raise NotPrivateError unless `directory` is a real folder of this user's with no
    access for group or others: whoever else made it (/tmp is everyone's) could put a socket
    of their own there, or read ours."""
    info = os.lstat(directory)
    uid = os.geteuid()
    if not stat.S_ISDIR(info.st_mode):
        raise NotPrivateError(
            errno.ENOTDIR, f"{directory} is not a folder (a link or a file): remove it"
        )
    if info.st_uid != uid:
        raise NotPrivateError(
            errno.EPERM,
            f"{directory} is owned by uid {info.st_uid}, not by this user (uid {uid}): "
            "someone else made it; remove it",
        )
    if info.st_mode & 0o077:
        mode = stat.S_IMODE(info.st_mode)
        raise NotPrivateError(
            errno.EPERM,
            f"{directory} is open to others (mode {mode:04o}, it must be 0700): "
            f"`chmod 700 {directory}`",
        )


def os_reason(exc: OSError) -> str:
    """An OSError in words: its message and the file it names, without `[Errno N]`."""
    text = exc.strerror or str(exc)
    return f"{text}: {exc.filename}" if exc.filename else text


def make_private(directory: str) -> None:
    """The user's socket folder, made 0700 if missing, then checked (`check_private`)."""
    with contextlib.suppress(FileExistsError):
        os.mkdir(directory, PRIVATE_MODE)
    check_private(directory)


# --------------------------------------------------------------------------- the record


def node_record(view: NodeView, devices: list[dict[str, Any]]) -> dict[str, Any]:
    """One node as the page shows it: the status it sends, axes, buttons, hat, why it waits."""
    frame = view.frame
    received = ReceivedNode(frame.node_id, group1=frame.group1, group2=frame.group2)
    return {
        "node_id": frame.node_id,
        "status": node_status(view),
        "failsafe": frame.failsafe,
        "axes": dict(zip(AXIS_NAMES, frame.axes, strict=False)),
        "buttons": received.pressed_buttons(),
        "hat": received.hat(),
        "waiting_for": list(view.waiting_for),
        "devices": devices,
    }


def node_status(view: NodeView) -> str:
    """The C2-16B status byte the node asks for (docs/ICD.md, "Status priority")."""
    frame = view.frame
    if frame.failsafe:
        return "!"
    if frame.handover is not None:
        return "&"
    return "%" if frame.low_battery else ">"


def device_record(node_id: int, info: DeviceInfo, entry: str, present: bool) -> dict[str, Any]:
    return {
        "node_id": node_id,
        "name": info.product or info.path,
        "vid_pid": f"{info.vid:04x}:{info.pid:04x}",
        "entry": entry,
        "present": present,
    }


def event_record(event: ServiceEvent, at: float) -> dict[str, Any]:
    record: dict[str, Any] = {
        "at": round(at, 3),
        "node_id": event.node_id,
        "kind": event.kind.value,
    }
    if event.kind is EventKind.ERROR:
        record["error_code"] = event.error_code
    if event.info is not None:
        record["device"] = event.info.product or event.info.path
    return record


def port_record(link: Link) -> dict[str, Any]:
    """Whether an output's port is open and, while it is not, why (the link's last error)."""
    if link.is_open:
        return {"port_open": True}
    return {"port_open": False, "port_error": link.last_error or "not opened yet"}


@dataclass(frozen=True)
class FailsafeWatch:
    """Whether an output sends failsafe, and for which nodes, from the nodes' frames: a
    channel output when a channel it reads is (`OutputChannels.evaluate`, as its ticks
    decide); C2-16B (no channels) for each node in failsafe, as it sends every node."""

    sources: tuple[ChannelSource, ...] | None = None
    channels: OutputChannels | None = None

    @classmethod
    def of(cls, sources: Sequence[ChannelSource] | None) -> FailsafeWatch:
        if sources is None:
            return cls()
        return cls(tuple(sources), OutputChannels.scaled(sources, RC11_SCALE))

    def record(self, frames: Mapping[int, NodeFrame]) -> dict[str, Any]:
        if self.sources is None or self.channels is None:
            nodes = sorted(node_id for node_id, frame in frames.items() if frame.failsafe)
            return {"failsafe": bool(nodes), "failsafe_nodes": nodes}
        _values, failsafe = self.channels.evaluate(frames.values())
        failing = {n for source in self.sources for n in failing_nodes(source, frames)}
        return {"failsafe": failsafe, "failsafe_nodes": sorted(failing) if failsafe else []}


def failing_nodes(source: ChannelSource, frames: Mapping[int, NodeFrame]) -> set[int]:
    """The nodes a channel reads that are in failsafe or do not exist (a mix: its lines')."""
    if source.kind == "mix":
        return {n for line in source.mix for n in failing_nodes(line.source, frames)}
    frame = frames.get(source.node_id)
    return {source.node_id} if frame is None or frame.failsafe else set()


def snapshot_record(snapshot: TableSnapshot, table: NodeTable) -> dict[str, Any]:
    """The nodes of the latest step and every device a node holds (one short table lock)."""
    devices = [
        device_record(node_id, info, binding.name, present)
        for node_id, info, binding, present, _type in table.attachments()
    ]
    by_node: dict[int, list[dict[str, Any]]] = {}
    for device in devices:
        by_node.setdefault(device["node_id"], []).append(device)
    nodes = [node_record(view, by_node.get(view.frame.node_id, [])) for view in snapshot.nodes]
    return {"period": snapshot.period, "nodes": nodes, "devices": devices}


# --------------------------------------------------------------------------- the server


@dataclass
class _Client:
    sock: socket.socket
    pending: bytearray = field(default_factory=bytearray)


@dataclass
class StatusCounters:
    clients_connected: int = 0  # now
    clients_total: int = 0
    clients_dropped: int = 0  # too slow: more than CLIENT_CAP_BYTES queued
    clients_refused: int = 0  # over MAX_CLIENTS
    lines: int = 0  # lines built (each goes to every client)
    line_errors: int = 0  # a line that could not be built (logged once each kind)

    def record(self) -> dict[str, int]:
        return dict(vars(self))


class StatusServer(Worker):
    """Serves `status()` lines on a unix socket from its own thread: `start()`, then
    `shutdown()` (stop, join, close the clients and remove the socket file)."""

    def __init__(
        self,
        path: str,
        status: Record,
        period_s: float = PERIOD_S,
        client_cap: int = CLIENT_CAP_BYTES,
        phase_s: float = 0.0,
    ) -> None:
        """`phase_s`: the lines go out at that offset from the multiples of `period_s` on
        the monotonic clock (the daemon gives the node clock's grid, where no output ticks,
        so that a line's work does not delay a tick)."""
        super().__init__("status-socket")
        self.path = path
        self._status = status
        self.period_s = period_s
        self.phase_s = phase_s
        self.client_cap = client_cap
        self.counters = StatusCounters()
        self._listener: socket.socket | None = None
        self._clients: dict[int, _Client] = {}  # by fileno; the server thread's own
        self._selector = selectors.DefaultSelector()
        self._logged_errors: set[str] = set()

    def start(self) -> None:
        """Bind (replacing a stale socket left by a killed daemon) and start serving.
        Raises OSError (SocketInUseError when another daemon answers there)."""
        self._listener = bind_unix(self.path)
        self._listener.setblocking(False)
        self._selector.register(self._listener, selectors.EVENT_READ)
        super().start()
        log.info("status socket: %s (`usb2rc web` reads it)", self.path)

    def shutdown(self, timeout: float = 0.5) -> None:
        """Stop the thread, close every client and the socket, and remove its file."""
        self.stop()
        self.join(timeout)
        for client in list(self._clients.values()):
            self._close(client)
        if self._listener is not None:
            with contextlib.suppress(OSError):
                os.unlink(self.path)
            self._selector.unregister(self._listener)
            self._listener.close()
            self._listener = None
        self._selector.close()

    # --- the thread ----------------------------------------------------------------------

    def run(self) -> None:
        next_line = self.line_after(time.monotonic())
        while not self.stopping:
            now = time.monotonic()
            if now >= next_line:
                if self._clients:  # nobody connected: no line built, no cost
                    self._broadcast(self._line())
                next_line = self.line_after(max(next_line + self.period_s / 2, now))
            timeout = min(self.period_s, max(0.0, next_line - time.monotonic()))
            for key, mask in self._selector.select(timeout):
                if key.fileobj is self._listener:
                    self._accept()
                elif (client := self._clients.get(key.fd)) is not None:
                    self._serve(client, mask)

    def line_after(self, now: float) -> float:
        """The first line time after `now` (late: the next one, never a burst to catch up)."""
        phase, period = self.phase_s, self.period_s
        return (math.floor((now - phase) / period) + 1) * period + phase

    def _line(self) -> bytes | None:
        try:
            record = self._status()
        except Exception as exc:  # a bug here must not stop the socket (nor the daemon)
            self.counters.line_errors += 1
            kind = type(exc).__name__
            if kind not in self._logged_errors:
                self._logged_errors.add(kind)
                log.exception("status socket: cannot build a status line")
            return None
        record["status_socket"] = self.counters.record()
        self.counters.lines += 1
        return (json.dumps(record, separators=(",", ":")) + "\n").encode()

    def _accept(self) -> None:
        assert self._listener is not None
        try:
            sock, _ = self._listener.accept()
        except (BlockingIOError, InterruptedError):
            return
        if len(self._clients) >= MAX_CLIENTS:
            self.counters.clients_refused += 1
            sock.close()
            return
        sock.setblocking(False)
        client = _Client(sock)
        self._clients[sock.fileno()] = client
        self._selector.register(sock, selectors.EVENT_READ)
        self.counters.clients_total += 1
        self.counters.clients_connected = len(self._clients)

    def _serve(self, client: _Client, mask: int) -> None:
        if mask & selectors.EVENT_READ:
            try:
                data = client.sock.recv(4096)  # read-only socket: read and thrown away
            except (BlockingIOError, InterruptedError):
                data = b"-"
            except OSError:
                data = b""
            if not data:
                self._close(client)
                return
        if mask & selectors.EVENT_WRITE:
            self._flush(client)

    def _broadcast(self, line: bytes | None) -> None:
        if line is None:
            return
        for client in list(self._clients.values()):
            if len(client.pending) + len(line) > self.client_cap:
                log.warning(
                    "status socket: a client read too slowly (%d bytes waiting): dropped",
                    len(client.pending),
                )
                self._close(client)
                # counted once it is gone: whoever reads the counters from another thread
                # and sees the drop sees it no longer connected
                self.counters.clients_dropped += 1
                continue
            client.pending += line
            self._flush(client)

    def _flush(self, client: _Client) -> None:
        try:
            sent = client.sock.send(client.pending)
        except (BlockingIOError, InterruptedError):
            sent = 0
        except OSError:  # the client went away
            self._close(client)
            return
        del client.pending[:sent]
        events = selectors.EVENT_READ | (selectors.EVENT_WRITE if client.pending else 0)
        self._selector.modify(client.sock, events)

    def _close(self, client: _Client) -> None:
        fd = client.sock.fileno()
        if self._clients.pop(fd, None) is None:
            return
        with contextlib.suppress(KeyError, ValueError):
            self._selector.unregister(client.sock)
        client.sock.close()
        self.counters.clients_connected = len(self._clients)


def bind_unix(path: str) -> socket.socket:
    """A listening socket at `path`, mode 0660, its directory made if missing (the user's
    own folder in /tmp: 0700, and refused when not private). A socket file nobody answers on
    (a daemon that was killed) is replaced; one that answers is not."""
    directory = os.path.dirname(path)
    if directory and is_user_directory(directory):
        make_private(directory)
    elif directory:
        os.makedirs(directory, mode=0o750, exist_ok=True)
    _remove_stale(path)
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        old_umask = os.umask(0o117)  # created 0660 from the start: no window wider than that
        try:
            listener.bind(path)
        finally:
            os.umask(old_umask)
        os.chmod(path, SOCKET_MODE)
        listener.listen(8)
    except OSError:
        listener.close()
        raise
    return listener


def _remove_stale(path: str) -> None:
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return
    if not stat.S_ISSOCK(mode):
        raise OSError(errno.EEXIST, f"{path} exists and is not a socket; not replacing it")
    probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        probe.connect(path)
    except OSError as exc:
        if exc.errno not in (errno.ECONNREFUSED, errno.ENOENT):
            raise
        log.info("status socket: %s was left by a daemon that is gone: replaced", path)
        with contextlib.suppress(FileNotFoundError):
            os.unlink(path)
        return
    finally:
        probe.close()
    raise SocketInUseError(
        errno.EADDRINUSE, f"{path}: another usb2rc answers there (give --status-socket PATH)"
    )


# --------------------------------------------------------------------------- the daemon's side


class StatusSource:
    """What one status line holds, read from the daemon's parts without holding a lock for
    more than the table's attachments: the stats record, the latest node snapshot, the last
    service events and the `check` verdict of the running config (worked out once per
    config: a reload makes a new one)."""

    def __init__(
        self,
        table: NodeTable,
        stats: Record,
        check: Callable[[], dict[str, Any]],
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.table = table
        self._stats = stats
        self._check = check
        self._clock = clock
        self._event_cursor = 0  # its own place in the table's service event log
        self._events: list[dict[str, Any]] = []

    def __call__(self) -> dict[str, Any]:
        now = self._clock()
        snapshot = self.table.snapshot()  # a read: it steps nothing
        events = snapshot.log.since(self._event_cursor)
        if events is None:  # fell behind the log's bound: what it still keeps
            events = snapshot.log.events
        self._event_cursor = snapshot.log.end
        self._events = (self._events + [event_record(e, now) for e in events])[-EVENTS_KEPT:]
        record: dict[str, Any] = {"at": round(now, 3), "stats": self._stats()}
        record.update(snapshot_record(snapshot, self.table))
        record["events"] = self._events
        record["check"] = self._check()
        return record
