"""`check --json` and `icd --json`: the same verdict and tables as the text, for scripts.

Each broken config's JSON problems must be the text errors, record by record (the text is
tested against the files' `# expect:` lines in test_check_icd_cli.py); each good config's
ICD tables must hold the rows the markdown document prints.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from cli_harness import usb2rc

from usb2rc.configfile import Problem

ROOT = Path(__file__).resolve().parent.parent
CONFIGS = Path(__file__).parent / "data" / "configs"
BROKEN = sorted((CONFIGS / "broken").glob("*.yaml"))
HOTAS = ROOT / "usb2rc" / "data" / "config" / "hotas.yaml"
DEMO = ROOT / "usb2rc" / "data" / "demo"


def as_problem(record: dict) -> Problem:
    return Problem(
        record["file"],
        record["line"],
        record["key"],
        record["message"],
        record["allowed"] or "",
        record["suggestion"],
    )


@pytest.mark.parametrize("path", BROKEN, ids=lambda p: p.stem)
def test_check_json_problems_are_the_text_errors(path: Path) -> None:
    text = usb2rc("check", "--config", str(path))
    result = usb2rc("check", "--json", "--config", str(path))
    assert result.returncode == text.returncode == 2
    document = json.loads(result.stdout)
    assert document["ok"] is False and document["config"] == str(path)
    records = document["problems"]
    assert {r["severity"] for r in records} == {"error"}
    assert [as_problem(r).format() for r in records] == text.stderr.splitlines()[:-1]
    assert all(r["file"] == str(path) for r in records)


def test_check_json_ok_with_replayed_devices() -> None:
    result = usb2rc("check", "--json", "--config", str(HOTAS), "--replay", str(DEMO))
    assert result.returncode == 0, result.stderr
    document = json.loads(result.stdout)
    assert document["ok"] is True
    (pedals,) = document["problems"]  # hotas.yaml's node 2 pedals are not in the demo
    assert (pedals["severity"], pedals["key"]) == ("warning", "devices[2]")
    assert "matches entry 'pedals' (match: vid 0x044f, pid 0xb679)" in pedals["message"]
    assert [o["protocol"] for o in document["outputs"]] == ["c2-16b", "sumd"]
    devices = {d["entry"]: d for d in document["replay"]}
    assert set(devices) == {"stick", "throttle"}
    assert devices["stick"]["node_id"] == 1 and devices["stick"]["used"] is True
    assert devices["stick"]["file"].endswith("stick.hid")


def test_check_json_warnings_are_the_text_warnings(tmp_path: Path) -> None:
    """A config `check` accepts with warnings (a CRSF address no receiver takes, a feedback
    rule for an output the stick does not have): `--json` gives each one the text prints,
    record by record, as a `warning`, and the exit stays 0."""
    config = tmp_path / "warned.yaml"
    config.write_text(
        "outputs:\n"
        "  - {protocol: crsf, port: loop://, address: 0x10, channels: [node1.x]}\n"
        "devices:\n"
        "  - name: pad\n"
        "    match: {vid: 0x054c, pid: 0x09cc}\n"
        "feedback:\n"
        "  - {when: mavlink.armed, device: pad, force: {x: 1}}\n"
    )
    text = usb2rc("check", "--config", str(config))
    result = usb2rc("check", "--json", "--config", str(config))
    assert text.returncode == result.returncode == 0, text.stderr
    printed = [line for line in text.stderr.splitlines() if ": warning: " in line]
    assert len(printed) >= 2, text.stderr
    document = json.loads(result.stdout)
    records = document["problems"]
    assert document["ok"] is True and {r["severity"] for r in records} == {"warning"}
    assert [as_problem(r).format() for r in records] == printed


def test_check_json_device_errors_and_unusable_files(tmp_path: Path) -> None:
    replay = tmp_path / "replay"
    replay.mkdir()
    (replay / "notes.hid").write_text("not a recording\n")
    config = tmp_path / "wants-wheel.yaml"
    config.write_text(
        "devices:\n  - name: stick\n    match: {vid: 0x044f, pid: 0xb10a}\n"
        "    axes: {x: {usage: Wheel}}\n"
    )
    (replay / "stick.hid").write_bytes((DEMO / "stick.hid").read_bytes())
    result = usb2rc(
        "check", "--json", "--config", str(config), "--replay", str(replay), "--port", "loop://"
    )
    assert result.returncode == 2
    error, warning = json.loads(result.stdout)["problems"]
    assert (error["file"], error["line"], error["key"]) == (str(config), 4, "devices[0].axes.x")
    assert error["severity"] == "error" and error["recording"] == str(replay / "stick.hid")
    assert error["message"].startswith("usage Wheel is not in this device")
    assert warning["severity"] == "warning" and warning["file"] == str(replay)
    assert "notes.hid" in warning["message"]


def test_icd_json_holds_the_documents_rows() -> None:
    result = usb2rc("icd", "--json", "--config", str(HOTAS))
    assert result.returncode == 0, result.stderr
    document = json.loads(result.stdout)
    markdown = usb2rc("icd", "--config", str(HOTAS)).stdout
    (node1,) = [n for n in document["nodes"] if n["node_id"] == 1]
    assert [d["name"] for d in node1["devices"]] == ["stick", "throttle"]
    assert node1["devices"][0]["match"] == {"vid": 0x044F, "pid": 0xB10A}
    for axis in node1["axes"]:
        row = f"| {axis['slot']} | {axis['device']} | {axis['source']} | {axis['kind']} |"
        assert row in markdown
    for button in node1["buttons"]:
        assert f"| {button['button']} | {button['group']} | {button['bit']} |" in markdown
    (sumd,) = document["sumd"]
    assert [c["channel"] for c in sumd["channels"]] == list(range(1, len(sumd["channels"]) + 1))
    assert sumd["channels"][0]["source"] == "node1.x"


def test_icd_json_of_a_broken_config_exits_2() -> None:
    result = usb2rc("icd", "--json", "--config", str(BROKEN[0]))
    assert result.returncode == 2 and result.stdout == ""
