"""What usb2rc.service's sandbox lets an output reach, and the drop-in that lets it.

The shipped unit allows no IP socket (`RestrictAddressFamilies=AF_UNIX AF_NETLINK`,
`IPAddressDeny=any`): a serial-only service needs none. An output on `udpout:`, `udpin:`,
`socket://` or `rfc2217://` then fails under systemd while it works from a shell.
`install-system` reads the config it installs and, for such outputs, writes
`usb2rc.service.d/network.conf`: AF_INET/AF_INET6, and `IPAddressAllow=` only the hosts the
outputs name. systemd checks a packet's remote address (the source of what comes in, the
destination of what goes out), so:

- `udpout:HOST` / `socket://HOST` / `rfc2217://HOST`: HOST's addresses (a name is resolved
  now, IPv4 as the daemon resolves it, and the resolvers of /etc/resolv.conf are allowed too:
  the service resolves the name again at each start);
- `udpin:` on a loopback address: `localhost` (only local senders can reach it);
- `udpin:` on any other address (0.0.0.0, a LAN address): `any`, with a warning. Who calls
  (a vehicle, a router) is not in the config; narrowing the drop-in's `IPAddressAllow=` by
  hand is kept (install-system replaces an edited file only with --force).

`check` reads the installed unit and its drop-ins the same way (`sandbox_warnings`) and warns
for an output the service could not open, naming the command that fixes it.
"""

from __future__ import annotations

import ipaddress
import socket
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from usb2rc.config.model import Config, OutputConfig
from usb2rc.config.udp_url import is_udp_url, parse_udp_url
from usb2rc.config.yamlnodes import Problem

UNIT = "/etc/systemd/system/usb2rc.service"
DROP_IN_DIR = UNIT + ".d"
DROP_IN = DROP_IN_DIR + "/network.conf"
NETWORK_FAMILIES = ("AF_INET", "AF_INET6")
TCP_SCHEMES = ("socket", "rfc2217")  # pyserial URLs that open a TCP connection
FIX_COMMAND = "sudo usb2rc install-system"
SYSTEM_ROOT = Path("/")  # where `check` looks for the installed unit (tests point it elsewhere)
# systemd's IPAddressAllow= keywords, as networks.
KEYWORDS = {
    "any": ("0.0.0.0/0", "::/0"),
    "localhost": ("127.0.0.0/8", "::1/128"),
    "link-local": ("169.254.0.0/16", "fe80::/64"),
    "multicast": ("224.0.0.0/4", "ff00::/8"),
}

Network = ipaddress.IPv4Network | ipaddress.IPv6Network


@dataclass(frozen=True)
class Endpoint:
    """The IP host an output's port names."""

    port: str  # as the config writes it
    host: str
    listening: bool  # udpin: the peers are whoever sends


@dataclass(frozen=True)
class Peers:
    """What one network output needs the sandbox to allow."""

    output: int  # index in the config's outputs
    endpoint: Endpoint
    allow: tuple[str, ...]  # IPAddressAllow= entries; empty: could not resolve
    comment: str  # for the drop-in: where the entries come from
    warning: str = ""  # what the user should know (empty: nothing)


def endpoint(port: str | None) -> Endpoint | None:
    """The IP host of a network port (None for a serial line or an unparsable one)."""
    if not port:
        return None
    if is_udp_url(port):
        try:
            addr = parse_udp_url(port)
        except ValueError:
            return None
        return Endpoint(port, addr.host, addr.scheme == "udpin")
    scheme, sep, rest = port.partition("://")
    if not sep or scheme.lower() not in TCP_SCHEMES:
        return None
    host = rest.split("?", 1)[0].rpartition(":")[0].strip("[]")
    return Endpoint(port, host, False) if host else None


def ip_literal(host: str) -> ipaddress.IPv4Address | ipaddress.IPv6Address | None:
    try:
        return ipaddress.ip_address(host)
    except ValueError:
        return None


def resolvers(root: Path) -> list[str]:
    """The nameservers of ROOT/etc/resolv.conf (the service resolves names through them)."""
    try:
        lines = (root / "etc/resolv.conf").read_text().splitlines()
    except OSError:
        return []
    words = [line.split() for line in lines]
    return [w[1] for w in words if len(w) >= 2 and w[0] == "nameserver" and ip_literal(w[1])]


def resolved(host: str) -> list[str]:
    """HOST's IPv4 addresses now (the daemon's udpout resolves names as AF_INET)."""
    try:
        infos = socket.getaddrinfo(host, None, socket.AF_INET, socket.SOCK_DGRAM)
    except OSError:
        return []
    return sorted({str(info[4][0]) for info in infos})


def peers_of(index: int, end: Endpoint, root: Path) -> Peers:
    literal = ip_literal(end.host)
    if end.listening:
        if literal is not None and literal.is_loopback:
            return Peers(index, end, ("localhost",), f"{end.port}: local senders only")
        return Peers(
            index,
            end,
            ("any",),
            f"{end.port}: listens beyond loopback, the senders are not in the config",
            f"{end.port} takes datagrams from any host that reaches it, so the drop-in "
            f"allows any address: narrow IPAddressAllow= in {DROP_IN} to the vehicle's",
        )
    if literal is not None:
        return Peers(index, end, (str(literal),), end.port)
    addresses = resolved(end.host)
    if not addresses:
        return Peers(
            index,
            end,
            (),
            f"{end.port}: {end.host} did not resolve: add its address here",
            f"{end.host} (in {end.port}) does not resolve now: the service cannot reach "
            f"it; add IPAddressAllow= its address to {DROP_IN}",
        )
    servers = resolvers(root)
    comment = f"{end.port}: {end.host} is {' '.join(addresses)} now"
    if servers:
        comment += f"; the resolvers of /etc/resolv.conf: {' '.join(servers)}"
    return Peers(
        index,
        end,
        tuple(addresses + servers),
        comment,
        f"{end.port} names a host, resolved at each start: the drop-in allows what "
        f"{end.host} is now ({' '.join(addresses)}); an address in the config is steadier",
    )


def network_peers(config: Config, root: Path = Path("/")) -> list[Peers]:
    """Every output that opens an IP socket, with what it needs allowed."""
    found = []
    for index, output in enumerate(config.outputs):
        end = endpoint(output.port)
        if end is not None:
            found.append(peers_of(index, end, root))
    return found


def drop_in_text(peers: Sequence[Peers], config_path: str) -> str:
    """network.conf for these outputs (a comment only, when there are none)."""
    head = [
        f"# Written by `usb2rc install-system` for {config_path}: usb2rc.service allows no",
        "# IP socket (RestrictAddressFamilies=AF_UNIX AF_NETLINK, IPAddressDeny=any); this",
        "# allows IP to the hosts its outputs name, and only those. Your edits are kept:",
        "# install-system replaces this file only with --force.",
    ]
    if not peers:
        return "\n".join([*head, "# No output of it opens an IP socket: nothing to allow."]) + "\n"
    lines = [*head, "[Service]", "RestrictAddressFamilies=" + " ".join(NETWORK_FAMILIES)]
    for peer in peers:
        lines.append(f"# outputs[{peer.output}] {peer.comment}")
        if peer.allow:
            lines.append("IPAddressAllow=" + " ".join(peer.allow))
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------- the installed unit


@dataclass
class Sandbox:
    """The network settings of a unit and its drop-ins, merged as systemd merges them."""

    families: set[str] | None = None  # allowed address families; None: no restriction
    denied_families: set[str] = field(default_factory=set)  # a `~` list
    allow: list[Network] = field(default_factory=list)
    deny: list[Network] = field(default_factory=list)

    def apply(self, key: str, value: str) -> None:
        words = value.split()
        if key == "RestrictAddressFamilies":
            self._families(words)
        elif key in ("IPAddressAllow", "IPAddressDeny"):
            target = self.allow if key == "IPAddressAllow" else self.deny
            if not words:
                target.clear()
            target.extend(n for w in words for n in networks(w))

    def _families(self, words: list[str]) -> None:
        if not words or words == ["none"]:
            self.families, self.denied_families = None, set()
        elif words[0].startswith("~"):
            self.denied_families |= {words[0][1:], *words[1:]}
        else:
            self.families = (self.families or set()) | set(words)

    def family_allowed(self, family: str) -> bool:
        allowed = self.families is None or family in self.families
        return allowed and family not in self.denied_families

    def reaches(self, address: str) -> bool:
        """Whether packets to/from address pass IPAddressAllow=/IPAddressDeny=."""
        literal = ipaddress.ip_address(address)
        if any(literal in net for net in self.allow):
            return True
        return not any(literal in net for net in self.deny)


def networks(word: str) -> list[Network]:
    try:
        return [ipaddress.ip_network(n) for n in KEYWORDS.get(word, (word,))]
    except ValueError:
        return []


def unit_settings(text: str) -> Iterable[tuple[str, str]]:
    """(key, value) of the [Service] section (comments, continuation lines not needed)."""
    section = ""
    for raw in text.splitlines():
        line = raw.strip()
        if not line or line[0] in "#;":
            continue
        if line.startswith("["):
            section = line
        elif section == "[Service]" and "=" in line:
            key, _, value = line.partition("=")
            yield key.strip(), value.strip()


def installed_sandbox(root: Path) -> Sandbox | None:
    """The installed unit's sandbox (unit, then its /etc drop-ins by name); None: none."""
    unit = root / UNIT.lstrip("/")
    if not unit.is_file():
        return None
    sandbox = Sandbox()
    drop_ins = sorted((root / DROP_IN_DIR.lstrip("/")).glob("*.conf"))
    for path in (unit, *drop_ins):
        for key, value in unit_settings(path.read_text()):
            sandbox.apply(key, value)
    return sandbox


def blocked_reason(sandbox: Sandbox, peer: Peers) -> str | None:
    """Why the service cannot use this output, or None."""
    literal = ip_literal(peer.endpoint.host)
    family = "AF_INET6" if literal is not None and literal.version == 6 else "AF_INET"
    if not sandbox.family_allowed(family):
        return f"it allows no {family} socket (RestrictAddressFamilies=)"
    if peer.endpoint.listening and literal is not None and not literal.is_loopback:
        if sandbox.allow or not sandbox.deny:
            return None  # any allowed sender will do: the user may have narrowed it
        return "IPAddressDeny= drops every sender and IPAddressAllow= lets none through"
    wanted = [a for a in peer.allow if ip_literal(a)] or (
        ["127.0.0.1"] if peer.endpoint.listening else []
    )
    missing = [a for a in wanted if not sandbox.reaches(a)]
    if missing:
        return f"IPAddressDeny= drops {' '.join(missing)} (not in IPAddressAllow=)"
    return None


def sandbox_warnings(config: Config, root: Path | None = None) -> list[Problem]:
    """A warning for each output the installed usb2rc.service could not open (none when the
    unit is not installed); root None: SYSTEM_ROOT."""
    root = SYSTEM_ROOT if root is None else root
    sandbox = installed_sandbox(root)
    if sandbox is None:
        return []
    problems = []
    for peer in network_peers(config, root):
        reason = blocked_reason(sandbox, peer)
        if reason is not None:
            output = config.outputs[peer.output]
            problems.append(_warning(config, output, peer, reason))
    return problems


def _warning(config: Config, output: OutputConfig, peer: Peers, reason: str) -> Problem:
    message = (
        f"warning: usb2rc.service as installed cannot open {peer.endpoint.port}: {reason}; "
        f"`{FIX_COMMAND}` writes {DROP_IN} for the config at /etc/usb2rc/usb2rc.yaml"
    )
    where = output.where
    if where is None:
        return Problem(config.source, None, f"outputs[{peer.output}].port", message)
    return Problem(where.source, where.line, f"{where.key}.port", message)
