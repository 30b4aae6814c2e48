"""Write docs/web.png and docs/web-phone.png: the status page on the demo recordings.

    .venv/bin/python tests/make_web_screenshots.py

A daemon on the built-in demo recordings (`--replay demo --replay-loop`, port `loop://`) and
`usb2rc web`, photographed by headless chromium (Debian's, as tests/test_web_browser.py drives
it) once the page is live; a phone-sized view and a desktop one."""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from daemon_harness import ROOT, DaemonProcess, wait_until
from web_harness import WebProcess, browser

LIVE = "return document.querySelectorAll('article.node[data-status=\">\"]').length"
SHOTS = {"web.png": (900, 760), "web-phone.png": (400, 1100)}


def main() -> None:
    with tempfile.TemporaryDirectory(prefix="usb2rc-shots-") as tmp:
        workdir = Path(tmp)
        sock = workdir / "status.sock"
        daemon = DaemonProcess(
            [
                "--port",
                "loop://",
                "--replay",
                "demo",
                "--replay-loop",
                "--status-socket",
                str(sock),
            ],
            workdir / "daemon.log",
        )
        web = WebProcess(sock, workdir / "web.log")
        try:
            for name, (width, height) in SHOTS.items():
                with browser(width, height) as driver:
                    driver.get(web.url + "/")
                    wait_until(lambda d=driver: d.execute_script(LIVE) == 2, "two live nodes", 20)
                    driver.save_screenshot(str(ROOT / "docs" / name))
                    print(f"wrote docs/{name}")
        finally:
            web.stop()
            daemon.stop()


if __name__ == "__main__":
    main()
