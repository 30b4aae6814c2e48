"""`usb2rc demo [--seconds N]`: the real daemon on replayed devices and a pseudo-terminal.

A stick and a throttle (shipped hid-recorder recordings) plug in, move, unplug and come
back on a loop; the daemon writes real C2-16B frames to a pty, and the other end of that pty
is decoded and shown as a receiver would see it.
"""

from __future__ import annotations

import argparse
import logging
import os
import select
import shutil
import sys
import tempfile
import threading
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from importlib import resources
from pathlib import Path

from usb2rc.commands.monitor import LogLines, captured_log
from usb2rc.config.layout import AXIS_NAMES
from usb2rc.configfile import Config
from usb2rc.daemon import Daemon
from usb2rc.hid.replay import ReplayBackend, install_file
from usb2rc.protocols.c2_16b.receiver import NodeView, ReceiverModel
from usb2rc.runtime.worker import Worker

log = logging.getLogger("usb2rc.demo")

# (seconds into the cycle, action, recording): the plug / unplug script of one cycle.
SCRIPT: tuple[tuple[float, str, str], ...] = (
    (0.0, "plug", "stick.hid"),
    (1.5, "plug", "throttle.hid"),
    (12.0, "unplug", "stick.hid"),
    (15.0, "plug", "stick.hid"),
    (19.0, "unplug", "throttle.hid"),
    (21.0, "plug", "throttle.hid"),
)
CYCLE_S = 24.0
JOIN_S = 1.0  # how long stop waits for each demo thread
KEPT_LOG_LINES = 4  # the live screen's newest daemon log lines (unplug warnings and such),
# each shown for monitor.LOG_SHOWN_S


def add_parser(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "demo", help="run usb2rc on built-in replayed devices and show what a receiver decodes"
    )
    parser.add_argument("--seconds", type=float, default=0.0, help="stop after N s (0: Ctrl-C)")
    parser.add_argument(
        "--plain", action="store_true", help="print text lines instead of a live screen"
    )
    parser.set_defaults(func=run)


def demo_recordings() -> dict[str, str]:
    folder = resources.files("usb2rc") / "data" / "demo"
    return {name: (folder / name).read_text() for name in ("stick.hid", "throttle.hid")}


class PlugScript(Worker):
    """Copies recordings into (and removes them from) the replay folder on a schedule."""

    def __init__(self, folder: Path, recordings: dict[str, str]) -> None:
        super().__init__("demo-plugs")
        self.folder = folder
        self.recordings = recordings

    def run(self) -> None:
        start = time.monotonic()
        cycle = 0
        while not self.stopping:
            for at, action, name in SCRIPT:
                due = start + cycle * CYCLE_S + at
                if self.sleep(max(0.0, due - time.monotonic())):
                    return
                self._apply(action, name)
            cycle += 1

    def _apply(self, action: str, name: str) -> None:
        path = self.folder / name
        if action == "plug":
            install_file(path, self.recordings[name])  # appears whole, never half a file
        else:
            path.unlink(missing_ok=True)


class PtyReceiver(Worker):
    """Reads the far end of the pty and folds what it decodes into a ReceiverModel."""

    def __init__(self, master_fd: int, model: ReceiverModel) -> None:
        super().__init__("demo-receiver")
        self.master_fd = master_fd
        self.model = model
        self.lock = threading.Lock()

    def run(self) -> None:
        while not self.stopping:
            ready, _, _ = select.select([self.master_fd], [], [], 0.1)
            if not ready:
                continue
            try:
                data = os.read(self.master_fd, 4096)
            except OSError:  # the daemon closed its end for a moment
                self.sleep(0.05)
                continue
            with self.lock:
                self.model.feed(data)


def axis_bar(value: int, width: int = 21) -> str:
    pos = round((value + 32768) / 65535 * (width - 1))
    return "".join(
        "|" if i == width // 2 and i != pos else ("#" if i == pos else "-") for i in range(width)
    )


def node_lines(node: NodeView) -> list[str]:
    state = {">": "LIVE", "!": "FAILSAFE"}.get(node.status, node.status)
    lines = [
        f"node {node.node_id} {state:<8} code {node.code:3d}  {node.product} "
        f"{node.vid_pid} {node.device_type}  frames {node.frames}, code gaps {node.code_gaps}"
    ]
    for name, value in zip(AXIS_NAMES, node.axes, strict=True):
        if value:
            lines.append(f"  {name:<6} {axis_bar(value)} {value:+6d}")
    buttons = node.pressed_buttons()
    lines.append(f"  buttons {buttons or '-'}  hat {node.hat()}")
    return lines


def screen_text(
    model: ReceiverModel,
    port: str,
    log_lines: Sequence[str] = (),
    size: tuple[int, int] | None = None,
) -> str:
    """The receiver's view; with `size` (columns, rows) it fits that window: each line cut to
    the width, and the oldest events, then log lines, left out first (their count shown).
    A screen taller or wider than the window leaves stale lines behind on a terminal."""
    head = [f"usb2rc demo: daemon -> {port} -> receiver (Ctrl-C stops)", ""]
    for node_id in sorted(model.nodes):
        head.extend(node_lines(model.nodes[node_id]))
    d = model.decoder
    head += [
        "",
        f"frames {d.frames}, bytes skipped {d.bytes_skipped}, CRC failures {d.crc_failures}",
    ]
    events = [f"  {event}" for event in model.events]
    logs = [f"log: {line}" for line in log_lines]
    if size is not None:
        if len(head) + len(events) + len(logs) + 2 > size[1]:  # +2: the title, a spare row
            head = [line for line in head if line]  # the blank lines go first
        events, logs = _fit_tails(events, logs, size[1] - len(head) - 2)
    lines = [*head, events_title(model.event_total, len(events)), *events, *logs]
    if size is not None:
        lines = [_cut(line, size[0]) for line in lines[: max(1, size[1] - 1)]]
    return "\n".join(lines)


def events_title(total: int, shown: int) -> str:
    if shown == total:
        return "service events:"
    if shown == 0:
        return f"service events: {total} (a taller window shows the last ones)"
    return f"service events: {total}, the last {shown}:"


def _fit_tails(events: list[str], logs: list[str], rows: int) -> tuple[list[str], list[str]]:
    """The newest events and log lines that fit in `rows` (log lines, the warnings, first)."""
    rows = max(0, rows)
    logs = logs[len(logs) - min(len(logs), rows) :]
    room = rows - len(logs)
    return events[len(events) - min(len(events), room) :], logs


def _cut(line: str, width: int) -> str:
    return line if len(line) < width else line[: max(0, width - 2)] + "…"


@contextmanager
def staged_folder() -> Iterator[Path]:
    folder = Path(tempfile.mkdtemp(prefix="usb2rc-demo-"))
    try:
        yield folder
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def _show_live(model: ReceiverModel, receiver: PtyReceiver, port: str, until: float) -> None:
    """Redraws in place; the daemon's log lines go into the screen, not to stderr (a write to
    the terminal under the live screen would leave its old lines behind)."""
    from rich.console import Console
    from rich.live import Live
    from rich.text import Text

    console = Console()
    logs = LogLines(logging.WARNING)
    with captured_log(logs), Live(console=console, auto_refresh=False) as live:
        while True:
            size = (console.size.width, console.size.height)  # the window may be resized
            with receiver.lock:
                text = screen_text(model, port, logs.recent()[-KEPT_LOG_LINES:], size)
            live.update(Text(text, no_wrap=True, overflow="ellipsis"), refresh=True)
            if time.monotonic() >= until:
                break
            time.sleep(max(0.0, min(0.1, until - time.monotonic())))


def _show_plain(model: ReceiverModel, receiver: PtyReceiver, port: str, until: float) -> None:
    printed_events = 0
    next_summary = time.monotonic()
    while time.monotonic() < until:
        with receiver.lock:
            for event in model.events_since(printed_events):
                print(f"event: {event}", flush=True)
            printed_events = model.event_total
            if time.monotonic() >= next_summary:
                for node_id in sorted(model.nodes):
                    print(node_lines(model.nodes[node_id])[0], flush=True)
                next_summary += 1.0
        time.sleep(0.05)


def run(args: argparse.Namespace) -> int:
    logging.basicConfig(  # the plain view's log lines, with their time as the live view's
        level=logging.WARNING, format="%(asctime)s %(levelname)s %(message)s", datefmt="%H:%M:%S"
    )
    master_fd, slave_fd = os.openpty()
    port = os.ttyname(slave_fd)
    model = ReceiverModel()
    receiver = PtyReceiver(master_fd, model)
    until = time.monotonic() + args.seconds if args.seconds > 0 else float("inf")
    with staged_folder() as folder:
        plugs = PlugScript(folder, demo_recordings())
        daemon = Daemon(Config.default(), ReplayBackend(folder, loop=True), port_override=port)
        receiver.start()
        daemon.start()
        plugs.start()
        try:
            show = _show_plain if args.plain or not sys.stdout.isatty() else _show_live
            show(model, receiver, port, until)
        except KeyboardInterrupt:
            pass
        finally:
            plugs.stop()
            daemon.stop()
            receiver.stop()
            plugs.join(JOIN_S)
            receiver.join(JOIN_S)
            os.close(master_fd)
            os.close(slave_fd)
    return 0
