"""`usb2rc monitor [--config FILE] [--replay DIR] [--seconds N] [--plain]`: a live input view.

For setting up a HOTAS: every node with its failsafe state, each axis as a bar with the value
it would carry on the wire, the raw HID value it comes from and the device and usage feeding
it, the pressed node buttons and the hat, the service events an output would send, and each
device's report count. It runs the daemon's own input side (hot-plug, one reader thread per
device, the compiled mapping, the node table) and opens no serial port unless `--outputs`
asks. On a terminal it redraws about 10 times a second (plain ANSI, fine over SSH); with
`--plain`, or when stdout is not a terminal, it prints a text snapshot once a second. With
`--outputs` it runs the config's outputs too (their ports are opened) and shows each
output's figures, a CRSF module's link quality and timing included, and what the far ends
say back: the telemetry as the feedback rules see it, each rule's last action and what each
driven device shows (docs/CONFIG.md "Feedback"), ahead of the other figures.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import sys
import textwrap
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

from usb2rc.commands.run import add_common_input_args, load_or_report, make_backend
from usb2rc.config.layout import AXIS_NAMES
from usb2rc.configfile import Config
from usb2rc.daemon import Daemon, NoPortError
from usb2rc.hid.backend import Backend, DeviceInfo, ErrorCode
from usb2rc.nodes.binding import DeviceBinding, describe_button_runs
from usb2rc.nodes.table import EventKind, NodeFrame, ServiceEvent
from usb2rc.protocols.c2_16b.receiver import NodeView
from usb2rc.runtime import stats_text

REFRESH_S = 0.1  # the live view: ~10 Hz
PLAIN_EVERY_S = 1.0  # --plain: one snapshot a second
BAR_WIDTH = 24
KEPT_LINES = 8  # events and log lines the live view keeps
LOG_SHOWN_S = 10.0  # the live views show a log line this long (the plain ones print it once)
PAGE_S = 4.0  # the live view shows each page of nodes this long when they do not all fit
FEEDBACK_INDENT = "    "  # a feedback line's continuation rows, in a narrow window
Preview = Callable[[list[NodeFrame]], str]  # a node snapshot -> what an output would send


def add_parser(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "monitor",
        help="live view of the nodes, axes, buttons and hats (no serial port needed)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_common_input_args(parser)
    parser.add_argument("--seconds", type=float, default=0.0, help="stop after N s (0: Ctrl-C)")
    parser.add_argument(
        "--plain", action="store_true", help="print a text snapshot every second instead"
    )
    parser.add_argument(
        "--outputs",
        action="store_true",
        help="also run the config's outputs (opens their ports) and show each output's "
        "figures, a CRSF module's link quality included, and the telemetry and feedback",
    )
    parser.set_defaults(func=run)


# --------------------------------------------------------------------------- input side


def output_previews(config: Config, daemon: Daemon) -> list[tuple[str, Preview]]:
    """For each MAVLink output: what it would send from a node snapshot (no port opened)."""
    previews: list[tuple[str, Preview]] = []
    for i, out in enumerate(config.outputs):
        if out.protocol != "mavlink":
            continue
        from usb2rc.config.mavlink import MavlinkOptions
        from usb2rc.protocols.mavlink.session import MavlinkChannels, preview_text

        message = MavlinkOptions.of(out).message
        channels = MavlinkChannels(daemon.mapping.sumd_channels(out), message)

        def preview(frames: list[NodeFrame], channels: MavlinkChannels = channels) -> str:
            return preview_text(channels, channels.evaluate(frames))

        previews.append((f"output {i + 1} mavlink {out.port or '(--port)'}", preview))
    return previews


class InputSide:
    """The daemon with its outputs left out: hot-plug, readers, mapping and the node table."""

    def __init__(self, config: Config, backend: Backend, outputs: bool = False) -> None:
        self.daemon = Daemon(config, backend, outputs=outputs)
        urls = ", ".join(out.link.url for out in self.daemon.outputs)
        self.ports = f"outputs on {urls}" if urls else "no serial port is opened"
        self.table = self.daemon.table
        self.previews = output_previews(config, self.daemon)
        # the service events an output would send (its own cursor in the table's event log);
        # buttons as they are now (no tap latch)
        self.event_cursor = 0
        self.events: deque[str] = deque(maxlen=200)
        self.event_total = 0

    def start(self) -> None:
        self.daemon.start()

    def stop(self) -> None:
        self.daemon.stop()

    def snapshot(self) -> Snapshot:
        table_now = self.table.step_if_due()
        frames = table_now.frames
        log = table_now.log
        events = log.since(self.event_cursor)
        if events is None:  # fell behind the log's bound: what it still keeps
            events = log.events
        self.event_cursor = log.end
        for event in events:
            self.events.append(event_text(event))
            self.event_total += 1
        described = self.table.describe()
        raw = self._raw_values()
        devices: dict[int, list[DeviceRow]] = {}
        for node_id, info, binding, present, _type in self.table.attachments():
            row = DeviceRow(info, binding, present, raw.get(info.key) if present else None)
            devices.setdefault(node_id, []).append(row)
        nodes = [
            self._node(f, described.get(str(f.node_id), {}), devices.get(f.node_id, []))
            for f in frames
        ]
        record = self.daemon.stats_record()
        told = record.pop("feedback", None)  # its own rows, ahead of the counters
        stats = stats_text.stats_lines(record)
        feedback = stats_text.feedback_lines(told) if told is not None else []
        outputs = [f"{name}: {preview(frames)}" for name, preview in self.previews]
        return Snapshot(
            nodes, list(self.events), self.event_total, stats, self.ports, outputs, feedback
        )

    def _raw_values(self) -> dict[str, tuple[int, ...]]:
        """Each reporting device's raw input values (its reader's last record), by key."""
        records = ((r.info.key, r.record) for r in self.daemon.lifecycle.readers)
        return {key: record.state.values for key, record in records if record.reports}

    def _node(
        self, frame: NodeFrame, described: dict[str, Any], devices: list[DeviceRow]
    ) -> NodeRow:
        view = NodeView(frame.node_id, group1=frame.group1, group2=frame.group2)
        return NodeRow(
            node_id=frame.node_id,
            failsafe=frame.failsafe,
            devices=devices,
            waiting=list(described.get("expected", [])),
            axes=axis_rows(frame, devices, described.get("trims", {})),
            buttons=view.pressed_buttons(),
            hat=view.hat(),
            waits_for=list(described.get("waiting_for", [])),
        )


def event_text(event: ServiceEvent) -> str:
    what = {
        EventKind.CONNECTED: "connected",
        EventKind.DISCONNECTED: "disconnected",
        EventKind.ERROR: "error",
    }[event.kind]
    text = f"node {event.node_id}: {what}"
    if event.kind is EventKind.ERROR:
        try:
            name = ErrorCode(event.error_code).name
        except ValueError:
            name = "unknown"
        text += f" 0x{event.error_code:02x} ({name})"
    if event.info is not None:
        text += f" {device_label(event.info)}"
    return text


# --------------------------------------------------------------------------- the view model


@dataclass(frozen=True)
class DeviceRow:
    info: DeviceInfo
    binding: DeviceBinding
    present: bool
    raw: tuple[int, ...] | None = None  # its raw input values; None: not reporting


@dataclass(frozen=True)
class AxisRow:
    slot: str
    value: int
    lo: int
    hi: int
    source: str  # "T.16000M: X (raw 0..16383)" or "" (no device feeds the slot)
    raw: int | None = None  # the raw HID value the sent one comes from; None: none now

    def raw_text(self) -> str:
        return f"raw {'-' if self.raw is None else self.raw:>6}"


@dataclass(frozen=True)
class NodeRow:
    node_id: int
    failsafe: bool
    devices: list[DeviceRow]
    waiting: list[str]  # config entries pinned here whose device has not come
    axes: list[AxisRow]
    buttons: list[int]
    hat: str
    waits_for: list[str] = field(default_factory=list)  # why it is `!` (the neutral guard ...)


@dataclass(frozen=True)
class Snapshot:
    nodes: list[NodeRow]
    events: list[str]
    event_total: int
    device_stats: list[str] = field(default_factory=list)  # and the outputs', with --outputs
    ports: str = "no serial port is opened"
    outputs: list[str] = field(default_factory=list)  # what each MAVLink output would send
    # with --outputs: the telemetry heard, each feedback rule's last action, what each
    # driven device shows (usb2rc.runtime.stats_text.feedback_lines)
    feedback: list[str] = field(default_factory=list)


def device_label(info: DeviceInfo) -> str:
    return f"{info.product or info.path} ({info.vid:04x}:{info.pid:04x}, port {info.port_path})"


def axis_rows(
    frame: NodeFrame, devices: list[DeviceRow], trims: dict[str, float] | None = None
) -> list[AxisRow]:
    """The slots a device feeds, and any other slot that is not 0 (a configured failsafe);
    `trims`: the node's stepped trims by slot name (docs/CONFIG.md, "Trims")."""
    rows = []
    for slot, (name, value) in enumerate(zip(AXIS_NAMES, frame.axes, strict=True)):
        feeder = next((d for d in devices if d.binding.axis_info[slot] is not None), None)
        if feeder is None:
            if value:
                rows.append(AxisRow(name, value, -32768, 32767, "(no device: config failsafe)"))
            continue
        info = feeder.binding.axis_info[slot]
        assert info is not None
        lo, hi = info.wire_range
        source = f"{feeder.info.product or feeder.info.path}: {info.source}"
        source += f" (raw {info.raw_min}..{info.raw_max}"
        source += "" if info.shaping == "linear" else f", {info.shaping}"
        if info.unsigned:
            source += ", unsigned"
        if trims and name in trims:
            source += f", trim {trims[name]:+.3f}"
        if not feeder.present:
            source += ", LOST: " + ("holds" if info.failsafe is None else "failsafe value")
        raw = None
        if feeder.raw is not None and info.field_index is not None:
            raw = feeder.raw[info.field_index]
        rows.append(AxisRow(name, value, lo, hi, source + ")", raw))
    return rows


def bar(value: int, lo: int, hi: int, width: int = BAR_WIDTH) -> str:
    """`[#######|-----]`-style: filled from the low end up to the value."""
    filled = round((min(max(value, lo), hi) - lo) * width / (hi - lo))
    return "#" * filled + "-" * (width - filled)


def state_name(node: NodeRow) -> str:
    if not node.failsafe:
        return "LIVE"
    return "FAILSAFE" + (f": waits for {', '.join(node.waits_for)}" if node.waits_for else "")


def device_lines(node: NodeRow) -> list[str]:
    lines = []
    for dev in node.devices:
        state = "" if dev.present else "  LOST (unplugged or failed)"
        entry = "" if dev.binding.name == dev.info.product else f" as {dev.binding.name}"
        lines.append(f"  device {device_label(dev.info)}{entry}{state}")
        runs = describe_button_runs(dev.binding.button_runs)
        lines += [f"    {line}" for line in [*runs, *dev.binding.hat_notes]]
        lines.append(f"    neutral guard: {dev.binding.guard.describe()}")
    lines += [f"  waiting for config entry {name}: not plugged" for name in node.waiting]
    return lines


def node_text(node: NodeRow) -> list[str]:
    lines = [f"node {node.node_id} {state_name(node)}"]
    lines += device_lines(node)
    for axis in node.axes:
        lines.append(
            f"  {axis.slot:<6} [{bar(axis.value, axis.lo, axis.hi)}] {axis.value:+6d}  "
            f"{axis.raw_text()}  <- {axis.source}"
        )
    lines.append(f"  buttons {' '.join(map(str, node.buttons)) or '-'}  hat {node.hat}")
    return lines


def snapshot_text(snap: Snapshot, log_lines: list[str]) -> str:
    head = f"usb2rc monitor: {len(snap.nodes)} node(s); {snap.ports}"
    lines = [head]
    for node in snap.nodes:
        lines += node_text(node)
    if not snap.nodes:
        lines.append("no devices (usb2rc list shows what is plugged and why a device is not used)")
    lines += [f"output: {line}" for line in snap.outputs]
    lines += snap.feedback  # each starts with its kind: "telemetry crsf: ", "feedback ..."
    lines += [f"stats: {line}" for line in snap.device_stats]
    lines += [f"event: {e}" for e in snap.events]
    lines += [f"log: {line}" for line in log_lines]
    return "\n".join(lines)


# --------------------------------------------------------------------------- rendering


@dataclass(frozen=True)
class NodeBlock:
    """A node's part of the live screen: the rows it must show (title, axes, buttons) and
    its device rows, shown when the window has room for them."""

    title: Any
    details: list[Any]
    table: Any
    buttons: Any
    axis_rows: int

    @property
    def essential_rows(self) -> int:
        return 2 + self.axis_rows


def _line(text: str, style: str = "") -> Any:
    """One screen row: cut with an ellipsis at the window's edge, never wrapped (a wrapped
    row would make the screen taller than the rows counted for it)."""
    from rich.text import Text

    return Text(text, style=style, no_wrap=True, overflow="ellipsis")


def node_block(node: NodeRow, width: int) -> NodeBlock:
    from rich.table import Table
    from rich.text import Text

    style = "bold red" if node.failsafe else "bold green"
    title = Text.assemble((f"node {node.node_id} ", "bold"), (state_name(node), style))
    title.no_wrap, title.overflow = True, "ellipsis"
    details = [_line(line, "red" if "LOST" in line else "dim") for line in device_lines(node)]
    # in a narrow window the bar gives up a third; then the device names shrink
    bar_width = max(8, min(BAR_WIDTH, width - 64))
    table = Table(box=None, show_header=False, pad_edge=False, padding=(0, 1))
    for column in ("slot", "bar", "value", "raw"):
        table.add_column(column, no_wrap=True)
    fixed = 6 + bar_width + 2 + 6 + 10 + 8  # slot, [bar], value, raw, the gaps between
    source_width = max(4, width - fixed)
    table.add_column("source", no_wrap=True, overflow="ellipsis", max_width=source_width)
    for axis in node.axes:
        table.add_row(
            f"{axis.slot:<6}",
            Text(f"[{bar(axis.value, axis.lo, axis.hi, bar_width)}]", style="cyan"),
            f"{axis.value:+6d}",
            axis.raw_text(),
            Text(f"<- {shorter_name(axis.source, source_width - 3)}", style="dim"),
        )
    buttons = _line(f"  buttons {' '.join(map(str, node.buttons)) or '-'}  hat {node.hat}")
    return NodeBlock(title, details, table, buttons, len(node.axes))


def shorter_name(source: str, width: int) -> str:
    """`Thrustmaster T.16000M: X (raw 0..16383)` in `width`: the device name shrinks first,
    so the usage and its range stay readable."""
    name, sep, rest = source.partition(": ")
    if len(source) <= width or not sep:
        return source
    keep = width - len(rest) - len(sep) - 1
    return name[:keep] + "…" + sep + rest if keep > 0 else rest


def paginate(rows: list[int], budget: int) -> list[list[int]]:
    """Node indexes in pages of at most `budget` rows (a node taller than that: a page alone)."""
    pages: list[list[int]] = [[]]
    used = 0
    for index, count in enumerate(rows):
        if pages[-1] and used + count > budget:
            pages.append([])
            used = 0
        pages[-1].append(index)
        used += count
    return pages


def feedback_rows(lines: list[str], width: int) -> list[Any]:
    """The telemetry and feedback lines in `width` columns: each wrapped (its continuation
    rows indented), never cut, so a line's age, at its end, stays on screen; a stale
    source's line in yellow."""
    rows = []
    for line in lines:
        style = "yellow" if "stale" in line else ""
        wrapped = textwrap.wrap(line, width, subsequent_indent=FEEDBACK_INDENT) or [""]
        rows += [_line(row, style) for row in wrapped]
    return rows


def render_live(
    snap: Snapshot,
    log_lines: list[str],
    size: tuple[int, int] | None = None,
    now: float = 0.0,
) -> Any:
    """The live screen; with `size` (columns, rows) it fits that window: the node rows first
    (in pages shown in turn, PAGE_S each, when they do not fit together), then outputs,
    the telemetry and feedback, device rows, log lines, events and stats as room allows;
    what is left out is counted."""
    from rich.console import Group

    width, height = size or (10_000, 10_000)
    blocks = [node_block(node, width) for node in snap.nodes]
    budget = height - 3  # the header, the "hidden" row, and a spare (a full window scrolls)
    pages = paginate([b.essential_rows for b in blocks], budget)
    page = int(now / PAGE_S) % len(pages)
    shown = [blocks[i] for i in pages[page]]
    room = budget - sum(b.essential_rows for b in shown)
    if not snap.nodes:
        room -= 1

    outputs = [
        _line(f"output: {line}", "red" if "FAILSAFE" in line else "") for line in snap.outputs
    ]
    feedback = feedback_rows(snap.feedback, width)
    stats = [_line(f"stats: {line}", "dim") for line in snap.device_stats]
    events = [_line(f"event: {line}") for line in snap.events[-KEPT_LINES:]]
    logs = [_line(f"log: {line}", "yellow") for line in log_lines[-KEPT_LINES:]]
    hidden = 0

    def take(parts: list[Any], newest: bool = False) -> list[Any]:
        nonlocal room, hidden
        count = max(0, min(room, len(parts)))
        room -= count
        hidden += len(parts) - count
        return parts[len(parts) - count :] if newest else parts[:count]

    outputs = take(outputs)
    feedback = take(feedback)
    details = [take(b.details) for b in shown]
    logs, events, stats = take(logs, True), take(events, True), take(stats)

    header = f"usb2rc monitor: {len(snap.nodes)} node(s); {snap.ports}; Ctrl-C stops"
    if len(pages) > 1:  # first: the row is cut at the window's edge
        ids = [snap.nodes[i].node_id for i in pages[page]]
        header = f"page {page + 1}/{len(pages)} (nodes {ids[0]}-{ids[-1]}): " + header
    parts: list[Any] = [_line(header)]
    for block, rows in zip(shown, details, strict=True):
        parts += [block.title, *rows, block.table, block.buttons]
    if not snap.nodes:
        parts.append(
            _line("no devices (usb2rc list shows what is plugged and why a device is not used)")
        )
    parts += [*outputs, *feedback, *stats, *events, *logs]
    if hidden:
        parts.append(_line(f"... {hidden} lines hidden: a taller window or --plain shows them"))
    return Group(*parts)


class LogLines(logging.Handler):
    """Collects the daemon's log lines for the view (stderr would tear the live screen),
    each with its time of day: `since(n)` for what is new (the plain views print each line
    once), `recent()` for the live views, which keep a line LOG_SHOWN_S and then let it go
    (a warning that was true at the plug must not stay on screen once the node is live)."""

    def __init__(self, level: int = logging.INFO) -> None:
        super().__init__(level)
        self.lines: deque[tuple[float, str]] = deque(maxlen=200)  # (monotonic, text)
        self.total = 0
        self._lock_lines = threading.Lock()

    def emit(self, record: logging.LogRecord) -> None:
        stamp = time.strftime("%H:%M:%S", time.localtime(record.created))
        text = f"{stamp} {record.levelname} {record.getMessage()}"
        with self._lock_lines:
            self.lines.append((time.monotonic(), text))
            self.total += 1

    def since(self, seen: int) -> list[str]:
        with self._lock_lines:
            new = min(self.total - seen, len(self.lines))
            return [text for _, text in list(self.lines)[-new:]] if new > 0 else []

    def recent(self, now: float | None = None, shown_s: float = LOG_SHOWN_S) -> list[str]:
        """The lines logged in the last `shown_s` seconds, oldest first."""
        now = time.monotonic() if now is None else now
        with self._lock_lines:
            return [text for at, text in self.lines if now - at < shown_s]


@contextmanager
def captured_log(handler: logging.Handler) -> Iterator[None]:
    """The `usb2rc` loggers write to `handler` only (not stderr) while inside."""
    logger = logging.getLogger("usb2rc")
    old_level, old_propagate = logger.level, logger.propagate
    logger.addHandler(handler)
    logger.setLevel(min(handler.level, logging.INFO))
    logger.propagate = False
    try:
        yield
    finally:
        logger.removeHandler(handler)
        logger.setLevel(old_level)
        logger.propagate = old_propagate


def _show_live(side: InputSide, logs: LogLines, until: float) -> None:
    from rich.console import Console
    from rich.live import Live

    console = Console()
    with Live(console=console, auto_refresh=False, redirect_stderr=False) as live:
        while True:
            snap = side.snapshot()
            size = (console.size.width, console.size.height)  # the window may be resized
            live.update(render_live(snap, logs.recent(), size, time.monotonic()), refresh=True)
            if time.monotonic() >= until:
                break
            time.sleep(max(0.0, min(REFRESH_S, until - time.monotonic())))


def _show_plain(side: InputSide, logs: LogLines, until: float) -> None:
    events_seen = logs_seen = 0
    start = next_print = time.monotonic()
    while True:
        now = time.monotonic()
        if now >= next_print:
            snap = side.snapshot()
            fresh = min(len(snap.events), snap.event_total - events_seen)
            shown = dataclasses.replace(snap, events=snap.events[len(snap.events) - fresh :])
            print(f"--- {now - start:.1f} s", flush=True)
            print(snapshot_text(shown, logs.since(logs_seen)), flush=True)
            events_seen, logs_seen = snap.event_total, logs.total
            next_print += PLAIN_EVERY_S
        else:
            # between snapshots the nodes are still evaluated ~10 times a second, as the
            # live view does: the neutral guard sees a stick at rest (docs/ICD.md)
            side.table.frames()
        if now >= until:
            break
        time.sleep(max(0.0, min(REFRESH_S, until - now, next_print - now)))


def run(args: argparse.Namespace) -> int:
    config = load_or_report(args.config)
    if config is None:
        return 2
    try:
        side = InputSide(config, make_backend(args), outputs=args.outputs)
    except NoPortError as exc:
        print(f"usb2rc monitor --outputs: {exc}", file=sys.stderr)
        return 2
    logs = LogLines()
    until = time.monotonic() + args.seconds if args.seconds > 0 else float("inf")
    with captured_log(logs):
        try:
            side.start()
            show = _show_plain if args.plain or not sys.stdout.isatty() else _show_live
            show(side, logs, until)
        except KeyboardInterrupt:
            pass
        finally:
            side.stop()
    return 0
