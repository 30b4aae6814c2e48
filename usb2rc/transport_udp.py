"""A UDP "line" for the MAVLink output: `udpout:host:port` or `udpin:host:port`, as mavutil
names them.

- `udpout:HOST:PORT` sends every datagram to HOST:PORT (a ground station or a MAVLink router
  listening there) from an ephemeral port; replies come back to that port.
- `udpin:HOST:PORT` binds HOST:PORT and sends to whoever sent the last datagram (an
  autopilot or router configured to send to us). Until something arrives there is nobody
  to talk to: the line opens with the first datagram.

It offers what the output thread needs of a link (`transport.SerialLink`'s shape):
`line_event()`, `write()`, `drained()`, ... A datagram goes out whole or not at all; the
socket is non-blocking, so a write never blocks a tick. What arrives is kept for
`take_received()` (the output thread reads it once a tick, no other thread touches the
socket).
"""

from __future__ import annotations

import contextlib
import logging
import select
import socket

from usb2rc.transport import LineEvent, LinkStats, Written
from usb2rc.udp_url import is_udp_url, parse_udp_url

__all__ = ["UdpLink", "is_udp_url", "parse_udp_url"]

log = logging.getLogger("usb2rc.udp")

MAX_DATAGRAMS_PER_POLL = 64  # what one tick reads at most: a flood cannot hold a tick up
RECEIVE_SIZE = 65535
KEEP_RECEIVED = 65536  # bytes kept for take_received() between ticks; older ones dropped


class UdpLink:
    """One UDP endpoint; the output thread alone uses it (opens, writes, reads, closes)."""

    baudrate = 0  # no baud rate: `check` knows a UDP link has no bandwidth limit to check

    def __init__(self, url: str) -> None:
        self.url = url
        self.address = parse_udp_url(url)
        self.stats = LinkStats()
        self.last_error = ""
        self.datagrams_received = 0
        self.datagrams_dropped = 0  # the OS refused a datagram (its send buffer full)
        self._sock: socket.socket | None = None
        self._peer: tuple[str, int] | None = None
        self._opened = False  # the writer was told OPENED for the current socket
        self._received = bytearray()

    @property
    def is_open(self) -> bool:
        """There is a socket and somebody to send to (udpin: once a datagram came): until
        then the daemon reports this output as waiting, as it does a missing serial port."""
        return self._sock is not None and self._peer is not None

    @property
    def peer(self) -> tuple[str, int] | None:
        """Where datagrams go: the udpout address, or udpin's last sender."""
        return self._peer

    def open_now(self) -> bool:
        """Open the socket if it is not (never raises); True once there is a peer."""
        if self._sock is None:
            try:
                self._sock = self._open()
            except OSError as exc:
                self.last_error = f"{self.url}: {exc.strerror or exc}"
                log.error("%s; retrying every second", self.last_error)
                return False
            self.stats.opens += 1
            self.last_error = "" if self._peer else f"{self.url}: nothing received yet"
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
        """OPENED once the socket is there and there is somebody to send to."""
        self._poll()
        if self._sock is None or self._opened or self._peer is None:
            return None
        self._opened = True
        return LineEvent.OPENED

    def _poll(self) -> None:
        """Read what waits (non-blocking, at most MAX_DATAGRAMS_PER_POLL datagrams); udpin
        learns its peer from the last sender."""
        sock = self._sock
        if sock is None:
            return
        for _ in range(MAX_DATAGRAMS_PER_POLL):
            try:
                data, sender = sock.recvfrom(RECEIVE_SIZE)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:  # an ICMP error of an earlier send (nobody listens): not fatal
                continue
            self.datagrams_received += 1
            self.stats.bytes_read += len(data)
            if self.address.scheme == "udpin":
                self._peer = sender[:2]
                self.last_error = ""
            self._received += data
            if len(self._received) > KEEP_RECEIVED:
                del self._received[: len(self._received) - KEEP_RECEIVED]

    def take_received(self) -> bytes:
        """What arrived since the last call (the far end's MAVLink stream)."""
        data, self._received = bytes(self._received), bytearray()
        return data

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

    def drained(self) -> bool:
        sock = self._sock
        if sock is None:
            return False
        try:
            return bool(select.select([], [sock], [], 0)[1])
        except (OSError, ValueError):
            return True

    def wait_drained(self, timeout_s: float) -> bool:
        sock = self._sock
        if sock is None:
            return False
        try:
            return bool(select.select([], [sock], [], max(0.0, timeout_s))[1])
        except (OSError, ValueError):
            return True

    def discard_stale(self) -> bool:
        """Nothing to discard: a datagram the OS refused is gone, none waits."""
        return False

    def _lost(self, exc: OSError) -> None:
        self.stats.losses += 1
        self.last_error = f"{self.url} lost: {exc.strerror or exc}"
        log.error("%s; reopening", self.last_error)
        self.close()

    def close(self) -> None:
        sock, self._sock = self._sock, None
        self._opened = False
        if sock is not None:
            with contextlib.suppress(OSError):
                sock.close()
