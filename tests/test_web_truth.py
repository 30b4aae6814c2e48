"""The status page tells the truth about the outputs, in a real browser at 1200 and 390 px.

A daemon with three outputs: C2-16B whose config port `--port loop://` replaces, SUMD on a pty
reading node 4, SBUS on a port that does not exist. Node 4 (a T.16000M) has no device at
first, so both SUMD and C2-16B send its failsafe; the SBUS port never opens. The page must
say so: the SBUS output not open (why, writes 0), which outputs send failsafe, the header's
state of the daemon (not of the page's own connection), the status byte in words, the
ports the daemon writes to in "Config check", pressed buttons labelled, and nothing cut off
at 390 px. Screenshots go to the test's folder."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from daemon_harness import DaemonProcess, PtyLine, StickState, install, recording, wait_until
from web_harness import WebProcess, browser

CONFIG = """
outputs:
  - protocol: c2-16b
    port: {missing}/serial0
  - protocol: sumd
    port: {sumd}
    channels: [node4.x, node4.y, node4.button1]
  - protocol: sbus
    port: {missing}/ttyUSB0
    channels: [node4.x, node4.y]
devices:
  - name: stick
    match: {{vid: 0x044f, pid: 0xb10a}}
    node_id: 4
"""

READ_PAGE = """
const text = (el) => el ? el.textContent.replace(/\\s+/g, ' ').trim() : null;
const badge = document.getElementById('connection');
const outputs = {};
for (const card of document.querySelectorAll('#outputs .output')) {
  outputs[card.dataset.output] = {open: card.dataset.open, failsafe: card.dataset.failsafe,
                                  writes: card.dataset.writes, text: text(card)};
}
const node = document.querySelector('article.node[data-node="4"]');
return {state: badge.dataset.state, badge: text(badge), outputs: outputs,
        node: node && {status: node.dataset.status, words: text(node.querySelector('.status')),
                       buttons: [...node.querySelectorAll('[data-button]')].map(text)},
        check: text(document.getElementById('check'))};
"""

# Every element of the page inside the page's width (the viewport less a scroll bar): nothing
# cut off, nothing to scroll sideways to.
CUT_OFF = """
const width = document.documentElement.clientWidth;
const out = [];
for (const el of document.body.querySelectorAll('*')) {
  const box = el.getBoundingClientRect();
  if (box.width > 0 && (box.right > width + 0.5 || box.left < -0.5))
    out.push(el.tagName + '.' + el.className + ' ' + Math.round(box.left) + '..' +
             Math.round(box.right) + ' ' + el.textContent.slice(0, 40));
}
return {viewport: window.innerWidth, width: width, scroll: document.documentElement.scrollWidth,
        cut: out.slice(0, 8)};
"""


@pytest.fixture
def sumd_line() -> Iterator[PtyLine]:
    pty = PtyLine("sumd")
    try:
        yield pty
    finally:
        pty.close()


def page(driver: Any) -> dict[str, Any]:
    return driver.execute_script(READ_PAGE)  # type: ignore[no-any-return]


def wait_page(driver: Any, condition: Any, what: str) -> dict[str, Any]:
    return wait_until(lambda: (p := page(driver)) and condition(p) and p, what, timeout=30)  # type: ignore[no-any-return]


def assert_nothing_cut_off(driver: Any, width: int) -> None:
    seen = driver.execute_script(CUT_OFF)
    assert seen["viewport"] == width, seen  # a scroll bar may take some of it: `width`
    assert seen["cut"] == [] and seen["scroll"] <= seen["width"], seen


def failsafe_and_a_closed_port(p: dict[str, Any]) -> bool:
    outs = p["outputs"]
    return (
        p["state"] == "failsafe"
        and len(outs) == 3
        and outs["output3-sbus"]["open"] == "false"
        and outs["output2-sumd"]["failsafe"] == "true"
        and "not open" in outs["output3-sbus"]["text"]
    )


def test_the_page_says_which_outputs_send_and_which_send_failsafe(
    tmp_path: Path, sumd_line: PtyLine
) -> None:
    missing, replay = tmp_path / "missing", tmp_path / "replay"
    replay.mkdir()
    config = tmp_path / "three.yaml"
    config.write_text(CONFIG.format(missing=missing, sumd=sumd_line.path))
    daemon = web = None
    try:
        daemon = DaemonProcess(
            ["--config", str(config), "--port", "loop://", "--replay", str(replay),
             "--status-socket", str(tmp_path / "status.sock")],
            tmp_path / "daemon.log",
        )  # fmt: skip
        web = WebProcess(tmp_path / "status.sock", tmp_path / "web.log")
        with browser(1200, 900) as driver:
            driver.get(web.url + "/")
            seen = wait_page(driver, failsafe_and_a_closed_port, "failsafe and SBUS not open")
            assert "1 node in failsafe" in seen["badge"] and "1 output" in seen["badge"]
            assert "live" not in seen["badge"]
            sbus = seen["outputs"]["output3-sbus"]
            assert sbus["writes"] == "0" and "writes 0" in sbus["text"]
            assert f"{missing}/ttyUSB0" in sbus["text"] and "No such file" in sbus["text"]
            c2 = seen["outputs"]["output1-c2-16b"]
            assert c2["open"] == "true" and c2["failsafe"] == "true" and "node 4" in c2["text"]
            assert seen["outputs"]["output2-sumd"]["open"] == "true"
            assert seen["node"] is not None and seen["node"]["status"] == "!"
            assert "failsafe" in seen["node"]["words"]
            # the port the daemon writes to, and that --port put it there
            assert "c2-16b loop://" in seen["check"] and "--port" in seen["check"]
            assert sumd_line.path in seen["check"]
            assert_nothing_cut_off(driver, 1200)
            driver.save_screenshot(str(tmp_path / "failsafe-1200.png"))
            driver.set_window_size(390, 844)
            assert_nothing_cut_off(driver, 390)
            driver.save_screenshot(str(tmp_path / "failsafe-390.png"))

            pressed = StickState(buttons=0b101)  # node buttons 1 and 3
            install(replay / "stick.hid", recording([pressed] * 30))
            live = wait_page(
                driver,
                lambda p: p["node"] and p["node"]["status"] == ">" and p["node"]["buttons"],
                "node 4 live with its buttons",
            )
            assert live["node"]["buttons"] == ["button 1", "button 3"]
            assert "live" in live["node"]["words"]
            assert live["state"] == "not-sending" and "failsafe" not in live["badge"]
            assert live["outputs"]["output2-sumd"]["failsafe"] == "false"
            aged = wait_page(
                driver,
                lambda p: "input age p50" in p["outputs"]["output2-sumd"]["text"],
                "the SUMD output's input age",
            )  # a frame carried the live stick's report: its age on the card
            assert "ms" in aged["outputs"]["output2-sumd"]["text"]
            assert_nothing_cut_off(driver, 390)
            driver.save_screenshot(str(tmp_path / "live-390.png"))
    finally:
        if web is not None:
            web.stop()
        if daemon is not None:
            assert daemon.stop() == 0
