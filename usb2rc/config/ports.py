"""The ports the outputs will use, `--port` applied, and what would fail when they open.

`used_ports(config, port_override)` is the one answer to "which output writes on which
port": `--port` replaces the first output's port, and nothing else. `check` prints it,
`run` starts with it (through `configfile.load_runnable`), the status socket's verdict
shows it. `port_problems` judges it before anything opens: an output without a port, a
port that exists but cannot be a serial line, and two outputs on one line (the second one's
exclusive lock would fail and it would retry for ever, sending nothing).
"""

from __future__ import annotations

import os
import stat
from dataclasses import dataclass

from usb2rc.config.model import Config, OutputConfig
from usb2rc.config.udp_url import is_udp_url, parse_udp_url
from usb2rc.config.yamlnodes import Problem

PORT_OPTION = "--port"


@dataclass(frozen=True)
class UsedPort:
    """One output and the port it will open."""

    index: int  # in `outputs:`
    output: OutputConfig
    port: str | None  # None: no port at all
    replaced: str | None = None  # given by --port: the config's own port ("" if none)

    @property
    def name(self) -> str:
        """`outputs[1] (sumd)`: how messages name the output."""
        return f"outputs[{self.index}] ({self.output.protocol})"

    @property
    def from_option(self) -> bool:
        return self.replaced is not None


def used_ports(config: Config, port_override: str | None) -> tuple[UsedPort, ...]:
    """Every output with the port it will open: the first one's replaced by `--port`."""
    used = []
    for index, output in enumerate(config.outputs):
        if index == 0 and port_override:
            used.append(UsedPort(index, output, port_override, output.port or ""))
        else:
            used.append(UsedPort(index, output, output.port))
    return tuple(used)


def port_problems(config: Config, port_override: str | None) -> list[Problem]:
    """Every output without a port once `--port` replaced the first one's, every port that
    exists but cannot be a serial line, and every output whose line an earlier output
    already has. A path that does not exist is no problem: the adapter may be plugged
    later, and the output retries it every second."""
    used = used_ports(config, port_override)
    problems = [p for u in used if (p := _open_problem(config, u)) is not None]
    return problems + _shared_lines(config, used)


def _open_problem(config: Config, used: UsedPort) -> Problem | None:
    reason = _NO_PORT if not used.port else serial_line_problem(used.port)
    if reason is None:
        return None
    if used.from_option:
        return Problem(PORT_OPTION, None, None, f"{used.port}: {reason}")
    message = reason if not used.port else f"{used.port}: {reason}"
    return _at_port(config, used, message)


_NO_PORT = (
    "no port: set `port:` here, or give the first output's with --port PORT "
    "(to `usb2rc run` and to `usb2rc check` alike)"
)


def _at_port(config: Config, used: UsedPort, message: str) -> Problem:
    """At the output's `port:` in the file; zero config has no line."""
    where = used.output.where
    if where is not None:
        return where.problem(message, key_suffix=".port")
    return Problem(config.source, None, f"outputs[{used.index}].port", message)


# --------------------------------------------------------------------------- one line each


def line_of(port: str) -> str | None:
    """What two outputs must not share: the device a path names (a symlink such as
    /dev/serial0 is the device it points to), the device under `spy://`, a `udpin:` port
    (bound once), any other URL as written; None for what every output has on its own
    (`loop://`, a `udpout:` peer)."""
    if is_udp_url(port):
        try:
            address = parse_udp_url(port)
        except ValueError:
            return None  # the config's own check names it
        return f"udpin port {address.port}" if address.scheme == "udpin" else None
    scheme, sep, rest = port.partition("://")
    if not sep:
        return os.path.realpath(port)
    if scheme.lower() == "loop":
        return None
    if scheme.lower() == "spy":
        return line_of(rest.partition("?")[0])
    return port


def _shared_lines(config: Config, used: tuple[UsedPort, ...]) -> list[Problem]:
    """A problem for each output whose line an earlier output already uses."""
    first: dict[str, UsedPort] = {}
    problems = []
    for this in used:
        line = line_of(this.port) if this.port else None
        if line is None:
            continue
        if line not in first:
            first[line] = this
            continue
        problems.append(_shared(config, first[line], this, line))
    return problems


def _shared(config: Config, earlier: UsedPort, later: UsedPort, line: str) -> Problem:
    same = "" if earlier.port == later.port else f" (both are {line})"
    two = f"{later.port}{same} would carry two outputs"
    given, other = (earlier, later) if earlier.from_option else (later, earlier)
    if given.from_option:
        instead = f"in place of {given.replaced}" if given.replaced else "(it has none)"
        message = (
            f"{two}: {_placed(given)}, to which --port gives it {instead}, and "
            f"{_placed(other)}, whose `port:` it is. --port replaces the first output's port "
            f"only, and one line carries one output: give --port the line for "
            f"outputs[{given.index}], or change outputs[{other.index}].port"
        )
        return Problem(PORT_OPTION, None, None, message)
    message = (
        f"{two}: {_placed(earlier)} and {_placed(later)}. One line carries one output: give "
        "each output a port of its own"
    )
    return _at_port(config, later, message)


def _placed(used: UsedPort) -> str:
    """`outputs[1] (sumd, hotas.yaml:12)`."""
    where = used.output.where
    at = "" if where is None else f", {where.source}:{where.line}"
    return f"outputs[{used.index}] ({used.output.protocol}{at})"


# --------------------------------------------------------------------------- serial lines


def serial_line_problem(port: str) -> str | None:
    """Why an existing `port` path cannot be a serial line, or None (URLs and absent paths
    are not judged here). Opens nothing: opening a serial port can reset what is on it."""
    if "://" in port:
        return None
    try:
        mode = os.stat(port)
    except OSError:
        return None  # absent (plugged later), a UDP address, or a name only pyserial knows
    if stat.S_ISDIR(mode.st_mode):
        return "is a directory, not a serial line"
    if stat.S_ISREG(mode.st_mode):
        return "is a regular file, not a serial line"
    if not stat.S_ISCHR(mode.st_mode):
        return "is not a character device, so not a serial line"
    device_class = _char_device_class(mode.st_rdev)
    if device_class not in (None, "tty"):
        return f"is a {device_class} device, not a serial line (tty)"
    return None


def _char_device_class(rdev: int) -> str | None:
    """The kernel's class of a character device ("tty", "mem", ...), from sysfs; None when
    sysfs does not list it (pseudo-terminals, other systems)."""
    link = f"/sys/dev/char/{os.major(rdev)}:{os.minor(rdev)}/subsystem"
    if not os.path.exists(link):
        return None
    return os.path.basename(os.path.realpath(link))
