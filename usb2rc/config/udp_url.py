"""MAVLink's UDP addresses as mavutil names them, `udpout:HOST:PORT` / `udpin:HOST:PORT`:
parsed without importing anything heavy (the config and `decode` read them;
`lines.udp_link.UdpLink` opens them)."""

from __future__ import annotations

from dataclasses import dataclass

SCHEMES = ("udpout", "udpin")


@dataclass(frozen=True)
class UdpAddress:
    scheme: str  # "udpout" or "udpin"
    host: str
    port: int


def is_udp_url(url: str) -> bool:
    return url.split(":", 1)[0] in SCHEMES


def parse_udp_url(url: str) -> UdpAddress:
    """`udpout:127.0.0.1:14550` → UdpAddress; ValueError with a message a user can act on."""
    scheme, _, rest = url.partition(":")
    if scheme not in SCHEMES:
        raise ValueError(f"{url!r} is not a UDP address (udpout:HOST:PORT or udpin:HOST:PORT)")
    host, sep, port_text = rest.rpartition(":")
    if not sep or not host or not port_text.isdigit() or not 1 <= int(port_text) <= 65535:
        raise ValueError(f"{url!r}: expected {scheme}:HOST:PORT with PORT 1..65535")
    return UdpAddress(scheme, host.strip("[]"), int(port_text))
