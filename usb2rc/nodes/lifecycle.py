"""DeviceLifecycle: the one thread that owns every device's life cycle.

Plug, unplug, a reader's exit, an open retry and a config reload are events, handled here
one at a time and in the order they came. Only this thread opens devices, starts and stops
readers, assigns Node-IDs and adds devices to or removes them from the NodeTable, so none of
that needs a lock of its own and no ordering between threads can change the outcome:

- a reload queued during a plug is handled before or after it, never in the middle: the
  device is bound with the new mapping either way (rebound, or bound afterwards);
- a reader is identified by itself, not by its hidraw path (the kernel reuses paths): a late
  exit of an old reader finds another reader under that path and is ignored;
- a device whose open failed (permission, busy) is tried again every `retry_s` while it is
  plugged: `3` with its error code once, the connect sequence when it opens;
- a device whose reports are all refused (its reader says so) gets `3` (BAD_REPORTS) and
  one log line per run of bad reports;
- a reload that pins a live device to another node moves it there (`2` on the old node, the
  connect sequence on the new one), and a pinned entry without a device is logged a few
  seconds after start and then once a minute (usb2rc.nodes.missing keeps the times).

This thread's wait for the next event ends when a retry or a warning is due: it is the one
clock for both.

The hot-plug monitor (its own thread, blocked in udev or a poll) only posts events here.
"""

from __future__ import annotations

import contextlib
import logging
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from usb2rc.config.unfed import DeviceFeed, unfed_slot_warnings
from usb2rc.hid.backend import (
    Backend,
    Device,
    DeviceGone,
    DeviceInfo,
    DevicePermissionError,
    ErrorCode,
)
from usb2rc.hid.descriptor import DescriptorError, DeviceLayout, parse_descriptor
from usb2rc.hid.reader import BAD_REPORTS_LIMIT, DeviceReader, OnExit, ReaderRecord
from usb2rc.hid.usages import device_type_name
from usb2rc.nodes.binding import DeviceBinding, MappingError
from usb2rc.nodes.mapping import Mapping
from usb2rc.nodes.missing import MissingWarnings
from usb2rc.nodes.node_ids import NodeIdAllocator, NodeIdError
from usb2rc.nodes.table import Expected, NodeTable
from usb2rc.runtime import stats_text
from usb2rc.runtime.worker import Worker

log = logging.getLogger("usb2rc")

RETRY_S = 1.0  # a device that could not be opened is tried again this often while plugged

MakeReader = Callable[[Device, DeviceLayout, OnExit], DeviceReader]


@dataclass(frozen=True)
class Plugged:
    info: DeviceInfo


@dataclass(frozen=True)
class Unplugged:
    info: DeviceInfo


@dataclass(frozen=True)
class ReaderExited:
    reader: DeviceReader
    code: ErrorCode | None


@dataclass(frozen=True)
class BadReports:
    """The reader's device entered or left error (all reports refused), in `record`."""

    reader: DeviceReader
    record: ReaderRecord


@dataclass(frozen=True)
class Reload:
    mapping: Mapping
    expected: Expected
    done: threading.Event


@dataclass(frozen=True)
class _Stop:
    pass


Event = Plugged | Unplugged | ReaderExited | BadReports | Reload | _Stop


@dataclass
class _Present:
    reader: DeviceReader
    layout: DeviceLayout
    bad_spells_told: int = 0  # the reader's runs of bad reports already logged and sent


@dataclass
class _Failed:
    """A plugged device that could not be opened: tried again at `next_try`."""

    info: DeviceInfo
    code: ErrorCode
    next_try: float


@dataclass(frozen=True)
class _Opened:
    device: Device
    layout: DeviceLayout
    binding: DeviceBinding


class _OpenFailed(Exception):
    """Open failed in a way worth trying again while the device stays plugged."""

    def __init__(self, code: ErrorCode) -> None:
        super().__init__(code)
        self.code = code


class DeviceLifecycle(Worker):
    def __init__(
        self,
        backend: Backend,
        table: NodeTable,
        mapping: Mapping,
        make_reader: MakeReader,
        forget: Callable[[str], None] = lambda key: None,
        retry_s: float = RETRY_S,
        carries_channels: Callable[[str], bool] | None = None,
    ) -> None:
        """`forget(key)`: make the hot-plug monitor report a device again if it is still
        present (after its reader ended: a read error, or a replug on a reused path).
        `carries_channels(protocol)`: whether an output of that protocol sends channels
        (the output registry's, which sits above this package); given, a plugged device's
        node is checked for channels that read an axis slot none of its devices feeds."""
        self.backend = backend
        self._carries_channels = carries_channels
        self.table = table
        self.mapping = mapping
        self.allocator = NodeIdAllocator(mapping.pinned_node_ids())
        self._make_reader = make_reader
        self._forget = forget
        self._retry_s = retry_s
        self._events: queue.SimpleQueue[Event] = queue.SimpleQueue()
        self._present: dict[str, _Present] = {}
        self._failed: dict[str, _Failed] = {}
        self._missing = MissingWarnings()
        # Published for other threads (statistics) by one assignment; never mutated.
        self.readers: tuple[DeviceReader, ...] = ()
        # Told after each event it handled (feedback's ring); set before start().
        self.on_devices: Callable[[], None] | None = None
        super().__init__("device-lifecycle")

    # --- what other threads call: they only post events ----------------------------------

    def post(self, event: Event) -> None:
        self._events.put(event)

    def plugged(self, info: DeviceInfo) -> None:
        self.post(Plugged(info))

    def unplugged(self, info: DeviceInfo) -> None:
        self.post(Unplugged(info))

    def reader_exited(self, reader: DeviceReader, code: ErrorCode | None) -> None:
        self.post(ReaderExited(reader, code))

    def bad_reports(self, reader: DeviceReader, record: ReaderRecord) -> None:
        self.post(BadReports(reader, record))

    def reload(self, mapping: Mapping, expected: Expected, timeout_s: float = 5.0) -> bool:
        """Queue a reload and wait until this thread has applied it (True), or timeout."""
        done = threading.Event()
        self.post(Reload(mapping, expected, done))
        if not self.is_alive():
            self.handle_queued()  # not started, or stopped: nobody else owns the devices
        return done.wait(timeout_s)

    def stop(self) -> None:
        super().stop()
        self.post(_Stop())  # wakes the thread out of its wait for the next event

    def shutdown(self, join_s: float) -> list[DeviceReader]:
        """End the thread, then stop every reader; returns them so the caller can join."""
        self.stop()
        self.join(join_s)
        readers = [p.reader for p in self._present.values()]
        self._present.clear()
        self.readers = ()
        for reader in readers:
            reader.stop()
        return readers

    # --- the thread ----------------------------------------------------------------------

    def handle_queued(self) -> None:
        """Handle what is queued now (start-up, before the thread runs; tests)."""
        while True:
            try:
                event = self._events.get_nowait()
            except queue.Empty:
                return
            if isinstance(event, _Stop):
                self._events.put(event)
                return
            self._handle_safely(event)

    def run(self) -> None:
        self._timers_due()  # the entries missing at start: their warnings' clock starts now
        while True:
            try:
                event = self._events.get(timeout=self._wait_s())
            except queue.Empty:
                self._timers_due()
                continue
            if isinstance(event, _Stop):
                return
            self._handle_safely(event)
            self._timers_due()

    def _wait_s(self) -> float | None:
        dues = [f.next_try for f in self._failed.values()]
        warning = self._missing.next_due()
        if warning is not None:
            dues.append(warning)
        if not dues:
            return None
        return max(0.0, min(dues) - time.monotonic())

    def _timers_due(self) -> None:
        self._retry_due()
        self._warn_missing()

    def _warn_missing(self) -> None:
        """A pinned entry without a device: its node is `!` for it, and the log says so
        (first after FIRST_WARNING_S, then once a minute; usb2rc.nodes.missing)."""
        for entry in self._missing.due(self.table.missing_entries(), time.monotonic()):
            log.warning(
                "%s: plug it in, or fix the entry's `match:` (`usb2rc list` shows what is plugged)",
                stats_text.missing_line(entry.record()),
            )

    def _handle_safely(self, event: Event) -> None:
        try:
            self._handle(event)
        except Exception:  # one bad event must not end device handling for all
            log.exception("device lifecycle: handling %s failed", type(event).__name__)
        if self.on_devices is not None:
            self.on_devices()  # feedback looks at the devices again (what plugged, went)

    def _handle(self, event: Event) -> None:
        if isinstance(event, Plugged):
            self._failed.pop(event.info.key, None)
            self._unplug(event.info.key)  # a reused path: the old device is gone
            self._add(event.info)
        elif isinstance(event, Unplugged):
            self._failed.pop(event.info.key, None)
            self._unplug(event.info.key)
        elif isinstance(event, ReaderExited):
            self._reader_ended(event.reader, event.code)
        elif isinstance(event, BadReports):
            self._bad_reports(event.reader, event.record)
        elif isinstance(event, Reload):
            self._reload(event)

    # --- devices -------------------------------------------------------------------------

    def _add(self, info: DeviceInfo, failed: _Failed | None = None) -> None:
        try:
            opened = self._open_and_bind(info, failed)
        except _OpenFailed as exc:
            self._failed[info.key] = _Failed(info, exc.code, time.monotonic() + self._retry_s)
            return
        if opened is not None:
            self._attach(info, opened)

    def _retry_due(self) -> None:
        now = time.monotonic()
        for key, failed in list(self._failed.items()):
            if failed.next_try <= now:
                del self._failed[key]
                self._add(failed.info, failed)

    def _unplug(self, key: str) -> None:
        present = self._present.pop(key, None)
        if present is None:
            return
        self._publish_readers()
        present.reader.stop()
        self.table.remove_device(key, source=present.reader)
        self.allocator.release(present.reader.info)  # its node stays (failsafe) in the table

    def _reader_ended(self, reader: DeviceReader, code: ErrorCode | None) -> None:
        key = reader.info.key
        present = self._present.get(key)
        if present is None or present.reader is not reader:
            return  # an old reader: its device was already taken off (unplug, replug)
        del self._present[key]
        self._publish_readers()
        self.table.remove_device(key, int(code) if code else None, source=reader)
        self.allocator.release(reader.info)
        # Still plugged (a transient read error, or a replug on the same path before the
        # monitor saw the unplug)? Then the next scan reports it again and it is reopened.
        self._forget(key)

    def _bad_reports(self, reader: DeviceReader, record: ReaderRecord) -> None:
        """`3` (BAD_REPORTS) and an error line once per run of refused reports; a line
        when its reports are good again (it goes live through the neutral guard)."""
        present = self._present.get(reader.info.key)
        if present is None or present.reader is not reader:
            return  # an old reader
        info = reader.info
        label = f"{info.product or info.path} ({info.vid:04x}:{info.pid:04x})"
        if record.bad_spells > present.bad_spells_told:
            present.bad_spells_told = record.bad_spells
            node_id = self.table.device_error(info.key, int(ErrorCode.BAD_REPORTS), reader)
            log.error(
                "%s: %d reports in a row were refused (a report ID its descriptor does not "
                "declare, or shorter than declared): node %s sends `!` and `3` (error 0x%02x, "
                "BAD_REPORTS). Check its descriptor with `usb2rc describe`; some devices "
                "need another mode (a switch or a driver) to send what they declare",
                label,
                max(record.refused_in_a_row, BAD_REPORTS_LIMIT),
                "?" if node_id is None else node_id,
                int(ErrorCode.BAD_REPORTS),
            )
        if not record.in_error:
            log.warning(
                "%s: its reports are understood again (%d refused in all): live once its "
                "guarded axes rest",
                label,
                record.bad_reports,
            )

    def _publish_readers(self) -> None:
        self.readers = tuple(p.reader for p in self._present.values())

    def _open(self, info: DeviceInfo, failed: _Failed | None) -> Device | None:
        """The open device; None when it is gone; _OpenFailed to try again later. The error
        is reported (log, `3`) on the first failure only, not on every retry."""
        try:
            return self.backend.open(info)
        except DeviceGone:
            # Listed but without a node: unplugged meanwhile, or a scan that came between
            # the kernel's sysfs entry and its /dev node. Let the monitor report it again if
            # it is still listed on its next scan (not an error: nothing to tell the far end).
            self._forget(info.key)
            return None
        except DevicePermissionError as exc:
            code, message = ErrorCode.PERMISSION_DENIED, str(exc)
        except OSError as exc:
            code, message = ErrorCode.OPEN_FAILED, f"cannot open: {exc}"
        if failed is None or failed.code != code:
            self._report_unusable(info, code, f"{message} (trying again every {self._retry_s:g} s)")
        raise _OpenFailed(code)

    def _open_and_bind(self, info: DeviceInfo, failed: _Failed | None = None) -> _Opened | None:
        device = self._open(info, failed)
        if device is None:
            return None
        with contextlib.ExitStack() as on_early_exit:
            on_early_exit.callback(device.close)
            try:
                layout = parse_descriptor(device.report_descriptor())
                binding = self.mapping.bind(info, layout)
            except (DescriptorError, MappingError, OSError) as exc:
                message = f"not used: {exc}; usb2rc goes on without it"
                self._report_unusable(info, ErrorCode.DESCRIPTOR_UNUSABLE, message)
                return None
            if binding is None:
                log.info(
                    "%s (%04x:%04x): ignored (`defaults: false` and no config entry matches)",
                    info.product,
                    info.vid,
                    info.pid,
                )
                return None
            if self._clashes(info, binding):
                return None
            on_early_exit.pop_all()  # the device is the reader's from here on
        return _Opened(device, layout, binding)

    def _clashes(self, info: DeviceInfo, binding: DeviceBinding) -> bool:
        message = self._clash(binding)
        if message is None:
            return False
        self._report_unusable(info, ErrorCode.CONFIG_CLASH, message, on_pinned=False)
        return True

    def _clash(self, binding: DeviceBinding) -> str | None:
        """Why the binding's pinned node cannot take the device, or None."""
        pinned = binding.node_id
        if pinned is None:
            return None
        if other := self.table.entry_in_use(pinned, binding.name):
            return (
                f"matches config entry {binding.name!r} like {other.product} "
                f"(port {other.port_path}), which already feeds node {pinned}: add `serial:` "
                "or `port:` to that entry's match so each device has its own entry"
            )
        if auto := self.table.automatic_device_on(pinned):
            return (
                f"config entry {binding.name!r} pins node {pinned}, which {auto.product} "
                f"(port {auto.port_path}) already has as its automatic ID since before the "
                "config was reloaded: restart usb2rc, or pin another node"
            )
        return None

    def _attach(self, info: DeviceInfo, opened: _Opened) -> None:
        binding = opened.binding
        pinned = binding.node_id
        if pinned is None:
            pinned = self.table.lost_node_of(info, binding)
        try:
            node_id = self.allocator.assign(info, pinned, taken=self.table.node_ids())
        except NodeIdError as exc:
            opened.device.close()
            log.error("%s: %s", info.product, exc)
            return
        reader = self._make_reader(opened.device, opened.layout, self.reader_exited)
        reader.on_bad_reports = self.bad_reports  # before it starts: then only it reads it
        self._present[info.key] = _Present(reader, opened.layout)
        self._publish_readers()
        device_type = device_type_name(opened.layout.application)
        self.table.add_device(node_id, info, binding, reader, device_type)
        reader.start()
        self._warn_unfed_slots(node_id)

    def _warn_unfed_slots(self, node_id: int) -> None:
        """The channels that read an axis slot no present device of `node_id` feeds, once
        per plug (`check --replay DIR` says the same before the devices are plugged)."""
        if self._carries_channels is None:
            return
        feeds = [
            DeviceFeed(info.product, info.vid, info.pid, nid, binding.axis_slots, binding.where)
            for nid, info, binding, present, _ in self.table.attachments()
            if present and nid == node_id
        ]
        config = self.mapping.config
        for problem in unfed_slot_warnings(config, feeds, self._carries_channels, {node_id}):
            log.warning("%s", problem)

    def _report_unusable(
        self, info: DeviceInfo, code: ErrorCode, message: str, on_pinned: bool = True
    ) -> None:
        """A device usb2rc cannot use: log what to do, and send `3` on the node it would
        have had (its pinned one, else an automatic ID it does not keep). A clash is
        reported on an automatic ID: the pinned node's own device is fine."""
        log.error(
            "%s (%04x:%04x, port %s): %s",
            info.product or info.path,
            info.vid,
            info.pid,
            info.port_path or "?",
            message,
        )
        entry = self.mapping.entry_for(info) if on_pinned else None
        try:
            node_id = self.allocator.assign(
                info, entry.node_id if entry else None, taken=self.table.node_ids()
            )
        except NodeIdError:
            return
        self.allocator.release(info)
        self.table.report_error(node_id, info, int(code))

    # --- reload --------------------------------------------------------------------------

    def _reload(self, event: Reload) -> None:
        """The new mapping for every present device (docs/ICD.md "A reload and the live
        devices"): on its node in place, or, pinned to another node now, moved there."""
        try:
            self.allocator.reserve(event.mapping.pinned_node_ids())
            bindings = self._new_bindings(event.mapping)
            moving = {key: b for key, b in bindings.items() if self._moves(key, b)}
            staying = {key: b for key, b in bindings.items() if key not in moving}
            self.table.rebind(lambda info: staying.get(info.key), event.expected)
            config = event.mapping.config  # switches keep their positions (by name)
            self.table.set_controls(config.switches, config.throttle_cuts)
            self.mapping = event.mapping
            for key, binding in moving.items():
                self._move(key, binding)
        finally:
            event.done.set()

    def _new_bindings(self, mapping: Mapping) -> dict[str, DeviceBinding]:
        """Each present device's binding under `mapping`; one that does not fit (or has no
        entry now, with `defaults: false`) keeps its previous one."""
        bindings = {}
        for key, present in sorted(self._present.items()):
            info = present.reader.info
            try:
                binding = mapping.bind(info, present.layout)
            except MappingError as exc:
                log.error("%s: %s (keeps its previous mapping)", info.product, exc)
                continue
            if binding is not None:
                bindings[key] = binding
        return bindings

    def _moves(self, key: str, binding: DeviceBinding) -> bool:
        """Pinned to another node than the one it feeds. (An entry that drops its pin
        leaves the device where it is: that node is now its automatic ID.)"""
        return binding.node_id is not None and binding.node_id != self.table.node_of(key)

    def _move(self, key: str, binding: DeviceBinding) -> None:
        """Re-pinned: the device leaves its node for the pinned one, unless that node has
        its own device of this entry, or an automatic device: then it stays, with its
        previous mapping, and the log says why."""
        reader = self._present[key].reader
        assert binding.node_id is not None
        clash = self._clash(binding)
        if clash is not None:
            log.error(
                "config reload: %s stays on Node-ID %s with its previous mapping: %s",
                reader.info.product or reader.info.path,
                self.table.node_of(key),
                clash,
            )
            return
        self.allocator.release(reader.info)
        self.allocator.assign(reader.info, binding.node_id)
        self.table.move_device(key, binding.node_id, binding, reader)
