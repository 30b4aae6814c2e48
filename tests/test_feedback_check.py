"""`usb2rc check` on `feedback:` rules: problems are errors (exit 2, file:line:key), and a
rule that names an output its device does not have is a warning (exit 0) when usb2rc knows
that device's outputs by its vid:pid (docs/CONFIG.md, "Feedback")."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from usb2rc.commands.check import feedback_warnings
from usb2rc.configfile import load_config_text

HEAD = """outputs:
  - protocol: c2-16b
    port: /dev/ttyUSB9
devices:
  - name: pad                            # a DualShock 4: rumble and a lightbar, no LEDs
    match: {vid: 0x054c, pid: 0x09cc}
  - name: stick                          # only a vid: not one known device
    match: {vid: 0x06a3}
feedback:
"""
HEAD_LINES = HEAD.count("\n")


def warned(feedback: str) -> list[str]:
    return [str(p) for p in feedback_warnings(load_config_text(HEAD + feedback, "fb.yaml"))]


def test_an_output_the_named_device_lacks_is_warned_at_its_key() -> None:
    got = warned(
        "  - when: mavlink.armed\n"
        "    device: pad\n"
        "    led: [0, fire]\n"
        "    rumble: {strong: 1, weak: 0.5}\n"
        "    force: {x: 1}\n"
    )
    line = HEAD_LINES + 3
    assert got == [
        f"fb.yaml:{line}: feedback[0].led: warning: pad (054c:09cc) has no indicator 0 "
        "(its indicators: none)",
        f"fb.yaml:{line}: feedback[0].led: warning: pad (054c:09cc) has no indicator 'fire' "
        "(its indicators: none)",
        f"fb.yaml:{line + 2}: feedback[0].force: warning: pad (054c:09cc) has no force_x or "
        "force_y",
    ]


def test_a_vid_pid_rule_is_checked_against_the_database() -> None:
    got = warned(
        '  - {device: "06a3:0762", led: [fire, Throttle, 21, nothere], brightness: 1,'
        " text: {line: 4, text: hi}, color: [1, 2, 3]}\n"
    )
    assert [g.split(": warning: ")[1] for g in got] == [
        "06a3:0762 has no indicator 21 (its indicators: 0..20)",
        "06a3:0762 has no indicator 'nothere' (its indicators: shift, fire, a red, a green, "
        "b red, b green, d red, d green, e red, e green, t1 red, t1 green, t2 red, t2 green, "
        "t3 red, t3 green, pov red, pov green, clutch red, clutch green, throttle)",
        "06a3:0762 has no red or green or blue",
        "06a3:0762 has no display line 4 (it has 3 lines)",
    ]


def test_no_warning_when_the_device_has_it_or_is_not_known() -> None:
    assert (
        warned(
            "  - {device: pad, rumble: {strong: 1}, color: [255, 0, 0], brightness: 0.5}\n"
            "  - {device: stick, led: 40, text: {line: 9, text: x}}\n"  # only a vid
            '  - {device: "1234:5678", force: {x: 1}}\n'  # not in the database
            "  - {led: 12, force: {y: 1}}\n"  # every device that has them
        )
        == []
    )
    assert feedback_warnings(load_config_text(HEAD.removesuffix("feedback:\n"), "f")) == []


def run_check(tmp_path: Path, text: str) -> subprocess.CompletedProcess[str]:
    path = tmp_path / "fb.yaml"
    path.write_text(text)
    return subprocess.run(
        [sys.executable, "-m", "usb2rc", "check", "--config", str(path)],
        capture_output=True,
        text=True,
        timeout=60,
    )


def test_check_warns_and_exits_0(tmp_path: Path) -> None:
    result = run_check(tmp_path, HEAD + "  - {device: pad, led: 0}\n")
    assert result.returncode == 0, result.stderr
    assert result.stdout.endswith(f"{tmp_path / 'fb.yaml'}: OK\n")
    assert result.stderr == (
        f"{tmp_path / 'fb.yaml'}:{HEAD_LINES + 1}: feedback[0].led: warning: pad (054c:09cc) "
        "has no indicator 0 (its indicators: none)\n"
    )


def test_check_reports_a_bad_rule_with_file_line_and_key_and_exits_2(tmp_path: Path) -> None:
    result = run_check(tmp_path, HEAD + "  - when: crsf.lq < 50\n    device: pda\n    led: 0\n")
    assert result.returncode == 2
    path = tmp_path / "fb.yaml"
    assert result.stderr.splitlines() == [
        f"{path}:{HEAD_LINES + 1}: feedback[0].when: unknown source 'crsf.lq'; did you mean "
        "'crsf.link_quality'? (allowed: downlink, crsf.link_quality, crsf.rssi, crsf.snr, "
        "crsf.battery_voltage, crsf.battery_remaining, crsf.flight_mode, mavlink.armed, "
        "mavlink.mode, mavlink.battery_voltage, mavlink.battery_remaining, mavlink.failsafe, "
        "node.failsafe, node.waiting, nodeN.failsafe, nodeN.waiting (N: 0..254))",
        f"{path}:{HEAD_LINES + 2}: feedback[0].device: no devices: entry is named 'pda'; did "
        "you mean 'pad'? (allowed: pad, stick, vvvv:pppp (a vid:pid in hex))",
        "2 error(s)",
    ]
