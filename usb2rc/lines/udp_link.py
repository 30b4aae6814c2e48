"""A UDP "line" for the MAVLink output: `udpout:host:port` or `udpin:host:port`, as mavutil
names them.

- `udpout:HOST:PORT` sends every datagram to HOST:PORT (a ground station or a MAVLink router
  listening there) from an ephemeral port; replies come back to that port.
- `udpin:HOST:PORT` binds HOST:PORT and waits to be called: it locks to the first sender
  whose datagram `calls_us` accepts (the MAVLink output: a valid HEARTBEAT from the target
  system, signed when signing is on) and talks to that address only. Until then there is
  nobody to talk to: the line opens with the call. Unlike mavutil's udpin, which answers
  whoever sent last, a datagram from any other address never redirects the stream: it is
  counted (`datagrams_from_others`) and dropped. The lock moves only once the peer has
  been silent for `PEER_SILENT_S` and another sender calls. `allow` (addresses or CIDRs)
  drops senders outside it before anything else (`datagrams_not_allowed`).

It is a `lines.link.Link`: `line_event()`, `write()`, `state()`, ... A datagram goes out
whole or not at all; the socket is non-blocking, so a write never blocks a tick. What
arrives from the peer is kept for `take_received()` (the driver polls it once a tick, no
other thread touches the socket). The driver is the one writer of every field: no helper or
reader thread, and
`open_now()` runs before that thread starts, `Daemon.stop`'s `close()` after it was joined.
An open that fails (a host that does not resolve) is retried once every
`REOPEN_INTERVAL_S`, logged once per distinct error and then reminded at most once every
`REMIND_S` (`OpenFailures`).
"""

from __future__ import annotations

import contextlib
import ipaddress
import logging
import select
import socket
import time
from collections.abc import Callable, Iterable

from usb2rc.config.udp_url import is_udp_url, parse_udp_url
from usb2rc.lines.link import LineEvent, LinkStats, Written
from usb2rc.lines.session import LinkState

__all__ = ["UdpLink", "is_udp_url", "parse_udp_url"]

log = logging.getLogger("usb2rc.udp")

MAX_DATAGRAMS_PER_POLL = 64  # what one tick reads at most: a flood cannot hold a tick up
RECEIVE_SIZE = 65535
KEEP_RECEIVED = 65536  # bytes kept for take_received() between ticks; older ones dropped
REOPEN_INTERVAL_S = 1.0  # a failed open (socket, bind, name lookup) is tried again after this
REMIND_S = 60.0  # the same open error is logged again at most this often
# udpin: the peer's lock moves to another caller only after the peer sent nothing for this
# long (a router restarted on a new port); MAVLink's GCS heartbeat-loss convention is ~5 s
PEER_SILENT_S = 5.0

Address = tuple[str, int]
Network = ipaddress.IPv4Network | ipaddress.IPv6Network


def allowed_networks(allow: Iterable[str]) -> tuple[Network, ...]:
    """The `allow` list (addresses or CIDRs, checked by the config) as networks."""
    return tuple(ipaddress.ip_network(entry, strict=False) for entry in allow)


class OpenFailures:
    """Logs a failing open without flooding: an ERROR for each distinct error, the same one
    again at most every `REMIND_S` (with the attempts since), and INFO once it opens."""

    def __init__(self, url: str, clock: Callable[[], float]) -> None:
        self.url = url
        self.clock = clock
        self.attempts = 0  # failed opens since the last success (or the start)
        self._logged = ""
        self._logged_at = 0.0
        self._attempts_logged = 0

    def failed(self, error: str) -> None:
        self.attempts += 1
        now = self.clock()
        if error != self._logged:
            log.error("%s; retrying every %.0f s", error, REOPEN_INTERVAL_S)
        elif now - self._logged_at >= REMIND_S:
            since = self.attempts - self._attempts_logged
            log.error("%s; still failing (%d attempts in %.0f s)", error, since, REMIND_S)
        else:
            log.debug("%s (attempt %d)", error, self.attempts)
            return
        self._logged, self._logged_at, self._attempts_logged = error, now, self.attempts

    def opened(self) -> None:
        if self._logged:
            log.info("%s opened after %d failed attempts", self.url, self.attempts)
        self.attempts, self._logged = 0, ""


class UdpLink:
    """One UDP endpoint; the output thread alone uses it (opens, writes, reads, closes).

    `calls_us(datagram)`: whether a udpin sender may become the peer (None: any datagram);
    `allow`: the addresses or CIDRs datagrams are taken from (empty: any)."""

    baudrate = 0  # no baud rate: `check` knows a UDP link has no bandwidth limit to check

    def __init__(
        self,
        url: str,
        calls_us: Callable[[bytes], bool] | None = None,
        allow: Iterable[str] = (),
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.url = url
        self.address = parse_udp_url(url)
        self.calls_us = calls_us
        self.allow = allowed_networks(allow)
        self.clock = clock
        self.stats = LinkStats()
        self.last_error = ""
        self.datagrams_received = 0  # from the peer, kept for take_received()
        self.datagrams_dropped = 0  # the OS refused a datagram (its send buffer full)
        self.datagrams_not_allowed = 0  # from a sender outside `allow`
        self.datagrams_from_others = 0  # from an allowed sender that is not the peer
        self.peer_locks = 0  # udpin: times a caller became the peer
        self._sock: socket.socket | None = None
        # the socket's readiness, asked before each read: a tick with nothing to read (the
        # usual one) costs a poll, not a failed read and its exception
        self._readable: select.poll | None = None
        self._peer: Address | None = None
        self._peer_heard_at = 0.0
        self._opened = False  # the writer was told OPENED for the current socket
        self._received = bytearray()
        self._next_open_at = 0.0
        self._open_failures = OpenFailures(url, clock)

    @property
    def is_open(self) -> bool:
        """There is a socket and somebody to send to (udpin: once a peer called): until
        then the daemon reports this output as waiting, as it does a missing serial port."""
        return self._sock is not None and self._peer is not None

    @property
    def peer(self) -> Address | None:
        """Where datagrams go: the udpout address, or the udpin peer that called."""
        return self._peer

    def open_now(self) -> bool:
        """Open the socket if it is not and the retry interval has passed (never raises);
        True once there is a peer."""
        if self._sock is None and self.clock() >= self._next_open_at:
            self._next_open_at = self.clock() + REOPEN_INTERVAL_S
            try:
                self._sock = self._open()
            except OSError as exc:
                self.last_error = f"{self.url}: {exc.strerror or exc}"
                self._open_failures.failed(self.last_error)
                return False
            self._open_failures.opened()
            self._readable = select.poll()
            self._readable.register(self._sock, select.POLLIN)
            self.stats.opens += 1
            self.last_error = "" if self._peer else f"{self.url}: no vehicle has called yet"
        return self.is_open

    def try_open(self) -> bool:
        """Opening a UDP socket does not wait on anything: done in the caller's thread."""
        return self.open_now()

    def _open(self) -> socket.socket:
        addr = self.address
        family = socket.AF_INET6 if ":" in addr.host else socket.AF_INET
        sock = socket.socket(family, socket.SOCK_DGRAM)
        try:
            sock.setblocking(False)
            if addr.scheme == "udpin":
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                sock.bind((addr.host, addr.port))
                self._peer = None
            else:
                info = socket.getaddrinfo(addr.host, addr.port, family, socket.SOCK_DGRAM)
                host, port = info[0][4][:2]
                self._peer = (str(host), int(port))
        except OSError:
            sock.close()
            raise
        return sock

    def line_event(self) -> LineEvent | None:
        """OPENED once the socket is there and there is somebody to send to. Only until
        then does it read (a `udpin` caller becomes the peer): after it, the driver's
        `take_received` is the tick's one read."""
        if self._sock is None or self._opened:
            return None
        self._poll()
        if self._peer is None:
            return None
        self._opened = True
        return LineEvent.OPENED

    def _poll(self) -> None:
        """Read what waits (non-blocking, at most MAX_DATAGRAMS_PER_POLL datagrams); keep
        the peer's, count and drop the rest."""
        sock, readable = self._sock, self._readable
        if sock is None or readable is None:
            return
        for _ in range(MAX_DATAGRAMS_PER_POLL):
            if not readable.poll(0):  # nothing waits (the usual tick): no read, no exception
                return
            try:
                data, sender = sock.recvfrom(RECEIVE_SIZE)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:  # an ICMP error of an earlier send (nobody listens): not fatal
                continue
            if self._from_peer((str(sender[0]), int(sender[1])), data):
                self._keep(data)

    def _from_peer(self, sender: Address, data: bytes) -> bool:
        """Whether this datagram is the peer's (udpin: a caller may become the peer)."""
        now = self.clock()
        if self.allow and not self._allowed(sender[0]):
            self.datagrams_not_allowed += 1
        elif sender == self._peer:
            self._peer_heard_at = now
            return True
        elif self.address.scheme == "udpin" and self._may_lock(now) and self._calls(data):
            self._lock(sender, now)
            return True
        else:
            self.datagrams_from_others += 1
        if self._peer is None:
            self.last_error = (
                f"{self.url}: no vehicle has called yet (ignored: {self.datagrams_from_others}"
                f" datagrams that were no valid call, {self.datagrams_not_allowed} from"
                " addresses not allowed)"
            )
        return False

    def _allowed(self, host: str) -> bool:
        try:
            ip = ipaddress.ip_address(host.split("%", 1)[0])
        except ValueError:
            return False
        return any(ip in network for network in self.allow)

    def _may_lock(self, now: float) -> bool:
        """No peer yet, or the peer went silent (a restarted router calls from a new port)."""
        return self._peer is None or now - self._peer_heard_at >= PEER_SILENT_S

    def _calls(self, data: bytes) -> bool:
        return self.calls_us is None or self.calls_us(data)

    def _lock(self, sender: Address, now: float) -> None:
        if self._peer is None:
            log.info("%s: %s:%d called; answering it only", self.url, *sender)
        else:
            log.warning(
                "%s: %s:%d was silent for %.0f s; %s:%d called and is answered now",
                self.url,
                *self._peer,
                now - self._peer_heard_at,
                *sender,
            )
        self._peer, self._peer_heard_at = sender, now
        self.peer_locks += 1
        self.last_error = ""

    def _keep(self, data: bytes) -> None:
        self.datagrams_received += 1
        self.stats.bytes_read += len(data)
        self._received += data
        if len(self._received) > KEEP_RECEIVED:
            del self._received[: len(self._received) - KEEP_RECEIVED]

    def counters(self) -> dict[str, int | str]:
        """The link's own counters for the stats record (labels: `usb2rc.runtime.stats_text`)."""
        record: dict[str, int | str] = {
            "datagrams_from_peer": self.datagrams_received,
            "datagrams_from_others": self.datagrams_from_others,
            "datagrams_not_allowed": self.datagrams_not_allowed,
        }
        if self._peer is not None:
            record["udp_peer"] = "{}:{}".format(*self._peer)
        elif self.address.scheme == "udpin":
            record["udp_peer"] = "none (no vehicle has called yet)"
        return record

    def take_received(self) -> list[tuple[bytes, float]]:
        """What arrived since the last call (the far end's MAVLink stream), read now."""
        self._poll()
        if not self._received:
            return []
        data, self._received = bytes(self._received), bytearray()
        return [(data, self.clock())]

    def write(self, data: bytes) -> Written:
        """One datagram; whole or not at all. Nobody listening is not an error for UDP."""
        sock, peer = self._sock, self._peer
        if sock is None or peer is None or not data:
            return Written(0)
        try:
            sent = sock.sendto(data, peer)
        except (BlockingIOError, InterruptedError):
            self.datagrams_dropped += 1
            self.stats.writes_skipped_queue_full += 1
            return Written(0)
        except (ConnectionRefusedError, ConnectionResetError):
            sent = len(data)  # the ICMP answer to an earlier datagram: this one went out
        except OSError as exc:
            self._lost(exc)
            return Written(0, lost=True)
        self.stats.writes += 1
        self.stats.bytes_written += sent
        return Written(sent)

    def state(self, probe_writable: bool) -> LinkState:
        """UDP holds nothing it can count or drop; `probe_writable`: whether the socket's
        send buffer takes a datagram again."""
        sock = self._sock
        if sock is None:
            return LinkState(writable=False)
        return LinkState(writable=not probe_writable or self.wait_writable(0.0))

    def wait_writable(self, timeout_s: float) -> bool:
        sock = self._sock
        if sock is None:
            return False
        try:
            return bool(select.select([], [sock], [], max(0.0, timeout_s))[1])
        except (OSError, ValueError):
            return True

    def flush(self, counted: bool = True) -> bool:
        """Nothing to drop: a datagram the OS refused is gone, none waits."""
        return False

    def _lost(self, exc: OSError) -> None:
        self.stats.losses += 1
        self.last_error = f"{self.url} lost: {exc.strerror or exc}"
        log.error("%s; reopening", self.last_error)
        self.close()

    def close(self) -> None:
        sock, self._sock = self._sock, None
        self._readable = None
        self._opened = False
        if sock is not None:
            with contextlib.suppress(OSError):
                sock.close()
