"""How an output's running pieces are wired: what a protocol's build function gets
(`OutputContext`), what it gives back (`BuiltOutput`), and the driver that runs its session
over its link (`running`, or `on_serial_port`: a serial link and its reader thread).

Each protocol's build function is in its package (`usb2rc.protocols.<name>.output`, its
registry row's `build`): it makes the protocol's session and hands it, with its link, to the
one generic driver (`usb2rc.lines.driver.LineDriver`) through these. `usb2rc.daemon` builds
each configured output through the registry (`usb2rc.outputs.build`) and only starts and
stops what comes back. pyserial is imported when a serial output is built: the commands that
only read the registry (`decode`, `check`, `icd`) load no port library.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from usb2rc.config.model import OutputConfig
from usb2rc.lines.driver import LineDriver
from usb2rc.lines.link import Link
from usb2rc.lines.rx import LinkReader
from usb2rc.lines.session import LineSession
from usb2rc.nodes.mapping import Mapping
from usb2rc.nodes.table import NodeTable


@dataclass(frozen=True)
class OutputContext:
    """What a build function gets: the output's name and config, the compiled
    mapping, the node table, the daemon's hooks and version."""

    name: str
    config: OutputConfig
    mapping: Mapping
    table: NodeTable
    on_tick: Callable[[], None] | None = None
    on_first_write: Callable[[], None] | None = None
    version: str = ""
    alone: bool = False  # the daemon's only output: no lead (`lines.driver.LineDriver`)


@dataclass
class BuiltOutput:
    """A running output's pieces: its link, its driver and, when the link is read on its
    own thread (a serial link), the reader. The daemon uses of `link` its `Link` side
    (`open_now()`, `is_open`, `url`, `last_error`, `stats`, `close()`), of `driver` (run by
    the drivers' thread, `lines.driver.DriverThread`) its `stats`, `period_s`,
    `last_tick_monotonic` and `protocol_stats()`."""

    link: Link
    driver: LineDriver
    rx: LinkReader | None = None


def running(context: OutputContext, link: Link, session: LineSession) -> BuiltOutput:
    """The driver of `session` over `link` at the configured rate (a link the driver polls
    itself: UDP)."""
    driver = LineDriver(
        context.name,
        link,
        session,
        context.table.step_if_due,
        1.0 / context.config.rate_hz,
        context.on_tick,
        context.on_first_write,
        alone=context.alone,
    )
    return BuiltOutput(link, driver)


def on_serial_port(context: OutputContext, session: LineSession, **framing: Any) -> BuiltOutput:
    """`session` on the output's serial port (`framing`: pyserial's parity and stop bits
    when not 8N1), read by a reader thread of its own."""
    from usb2rc.lines.serial_link import SerialLink  # pyserial: only when an output is built

    out = context.config
    assert out.port
    link = SerialLink(out.port, out.baudrate, **framing)
    built = running(context, link, session)
    built.rx = LinkReader(f"{context.name}-rx", link)
    return built
