"""`usb2rc web` without a browser: localhost unless a token is given, the token enforced,
`/api/status` while the daemon is away and once it is there, and `install-system --web`."""

from __future__ import annotations

import subprocess
import sys
import urllib.error
from pathlib import Path

import pytest
from daemon_harness import ROOT, DaemonProcess, wait_until
from web_harness import WebProcess

TOKEN = "0123456789abcdef0123"


def usb2rc(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "usb2rc", *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=30,
    )


def test_another_address_without_a_token_is_refused_with_the_fix() -> None:
    result = usb2rc("web", "--listen", "0.0.0.0:8080")
    assert result.returncode == 2
    assert "--token-file" in result.stderr and "openssl rand -hex 16" in result.stderr


def test_a_short_or_missing_token_file_is_refused(tmp_path: Path) -> None:
    short = tmp_path / "short"
    short.write_text("abc\n")
    result = usb2rc("web", "--listen", "0.0.0.0:8080", "--token-file", str(short))
    assert result.returncode == 2 and "at least 16 characters" in result.stderr
    result = usb2rc("web", "--token-file", str(tmp_path / "nope"))
    assert result.returncode == 2 and "No such file" in result.stderr


def test_a_bad_listen_is_a_usage_error() -> None:
    result = usb2rc("web", "--listen", "8080")
    assert result.returncode == 2 and "HOST:PORT" in result.stderr


def test_status_says_the_daemon_is_away_then_serves_its_record(tmp_path: Path) -> None:
    sock = tmp_path / "status.sock"
    web = WebProcess(sock, tmp_path / "web.log")
    daemon = None
    try:
        away = web.get("/api/status")
        assert away["web"]["connected"] is False and "stats" not in away
        daemon = DaemonProcess(
            ["--port", "loop://", "--replay", "demo", "--status-socket", str(sock)],
            tmp_path / "daemon.log",
        )
        status = wait_until(
            lambda: (s := web.get("/api/status"))["web"]["connected"] and s.get("nodes") and s,
            "the daemon's record through usb2rc web",
        )
        assert {"uptime_s", "outputs", "devices", "missing_devices"} <= set(status["stats"])
        assert {d["vid_pid"] for d in status["devices"]} == {"044f:b10a", "044f:b687"}
        assert status["check"]["ok"] is True
    finally:
        web.stop()
        if daemon is not None:
            assert daemon.stop() == 0


def test_the_token_is_needed_by_every_request(tmp_path: Path) -> None:
    token_file = tmp_path / "token"
    token_file.write_text(TOKEN + "\n")
    web = WebProcess(tmp_path / "s.sock", tmp_path / "web.log", "--token-file", str(token_file))
    try:
        for path in ("/", "/api/status", "/api/events", "/static/app.js"):
            with pytest.raises(urllib.error.HTTPError) as refused:
                web.get(path)
            assert refused.value.code == 401
        assert web.get(f"/api/status?token={TOKEN}")["web"]["connected"] is False
        bearer = {"Authorization": f"Bearer {TOKEN}"}
        assert web.get("/api/status", bearer)["web"]["connected"] is False
        with pytest.raises(urllib.error.HTTPError):
            web.get("/api/status", {"Authorization": "Bearer " + TOKEN[:-1] + "x"})
    finally:
        web.stop()


def test_install_system_web_writes_the_web_unit(tmp_path: Path) -> None:
    result = usb2rc(
        "install-system", "--root", str(tmp_path), "--web", "--exec", "/opt/v/bin/usb2rc"
    )
    assert result.returncode in (0, 1), result.stderr  # 1: no systemd-sysusers here
    unit = (tmp_path / "etc/systemd/system/usb2rc-web.service").read_text()
    assert "ExecStart=/opt/v/bin/usb2rc web --listen 127.0.0.1:8080" in unit
    assert "IPAddressAllow=localhost" in unit and "SupplementaryGroups=usb2rc" in unit
    main = (tmp_path / "etc/systemd/system/usb2rc.service").read_text()
    assert "RuntimeDirectory=usb2rc" in main
    without = usb2rc("install-system", "--root", str(tmp_path / "b"), "--exec", "/opt/v/bin/usb2rc")
    assert without.returncode in (0, 1)
    assert not (tmp_path / "b/etc/systemd/system/usb2rc-web.service").exists()
