"""Write docs/web.png and docs/web-phone.png: the status page on the demo recordings.

    .venv/bin/python tests/make_web_screenshots.py

A daemon on the built-in demo recordings (`--replay demo --replay-loop`) with
config/hotas-demo.yaml: C2-16B on `loop://` (`--port`), SUMD on a pty this script reads; and
`usb2rc web`, photographed by headless chromium (Debian's, as tests/test_web_browser.py drives
it) once every node is live: a desktop view 1200 px wide and a phone's 390 px."""

from __future__ import annotations

import functools
import sys
import tempfile
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from daemon_harness import ROOT, DaemonProcess, PtyLine, wait_until
from web_harness import WebProcess, browser

LIVE = "return document.getElementById('connection').dataset.state"
SHOTS = {"web.png": (1200, 900), "web-phone.png": (390, 1400)}


def all_live(driver: Any) -> bool:
    return bool(driver.execute_script(LIVE) == "all-live")


def main() -> None:
    with tempfile.TemporaryDirectory(prefix="usb2rc-shots-") as tmp:
        workdir = Path(tmp)
        sock = workdir / "status.sock"
        sumd = PtyLine("sumd")  # the far end: read, so the SUMD output never stalls
        config = workdir / "hotas-demo.yaml"
        text = (ROOT / "config" / "hotas-demo.yaml").read_text()
        config.write_text(text.replace("port: /dev/ttyUSB0", f"port: {sumd.path}"))
        daemon = web = None
        try:
            daemon = DaemonProcess(
                ["--config", str(config), "--port", "loop://", "--replay", "demo",
                 "--replay-loop", "--status-socket", str(sock)],
                workdir / "daemon.log",
            )  # fmt: skip
            web = WebProcess(sock, workdir / "web.log")
            for name, (width, height) in SHOTS.items():
                with browser(width, height) as driver:
                    driver.get(web.url + "/")
                    wait_until(functools.partial(all_live, driver), "all live", 30)
                    driver.save_screenshot(str(ROOT / "docs" / name))
                    print(f"wrote docs/{name}")
        finally:
            if web is not None:
                web.stop()
            if daemon is not None:
                daemon.stop()
            sumd.close()


if __name__ == "__main__":
    main()
