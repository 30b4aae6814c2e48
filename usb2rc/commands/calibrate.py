"""`usb2rc calibrate --config FILE [--replay DIR [--replay-loop]] [DEVICE]`: a terminal wizard.

For each axis of each config entry whose device is plugged in (or only the entry named
DEVICE) it shows the live raw value and asks you to move the axis through its whole range
(Enter), then to let it rest (Enter; `m` for an axis without a centre, a throttle or slider,
takes the midpoint). It writes `calibration: {min, center, max}` and, when the axis was not
perfectly still at rest, a suggested `deadband` into FILE, changing nothing else in it
(comments and layout stay). `s` skips an axis, `r` starts it again, `q` quits without
writing. Axes need an explicit `usage:` entry in the config (`usb2rc init` writes them).
Exit 0 written (or nothing to write), 1 quit or no device, 2 usage or config error.
"""

from __future__ import annotations

import argparse
import contextlib
import difflib
import os
import select
import sys
import termios
import threading
import tty
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

from usb2rc.commands.arguments import replay_dir
from usb2rc.commands.config_edit import AxisCalibration, EditError, set_calibrations
from usb2rc.commands.list_devices import UnreadableDevice, read_layout
from usb2rc.config.calibration import (
    AxisResult,
    AxisTarget,
    Step,
    Wizard,
)
from usb2rc.configfile import Config, ConfigError, DeviceConfig, load_config
from usb2rc.hid.backend import Backend, DeviceInfo, ErrorCode
from usb2rc.hid.choose import choose_backend
from usb2rc.hid.descriptor import DeviceLayout, InputState, ReportDecoder
from usb2rc.hid.hotplug import initial_devices
from usb2rc.hid.reader import DeviceReader
from usb2rc.nodes.binding import MappingError, usage_label
from usb2rc.nodes.mapping import compile_mapping
from usb2rc.runtime.textfile import write_atomically

REFRESH_S = 0.05  # the view and the samples: 20 Hz
BAR_WIDTH = 40
JOIN_S = 2.0


def add_parser(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "calibrate",
        help="interactive axis calibration, written into the config (comments kept)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("device", nargs="?", metavar="DEVICE", help="only this config entry")
    parser.add_argument("--config", metavar="FILE", help="the config to write into (required)")
    parser.add_argument(
        "--replay", metavar="DIR", type=replay_dir, help="hid-recorder files in DIR as devices"
    )
    parser.add_argument("--replay-loop", action="store_true", help="replay each recording forever")
    parser.set_defaults(func=run)


class UsageError(Exception):
    """Exit 2 with this message."""


class NothingToDo(Exception):
    """Exit 1 with this message: no device, or nothing in it to calibrate."""


# --------------------------------------------------------------------------- devices


class TrackingDecoder:
    """The device's decoder, plus the lowest / highest value of each field since the UI last
    looked (`take`): a flick to an end between two refreshes still counts. Fed by the reader
    thread, read by the UI thread, hence the lock (this is not the daemon's hot path)."""

    def __init__(self, inner: ReportDecoder) -> None:
        self._inner = inner
        self._lock = threading.Lock()
        self._low: dict[int, int] = {}
        self._high: dict[int, int] = {}

    def feed(self, report: bytes) -> bool:
        ok = self._inner.feed(report)
        if ok:
            values = self._inner.state().values
            with self._lock:
                for i, v in enumerate(values):
                    self._low[i] = min(self._low.get(i, v), v)
                    self._high[i] = max(self._high.get(i, v), v)
        return ok

    def feed_batch(
        self, reports: Sequence[bytes], on_buttons: Callable[[int], None] | None = None
    ) -> tuple[int, int]:
        """Each report, one by one (not the inner decoder's batch, which decodes only the
        last of each report ID): a flick in the middle of a batch counts too. `on_buttons`
        is never called: the reader asks for presses only from a decoder with `buttons`."""
        accepted = sum(self.feed(report) for report in reports)
        return accepted, len(reports) - accepted

    def state(self) -> InputState:
        return self._inner.state()

    def take(self, index: int, value: int) -> tuple[int, int]:
        """(lowest, highest) of field `index` since the last take, `value` included."""
        with self._lock:
            low = min(self._low.pop(index, value), value)
            high = max(self._high.pop(index, value), value)
        return low, high


@dataclass
class LiveDevice:
    info: DeviceInfo
    entry: DeviceConfig
    reader: DeviceReader
    decoder: TrackingDecoder
    gone: str = ""  # why it stopped, set by the reader thread

    def sample(self, index: int) -> tuple[int, int, int] | None:
        """(value, lowest, highest) of field `index`; None before the device's first report
        (its state is only the descriptor's centre then, not where the axis is)."""
        record = self.reader.record
        if not record.reports:
            return None
        value = record.state.values[index]
        low, high = self.decoder.take(index, value)
        return value, low, high


def axis_targets(config: Config, entry: DeviceConfig, layout: DeviceLayout) -> list[AxisTarget]:
    """The entry's axes with a usage source, in config order, found in the device's layout."""
    device = config.devices.index(entry)
    targets = []
    for axis in entry.axes:
        if axis.usage is None:  # hats and button pairs have no raw range
            continue
        field = next(
            f for f in layout.inputs if f.usage == axis.usage and f.occurrence == axis.occurrence
        )
        source = usage_label(field.usage, field.occurrence)
        targets.append(
            AxisTarget(
                device,
                entry.name,
                axis.slot,
                source,
                field.index,
                field.logical_min,
                field.logical_max,
                axis.deadband,
            )
        )
    return targets


def wanted_entry(config: Config, name: str | None) -> DeviceConfig | None:
    if name is None:
        return None
    for entry in config.devices:
        if entry.name == name:
            return entry
    names = [e.name for e in config.devices]
    close = difflib.get_close_matches(name, names, n=1)
    hint = f"; did you mean {close[0]!r}?" if close else ""
    raise UsageError(
        f"no device entry {name!r} in {config.source} (entries: {', '.join(names) or 'none'}){hint}"
    )


def open_devices(
    config: Config, backend: Backend, only: DeviceConfig | None
) -> tuple[list[LiveDevice], list[AxisTarget], list[str]]:
    """Open each plugged device that has an entry (the first device of each entry), start a
    reader on it; (devices, axes to calibrate, notes for the user)."""
    mapping = compile_mapping(config)
    devices: list[LiveDevice] = []
    targets: list[AxisTarget] = []
    notes: list[str] = []
    taken: set[str] = set()
    for info in initial_devices(backend):
        compiled = mapping.compiled_entry_for(info)
        label = f"{info.product or info.path} ({info.vid:04x}:{info.pid:04x})"
        if compiled is None or (only is not None and compiled.config != only):
            continue
        entry = compiled.config
        if entry.name in taken:
            notes.append(f"{label}: entry {entry.name!r} is calibrated on its first device")
            continue
        if entry.default_layout:
            notes.append(
                f"{label}: entry {entry.name!r} lists no axes (default layout); list them to "
                "calibrate them (`usb2rc init` writes them out)"
            )
            continue
        try:
            layout = read_layout(backend, info)
            compiled.bind(layout)  # a usage the device lacks: MappingError, naming the line
        except UnreadableDevice as exc:
            notes.append(f"{label}: {exc}")
            continue
        except MappingError as exc:
            raise UsageError(str(exc)) from None
        found = axis_targets(config, entry, layout)
        if not found:
            notes.append(f"{label}: entry {entry.name!r} has no axis with a usage source")
            continue
        devices.append(start_reader(backend, info, entry, layout))
        targets += found
        taken.add(entry.name)
    return devices, targets, notes


def start_reader(
    backend: Backend, info: DeviceInfo, entry: DeviceConfig, layout: DeviceLayout
) -> LiveDevice:
    decoder = TrackingDecoder(layout.make_decoder())
    holder: list[LiveDevice] = []

    def on_exit(_reader: DeviceReader, code: ErrorCode | None) -> None:
        if holder:
            holder[0].gone = "unplugged" if code is None else f"read failed ({code.name})"

    reader = DeviceReader(backend.open(info), decoder, on_exit)
    live = LiveDevice(info, entry, reader, decoder)
    holder.append(live)
    reader.start()
    return live


def stop_devices(devices: Sequence[LiveDevice]) -> None:
    for dev in devices:
        dev.reader.stop()
    for dev in devices:
        dev.reader.join(JOIN_S)


# --------------------------------------------------------------------------- keys


KEYS = {b"\r": "enter", b"\n": "enter"}  # Ctrl-C stays a signal (cbreak keeps ISIG)


@contextlib.contextmanager
def cbreak(fd: int) -> Iterator[None]:
    """Keys arrive one by one, unechoed; Ctrl-C still interrupts. Restored on the way out."""
    saved = termios.tcgetattr(fd)
    try:
        tty.setcbreak(fd)
        yield
    finally:
        termios.tcsetattr(fd, termios.TCSADRAIN, saved)


def read_keys(fd: int, timeout_s: float) -> list[str]:
    """The keys pressed within timeout_s (none: []). Escape sequences (arrows) are dropped."""
    ready, _, _ = select.select([fd], [], [], timeout_s)
    if not ready:
        return []
    data = os.read(fd, 64)
    if data.startswith(b"\x1b"):
        return []
    keys = []
    for byte in data:
        char = bytes([byte])
        keys.append(KEYS.get(char) or char.decode("ascii", "replace").lower())
    return keys


# --------------------------------------------------------------------------- the view


def bar(value: int, lo: int, hi: int, width: int = BAR_WIDTH) -> str:
    filled = round((min(max(value, lo), hi) - lo) * width / max(hi - lo, 1))
    return "#" * filled + "-" * (width - filled)


def result_line(result: AxisResult) -> str:
    cal, t = result.calibration, result.target
    line = f"  {t.entry}.{t.slot:<7} min {cal.min}  center {cal.center}  max {cal.max}"
    if result.deadband is not None:
        line += f"  deadband {result.deadband:g}"
    elif result.suggested_deadband:
        line += (
            f"  (deadband {t.deadband:g} kept: above the suggested {result.suggested_deadband:g})"
        )
    return line


def axis_lines(wizard: Wizard, device: LiveDevice) -> list[str]:
    t = wizard.target
    assert t is not None
    number, total = wizard.position
    lines = [
        f"axis {number} of {total}: {t.entry}.{t.slot} <- {t.source} "
        f"(logical {t.logical_min}..{t.logical_max})",
    ]
    if wizard.value is None:
        lines.append("raw       -  (no report from the device yet: move it)")
    else:
        value = wizard.value
        lines.append(f"raw {value:>7}  [{bar(value, t.logical_min, t.logical_max)}]")
    seen = wizard.range
    if wizard.step is Step.RANGE:
        lines.append("step 1 of 2: move it through its whole range, then press Enter")
        if seen.low is not None:
            lines.append(f"seen {seen.low}..{seen.high} ({wizard.travel():.0%} of the range)")
    else:
        rest = wizard.rest
        lines.append("step 2 of 2: let go of it, press Enter when it sits still")
        lines.append("             (no centre, a throttle or slider: press m for the midpoint)")
        lines.append(f"range {seen.low}..{seen.high}")
        if rest.low is not None:
            lines.append(
                f"at rest {rest.low}..{rest.high}, {len(rest.values)} samples" + rest_hint(wizard)
            )
    if device.gone:
        lines.append(f"DEVICE {device.gone}: s skips this axis, q quits")
    lines.append("keys: Enter next step, s skip axis, r restart axis, q quit without writing")
    return lines


def rest_hint(wizard: Wizard) -> str:
    preview = wizard.preview()
    if isinstance(preview, str):
        return f" ({preview})"
    cal = preview.calibration
    return f", centre {cal.center}, deadband {preview.suggested_deadband:g}: Enter takes it"


def summary_lines(wizard: Wizard, path: str) -> list[str]:
    lines = [f"calibration to write into {path}:"]
    lines += [result_line(r) for r in wizard.results]
    lines += [f"  {t.entry}.{t.slot:<7} skipped (left as it is)" for t in wizard.skipped]
    if wizard.results:
        lines.append(f"Enter: write {path}    q: quit without writing")
    else:
        lines.append("nothing to write: Enter or q ends")
    return lines


def render(wizard: Wizard, devices: dict[int, LiveDevice], path: str) -> Any:
    from rich.console import Group
    from rich.text import Text

    parts: list[Any] = [Text(f"usb2rc calibrate {path}", style="bold")]
    target = wizard.target
    if wizard.step is Step.SUMMARY or target is None:
        lines = summary_lines(wizard, path)
    else:
        lines = axis_lines(wizard, devices[target.device])
    parts += [Text(line) for line in lines]
    if wizard.message:
        parts.append(Text(wizard.message, style="bold yellow"))
    return Group(*parts)


def run_wizard(wizard: Wizard, devices: dict[int, LiveDevice], path: str, fd: int) -> None:
    from rich.console import Console
    from rich.live import Live

    with cbreak(fd), Live(console=Console(), auto_refresh=False) as live:
        while not wizard.finished:
            target = wizard.target
            if target is not None and wizard.step is not Step.SUMMARY:
                sample = devices[target.device].sample(target.field_index)
                if sample is not None:
                    wizard.observe(*sample)
            live.update(render(wizard, devices, path), refresh=True)
            for key in read_keys(fd, REFRESH_S):
                wizard.key(key)
                if wizard.finished:
                    break
        live.update(render(wizard, devices, path), refresh=True)


# --------------------------------------------------------------------------- the file


def write_results(path: str, original: str, results: Sequence[AxisResult]) -> str:
    """The edited text, written to path; raises EditError, or OSError."""
    with open(path, encoding="utf-8") as handle:
        if handle.read() != original:
            raise EditError(f"{path} changed while calibrating; run calibrate again")
    updates = [
        AxisCalibration(r.target.device, r.target.slot, r.calibration, r.deadband) for r in results
    ]
    text = set_calibrations(original, updates, path)
    write_atomically(path, text)
    return text


def load(path: str | None) -> tuple[Config, str]:
    if path is None:
        raise UsageError("--config FILE is required: the config to write into (usb2rc init)")
    try:
        with open(path, encoding="utf-8") as handle:
            text = handle.read()
        return load_config(path), text
    except OSError as exc:
        raise UsageError(f"{path}: cannot read: {exc.strerror or exc}") from None


def prepare(args: argparse.Namespace) -> tuple[Config, str, list[LiveDevice], list[AxisTarget]]:
    config, text = load(args.config)
    only = wanted_entry(config, args.device)
    if not (sys.stdin.isatty() and sys.stdout.isatty()):
        raise UsageError("calibrate is interactive: run it in a terminal")
    backend = choose_backend(args.replay, loop=args.replay_loop)
    devices, targets, notes = open_devices(config, backend, only)
    for note in notes:
        print(f"usb2rc calibrate: {note}", file=sys.stderr)
    if not targets:
        stop_devices(devices)
        which = f"entry {only.name!r}" if only else "any entry of the config"
        raise NothingToDo(f"no plugged device of {which} has an axis to calibrate")
    return config, text, devices, targets


def run(args: argparse.Namespace) -> int:
    try:
        config, text, devices, targets = prepare(args)
    except ConfigError as exc:
        print("\n".join(exc.errors), file=sys.stderr)
        return 2
    except UsageError as exc:
        print(f"usb2rc calibrate: {exc}", file=sys.stderr)
        return 2
    except NothingToDo as exc:
        print(f"usb2rc calibrate: {exc}", file=sys.stderr)
        return 1
    wizard = Wizard(targets)
    by_device = {t.device: d for d in devices for t in targets if t.entry == d.entry.name}
    try:
        run_wizard(wizard, by_device, args.config, sys.stdin.fileno())
    finally:
        stop_devices(devices)
    if wizard.step is Step.QUIT:
        print(f"quit: {args.config} unchanged")
        return 1
    if not wizard.results:
        print(f"nothing calibrated: {args.config} unchanged")
        return 0
    try:
        write_results(args.config, text, wizard.results)
    except (EditError, OSError) as exc:
        print(f"usb2rc calibrate: not written: {exc}", file=sys.stderr)
        return 1
    print(f"wrote {len(wizard.results)} calibration(s) into {config.source}")
    print(f"next: usb2rc check --config {args.config}")
    return 0
