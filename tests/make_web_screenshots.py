"""Write docs/web.png and docs/web-phone.png: the status page on the demo recordings.

    .venv/bin/python tests/make_web_screenshots.py

A daemon on the demo recordings (usb2rc/data/demo, looped) and a replayed LED stick, with
config/hotas-demo.yaml plus the stick on node 2, a CRSF and a MAVLink output and two
feedback rules; every output on a pty whose far end this script plays (web_harness.FarEnds:
a C2-16B downlink for node 2, a CRSF module's telemetry, an armed vehicle), so the
"Telemetry & feedback" card shows values; and `usb2rc web`, photographed by headless
chromium (Debian's, as tests/test_web_browser.py drives it) once every node is live and the
card shows every far end: a desktop view 1200 px wide and a phone's 390 px."""

from __future__ import annotations

import functools
import shutil
import sys
import tempfile
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from daemon_harness import ROOT, DaemonProcess, PtyLine, install, wait_until
from web_harness import FEEDBACK_RULES, FarEnds, WebProcess, browser, led_stick_recording

SHOTS = {"web.png": (1200, 900), "web-phone.png": (390, 1800)}
MORE_OUTPUTS = """\
  - protocol: crsf
    port: {crsf}
    channels: [node1.x, node1.y, node1.z, node1.rz]
  - protocol: mavlink
    port: {mavlink}
    channels: [node1.x, node1.y, node1.z, node1.rz]

defaults: false"""
MORE_DEVICES = """
  - name: leds                # a stick with LEDs (replayed): what the far ends light
    match: {vid: 0x1209, pid: 0x0001}
    node_id: 2

"""
# Every node live, and the card shows CRSF, MAVLink and node 2's downlink fresh, and both
# rules' actions.
READY = """
if (document.getElementById('connection').dataset.state !== 'all-live') return false;
const fresh = [...document.querySelectorAll('#feedback [data-state="fresh"]')].length;
return fresh === 3 && document.querySelectorAll('#feedback [data-rule]').length === 2;
"""


def ready(driver: Any) -> bool:
    return bool(driver.execute_script(READY))


def screenshot_config(crsf: str, mavlink: str) -> str:
    text = (ROOT / "config" / "hotas-demo.yaml").read_text()
    text = text.replace("\ndefaults: false", MORE_OUTPUTS.format(crsf=crsf, mavlink=mavlink))
    return text.rstrip("\n") + "\n" + MORE_DEVICES + FEEDBACK_RULES


def main() -> None:
    with tempfile.TemporaryDirectory(prefix="usb2rc-shots-") as tmp:
        workdir = Path(tmp)
        sock, replay = workdir / "status.sock", workdir / "replay"
        replay.mkdir()
        for recording in (ROOT / "usb2rc" / "data" / "demo").glob("*.hid"):
            shutil.copy(recording, replay / recording.name)
        install(replay / "leds.hid", led_stick_recording())
        lines: list[PtyLine] = []
        daemon = web = far_ends = None
        try:
            for protocol in ("c2-16b", "sumd", "crsf", "mavlink"):
                lines.append(PtyLine(protocol))  # each far end reads: no output stalls
            c2, sumd, crsf, mavlink = lines
            config = workdir / "hotas-demo.yaml"
            text = screenshot_config(crsf.path, mavlink.path)
            config.write_text(text.replace("port: /dev/ttyUSB0", f"port: {sumd.path}"))
            far_ends = FarEnds(c2, crsf, mavlink, node=2)
            far_ends.start()
            daemon = DaemonProcess(
                ["--config", str(config), "--port", c2.path, "--replay", str(replay),
                 "--replay-loop", "--status-socket", str(sock)],
                workdir / "daemon.log",
            )  # fmt: skip
            web = WebProcess(sock, workdir / "web.log")
            for name, (width, height) in SHOTS.items():
                with browser(width, height) as driver:
                    driver.get(web.url + "/")
                    wait_until(functools.partial(ready, driver), "all live, the card full", 30)
                    driver.save_screenshot(str(ROOT / "docs" / name))
                    print(f"wrote docs/{name}")
        finally:
            if far_ends is not None:
                far_ends.stop()
            if web is not None:
                web.stop()
            if daemon is not None:
                daemon.stop()
            for line in lines:
                line.close()


if __name__ == "__main__":
    main()
