"""The daemon's status socket: JSON lines to every client, read-only, bounded per client.

In-process: the server on a status function of the test's own (a slow client is dropped, a
stale socket file replaced, a live one refused). As a pilot's day: a real daemon subprocess
on replayed devices, whose socket survives a reload, goes with SIGTERM, is replaced after a
SIGKILL, and keeps serving while five clients connect and never read."""

from __future__ import annotations

import json
import logging
import os
import signal
import socket
import stat
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from daemon_harness import (
    INVERT_X_CONFIG,
    DaemonProcess,
    PtyLine,
    StickState,
    data_frames,
    install,
    recording,
    wait_until,
)

from usb2rc.config.model import HandoverConfig
from usb2rc.nodes.step import NodeFrame, NodeView
from usb2rc.status_socket import (
    SocketInUseError,
    StatusServer,
    default_path,
    node_record,
)


def connect(path: Path | str) -> socket.socket:
    client = connected(path)
    assert client is not None, f"nobody listens on {path}"
    return client


def connected(path: Path | str) -> socket.socket | None:
    """A connection, or None while nobody listens there yet (a daemon that is starting)."""
    client = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    client.settimeout(10)
    try:
        client.connect(str(path))
    except (ConnectionRefusedError, FileNotFoundError):
        client.close()
        return None
    return client


def read_lines(client: socket.socket, count: int) -> list[dict[str, Any]]:
    """The next `count` whole lines, as JSON."""
    reader = client.makefile("rb")
    return [json.loads(reader.readline()) for _ in range(count)]


@pytest.fixture
def served(tmp_path: Path) -> Iterator[StatusServer]:
    calls = {"n": 0}

    def status() -> dict[str, Any]:
        calls["n"] += 1
        return {"n": calls["n"], "pad": "x" * 20_000}

    server = StatusServer(str(tmp_path / "run" / "status.sock"), status, period_s=0.01)
    server.start()
    yield server
    server.shutdown()


# --------------------------------------------------------------------------- in-process


def test_each_client_gets_every_line_and_what_it_sends_is_ignored(served: StatusServer) -> None:
    client = connect(served.path)
    client.sendall(b"stop\nset x 1\n" + bytes(range(256)) * 64)  # read and thrown away
    lines = read_lines(client, 5)
    numbers = [line["n"] for line in lines]
    assert numbers == list(range(numbers[0], numbers[0] + 5))  # in order, none skipped
    assert lines[-1]["status_socket"]["clients_connected"] == 1
    client.close()
    wait_until(lambda: served.counters.clients_connected == 0, "the server to see it go")


def test_lines_go_out_on_the_node_clocks_steps_where_no_output_ticks() -> None:
    """The daemon's status lines ride on the node clock's grid (a whole number of its steps
    near 0.1 s apart, at its phase from the grid's epoch), so a line's work does not fall on
    an output's tick."""
    from usb2rc.daemon import status_grid
    from usb2rc.nodes.step import GRID_EPOCH_S, clock_phase

    epoch = GRID_EPOCH_S
    alone = status_grid(0.020, 0.010)  # C2-16B alone
    assert alone == (pytest.approx(0.100), pytest.approx(epoch + 0.010))
    five = [1 / 50, 1 / 100, 1 / 250, 1 / 100, 1 / 50]
    period, phase = status_grid(0.004, clock_phase(0.004, five))
    assert period == pytest.approx(0.100) and phase == pytest.approx(epoch + 0.001)
    assert status_grid(0.008, 0.004)[0] == pytest.approx(0.096)  # 12 steps of 8 ms
    server = StatusServer("unused", dict, period_s=0.1, phase_s=0.01)
    assert server.line_after(1000.0) == pytest.approx(1000.01)
    assert server.line_after(1000.01) == pytest.approx(1000.11)  # strictly after
    late = 1000.01 + 0.35  # a line that ran late: the next one on the grid, no burst
    assert server.line_after(late) == pytest.approx(1000.41)
    ticks = [epoch + k * 0.004 for k in range(250)] + [epoch + k * 0.010 for k in range(100)]
    for k in range(10):  # over a second of lines, each at least 1 ms from any tick
        at = k * period + phase
        assert min(abs(at - tick) for tick in ticks) == pytest.approx(0.001)


def test_the_socket_is_0660(served: StatusServer) -> None:
    assert stat.S_IMODE(os.stat(served.path).st_mode) == 0o660


def test_a_client_that_never_reads_is_dropped_others_go_on(
    served: StatusServer, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.WARNING, "usb2rc.status")
    close, dropped_at_close = served._close, []

    def noting_close(client: Any) -> None:  # what another thread could read as it closes
        dropped_at_close.append(served.counters.clients_dropped)
        close(client)

    served._close = noting_close  # type: ignore[method-assign]
    stuck = connect(served.path)
    reading = connect(served.path)
    reader = reading.makefile("rb")
    # 20 kB lines at 100 Hz fill the stuck client's socket buffer and then the server's cap
    wait_until(lambda: reader.readline() and served.counters.clients_dropped == 1, "a drop")
    # counted once gone: a reader that sees the drop never sees the client connected
    assert dropped_at_close == [0]
    assert json.loads(reader.readline())["n"] > 0  # the reading client is still served
    assert served.counters.clients_connected == 1
    assert sum("read too slowly" in r.message for r in caplog.records) == 1
    assert stuck.recv(1 << 20)  # what was sent before the drop, then the end
    stuck.close()


def test_stop_removes_the_socket_file(tmp_path: Path) -> None:
    server = StatusServer(str(tmp_path / "s.sock"), dict)
    server.start()
    assert (tmp_path / "s.sock").exists()
    server.shutdown()
    assert not (tmp_path / "s.sock").exists()


def test_a_stale_socket_is_replaced_a_live_one_and_a_file_are_not(tmp_path: Path) -> None:
    path = tmp_path / "s.sock"
    dead = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    dead.bind(str(path))
    dead.close()  # the file stays, nobody listens: a killed daemon's
    first = StatusServer(str(path), dict)
    first.start()
    try:
        with pytest.raises(SocketInUseError, match="another usb2rc answers there"):
            StatusServer(str(path), dict).start()
    finally:
        first.shutdown()
    path.write_text("not a socket")
    with pytest.raises(OSError, match="is not a socket"):
        StatusServer(str(path), dict).start()
    assert path.read_text() == "not a socket"


def test_a_failing_status_is_counted_and_logged_once(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    def broken() -> dict[str, Any]:
        raise KeyError("boom")

    server = StatusServer(str(tmp_path / "s.sock"), broken, period_s=0.01)
    server.start()
    client = connect(server.path)  # lines are built only while a client is there
    try:
        wait_until(lambda: server.counters.line_errors >= 5, "several failed lines")
    finally:
        client.close()
        server.shutdown()
    assert sum("cannot build a status line" in r.message for r in caplog.records) == 1


def test_default_path_under_the_service_and_for_a_user() -> None:
    assert default_path({"RUNTIME_DIRECTORY": "/run/usb2rc"}) == "/run/usb2rc/status.sock"
    assert default_path({"XDG_RUNTIME_DIR": "/run/user/1000"}) == (
        "/run/user/1000/usb2rc/status.sock"
    )
    assert default_path({}, uid=0) == "/run/usb2rc/status.sock"
    assert default_path({}, uid=1000) == "/tmp/usb2rc-1000/status.sock"


def test_a_node_record_names_its_status_axes_buttons_and_hat() -> None:
    axes = (100, -200, 0, 0, 0, 0, 32767, 0, 0, 0)
    group1 = 0b101 | 1 << 24  # node buttons 1 and 3, hat UP
    live = NodeView(NodeFrame(4, False, axes, group1, 1))  # group 2 bit 0: node button 25
    record = node_record(live, [])
    assert record["status"] == ">" and record["failsafe"] is False
    assert record["axes"]["x"] == 100 and record["axes"]["rz"] == 32767
    assert record["buttons"] == [1, 3, 25] and record["hat"] == "UP"
    waiting = NodeView(NodeFrame(4, True, axes, 0, 0), waiting_for=("X to rest",))
    assert node_record(waiting, [])["status"] == "!"
    assert node_record(waiting, [])["waiting_for"] == ["X to rest"]
    handover = NodeView(NodeFrame(4, False, axes, 0, 0, handover=HandoverConfig(2, 7)))
    assert node_record(handover, [])["status"] == "&"
    low = NodeView(NodeFrame(4, False, axes, 0, 0, low_battery=True))
    assert node_record(low, [])["status"] == "%"


# --------------------------------------------------------------------------- journeys


def start(tmp_path: Path, line: PtyLine, replay: Path, sock: Path, log: str) -> DaemonProcess:
    config = tmp_path / "stick.yaml"
    config.write_text(INVERT_X_CONFIG.format(invert="false"))
    args = ["--config", str(config), "--port", line.path, "--replay", str(replay)]
    return DaemonProcess([*args, "--status-socket", str(sock)], tmp_path / log)


def node_4_live(lines: list[dict[str, Any]]) -> bool:
    return any(n["node_id"] == 4 and n["status"] == ">" for n in lines[-1]["nodes"])


def test_reload_keeps_the_socket_sigterm_removes_it(
    tmp_path: Path, line: PtyLine, replay_dir: Path
) -> None:
    install(replay_dir / "stick.hid", recording([StickState()] * 5))
    sock = tmp_path / "run" / "status.sock"
    daemon = start(tmp_path, line, replay_dir, sock, "daemon.log")
    try:
        client = wait_until(lambda: connected(sock), "the status socket listening")
        first = wait_until(
            lambda: (got := read_lines(client, 1)) and node_4_live(got) and got, "node 4 live"
        )
        assert first[0]["check"]["ok"] and first[0]["check"]["source"].endswith("stick.yaml")
        daemon.signal(signal.SIGHUP)
        wait_until(lambda: "reloaded" in daemon.log(), "the reload")
        after = read_lines(client, 3)  # the same connection goes on
        assert after[-1]["at"] > first[0]["at"]
        assert [line_["stats"]["outputs"][0]["tick_errors"] for line_ in after] == [0, 0, 0]
        client.close()
    finally:
        assert daemon.stop() == 0
    assert not sock.exists()


def test_a_killed_daemons_socket_is_replaced_at_start(
    tmp_path: Path, line: PtyLine, replay_dir: Path
) -> None:
    sock = tmp_path / "status.sock"
    killed = start(tmp_path, line, replay_dir, sock, "killed.log")
    wait_until(sock.exists, "the status socket")
    killed.proc.kill()
    killed.stop()
    assert sock.exists()  # nobody removed it
    daemon = start(tmp_path, line, replay_dir, sock, "daemon.log")
    try:
        wait_until(lambda: "left by a daemon that is gone: replaced" in daemon.log(), "the note")
        # the note comes as the stale file goes, before the new socket listens
        client = wait_until(lambda: connected(sock), "the new daemon listening")
        assert read_lines(client, 1)[0]["stats"]["outputs"]
    finally:
        assert daemon.stop() == 0


def test_the_service_runtime_directory_and_a_0077_umask(tmp_path: Path, replay_dir: Path) -> None:
    """As the unit runs it: no --status-socket, RUNTIME_DIRECTORY set by systemd, UMask=0077;
    the socket is still 0660 (group usb2rc may connect)."""
    runtime = tmp_path / "run-usb2rc"
    runtime.mkdir(mode=0o750)
    daemon = DaemonProcess(
        ["--port", "loop://", "--replay", str(replay_dir)],
        tmp_path / "daemon.log",
        env={"RUNTIME_DIRECTORY": str(runtime)},
        prefix=["sh", "-c", 'umask 077; exec "$0" "$@"'],
    )
    try:
        sock = runtime / "status.sock"
        client = wait_until(lambda: connected(sock), "the socket in $RUNTIME_DIRECTORY")
        assert stat.S_IMODE(os.stat(sock).st_mode) == 0o660
        assert read_lines(client, 1)[0]["nodes"] == []
    finally:
        assert daemon.stop() == 0


def test_five_clients_that_never_read_do_not_stop_the_frames(
    tmp_path: Path, line: PtyLine, replay_dir: Path
) -> None:
    install(replay_dir / "stick.hid", recording([StickState(x=9000)] * 5))
    sock = tmp_path / "status.sock"
    daemon = start(tmp_path, line, replay_dir, sock, "daemon.log")
    try:
        stuck = [wait_until(lambda: connected(sock), "the status socket listening")]
        stuck += [connect(sock) for _ in range(4)]
        for client in stuck:
            client.sendall(b"x" * 100_000)  # and never read
        before = len(line.frames())
        reading = connect(sock)
        lines = read_lines(reading, 20)  # two seconds of lines
        assert lines[-1]["status_socket"]["clients_connected"] == 6
        assert len(data_frames(line.frames(), 4)) > 0
        assert len(line.frames()) > before + 50  # the line kept going all along
        assert lines[-1]["stats"]["outputs"][0]["tick_errors"] == 0
        for client in [*stuck, reading]:
            client.close()
    finally:
        assert daemon.stop() == 0


def test_off_means_no_socket(tmp_path: Path, replay_dir: Path) -> None:
    runtime = tmp_path / "rt"
    runtime.mkdir()
    daemon = DaemonProcess(
        ["--port", "loop://", "--replay", str(replay_dir), "--status-socket", "off"],
        tmp_path / "daemon.log",
        env={"RUNTIME_DIRECTORY": str(runtime)},
    )
    try:
        wait_until(lambda: " running" in daemon.log(), "the daemon to run")
    finally:
        assert daemon.stop() == 0
    assert list(runtime.iterdir()) == []
    assert "status socket" not in daemon.log()
