"""Config reloads (SIGHUP) and `usb2rc check` as users meet them (issue 19 points 1, 5, 9;
issue 20's `check` slips). docs/CONFIG.md, "Reload", and docs/ICD.md, "Stop", are the judge.

The daemon runs as a subprocess on a pty with a replayed T.16000M pinned to node 4; its X is
at 0, so the node's X is -32768, or 32767 with `invert: true`: which config runs is read off
the wire. A refused reload must leave the daemon running, the old mapping on the wire and one
log line; `usb2rc check` must refuse the same file (one function judges both).
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from cli_harness import usb2rc
from daemon_harness import (
    INVERT_UNGUARDED_X_CONFIG,
    INVERT_X_CONFIG,
    ROOT,
    DaemonProcess,
    PtyLine,
    StickState,
    data_frames,
    install,
    recording,
    run_daemon,
)

from usb2rc.protocols.c2_16b.codec import FAILSAFE, LIVE

INVERTED, PLAIN = 32767, -32768  # node 4's X with and without `invert: true`
DEADLINE_S = 15.0
# At rest first, long enough for the guard to arm on a starved machine (two busy loops on
# both cores: the reader got to the rest report too late for a 0.1 s rest, 4 runs in 20).
MOVED_STICK = recording([StickState(), StickState(x=0)], hold_s=0.5)


def with_port(text: str, port: str) -> str:
    return f"outputs:\n  - protocol: c2-16b\n    port: {port}\n{text}"


def without_port(text: str) -> str:
    """The same config with its `port:` commented out, as an editor would leave it."""
    return f"outputs:\n  - protocol: c2-16b\n    # port: /dev/ttyUSB0\n{text}"


def x_of_node4(line: PtyLine, after: int, frames: int = 10) -> set[int]:
    """Node 4's X over `frames` data frames that came after frame number `after`."""
    line.wait_for(lambda fr: len(data_frames(fr[after:], 4)) >= frames)
    return {f.axes[0] for f in data_frames(line.frames()[after:], 4)}


def wait_log(daemon: DaemonProcess, text: str, count: int = 1) -> str:
    """The log once `text` is in it `count` times; fails if the daemon exits first."""
    deadline = time.monotonic() + DEADLINE_S
    while daemon.log().count(text) < count:
        assert daemon.proc.poll() is None, f"the daemon exited:\n{daemon.log()[-3000:]}"
        assert time.monotonic() < deadline, f"no {text!r} in the log:\n{daemon.log()[-3000:]}"
        time.sleep(0.01)  # polling a file: what we wait for is in it or not
    return daemon.log()


def started(tmp_path: Path, line: PtyLine, replay_dir: Path, config: Path, *extra: str):
    """The daemon on `config` (and `extra` arguments) once node 4 is on the wire."""
    install(replay_dir / "stick.hid", MOVED_STICK)
    daemon = DaemonProcess(
        ["--replay", str(replay_dir), "--config", str(config), *extra], tmp_path / "daemon.log"
    )
    try:
        wait_x(line, INVERTED)
    except BaseException:
        daemon.stop()  # the caller's `try` has not begun: the daemon is ours to stop
        raise
    return daemon


def wait_x(line: PtyLine, value: int) -> None:
    """Until node 4's X is `value` (the neutral guard holds a moved stick until it rested)."""
    line.wait_for(lambda fr: data_frames(fr, 4)[-1:] and data_frames(fr, 4)[-1].axes[0] == value)


# --- point 1: a reload is checked whole first; refused, the old config runs on ------------


def refused_configs(line: PtyLine, tmp_path: Path) -> dict[str, str]:
    """Each config a reload must refuse, with `invert: false` (the running one inverts)."""
    plain = INVERT_X_CONFIG.format(invert="false")
    (tmp_path / "a-file").write_text("")
    return {
        "port-commented-out": without_port(plain),
        "empty-file": "",
        "only-comments": "# being edited\n",
        "port-dev-null": with_port(plain, "/dev/null"),
        "port-regular-file": with_port(plain, str(tmp_path / "a-file")),
        "port-directory": with_port(plain, str(tmp_path)),
    }


REFUSED = [
    "port-commented-out",
    "empty-file",
    "only-comments",
    "port-dev-null",
    "port-regular-file",
    "port-directory",
]


@pytest.mark.parametrize("case", REFUSED)
def test_a_refused_reload_keeps_the_daemon_and_the_old_mapping(tmp_path, line, replay_dir, case):
    """Before: no port killed the daemon (exit 1, NoPortError) after the new mapping was
    applied; /dev/null, a file or a directory were taken. `check` passed them all."""
    config = tmp_path / "usb2rc.yaml"
    config.write_text(with_port(INVERT_X_CONFIG.format(invert="true"), line.path))
    daemon = started(tmp_path, line, replay_dir, config)  # no --port: the config's port
    try:
        config.write_text(refused_configs(line, tmp_path)[case])
        before = len(daemon.log())
        daemon.signal(signal.SIGHUP)
        log = wait_log(daemon, "rejected")
        after = len(line.frames())
        assert x_of_node4(line, after, 25) == {INVERTED}  # the old mapping, frames flowing
        assert daemon.proc.poll() is None
    finally:
        assert daemon.stop() == 0
    errors = [ln for ln in log[before:].splitlines() if " ERROR " in ln or " WARNING " in ln]
    assert len(errors) == 1, errors  # one line says it all
    assert f"config {config} rejected, the running config stays: {config}" in errors[0]
    assert "Traceback" not in daemon.log()
    check = usb2rc("check", "--config", str(config))
    assert check.returncode == 2, check.stdout  # what a reload refuses, check refuses
    assert check.stderr.splitlines()[0] in errors[0]


def test_a_reload_without_a_port_takes_the_port_given_with_dash_dash_port(
    tmp_path, line, replay_dir
):
    """Decision: `--port` replaces the first output's port at start and on every reload, so
    a config without one is taken (and `check --port` passes it)."""
    config = tmp_path / "usb2rc.yaml"
    config.write_text(without_port(INVERT_UNGUARDED_X_CONFIG.format(invert="true")))
    daemon = started(tmp_path, line, replay_dir, config, "--port", line.path)
    try:
        config.write_text(without_port(INVERT_UNGUARDED_X_CONFIG.format(invert="false")))
        daemon.signal(signal.SIGHUP)
        wait_log(daemon, "reloaded")
        after = len(line.frames())
        line.wait_for(lambda fr: {f.axes[0] for f in data_frames(fr[after:], 4)[-5:]} == {PLAIN})
    finally:
        assert daemon.stop() == 0
    assert usb2rc("check", "--config", str(config), "--port", line.path).returncode == 0
    assert usb2rc("check", "--config", str(config)).returncode == 2


def test_run_refuses_at_start_what_a_reload_refuses(tmp_path):
    """One verdict: `run` exits 2 on the config a reload refuses, with `check`'s error.
    Before: it started on /dev/null and retried it every second, sending nothing."""
    config = tmp_path / "c.yaml"
    config.write_text(with_port(INVERT_X_CONFIG.format(invert="true"), "/dev/null"))
    run = usb2rc("run", "--config", str(config), "--replay", str(tmp_path))
    check = usb2rc("check", "--config", str(config))
    assert run.returncode == check.returncode == 2
    error = f"{config}:2: outputs[0].port: /dev/null: is a mem device, not a serial line (tty)"
    assert run.stderr.splitlines() == [error]
    assert check.stderr.splitlines() == [error, "1 error(s)"]


# --- point 5: a stop preempts a reload ------------------------------------------------------


def first_failsafe_after(line: PtyLine, after: int) -> int:
    """How many live `>` frames came after frame `after` before the first `!`."""
    frames = line.wait_for(
        lambda fr: fr if any(f.status == FAILSAFE for f in data_frames(fr[after:])) else None
    )
    statuses = [f.status for f in data_frames(frames[after:])]
    return statuses[: statuses.index(FAILSAFE)].count(LIVE)


def test_sigterm_during_a_10_mb_reload_stops_at_once(tmp_path, line, replay_dir):
    """Before: the first `!` came 5 s after SIGTERM, 258 `>` frames later (the reload
    parsed 10 MB first). Now the file is refused unread past 128 KiB, and a stop abandons
    whatever a reload does. A tick is 20 ms: 25 frames is half a second."""
    config = tmp_path / "usb2rc.yaml"
    config.write_text(INVERT_X_CONFIG.format(invert="true"))
    install(replay_dir / "stick.hid", MOVED_STICK)
    daemon = run_daemon(tmp_path, line.path, replay_dir, "--config", str(config))
    try:
        wait_x(line, INVERTED)
        big = INVERT_X_CONFIG.format(invert="false") + ("# " + "x" * 98 + "\n") * 100_000
        config.write_text(big)
        assert config.stat().st_size > 10_000_000
        daemon.signal(signal.SIGHUP)
        wait_log(daemon, "reloading")
        after = len(line.frames())
        daemon.signal(signal.SIGTERM)
        assert first_failsafe_after(line, after) < 25
    finally:
        assert daemon.stop() == 0


def test_sigterm_while_a_reload_waits_on_the_file_abandons_it(tmp_path, line, replay_dir):
    """A reload stuck reading its file (a FIFO here; a hung network mount in the field):
    SIGTERM abandons it, the `!` frames go out and the daemon exits 0. Before: the stop
    waited for the read, which never ended."""
    config = tmp_path / "usb2rc.yaml"
    config.write_text(INVERT_X_CONFIG.format(invert="true"))
    install(replay_dir / "stick.hid", MOVED_STICK)
    daemon = run_daemon(tmp_path, line.path, replay_dir, "--config", str(config))
    writer = None
    try:
        wait_x(line, INVERTED)
        config.unlink()
        os.mkfifo(config)
        daemon.signal(signal.SIGHUP)
        writer = open_when_read(config, daemon)  # the reload is in open()/read() now
        after = len(line.frames())
        daemon.signal(signal.SIGTERM)
        try:
            live_after_stop = first_failsafe_after(line, after)
        except AssertionError as exc:
            raise AssertionError(f"{exc}; the daemon's log:\n{daemon.log()}") from None
        assert live_after_stop < 25
        assert daemon.proc.wait(DEADLINE_S) == 0
    finally:
        daemon.stop()
        if writer is not None:
            os.close(writer)
    assert "stop during the config reload: the reload is abandoned" in daemon.log()


def open_when_read(fifo: Path, daemon: DaemonProcess) -> int:
    """The FIFO's write end, once the daemon holds its read end (ENXIO until then)."""
    deadline = time.monotonic() + DEADLINE_S
    while True:
        try:
            return os.open(fifo, os.O_WRONLY | os.O_NONBLOCK)
        except OSError:
            assert daemon.proc.poll() is None, daemon.log()
            assert time.monotonic() < deadline, "the daemon never opened the config"
            time.sleep(0.01)  # polling the FIFO's state; nothing to wait on


# --- point 9: what a reload would parse is bounded, with an error that says why -------------


def test_a_config_past_the_size_limit_is_an_error_naming_the_limit(tmp_path):
    """Before: any size was parsed (10 MB: 5 s, ticks held up 63 ms) and passed `check`."""
    config = tmp_path / "big.yaml"
    config.write_text(with_port("", "loop://") + "#" * (128 * 1024))
    result = usb2rc("check", "--config", str(config))
    assert result.returncode == 2
    assert result.stderr.startswith(f"{config}: larger than 128 KiB: a config is a few KiB")
    assert "hold up the outputs" in result.stderr


def test_more_device_entries_than_the_limit_is_an_error_at_devices(tmp_path):
    """Before: 2000 valid entries took 1.6 s to reload, ticks held up 105 ms."""
    entries = "".join(f"  - name: d{i}\n    match: {{vid: 0x1234, pid: {i}}}\n" for i in range(129))
    config = tmp_path / "many.yaml"
    config.write_text(with_port("devices:\n" + entries, "loop://"))
    result = usb2rc("check", "--config", str(config))
    assert result.returncode == 2
    first = result.stderr.splitlines()[0]
    assert first.startswith(f"{config}:5: devices: 129 entries, more than 128")
    assert first.endswith("(allowed: 1..128 entries)")


# --- issue 20: check's slips ----------------------------------------------------------------


def check_into_closed_pipe(*args: str, stderr_too: bool) -> int:
    """`usb2rc check ARGS | head -0`: the reader of stdout (and of stderr with
    `stderr_too`, as `2>&1 | head`) is gone before the first line; the exit status."""
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        proc = subprocess.run(
            [sys.executable, "-m", "usb2rc", "check", *args],
            stdout=write_end,
            stderr=write_end if stderr_too else subprocess.DEVNULL,
            cwd=ROOT,
            timeout=60,
            check=False,
        )
    finally:
        os.close(write_end)
    return proc.returncode


BROKEN = ROOT / "tests" / "data" / "configs" / "broken"


@pytest.mark.parametrize("stderr_too", [False, True], ids=["stdout", "stdout+stderr"])
def test_check_exit_status_survives_a_reader_that_went_away(tmp_path, stderr_too):
    """Before: `usb2rc check --config broken.yaml 2>&1 | head -1` exited 0."""
    broken = next(BROKEN.glob("*.yaml"))
    assert check_into_closed_pipe("--config", str(broken), stderr_too=stderr_too) == 2
    assert check_into_closed_pipe("--json", "--config", str(broken), stderr_too=stderr_too) == 2
    wants_wheel = tmp_path / "c.yaml"
    wants_wheel.write_text(
        with_port("devices:\n  - name: s\n    match: {vid: 0x044f, pid: 0xb10a}\n", "loop://")
        + "    axes: {x: {usage: Wheel}}\n"
    )
    demo = str(ROOT / "usb2rc" / "data" / "demo")
    args = ("--config", str(wants_wheel), "--replay", demo)
    assert check_into_closed_pipe(*args, stderr_too=stderr_too) == 2
    hotas = str(ROOT / "usb2rc" / "data" / "config" / "hotas.yaml")
    assert check_into_closed_pipe("--config", hotas, stderr_too=stderr_too) == 0


def test_check_replay_prints_no_ok_before_an_error_and_the_verdict_last(tmp_path):
    """Before: `check --replay DIR` printed `FILE: OK` first, then a device ERROR, exit 2."""
    config = tmp_path / "c.yaml"
    config.write_text(
        with_port("devices:\n  - name: s\n    match: {vid: 0x044f, pid: 0xb10a}\n", "loop://")
        + "    axes: {x: {usage: Wheel}}\n"
    )
    result = usb2rc("check", "--config", str(config), "--replay", str(ROOT / "usb2rc/data/demo"))
    assert result.returncode == 2
    assert "OK" not in result.stdout
    assert "ERROR" in result.stdout
    assert result.stderr.splitlines()[-1] == f"{config}: 1 error(s)"


def test_check_replay_warns_about_entries_no_device_matches():
    """The shipped hotas.yaml pins pedals to node 2; the demo has no pedals. Before: silent."""
    result = usb2rc(
        "check",
        "--config",
        "usb2rc/data/config/hotas.yaml",
        "--replay",
        "usb2rc/data/demo",
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.splitlines()[-1] == "usb2rc/data/config/hotas.yaml: OK"
    (warning,) = [ln for ln in result.stderr.splitlines() if "matches entry" in ln]
    assert re.match(r"usb2rc/data/config/hotas.yaml:\d+: devices\[2\]: warning: ", warning)
    assert "no device in usb2rc/data/demo matches entry 'pedals'" in warning
    assert "(match: vid 0x044f, pid 0xb679)" in warning


@pytest.mark.parametrize("port", ["/dev/null", "a-file", "."], ids=["dev-null", "file", "dir"])
def test_check_refuses_a_port_that_cannot_be_a_serial_line(tmp_path, port):
    """Before: `port: /dev/null` (or a file, a directory) passed `check`; the daemon then
    retried it every second, sending nothing."""
    (tmp_path / "a-file").write_text("")
    path = port if port.startswith("/") else str(tmp_path / port)
    config = tmp_path / "c.yaml"
    config.write_text(with_port("", path))
    result = usb2rc("check", "--config", str(config))
    assert result.returncode == 2
    assert result.stderr.startswith(f"{config}:2: outputs[0].port: {path}: is a ")
    assert "not a serial line" in result.stderr.splitlines()[0]


def test_check_takes_a_port_that_does_not_exist_yet(tmp_path):
    """Decision: an absent device path is fine: the adapter may be plugged later."""
    config = tmp_path / "c.yaml"
    config.write_text(with_port("", "/dev/ttyUSB-not-plugged"))
    assert usb2rc("check", "--config", str(config)).returncode == 0


# --- the slow suite: editors racing SIGHUP ---------------------------------------------------


def editor_saves(config: Path, good: str, rng_seed: int, until: float) -> int:
    """Save `config` as editors do, over and over: truncate+write, write-temp+rename, and
    moments when the file is empty or without its port. How many saves."""
    import random

    rng = random.Random(rng_seed)
    saves = 0
    while time.monotonic() < until:
        style = rng.randrange(4)
        if style == 0:  # truncate, then write (vim with backupcopy=yes, nano)
            with open(config, "w") as fh:
                fh.flush()
                fh.write(good)
        elif style == 1:  # write a temporary file, rename it over (most editors)
            tmp = config.with_name(f".{config.name}.swp")
            tmp.write_text(good)
            os.replace(tmp, config)
        elif style == 2:  # an empty file for a moment
            config.write_text("")
            config.write_text(good)
        else:  # the port commented out for a moment
            config.write_text(good.replace("    port:", "    # port:"))
            config.write_text(good)
        saves += 1
    return saves


@pytest.mark.slow
def test_editor_saves_racing_sighup_for_60_s_never_stop_the_daemon(tmp_path, line, replay_dir):
    config = tmp_path / "usb2rc.yaml"
    good = with_port(INVERT_X_CONFIG.format(invert="true"), line.path)
    config.write_text(good)
    daemon = started(tmp_path, line, replay_dir, config)
    until = time.monotonic() + 60
    hups = 0
    try:
        import threading

        saver = threading.Thread(target=editor_saves, args=(config, good, 19, until))
        saver.start()
        while time.monotonic() < until:
            daemon.signal(signal.SIGHUP)
            hups += 1
            assert daemon.proc.poll() is None, daemon.log()[-3000:]
            time.sleep(0.005)  # SIGHUPs at ~200/s, not a wait for anything
        saver.join()
        config.write_text(good)
        after = len(line.frames())
        assert x_of_node4(line, after, 25) == {INVERTED}
    finally:
        assert daemon.stop() == 0
    log = daemon.log()
    assert "Traceback" not in log
    assert hups > 1000 and "reloaded" in log
