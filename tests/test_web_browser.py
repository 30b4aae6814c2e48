"""The status page in a real browser (Debian's chromium), on a real daemon and `usb2rc web`.

A replayed T.16000M pinned to node 4 comes in while the page is open: its X bar moves when
the recording moves the stick, the node shows failsafe when the file goes (unplug), and the
page comes back by itself with live data after the daemon is stopped and started again. The
header's badge says the daemon's state all along: all live, 1 node in failsafe, daemon not
running."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from daemon_harness import (
    INVERT_X_CONFIG,
    DaemonProcess,
    StickState,
    install,
    timed_recording,
    wait_until,
)
from web_harness import WebProcess, browser

CENTRE_S = 3.0  # the stick rests this long (the guard arms it), then X goes full right
FULL_RIGHT = 16383

# What the page shows of node 4's X: the number and the bar's width, from the DOM.
READ_NODE = """
const card = document.querySelector('article.node[data-node="4"]');
if (!card) return null;
const axis = card.querySelector('.axis[data-axis="x"]');
return {status: card.dataset.status, failsafe: card.dataset.failsafe,
        value: axis ? Number(axis.dataset.value) : null,
        width: axis ? parseFloat(axis.querySelector('.fill').style.width) : null,
        connected: document.getElementById('connection').dataset.connected,
        connects: Number(document.getElementById('connection').dataset.connects),
        state: document.getElementById('connection').dataset.state,
        badge: document.getElementById('connection').textContent};
"""
UPTIME = "return document.getElementById('uptime').textContent;"
BADGE = "const b = document.getElementById('connection'); return [b.dataset.state, b.textContent];"


def stick_moves() -> str:
    centre = StickState()
    moved = StickState(x=FULL_RIGHT)
    events = [(i * 0.02, centre) for i in range(int(CENTRE_S / 0.02))]
    events += [(CENTRE_S + i * 0.02, moved) for i in range(10)]
    return timed_recording(events)


def start_daemon(tmp_path: Path, replay: Path, sock: Path, name: str) -> DaemonProcess:
    config = tmp_path / "stick.yaml"
    config.write_text(INVERT_X_CONFIG.format(invert="false"))
    args = ["--config", str(config), "--port", "loop://", "--replay", str(replay)]
    return DaemonProcess([*args, "--status-socket", str(sock)], tmp_path / name)


def node_4(driver: Any) -> dict[str, Any]:
    return driver.execute_script(READ_NODE) or {}


def wait_page(driver: Any, condition: Any, what: str, timeout: float = 20.0) -> dict[str, Any]:
    return wait_until(lambda: (n := node_4(driver)) and condition(n) and n, what, timeout)  # type: ignore[no-any-return]


def plug_and_see_the_bar_move(driver: Any, stick: Path) -> None:
    install(stick, stick_moves())
    wait_page(
        driver, lambda n: n["status"] == ">" and abs(n["value"]) < 1000, "node 4 live, X centred"
    )
    moved = wait_page(driver, lambda n: n["value"] > 30000, "node 4's X bar to move right")
    assert moved["width"] > 45.0  # the bar's fill: half the track, from the centre
    assert (moved["state"], moved["badge"]) == ("all-live", "all live")


def test_page_follows_the_stick_an_unplug_and_a_daemon_restart(tmp_path: Path) -> None:
    replay, sock = tmp_path / "replay", tmp_path / "run" / "status.sock"
    replay.mkdir()
    stick = replay / "stick.hid"
    daemon: DaemonProcess | None = None
    web: WebProcess | None = None
    try:
        daemon = start_daemon(tmp_path, replay, sock, "daemon1.log")
        web = WebProcess(sock, tmp_path / "web.log")
        with browser() as driver:
            driver.get(web.url + "/")
            first = wait_page(driver, lambda n: n["connected"] == "true", "the page to go live")
            assert first["failsafe"] == "true"  # pinned, no device yet: `!`
            assert (first["state"], first["badge"]) == ("failsafe", "1 node in failsafe")

            plug_and_see_the_bar_move(driver, stick)
            status = web.get("/api/status")
            assert status["stats"]["outputs"][0]["ticks"] > 0
            # what usb2rc takes of the host, beside its uptime
            uptime = wait_until(
                lambda: (text := driver.execute_script(UPTIME)) and " % of a core" in text and text,
                "the CPU share beside the uptime",
            )
            assert re.fullmatch(r"up \d+ s, CPU \d+\.\d % of a core", uptime)
            assert [n["status"] for n in status["nodes"] if n["node_id"] == 4] == [">"]

            stick.unlink()  # unplug
            gone = wait_page(
                driver, lambda n: n["failsafe"] == "true" and n["status"] == "!", "failsafe"
            )
            assert (gone["state"], gone["badge"]) == ("failsafe", "1 node in failsafe")

            assert daemon.stop() == 0
            assert not sock.exists()  # SIGTERM removed the socket
            wait_until(
                lambda: driver.execute_script(BADGE) == ["no-daemon", "daemon not running"],
                "the page to say the daemon is gone",
            )
            daemon = None
            daemon = start_daemon(tmp_path, replay, sock, "daemon2.log")
            wait_page(
                driver, lambda n: n["connected"] == "true" and n["connects"] == 2, "reconnect"
            )
            plug_and_see_the_bar_move(driver, stick)
    finally:
        if web is not None:
            web.stop()
        if daemon is not None:
            daemon.stop()


def test_with_a_token_the_page_goes_live_through_its_cookie(tmp_path: Path) -> None:
    """`?token=` once: the page, its script and its live stream get in by the cookie (no
    daemon here: the stream says so)."""
    token = "0123456789abcdef0123"
    (tmp_path / "token").write_text(token)
    web: WebProcess | None = None
    try:
        web = WebProcess(
            tmp_path / "s.sock", tmp_path / "web.log", "--token-file", str(tmp_path / "token")
        )
        with browser() as driver:
            driver.get(f"{web.url}/?token={token}")
            badge = "return document.getElementById('connection').textContent"
            wait_until(
                lambda: "daemon not running" in driver.execute_script(badge),
                "the live stream's first record",
            )
            driver.get(web.url + "/")  # the cookie alone
            wait_until(lambda: "daemon not running" in driver.execute_script(badge), "again")
    finally:
        if web is not None:
            web.stop()
