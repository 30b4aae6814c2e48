"""The status socket without flags: where neither RUNTIME_DIRECTORY nor XDG_RUNTIME_DIR is set
(root, `sudo`, a container, a cron job), `usb2rc run` and `usb2rc web` agree on one default.

Root: `/run/usb2rc/status.sock`, in a mount namespace of its own with a fresh /run (so no
other daemon of the machine or of a parallel test answers there). Another user: a private
folder `/tmp/usb2rc-<uid>/` (0700), as that user inside a user namespace (the daemon sees
itself as that uid; the files are the test's). A folder someone else owns, or that others
may enter, is refused with the reason; `web` names the path it tries and what to do."""

from __future__ import annotations

import os
import random
import shutil
import stat
import subprocess
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from daemon_harness import DaemonProcess, wait_until
from web_harness import WebProcess

NO_RUNTIME_DIRS = ["env", "-u", "XDG_RUNTIME_DIR", "-u", "RUNTIME_DIRECTORY"]
DAEMON_ARGS = ["--port", "loop://", "--replay", "demo", "--replay-loop"]
SERVICE_SOCKET = "/run/usb2rc/status.sock"


def _needs(command: list[str], why: str) -> None:
    """Skip (fail under CI, which runs as root) when the namespace cannot be made here."""
    probe = subprocess.run([*command, "true"], capture_output=True, timeout=30)
    if probe.returncode == 0:
        return
    reason = f"{why}: {' '.join(command)} failed ({probe.stderr.decode().strip()})"
    if os.environ.get("CI"):
        pytest.fail(reason, pytrace=False)
    pytest.skip(reason)


def private_run() -> list[str]:
    """Root with a fresh, empty /run of its own (a tmpfs in a new mount namespace)."""
    return [
        "unshare",
        "--mount",
        "--propagation",
        "private",
        "sh",
        "-c",
        'mount -t tmpfs tmpfs /run && exec "$@"',
        "sh",
        *NO_RUNTIME_DIRS,
    ]


def as_user(uid: int) -> list[str]:
    """This uid (and gid), without runtime directories: a user namespace maps us onto it."""
    return ["unshare", "--user", f"--map-user={uid}", f"--map-group={uid}", *NO_RUNTIME_DIRS]


@pytest.fixture
def uid() -> Iterator[int]:
    """A uid nobody else here uses; its /tmp/usb2rc-<uid> is removed afterwards."""
    chosen = random.randrange(40000, 60000)
    folder = Path(f"/tmp/usb2rc-{chosen}")
    _needs(as_user(chosen), "a user namespace as another uid")
    assert not folder.exists(), f"{folder} left by something else"
    try:
        yield chosen
    finally:
        shutil.rmtree(folder, ignore_errors=True)


@dataclass
class Started:
    """What a test started; the `started` fixture stops it whatever happens."""

    daemon: DaemonProcess | None = None
    web: WebProcess | None = None


@pytest.fixture
def started() -> Iterator[Started]:
    processes = Started()
    try:
        yield processes
    finally:
        if processes.web is not None:
            processes.web.stop()
        if processes.daemon is not None:
            assert processes.daemon.stop() == 0


def status_of(web: WebProcess) -> dict:  # type: ignore[type-arg]
    return web.get("/api/status")  # type: ignore[no-any-return]


def live_nodes(web: WebProcess) -> bool:
    status = status_of(web)
    return bool(status["web"]["connected"] and status.get("nodes"))


def test_root_daemon_and_web_meet_at_run_usb2rc_without_flags(
    tmp_path: Path, started: Started
) -> None:
    if os.geteuid() != 0:
        pytest.skip("root's default (/run/usb2rc) needs root")
    _needs(private_run(), "a mount namespace with its own /run")
    daemon = started.daemon = DaemonProcess(
        DAEMON_ARGS, tmp_path / "daemon.log", prefix=private_run()
    )
    wait_until(
        lambda: f"status socket: {SERVICE_SOCKET}" in daemon.log(),
        "the daemon to say where its status socket is",
        timeout=30,
    )
    inside = ["nsenter", f"--mount=/proc/{daemon.proc.pid}/ns/mnt", "--", *NO_RUNTIME_DIRS]
    web = started.web = WebProcess(None, tmp_path / "web.log", prefix=inside)
    wait_until(lambda: live_nodes(web), "the page's record to show the nodes", timeout=30)
    assert status_of(web)["web"]["socket"] == SERVICE_SOCKET
    assert SERVICE_SOCKET in web.log()  # it says which path it reads


def test_a_user_daemon_and_web_meet_in_a_private_folder(
    tmp_path: Path, uid: int, started: Started
) -> None:
    folder = Path(f"/tmp/usb2rc-{uid}")
    sock = folder / "status.sock"
    daemon = started.daemon = DaemonProcess(
        DAEMON_ARGS, tmp_path / "daemon.log", prefix=as_user(uid)
    )
    wait_until(
        lambda: f"status socket: {sock}" in daemon.log(),
        "the daemon to say where its status socket is",
        timeout=30,
    )
    assert stat.S_IMODE(folder.stat().st_mode) == 0o700
    assert stat.S_ISSOCK(sock.stat().st_mode)
    web = started.web = WebProcess(None, tmp_path / "web.log", prefix=as_user(uid))
    wait_until(lambda: live_nodes(web), "the page's record to show the nodes", timeout=30)
    assert status_of(web)["web"]["socket"] == str(sock)


@pytest.mark.parametrize("whose", ["another user's", "open to others"])
def test_a_folder_that_is_not_private_is_refused_with_the_reason(
    tmp_path: Path, uid: int, whose: str, started: Started
) -> None:
    folder = Path(f"/tmp/usb2rc-{uid}")
    folder.mkdir(mode=0o700)
    if whose == "another user's":
        os.chown(folder, 1234, 1234)  # not mapped in the namespace: not the user's
    else:
        folder.chmod(0o755)
    daemon = started.daemon = DaemonProcess(
        DAEMON_ARGS, tmp_path / "daemon.log", prefix=as_user(uid)
    )
    refused = wait_until(
        lambda: next((ln for ln in daemon.log().splitlines() if str(folder) in ln), None),
        "the daemon to say why it has no status socket",
        timeout=30,
    )
    assert "running without it" in refused and "--status-socket" in refused
    assert ("owned by" in refused) if whose == "another user's" else ("0755" in refused)
    wait_until(lambda: " running" in daemon.log(), "the daemon to run on without it")
    assert not (folder / "status.sock").exists()

    web = started.web = WebProcess(None, tmp_path / "web.log", prefix=as_user(uid))
    status = wait_until(
        lambda: (s := status_of(web))["web"].get("error") and s, "web's reason", timeout=30
    )
    assert str(folder) in status["web"]["error"] and status["web"]["connected"] is False


def test_web_names_the_path_it_tries_and_what_to_do(
    tmp_path: Path, uid: int, started: Started
) -> None:
    """No daemon: `web` (no flags) says where it looks, and that `usb2rc run` as this user
    makes its socket there, or `--socket` with the path the daemon logged."""
    sock = f"/tmp/usb2rc-{uid}/status.sock"
    web = started.web = WebProcess(None, tmp_path / "web.log", prefix=as_user(uid))
    hint = wait_until(lambda: status_of(web)["web"].get("hint"), "the page's hint")
    log = wait_until(lambda: "--socket" in web.log() and web.log(), "the log's hint")
    for text in (hint, log):
        assert sock in text and "usb2rc run" in text and "--socket" in text
