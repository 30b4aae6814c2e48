"""`usb2rc web` on an address another program holds: a usage error (exit 2) that names the
address and `--listen`, not the web server's raw bind error."""

from __future__ import annotations

import socket
import subprocess
import sys
from pathlib import Path

from daemon_harness import ROOT


def test_a_taken_address_is_exit_2_naming_it_and_listen(tmp_path: Path) -> None:
    with socket.socket() as holder:
        holder.bind(("127.0.0.1", 0))
        holder.listen(1)
        address = f"127.0.0.1:{holder.getsockname()[1]}"
        result = subprocess.run(
            [
                sys.executable,
                "-m",
                "usb2rc",
                "web",
                "--listen",
                address,
                "--socket",
                str(tmp_path / "status.sock"),
            ],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=60,
        )
    assert result.returncode == 2, result.stderr
    assert address in result.stderr and "--listen" in result.stderr
    assert "error while attempting to bind" not in result.stderr  # uvicorn's own words
    assert "Traceback" not in result.stderr
