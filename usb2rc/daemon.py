"""The daemon: wires HID sources, the compiled mapping, node state and the outputs together.

    hotplug ──events──> DeviceLifecycle ──> readers ──records──> NodeTable
                                                     outputs <── NodeTable
                                                     outputs ──> serial line / UDP

The outputs are one per config `outputs:` entry, in any protocol of the registry
(usb2rc.outputs: C2-16B, SUMD, CRSF, SBUS, iBus, MAVLink), built by usb2rc.wiring.

Devices come and go only on the lifecycle thread (usb2rc.nodes.lifecycle); readers publish records
that the table reads without waiting; the drivers' thread (every output's ticks) never waits on
a device.
"""

from __future__ import annotations

import dataclasses
import gc
import logging
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from usb2rc import __version__
from usb2rc.configfile import Config, OutputConfig
from usb2rc.feedback.engine import FeedbackEngine
from usb2rc.feedback.worker import FeedbackWorker, FeedDevice
from usb2rc.hid.backend import Backend, Device
from usb2rc.hid.descriptor import DeviceLayout
from usb2rc.hid.hotplug import HotplugMonitor
from usb2rc.hid.reader import DeviceReader, OnExit
from usb2rc.lines.driver import DriverThread as Drivers
from usb2rc.lines.driver import LineDriver as Driver
from usb2rc.lines.link import Link
from usb2rc.lines.rx import Handoff, LinkReader
from usb2rc.nodes.lifecycle import DeviceLifecycle
from usb2rc.nodes.mapping import Mapping, compile_mapping, match_text
from usb2rc.nodes.step import (
    GRID_EPOCH_S,
    NodeClock,
    clock_period,
    clock_phase,
)
from usb2rc.nodes.table import Expected, ExpectedEntry, NodeFrame, NodeTable
from usb2rc.outputs import build, protocol
from usb2rc.runtime import realtime, stats_text
from usb2rc.runtime.load import CpuMark, share_pct, thread_cpu_s
from usb2rc.status_socket import PERIOD_S as STATUS_PERIOD_S
from usb2rc.status_socket import (
    FailsafeWatch,
    StatusServer,
    StatusSource,
    os_reason,
    port_record,
)
from usb2rc.wiring import OutputContext

# How often the liveness hook (systemd's watchdog, seconds apart) asks whether every output
# ticks: not at each of their ticks.
LIVENESS_CHECK_S = 0.05

log = logging.getLogger("usb2rc")

JOIN_TIMEOUT_S = 0.5
# A thread that wants the GIL asks the running one to drop it after this long (Python's
# default: 5 ms). Plugging a device runs Python for milliseconds on the lifecycle and hot-plug
# threads (descriptor parse, decoder plan, a replayed recording); the drivers' thread needs
# the GIL after its wake-up and after each system call of a tick (~3 times), and may wait a
# whole slice each time: up to ~15 ms late with 5 ms slices (bench/bench_daemon.py, plug
# figures). Busy readers hold the GIL ~0.1 ms per wake-up: they are not sliced more often.
GIL_SWITCH_S = 0.0005


# Beside outputs the node clock is a safety net: every driver steps the table before each of
# its ticks, so a clock step is for nobody unless the drivers stall. About this often.
SAFETY_NET_PERIOD_S = 0.25


def node_clock_period(grid_period_s: float, every_node_read: bool) -> float:
    """The node clock's period: the only step of a node no output reads (`grid_period_s`,
    `nodes.step.clock_period`: with no output, or beside channel outputs that read some
    nodes only); beside an output that reads every node (C2-16B, MAVLink), which steps the
    table at each tick, the whole number of grid periods nearest SAFETY_NET_PERIOD_S, so
    its steps stay on the grid's points at the clock's phase, away from every tick."""
    if not every_node_read:
        return grid_period_s
    return max(1, round(SAFETY_NET_PERIOD_S / grid_period_s)) * grid_period_s


def status_grid(grid_period_s: float, clock_phase_s: float) -> tuple[float, float]:
    """The status socket's period and phase: a whole number of the node clock's grid
    periods near STATUS_PERIOD_S apart, at the clock's phase, where no output ticks (the
    phase from 0 on the monotonic clock: the grid's epoch and the clock's phase in it)."""
    steps = max(1, round(STATUS_PERIOD_S / grid_period_s))
    return steps * grid_period_s, GRID_EPOCH_S + clock_phase_s


class NoPortError(ValueError):
    """No serial port in the config nor on the command line."""


@dataclass
class _Output:
    config: OutputConfig
    link: Link
    driver: Driver
    rx: LinkReader | None = None
    failsafe: FailsafeWatch = field(default_factory=FailsafeWatch)  # for the stats
    port_from: str = "config"  # or "--port": where its port came from
    config_port: str | None = None  # the config file's (--port may have replaced it)


@dataclass(frozen=True)
class PreparedReload:
    """A reload worked out whole before it is applied: the config, its compiled mapping,
    the nodes it pins and its outputs (with --port applied)."""

    config: Config
    mapping: Mapping
    expected: Expected
    outputs: tuple[OutputConfig, ...]


@dataclass(frozen=True)
class ReloadResult:
    taken: bool  # the lifecycle thread applied it within its timeout
    outputs_changed: bool  # they take effect after a restart only


def log_reload(result: ReloadResult) -> None:
    if not result.taken:
        log.error(
            "config reload: the device thread has not taken it within 5 s; it takes it when free"
        )
    if result.outputs_changed:
        log.warning("config reloaded; changed outputs take effect after a restart")


def outputs_with_port(config: Config, port_override: str | None) -> tuple[OutputConfig, ...]:
    """The config's outputs, the first one's port replaced by --port; every one needs a port."""
    outputs = list(config.outputs) or [OutputConfig()]
    if port_override:
        outputs[0] = dataclasses.replace(outputs[0], port=port_override)
    missing = [i + 1 for i, out in enumerate(outputs) if not out.port]
    if missing:
        raise NoPortError(
            "no serial port for output "
            + ", ".join(map(str, missing))
            + ": give one with --port /dev/ttyUSB0 (or a pyserial URL such as "
            "socket://host:port), or set `port:` under `outputs:` in the config."
        )
    return tuple(outputs)


def _rounded(pct: float | None) -> float | None:
    return None if pct is None else round(pct, 2)


def expected_nodes(config: Config | Mapping) -> Expected:
    """Config entries pinned to a Node-ID, as what they send before their device comes:
    the configured failsafe values, 0 for axes without one (docs/ICD.md, "Failsafe"), and
    their unsigned slots; both compiled with the entry (`mapping.CompiledEntry`)."""
    mapping = config if isinstance(config, Mapping) else compile_mapping(config)
    nodes: Expected = {}
    for entry in mapping.pinned_entries():
        assert entry.node_id is not None
        match, where = match_text(entry.config.match), str(entry.config.where)
        expected = ExpectedEntry(entry.failsafe, entry.unsigned_slots, match, where)
        nodes.setdefault(entry.node_id, {})[entry.name] = expected
    return nodes


class Daemon:
    def __init__(
        self,
        config: Config,
        backend: Backend,
        *,
        port_override: str | None = None,
        version: str = __version__,
        on_ready: Callable[[], object] | None = None,
        on_tick: Callable[[], None] | None = None,
        on_status: Callable[[str], object] | None = None,
        outputs: bool = True,
        status_socket: str | None = None,
        judge: Callable[[Config], dict[str, Any]] | None = None,
        realtime_priority: int = realtime.DEFAULT_PRIORITY,
    ) -> None:
        """outputs=False: the input side only (hot-plug, readers, mapping, node table), as
        `usb2rc monitor` runs it; no port is needed or opened. status_socket: the path of
        the read-only status socket (usb2rc.status_socket); None: none. judge: `check`'s
        verdict on a config as a record, for the status socket (the command that runs the
        daemon gives it: usb2rc.commands.check.check_record). realtime_priority: the real-time
        (SCHED_RR) priority for the daemon's threads while outputs run, where the system grants it
        (usb2rc.runtime.realtime); 0: normal priority."""
        self.config = config
        self.backend = backend
        self.version = version
        self.port_override = port_override
        self.output_configs = outputs_with_port(config, port_override) if outputs else ()
        self.mapping: Mapping = compile_mapping(config)
        self.table = NodeTable(expected_nodes(self.mapping))
        self.table.set_controls(config.switches, config.throttle_cuts)  # nodes/switches.py
        self._on_ready = on_ready
        self._on_tick = on_tick
        self._liveness_asked_at = -LIVENESS_CHECK_S  # when `_tick` last asked (drivers' thread)
        self._on_status = on_status
        self._ready_once = threading.Event()  # set once, under _ready_lock; read anywhere
        # set after `_ready_once`: what `_tick` reads at every output's tick (an attribute,
        # where `Event.is_set` is a Python call)
        self._ready = False
        self._ready_lock = threading.Lock()
        self.outputs = [self._make_output(i, out) for i, out in enumerate(self.output_configs)]
        self.drivers = Drivers("drivers", [out.driver for out in self.outputs])
        # the clock that steps the nodes whether or not an output reads, on the drivers' grid
        periods = [out.driver.period_s for out in self.outputs]
        grid = clock_period(periods)
        phase = clock_phase(grid, periods)
        every_node_read = any(out.driver.session.reads is None for out in self.outputs)
        period = node_clock_period(grid, every_node_read)
        self.node_clock = NodeClock(
            lambda: self.table.step_if_stale(period), time.monotonic, period, phase
        )
        self.lifecycle = DeviceLifecycle(
            backend,
            self.table,
            self.mapping,
            self._make_reader,
            forget=self._forget,
            carries_channels=lambda name: protocol(name).channels is not None,
        )
        self.monitor = HotplugMonitor(backend, self.lifecycle.plugged, self.lifecycle.unplugged)
        self.feedback = self._make_feedback(config) if self.outputs else None
        self._wire_wakes()
        self.started_at = 0.0
        self.cpu_at_start = CpuMark.now()  # its CPU share in the stats counts from start()
        self._switch_interval: float | None = None  # the GIL's, to restore on stop()
        self._realtime_priority = realtime_priority
        # what its threads run at (start() asks, with outputs: none, nothing is kept on time)
        self.scheduling = realtime.Scheduling(
            "normal", "not started" if self.output_configs else "no outputs"
        )
        self._frozen = False  # gc.freeze() at start(): unfrozen on stop()
        self._judge = judge
        self._checked: tuple[Config, dict[str, Any]] | None = None  # config, its check
        status_period, status_phase = status_grid(grid, phase)
        self.status_server = (
            StatusServer(
                status_socket,
                StatusSource(self.table, self.stats_record, self.checked),
                period_s=status_period,
                phase_s=status_phase,
            )
            if status_socket
            else None
        )

    # --- outputs ---------------------------------------------------------------------------

    def _make_output(self, index: int, out: OutputConfig) -> _Output:
        """The protocol's build function (`usb2rc.wiring`) makes its pieces."""
        assert out.port
        name = f"output{index + 1}-{out.protocol}"
        count = len(self.output_configs)
        context = OutputContext(
            name,
            out,
            self.mapping,
            self.table,
            self._tick,
            self._first_write,
            self.version,
            alone=count == 1,
        )
        built = build(context)
        reads = self.mapping.sumd_channels(out) if protocol(out.protocol).channels else None
        replaced = index == 0 and bool(self.port_override)
        in_file = self.config.outputs[index] if index < len(self.config.outputs) else None
        config_port = None if in_file is None else in_file.port
        return _Output(
            out,
            built.link,
            built.driver,
            built.rx,
            FailsafeWatch.of(reads),
            "--port" if replaced else "config",
            config_port,
        )

    # --- feedback (docs/ICD.md "Downlink", docs/CONFIG.md "Feedback") ----------------------

    def _make_feedback(self, config: Config) -> FeedbackWorker:
        """The thread that drives the devices' outputs from the far ends' telemetry: rung by
        each output's driver when its telemetry changed, and by the lifecycle after a plug."""
        worker = FeedbackWorker(
            FeedbackEngine(config.feedback),
            [out.driver.session for out in self.outputs],
            self.table.snapshot,
            self._feed_devices,
        )
        for out in self.outputs:
            out.driver.on_telemetry = worker.ring
        return worker

    def _wire_wakes(self) -> None:
        """Who wakes whom: after each device event the feedback thread and the drivers'
        thread (an asleep output has nodes to send again); a serial far end's bytes wake the
        drivers' thread, so such an output may sleep while it has nothing to send (a UDP
        link is polled by its driver: it keeps ticking)."""
        feedback, drivers = self.feedback, self.drivers

        def devices_changed() -> None:
            drivers.wake()
            if feedback is not None:
                feedback.ring()

        self.lifecycle.on_devices = devices_changed
        for out in self.outputs:
            received = getattr(out.link, "received", None)
            if isinstance(received, Handoff):
                received.on_put = drivers.wake
                out.driver.can_doze = True

    def _feed_devices(self) -> list[FeedDevice]:
        """The present devices, by node, each node's in config-entry order, then in the
        order they joined it (the order a node's downlink lights their indicators in)."""
        order = {device.name: index for index, device in enumerate(self.config.devices)}
        present = [
            (node_id, name, source)
            for node_id, name, source in self.table.present_sources()
            if isinstance(source, DeviceReader)
        ]
        ranked = sorted(
            enumerate(present),
            key=lambda item: (item[1][0], order.get(item[1][1], len(order)), item[0]),
        )
        return [
            FeedDevice(node_id, name if name in order else None, reader)
            for _, (node_id, name, reader) in ranked
        ]

    def _first_write(self) -> None:
        self._status("running: frames on " + ", ".join(o.link.url for o in self.outputs))
        self._become_ready("first frame written: usb2rc is running")

    def _become_ready(self, message: str) -> None:
        """Once, whichever output threads get here together: the check and the set are one
        step under `_ready_lock`, so READY=1 and the "running" line go out exactly once. The
        hooks run outside the lock (sd_notify is a socket write)."""
        with self._ready_lock:
            if self._ready_once.is_set():
                return
            self._ready_once.set()
            self._ready = True
        log.info(message)
        if self._on_ready:
            self._on_ready()

    def _status(self, text: str) -> None:
        if self._on_status:
            self._on_status(text)

    def _tick(self) -> None:
        """Called by every output after each tick: the liveness hook (systemd watchdog)."""
        if not self._ready and not any(o.link.is_open for o in self.outputs):
            # Decision: with every serial port missing the pipeline still runs and retries
            # each second (that is its job), so it is ready; the status line says what waits.
            waiting = "; ".join(o.link.last_error for o in self.outputs if o.link.last_error)
            self._status(f"waiting for the serial line: {waiting}")
            self._become_ready("running; no serial port open yet, retrying every second")
        if self._on_tick is None:
            return
        now = time.monotonic()
        if now - self._liveness_asked_at < LIVENESS_CHECK_S:
            return  # asked for every output's tick (550 a second): an answer 50 ms old holds
        self._liveness_asked_at = now
        if self.all_outputs_ticking():
            self._on_tick()

    def _forget(self, key: str) -> None:
        self.monitor.forget(key)

    def all_outputs_ticking(self, within_s: float = 1.0) -> bool:
        """True while every output has ticked in the last `within_s` seconds: one whose ticks
        fail, or a hung drivers' thread, stops the watchdog being fed; a stuck device cannot
        (it has no say here)."""
        now = time.monotonic()
        return all(now - out.driver.last_tick_monotonic < within_s for out in self.outputs)

    # --- devices ---------------------------------------------------------------------------

    def _make_reader(self, device: Device, layout: DeviceLayout, on_exit: OnExit) -> DeviceReader:
        return DeviceReader(device, layout.make_decoder(), on_exit, pulled=True)

    # --- life cycle ------------------------------------------------------------------------

    def start(self) -> None:
        self.cpu_at_start = CpuMark.now()
        self.started_at = self.cpu_at_start.at
        if self.outputs:
            # first: every thread started from here on inherits it
            self.scheduling = realtime.request(self._realtime_priority)
            log.info("scheduling: %s", self.scheduling.describe())
            self._switch_interval = sys.getswitchinterval()
            sys.setswitchinterval(GIL_SWITCH_S)
            # A full garbage collection holds the GIL while it walks every tracked object
            # (~32,000 once the modules are imported: milliseconds, a 500 Hz tick missed).
            # What is alive now (modules, classes, the config, the daemon) is frozen out of
            # the collections, after one collection while nothing ticks yet: a full one then
            # walks only what was made since. Unfrozen at stop: a process that runs daemons
            # one after another (the tests) collects each one's objects once it is gone.
            gc.collect()
            gc.freeze()
            self._frozen = True
        for out in self.outputs:
            out.link.open_now()
        present = self.monitor.initial_devices()
        if not present:
            log.info(
                "no joystick, gamepad or flight control found yet: waiting for one to be "
                "plugged in (`usb2rc list --all` shows every HID device and why it is not used)"
            )
        for info in present:
            self.lifecycle.plugged(info)
        self.lifecycle.handle_queued()  # before the outputs start: no thread owns them yet
        self.node_clock.start()
        if self.outputs:
            self.drivers.start()
        for out in self.outputs:
            if out.rx is not None:
                out.rx.start()
        self.lifecycle.start()
        self.monitor.start()
        if self.feedback is not None:
            self.feedback.start()
        self._start_status_server()

    def _start_status_server(self) -> None:
        """The status socket is a view: without it the daemon runs on (the reason logged)."""
        if self.status_server is None:
            return
        try:
            self.status_server.start()
        except OSError as exc:
            log.error(
                "status socket %s: %s; running without it: `usb2rc web` cannot see this "
                "daemon (--status-socket PATH puts the socket elsewhere)",
                self.status_server.path,
                os_reason(exc),
            )
            self.status_server = None

    def stop(self) -> None:
        self.monitor.stop()
        if self.feedback is not None:
            # before the readers stop: each writes its device's rest state as its last act
            self.feedback.stop()
            self.feedback.join(JOIN_TIMEOUT_S)
            self.feedback.rest_all()
        self.table.stop()  # every node `!` from here; each output sends it before it closes
        readers = self.lifecycle.shutdown(JOIN_TIMEOUT_S)
        self.drivers.stop()
        for out in self.outputs:
            if out.rx is not None:
                out.rx.stop()
        self.monitor.join(JOIN_TIMEOUT_S)
        for reader in readers:
            reader.join(JOIN_TIMEOUT_S)
        self.drivers.join(JOIN_TIMEOUT_S)
        for out in self.outputs:
            if out.rx is not None:
                out.rx.join(JOIN_TIMEOUT_S)
            out.link.close()
        self.node_clock.stop()
        self.node_clock.join(JOIN_TIMEOUT_S)
        if self.status_server is not None:  # last: a page sees the nodes go `!`
            self.status_server.shutdown(JOIN_TIMEOUT_S)
        if self._switch_interval is not None:
            sys.setswitchinterval(self._switch_interval)
            self._switch_interval = None
        if self._frozen:
            gc.unfreeze()
            self._frozen = False
        realtime.release(self.scheduling)

    def prepare_reload(self, config: Config) -> PreparedReload:
        """Everything a reload changes, computed before anything is changed (docs/CONFIG.md,
        "Reload"). Raises NoPortError for outputs without a port; `config.load_runnable`
        refuses those first, so this only guards a config that did not come through it."""
        mapping = compile_mapping(config)
        outputs = outputs_with_port(config, self.port_override) if self.outputs else ()
        return PreparedReload(config, mapping, expected_nodes(mapping), outputs)

    def apply_reload(self, prepared: PreparedReload) -> ReloadResult:
        """Hand the lifecycle thread the whole new mapping: it applies it between two device
        events, so a device plugged meanwhile is bound with the new mapping either way. Logs
        nothing: the main loop runs this where a stop may abandon it (usb2rc.service.signals)."""
        taken = self.lifecycle.reload(prepared.mapping, prepared.expected)
        # Not taken within the timeout: it is queued and the thread applies it when free.
        self.mapping = prepared.mapping
        self.config = prepared.config
        if self.feedback is not None:
            self.feedback.reload(FeedbackEngine(prepared.config.feedback))
        outputs_changed = bool(self.outputs) and prepared.outputs != self.output_configs
        return ReloadResult(taken, outputs_changed)

    def reload(self, config: Config) -> None:
        """Take a new config (validated by `config.load_runnable`), and log what it did."""
        log_reload(self.apply_reload(self.prepare_reload(config)))

    # --- stats -----------------------------------------------------------------------------

    def checked(self) -> dict[str, Any]:
        """`check`'s verdict on the running config, worked out once per config."""
        config = self.config
        if self._checked is None or self._checked[0] is not config:
            self._checked = (config, self._judge(config) if self._judge else {})
        return self._checked[1]

    def stats_lines(self) -> list[str]:
        return stats_text.stats_lines(self.stats_record())

    def stats_record(self) -> dict[str, Any]:
        """Every counter, per output and per device (keys: usb2rc.runtime.stats_text); plain JSON
        values, so `run --stats-format json` prints it as it is."""
        now = time.monotonic()
        uptime = max(1e-9, now - self.started_at)
        frames = {view.frame.node_id: view.frame for view in self.table.snapshot().nodes}
        return {
            # µs: two dumps asked for back to back can be under a millisecond apart
            "uptime_s": round(uptime, 6),
            # % of one core since start (every thread; the drivers' thread alone): how much
            # of the host usb2rc takes; None where it is not known
            "cpu_pct": _rounded(self.cpu_at_start.share_pct(CpuMark.now())),
            "drivers_cpu_pct": _rounded(share_pct(thread_cpu_s(self.drivers.native_id), uptime)),
            "scheduling": self.scheduling.describe(),
            "outputs": [self._output_stats(out, frames) for out in self.outputs],
            "devices": [
                self._device_stats(reader, now, uptime) for reader in self.lifecycle.readers
            ],
            # pinned entries without a device: their nodes send `!` (docs/ICD.md "Node-IDs")
            "missing_devices": [m.record() for m in self.table.missing_entries()],
            **({} if self.feedback is None else {"feedback": self.feedback.record(now)}),
        }

    def _output_stats(self, out: _Output, frames: dict[int, NodeFrame]) -> dict[str, Any]:
        st, link = out.driver.stats, out.link.stats
        record: dict[str, Any] = {
            "name": out.driver.name,
            "url": out.link.url,
            "protocol": out.config.protocol,
            "port_from": out.port_from,
            "config_port": out.config_port,
            **port_record(out.link),
            **out.failsafe.record(frames),
            "writes": st.writes,
            "ticks": st.ticks,
            # times every output was asleep and the drivers' thread slept until woken
            "dozes": self.drivers.dozes,
            "late_ticks": st.late_ticks,
            "missed_ticks": st.missed_ticks,
            "period_p99_error_ms": st.period_p99_error_ms(out.driver.period_s),
            "tick_p99_ms": st.tick_p99_ms(),
            # p50/p99/max ms from the read of a frame's newest report to its write; None
            # before a frame carried a live device's report
            "input_age_ms": st.input_age_ms(),
            "bytes_written": link.bytes_written,
            "queue_full_skips": link.writes_skipped_queue_full,  # UDP: refused datagrams
            "write_timeouts": link.write_timeouts,
            "short_writes": link.short_writes,
            "stalls": st.stalls,
            "stale_flushes": link.flushes,
            "line_losses": link.losses,
            "tick_errors": st.tick_errors,
        }
        record.update(out.driver.protocol_stats())
        record["queue_full_skips"] += record.pop("queue_full_ticks", 0)
        if out.rx is not None:  # a far end faster than its line loses the excess
            record["rx_dropped_bytes"] = out.rx.budget.dropped_bytes
        return record

    @staticmethod
    def _device_stats(reader: DeviceReader, now: float, uptime: float) -> dict[str, Any]:
        info, record = reader.info, reader.record
        stats: dict[str, Any] = {
            "name": info.product or info.path,
            "port_path": info.port_path,
            "vid": info.vid,
            "pid": info.pid,
            "reports": record.reports,
            "reports_per_s": record.reports / uptime,
            "bad_reports": record.bad_reports,
            "last_report_age_s": None if record.at is None else now - record.at,
        }
        busy_s = getattr(reader.device, "busy_s", None)  # the replay backend's own work
        if busy_s is not None:
            stats["backend_busy_ms"] = busy_s * 1000
        queue_full = getattr(reader.device, "queue_full", 0)  # a hidraw fd's, when it filled
        if queue_full:
            stats["kernel_queue_full"] = queue_full
        if reader.keep_every_s is not None:  # its reader pulls it between the steps too
            stats["pulled_between_steps_ms"] = reader.keep_every_s * 1000
        outputs = reader.outputs
        if outputs.written or outputs.refused:
            stats["outputs_written"] = outputs.written
            stats["outputs_refused"] = outputs.refused
            if outputs.last_error:
                stats["output_error"] = outputs.last_error
        return stats
