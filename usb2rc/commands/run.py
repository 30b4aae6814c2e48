"""`usb2rc [run] --config FILE [--port PORT] [--replay DIR]`: the daemon."""

from __future__ import annotations

import argparse
import atexit
import contextlib
import functools
import json
import logging
import os
import queue
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable
from typing import Any, TypeVar, cast

from usb2rc import compiled_path, status_socket
from usb2rc.commands.arguments import replay_dir
from usb2rc.commands.check import check_record
from usb2rc.config.port_url import port_argument
from usb2rc.configfile import Config, ConfigError, load_config, load_runnable
from usb2rc.daemon import Daemon, NoPortError, ReloadResult, log_reload
from usb2rc.hid import speedups
from usb2rc.hid.backend import Backend
from usb2rc.hid.choose import choose_backend
from usb2rc.nodes import steady
from usb2rc.runtime import log_escape, realtime
from usb2rc.service.sdnotify import Notifier
from usb2rc.service.signals import DaemonSignals, ReloadAbandoned, install_daemon_signals

log = logging.getLogger("usb2rc")

T = TypeVar("T")
READ_WAIT_S = 0.1  # the main thread's wait for a reload's read, in slices of this

SERVICE_CONFIG = "/etc/usb2rc/usb2rc.yaml"
STATS_FORMATS = ("text", "json")


def add_common_input_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", metavar="FILE", help="YAML config (default: zero config)")
    parser.add_argument(
        "--replay",
        metavar="DIR",
        type=replay_dir,
        help="replay hid-recorder files in DIR instead of real devices",
    )
    parser.add_argument("--replay-loop", action="store_true", help="replay each recording forever")


def add_parser(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "run",
        help="run the daemon (the default command)",
        description="Run the daemon: read the joysticks (or --replay recordings), map them as "
        "the config says (zero config without one) and send each output's stream (C2-16B, "
        "SUMD, CRSF, SBUS or MAVLink) on its serial port or UDP address until SIGTERM or "
        "Ctrl-C. SIGHUP re-reads the config, SIGUSR1 logs statistics. Exit 0 when stopped, "
        "2 on a usage or config error, 1 otherwise.",
    )
    add_common_input_args(parser)
    parser.add_argument(
        "--port",
        type=port_argument,
        help="serial port or pyserial URL (overrides the first output)",
    )
    parser.add_argument(
        "--log-level", default="info", choices=["debug", "info", "warning", "error"]
    )
    parser.add_argument(
        "--stats-interval",
        type=float,
        default=0.0,
        metavar="S",
        help="log statistics every S seconds (also on SIGUSR1)",
    )
    parser.add_argument(
        "--stats-format",
        choices=STATS_FORMATS,
        default="text",
        help="text: log lines (stderr); json: one JSON object per dump on stdout, for scripts",
    )
    parser.add_argument(
        "--status-socket",
        metavar="PATH|off",
        help="the read-only status socket `usb2rc web` reads (default: "
        "$RUNTIME_DIRECTORY/status.sock under the service, i.e. /run/usb2rc/status.sock, "
        "else $XDG_RUNTIME_DIR/usb2rc/status.sock, else /run/usb2rc/status.sock for root "
        "and /tmp/usb2rc-UID/status.sock (a private 0700 folder) for another user; "
        "`usb2rc web` looks in the same place); off: none",
    )
    parser.add_argument(
        "--realtime-priority",
        type=realtime_priority,
        default=realtime.DEFAULT_PRIORITY,
        metavar="N",
        help="real-time (SCHED_RR) priority of the daemon's threads, so that ticks are written on "
        f"time on a busy machine (default {realtime.DEFAULT_PRIORITY}, at most "
        f"{realtime.MAX_PRIORITY}); where the system refuses it, the daemon runs at normal "
        "priority and logs why; 0: normal priority",
    )
    parser.set_defaults(func=run)


def realtime_priority(text: str) -> int:
    """--realtime-priority's value: 0 (off) to realtime.MAX_PRIORITY."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
    if not 0 <= value <= realtime.MAX_PRIORITY:
        raise argparse.ArgumentTypeError(f"{value} is not within 0..{realtime.MAX_PRIORITY}")
    return value


def status_socket_path(args: argparse.Namespace) -> str | None:
    """--status-socket PATH, `off` (None), or the default (usb2rc.status_socket)."""
    chosen: str | None = getattr(args, "status_socket", None)
    if chosen == "off":
        return None
    return chosen or status_socket.default_path()


def under_systemd() -> bool:
    return bool(os.environ.get("INVOCATION_ID") or os.environ.get("JOURNAL_STREAM"))


def setup_logging(level: str) -> None:
    # The journal stamps every line itself: no second timestamp under systemd.
    fmt = (
        "%(levelname)s %(message)s" if under_systemd() else "%(asctime)s %(levelname)s %(message)s"
    )
    logging.basicConfig(level=getattr(logging, level.upper()), format=fmt, stream=sys.stderr)
    log_escape.install()  # device-chosen names with ESC/BEL never reach the log raw


def config_path_for(args: argparse.Namespace) -> str | None:
    if args.config:
        return str(args.config)
    if under_systemd() and os.path.exists(SERVICE_CONFIG):
        return SERVICE_CONFIG
    return None


def load_or_report(path: str | None) -> Config | None:
    """The config for the input side only (`monitor`): no output, so no port is needed."""
    return _or_report(path, lambda: Config.default() if path is None else load_config(path))


def runnable_or_report(path: str | None, port_override: str | None) -> Config | None:
    """The config `run` starts with: `load_runnable`, as a reload and `check` judge it."""
    return _or_report(path, lambda: load_runnable(path, port_override))


def _or_report(path: str | None, load: Callable[[], Config]) -> Config | None:
    """load(), or None with every problem on stderr."""
    try:
        return load()
    except ConfigError as exc:
        for error in exc.errors:
            print(error, file=sys.stderr)
        return None
    except OSError as exc:
        print(f"{path}: cannot read the config: {exc.strerror}", file=sys.stderr)
        return None


def make_backend(args: argparse.Namespace) -> Backend:
    return choose_backend(args.replay, loop=args.replay_loop)


class _WatchdogFeeder:
    """Feeds systemd's watchdog from the output threads' ticks: a hung one stops feeding."""

    def __init__(self, notifier: Notifier) -> None:
        self.notifier = notifier
        self.interval = notifier.watchdog_interval_s()
        self._next = 0.0

    def __call__(self) -> None:
        if self.interval is None:
            return
        now = time.monotonic()
        if now >= self._next:
            self._next = now + self.interval
            self.notifier.watchdog()


def serve(
    daemon: Daemon,
    config_path: str | None,
    stats_interval: float,
    notifier: Notifier | None = None,
    signals: DaemonSignals | None = None,
    stats_format: str = "text",
) -> int:
    """Run until SIGTERM/SIGINT; SIGHUP reloads the config, SIGUSR1 logs statistics.

    Every stop returns 0. The handlers stay installed to the end (usb2rc.service.signals): a signal
    while stopping is logged and ignored, never the default action that kills the process.
    """
    if signals is None:
        signals = install_daemon_signals()
    if not signals.running():
        log.info("stopped while starting")
        return 0
    log.info("%s", speedups.status())
    log.info("%s", steady.status())
    log.info("%s", compiled_path.status())
    try:
        daemon.start()  # inside: a start that fails half-way still stops what it started
        _main_loop(daemon, config_path, stats_interval, notifier, signals, stats_format)
    finally:
        signals.stopping()
        daemon.stop()
        _log_ignored(signals)
    log.info("stopped")
    # Signals still come while the interpreter winds down; log those too (atexit runs this
    # before logging's own shutdown, which was registered earlier).
    atexit.register(_log_ignored, signals)
    return 0


def _main_loop(
    daemon: Daemon,
    config_path: str | None,
    stats_interval: float,
    notifier: Notifier | None,
    signals: DaemonSignals,
    stats_format: str = "text",
) -> None:
    """Serve the signals' requests until a stop; stats every `stats_interval` s (if > 0)."""
    next_stats = time.monotonic() + stats_interval if stats_interval > 0 else None
    while True:
        timeout = 1.0 if next_stats is None else max(0.0, next_stats - time.monotonic())
        try:
            what = signals.requests.get(timeout=timeout)
        except queue.Empty:
            what = "stats" if next_stats is not None else ""
            if next_stats is not None:
                next_stats = time.monotonic() + stats_interval
        # CPython runs pending handlers in signal-number order, so a SIGHUP that came just
        # after a SIGTERM may be queued first: once a stop is asked for, nothing else runs.
        if what == "stop" or signals.stop_requested:
            return
        if what == "reload":
            try:
                _reload_notified(daemon, config_path, notifier, signals)
            except ReloadAbandoned:
                log.info("stop during the config reload: the reload is abandoned")
                return
        elif what == "stats":
            stats_format = write_stats(daemon, stats_format)


def write_stats(daemon: Daemon, stats_format: str) -> str:
    """text: a log line per output and device; json: `{"stats": ...}` on one stdout line
    (the log stays on stderr, so `usb2rc run --stats-format json | jq` reads only these).
    Returns the format for the next dump: a reader that went away must not stop the
    stream, so the stats go to the log from then on."""
    if stats_format == "json":
        line = json.dumps({"stats": daemon.stats_record()}, separators=(",", ":"))
        try:
            print(line, flush=True)
            return stats_format
        except OSError as exc:
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # drop the rest
            log.warning("stats: stdout is gone (%s); logging them from now on", exc)
    for text in daemon.stats_lines():
        log.info("stats: %s", text)
    return "text"


def _reload_notified(
    daemon: Daemon, config_path: str | None, notifier: Notifier | None, signals: DaemonSignals
) -> None:
    if notifier is not None:
        notifier.reloading()
    reload(daemon, config_path, signals)
    if notifier is not None:
        notifier.ready()


def _log_ignored(signals: DaemonSignals) -> None:
    """One line per signal name: a stream of signals while stopping is not a stream of lines."""
    for name, count in Counter(signals.take_ignored()).items():
        times = f" ({count} times)" if count > 1 else ""
        log.info("%s while stopping: ignored%s", name, times)


def reload(daemon: Daemon, config_path: str | None, signals: DaemonSignals | None = None) -> None:
    """SIGHUP: the config file again, applied whole or not at all (docs/CONFIG.md, "Reload").

    It is checked as `run` and `check` check it (`load_runnable`, with the daemon's --port)
    before anything changes; a refused one leaves the running config, with one log line.
    With `signals`, a stop abandons it wherever it is (ReloadAbandoned, raised out of here).
    """
    if config_path is None:
        log.warning("SIGHUP: no config file to re-read (zero config)")
        return
    log.debug("config %s: reloading (SIGHUP)", config_path)  # debug: refused is one line
    abandonable = signals.abandoned_on_stop() if signals else contextlib.nullcontext()
    try:
        with abandonable:
            result = _load_and_apply(daemon, config_path)
    except (ConfigError, NoPortError, OSError) as exc:
        errors = exc.errors if isinstance(exc, ConfigError) else [str(exc)]
        log.error(
            "config %s rejected, the running config stays: %s", config_path, " | ".join(errors)
        )
        return
    log_reload(result)
    log.info("config %s reloaded", config_path)


def _load_and_apply(daemon: Daemon, config_path: str) -> ReloadResult:
    """Read, check and compile the whole config, then hand it over: nothing logged here (a
    stop may abandon it at any point, usb2rc.service.signals)."""
    config = off_the_main_thread(lambda: load_runnable(config_path, daemon.port_override))
    return daemon.apply_reload(daemon.prepare_reload(config))


def off_the_main_thread(work: Callable[[], T]) -> T:
    """`work`'s result (or its exception), computed in a helper thread while the main thread
    waits in slices of READ_WAIT_S, running its signal handlers between them.

    Why: a file that never answers (a hung network mount, a FIFO) holds a reader in read().
    A SIGTERM that arrives while that read runs breaks it (EINTR); one that arrives just
    before it leaves its Python handler waiting for the read to return, which it never does
    (seen: 1 stop in 5 under load never happened). The main thread now only waits, in
    slices; the helper is a daemon thread, so a read abandoned with the reload does not keep
    the process alive."""
    results: queue.SimpleQueue[tuple[bool, Any]] = queue.SimpleQueue()

    def run() -> None:
        try:
            results.put((True, work()))
        except BaseException as exc:  # handed to the main thread, which raises it
            results.put((False, exc))

    threading.Thread(target=run, name="config-read", daemon=True).start()
    while True:
        try:
            done, value = results.get(timeout=READ_WAIT_S)
        except queue.Empty:
            continue  # back in Python: a pending stop's handler runs here
        if done:
            return cast(T, value)
        raise value


def run(args: argparse.Namespace) -> int:
    signals = install_daemon_signals()  # already done by cli.main, unless called directly
    setup_logging(args.log_level)
    config_path = config_path_for(args)
    config = runnable_or_report(config_path, args.port)
    if config is None:
        return 2
    notifier = Notifier.from_env()
    try:
        daemon = Daemon(
            config,
            make_backend(args),
            port_override=args.port,
            on_ready=notifier.ready,
            on_tick=_WatchdogFeeder(notifier) if notifier.watchdog_interval_s() else None,
            on_status=notifier.status,
            status_socket=status_socket_path(args),
            judge=functools.partial(check_record, port_override=args.port),
            realtime_priority=getattr(args, "realtime_priority", realtime.DEFAULT_PRIORITY),
        )
    except NoPortError as exc:
        print(f"usb2rc: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"usb2rc: {exc}", file=sys.stderr)
        return 1
    try:
        return serve(daemon, config_path, args.stats_interval, notifier, signals, args.stats_format)
    finally:
        notifier.stopping()
        notifier.close()
