"""A config reload keeps nothing of the config before it (issue 11: ~100 KB per SIGHUP).

In-process: no YAML node outlives a load, and a few hundred loads allocate nothing that
stays (tracemalloc). Slow: 1500 SIGHUPs to the real daemon with the starter hotas.yaml, each
waited for in its log, and its RSS from /proc flat after a warm-up.
"""

from __future__ import annotations

import gc
import signal
import time
import tracemalloc
from pathlib import Path

import pytest
import yaml
from daemon_harness import ROOT, DaemonProcess, PtyLine, StickState, install, recording

from usb2rc.configfile import load_config

HOTAS = str(ROOT / "usb2rc" / "data" / "config" / "hotas.yaml")


def yaml_nodes() -> int:
    gc.collect()
    return sum(isinstance(obj, yaml.nodes.Node) for obj in gc.get_objects())


def test_no_yaml_node_outlives_a_load():
    load_config(HOTAS)
    before = yaml_nodes()
    for _ in range(20):
        load_config(HOTAS)
    assert yaml_nodes() == before  # the shared constructor kept ~300 nodes a load


def test_loads_keep_no_memory():
    for _ in range(10):  # warm-up: imports, interned strings, caches of fixed size
        load_config(HOTAS)
    tracemalloc.start()  # slows each load down ~10x: a few loads are enough
    try:
        for _ in range(3):
            load_config(HOTAS)
        gc.collect()
        start, _ = tracemalloc.get_traced_memory()
        for _ in range(10):
            load_config(HOTAS)
        gc.collect()
        end, _ = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    # The leak was ~90 KB a load (0.9 MB here); what is left is allocator noise.
    assert end - start < 64 * 1024, f"{(end - start) / 10:.0f} bytes kept per load"


# --- the daemon -----------------------------------------------------------------------------


class LogTail:
    """Counts the lines with a given text the daemon appends to its log, reading only the
    new part each time (1500 reloads make a long log)."""

    def __init__(self, path: Path, text: bytes) -> None:
        self._file = path.open("rb")
        self._text = text
        self._partial = b""

    def new_matches(self) -> int:
        data = self._partial + self._file.read()
        *lines, self._partial = data.split(b"\n")
        return sum(self._text in line for line in lines)

    def close(self) -> None:
        self._file.close()


def vm_rss_kb(pid: int) -> int:
    status = Path(f"/proc/{pid}/status").read_text()
    line = next(ln for ln in status.splitlines() if ln.startswith("VmRSS:"))
    return int(line.split()[1])


def reload_and_wait(daemon: DaemonProcess, tail: LogTail, timeout: float = 10.0) -> None:
    """One SIGHUP, then wait for its `config ... reloaded` line: one reload at a time."""
    daemon.signal(signal.SIGHUP)
    deadline = time.monotonic() + timeout
    while not tail.new_matches():
        assert daemon.proc.poll() is None, daemon.log()[-2000:]
        assert time.monotonic() < deadline, "no `reloaded` line after SIGHUP"
        time.sleep(0.001)  # polling the log file for the line


@pytest.mark.slow
def test_1500_sighups_keep_rss_flat(tmp_path):
    replay = tmp_path / "replay"
    replay.mkdir()
    install(replay / "stick.hid", recording([StickState()]))  # bound by the stick entry
    c2, sumd = PtyLine(), PtyLine("sumd")
    config = tmp_path / "hotas.yaml"  # the starter hotas.yaml, its SUMD port a pty we own
    config.write_text(Path(HOTAS).read_text().replace("/dev/ttyUSB0", sumd.path))
    args = ["--port", c2.path, "--replay", str(replay), "--config", str(config)]
    daemon = DaemonProcess([*args, "--log-level", "info"], tmp_path / "d.log")
    tail = LogTail(tmp_path / "d.log", b" reloaded")
    try:
        c2.wait_for(lambda frames: len(frames) > 5)
        for _ in range(200):  # warm-up
            reload_and_wait(daemon, tail)
        warm = vm_rss_kb(daemon.proc.pid)
        for _ in range(1300):
            reload_and_wait(daemon, tail)
        end = vm_rss_kb(daemon.proc.pid)
    finally:
        tail.close()
        code = daemon.stop()
        c2.close()
        sumd.close()
    assert code == 0
    print(f"RSS after 200 reloads {warm} kB, after 1500 {end} kB: {end - warm:+d} kB")
    assert end - warm < 3 * 1024, f"RSS grew {end - warm} kB over 1300 reloads"
