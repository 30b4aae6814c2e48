"""The page's "Telemetry & feedback" card in a real browser, on a real daemon and `usb2rc web`.

A daemon with three outputs on ptys: C2-16B, CRSF and MAVLink, and a replayed LED stick
(8 indicators by its descriptor, and a brightness) pinned to node 1. The far ends talk back
as real ones do, over and over: the C2-16B far end a `>` downlink for node 1 (indicator 0,
brightness half), the CRSF module its link statistics, battery and flight mode, the
vehicle (pymavlink) its HEARTBEAT, armed in LOITER, and SYS_STATUS. The card must show
first that nothing was heard, then the values the far ends sent, the downlink fresh, the
rules' last actions with their file:line, the stick's lit indicators by name, its
brightness and its output writes; and the downlink stale once its far end goes quiet.
Nothing is cut off at 1200 or 390 px."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from daemon_harness import DaemonProcess, PtyLine, install, wait_until
from test_web_truth import assert_nothing_cut_off
from web_harness import (
    ARMED_RULE_LINE,
    FEEDBACK_CONFIG,
    LQ_RULE_LINE,
    FarEnds,
    WebProcess,
    browser,
    led_stick_recording,
)

READ_CARD = """
const text = (el) => el ? el.textContent.replace(/\\s+/g, ' ').trim() : null;
const section = document.getElementById('feedback-section');
const sources = {};
for (const row of document.querySelectorAll('#feedback [data-source]')) {
  const values = {};
  for (const chip of row.querySelectorAll('[data-key]')) values[chip.dataset.key] = text(chip);
  sources[row.dataset.source] = {state: row.dataset.state, values: values, text: text(row)};
}
const downlinks = {};
for (const row of document.querySelectorAll('#feedback [data-downlink]'))
  downlinks[row.dataset.downlink] = {state: row.dataset.state, text: text(row)};
const driven = {};
for (const card of document.querySelectorAll('#feedback [data-driven]'))
  driven[card.dataset.driven] = {lit: [...card.querySelectorAll('[data-lit]')].map(text),
                                 analog: [...card.querySelectorAll('[data-analog]')].map(text),
                                 text: text(card)};
return {shown: !section.hidden, connected: document.getElementById('connection').dataset.connected,
        sources: sources, downlinks: downlinks, driven: driven,
        actions: [...document.querySelectorAll('#feedback [data-rule]')].map(text)};
"""


# Each row label of the card ("CRSF", "MAVLink", "node 1", "rule 2") on one line: a label
# broken across lines ("MAVLin" / "k") is not cut off, but unreadable all the same.
BROKEN_LABELS = """
const broken = [];
for (const label of document.querySelectorAll('#feedback .src')) {
  const range = document.createRange();
  range.selectNodeContents(label);
  if (range.getClientRects().length > 1) broken.push(label.textContent);
}
return broken;
"""


@pytest.fixture
def lines() -> Iterator[tuple[PtyLine, PtyLine, PtyLine]]:
    opened: list[PtyLine] = []
    try:
        for protocol in ("c2-16b", "crsf", "mavlink"):
            opened.append(PtyLine(protocol))
        yield opened[0], opened[1], opened[2]
    finally:
        for line in opened:
            line.close_at_the_end()


def card(driver: Any) -> dict[str, Any]:
    return driver.execute_script(READ_CARD)  # type: ignore[no-any-return]


def wait_card(driver: Any, condition: Callable[[dict[str, Any]], Any], what: str) -> dict[str, Any]:
    """Until the card shows `condition`; a timeout names `what` and the card's last reading."""
    last: list[dict[str, Any]] = [{}]

    def shows() -> dict[str, Any] | None:
        last[0] = card(driver)
        return last[0] if condition(last[0]) else None

    try:
        return wait_until(shows, what, timeout=30)  # type: ignore[no-any-return]
    except AssertionError as failed:
        raise AssertionError(f"{failed}; the card: {last[0]}") from None


def nothing_heard(c: dict[str, Any]) -> bool:
    states = {s: v["state"] for s, v in c["sources"].items()}
    return (
        c["shown"]
        and states == {"crsf": "not-heard", "mavlink": "not-heard"}
        and c["downlinks"].get("none", {}).get("text") == "downlink none heard"
        and "LED stick" in c["driven"]
    )


def all_heard(c: dict[str, Any]) -> bool:
    sources = c["sources"]
    return (
        sources["crsf"]["state"] == "fresh"
        and sources["crsf"]["values"]["crsf.flight_mode"] == "mode ACRO"
        and sources["crsf"]["values"]["crsf.battery_remaining"] == "76 %"
        and sources["mavlink"]["state"] == "fresh"
        and sources["mavlink"]["values"]["mavlink.battery_remaining"] == "64 %"
        and c["downlinks"].get("1", {}).get("state") == "fresh"
        and len(c["actions"]) == 2
        and "written" in c["driven"]["LED stick"]["text"]
        and len(c["driven"]["LED stick"]["lit"]) == 3
    )


def check_what_was_sent(seen: dict[str, Any], config: Path) -> None:
    crsf_row, mav_row = seen["sources"]["crsf"], seen["sources"]["mavlink"]
    assert crsf_row["values"] == {
        "crsf.link_quality": "LQ 87 %",
        "crsf.rssi": "RSSI -60 dBm",  # the better antenna
        "crsf.snr": "SNR 9 dB",
        "crsf.battery_voltage": "battery 15.2 V",
        "crsf.battery_remaining": "76 %",
        "crsf.flight_mode": "mode ACRO",
    }, crsf_row
    assert mav_row["values"] == {
        "mavlink.armed": "ARMED",
        "mavlink.mode": "mode LOITER",
        "mavlink.battery_voltage": "battery 12.6 V",
        "mavlink.battery_remaining": "64 %",
        "mavlink.failsafe": "failsafe no",
    }, mav_row
    assert crsf_row["text"].endswith(" s ago") and mav_row["text"].endswith(" s ago")
    assert seen["downlinks"]["1"]["text"].startswith("node 1 downlink fresh")
    armed, lq = sorted(seen["actions"], key=lambda a: a.split()[1])
    # where each rule is: the file's name (its full path in the element's title) and line
    assert armed.startswith(f"rule 1 {config.name}:{ARMED_RULE_LINE} led LED Caps Lock"), armed
    assert lq.startswith(f"rule 2 {config.name}:{LQ_RULE_LINE} led LED Scroll Lock"), lq
    stick = seen["driven"]["LED stick"]
    # the downlink's indicator 0, and the two rules' LEDs over it
    assert stick["lit"] == ["LED Num Lock", "LED Caps Lock", "LED Scroll Lock"], stick
    assert stick["analog"] == ["brightness 0.50"], stick
    assert "of 8 indicators" in stick["text"] and "refused 0" in stick["text"], stick


def test_the_card_shows_what_the_far_ends_and_the_vehicle_said(
    tmp_path: Path, lines: tuple[PtyLine, PtyLine, PtyLine]
) -> None:
    c2, module, vehicle = lines
    replay, sock = tmp_path / "replay", tmp_path / "status.sock"
    replay.mkdir()
    config = tmp_path / "feedback.yaml"
    config.write_text(FEEDBACK_CONFIG.format(c2=c2.path, crsf=module.path, mavlink=vehicle.path))
    far_ends = FarEnds(c2, module, vehicle)
    daemon = web = None
    try:
        daemon = DaemonProcess(
            ["--config", str(config), "--replay", str(replay), "--status-socket", str(sock)],
            tmp_path / "daemon.log",
        )
        web = WebProcess(sock, tmp_path / "web.log")
        install(replay / "stick.hid", led_stick_recording())
        with browser(1200, 900) as driver:
            driver.get(web.url + "/")
            first = wait_card(driver, nothing_heard, "the card: nothing heard yet")
            assert first["actions"] == [] and first["driven"]["LED stick"]["lit"] == []

            far_ends.start()
            seen = wait_card(driver, all_heard, "the card: what the far ends sent")
            check_what_was_sent(seen, config)
            assert_nothing_cut_off(driver, 1200)
            assert driver.execute_script(BROKEN_LABELS) == []
            driver.save_screenshot(str(tmp_path / "feedback-1200.png"))
            driver.set_window_size(390, 1400)
            assert_nothing_cut_off(driver, 390)
            assert driver.execute_script(BROKEN_LABELS) == []
            driver.save_screenshot(str(tmp_path / "feedback-390.png"))

            far_ends.quiet["c2"].set()  # the C2-16B far end goes quiet: stale after 1 s
            quiet = wait_card(
                driver,
                lambda c: c["downlinks"]["1"]["state"] == "stale",
                "the downlink stale",
            )
            assert quiet["downlinks"]["1"]["text"].startswith("node 1 downlink stale")
            assert "LED Num Lock" not in quiet["driven"]["LED stick"]["lit"]
            assert quiet["sources"]["crsf"]["state"] == "fresh"  # the others still talk
    finally:
        far_ends.stop()
        if web is not None:
            web.stop()
        if daemon is not None:
            assert daemon.stop() == 0
