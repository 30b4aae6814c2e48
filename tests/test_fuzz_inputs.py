"""Fuzzing the other readers of outside bytes: HID input reports, hid-recorder files (and the
replay backend that lists them), and the YAML config loader.

- Reports: any bytes, any length, any report ID: `ReportDecoder.feed` returns True/False and
  never raises; False exactly for a short report or an unknown ID.
- hid-recorder: mutated recordings give a Recording or a RecordingError naming the source;
  a replay directory full of them lists the good ones and names the bad ones.
- YAML: mutated configs give a Config or a ConfigError whose every line is `file:line: ...`;
  `usb2rc check` on them exits 0 or 2, never with a traceback. The tests at the end pin the
  inputs this fuzzing found escaping as other exceptions (fixed in config.py since).
"""

from __future__ import annotations

import errno
import json
import math
import random
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from stress_harness import env_int, figures, mutate

from usb2rc.configfile import ConfigError, load_config, load_config_text
from usb2rc.hid.descriptor import parse_descriptor
from usb2rc.hid.recording import RecordingError, format_recording, parse_recording
from usb2rc.hid.replay import ReplayBackend

ROOT = Path(__file__).resolve().parent.parent
DATA = Path(__file__).parent / "data"
DEVICES = {
    d["name"]: bytes.fromhex(d["hex"]) for d in json.loads((DATA / "real-devices.json").read_text())
}
LAYOUTS = {name: parse_descriptor(desc) for name, desc in DEVICES.items()}
STARTERS = ROOT / "usb2rc" / "data" / "config"  # the starter configs the package ships
GOOD_CONFIGS = {
    p.name: p.read_text()
    for p in sorted((DATA / "configs" / "good").glob("*.yaml")) + sorted(STARTERS.glob("*.yaml"))
}
BROKEN_CONFIGS = {
    p.name: p.read_text() for p in sorted((DATA / "configs" / "broken").glob("*.yaml"))
}
ERROR_LINE = re.compile(r"^.+:\d+: .+")


# --- reports --------------------------------------------------------------------------------


@settings(max_examples=400, deadline=None)
@given(st.sampled_from(sorted(LAYOUTS)), st.binary(max_size=100))
def test_reports_of_any_shape(name, report):
    layout = LAYOUTS[name]
    decoder = layout.make_decoder()
    before = decoder.state()
    took = decoder.feed(report)
    if layout.uses_report_ids:
        length = layout.input_report_lengths.get(report[0]) if report else None
        expected = length is not None and len(report) - 1 >= length
    else:
        expected = len(report) >= layout.input_report_lengths[0]
    assert took == expected
    assert (decoder.bad_reports, decoder.reports) == ((0, 1) if took else (1, 0))
    if not took:
        assert decoder.state() == before  # a rejected report changes nothing


def run_reports(n: int, seed: int) -> dict[str, int]:
    rng = random.Random(seed)
    tally = {"reports": 0, "taken": 0, "rejected": 0}
    decoders = {name: layout.make_decoder() for name, layout in LAYOUTS.items()}
    for _ in range(n):
        name = rng.choice(sorted(LAYOUTS))
        layout, decoder = LAYOUTS[name], decoders[name]
        rid = rng.choice(sorted(layout.input_report_lengths))
        length = layout.input_report_lengths[rid]
        prefix = bytes([rid if rng.random() < 0.8 else rng.randrange(256)])
        if not layout.uses_report_ids:
            prefix = b""
        size = max(0, length + rng.choice((-length, -1, 0, 0, 0, 1, 5, 64)))
        took = decoder.feed(prefix + rng.randbytes(size))
        tally["reports"] += 1
        tally["taken" if took else "rejected"] += 1
    for name, decoder in decoders.items():
        state = decoder.state()
        assert len(state.values) == len(LAYOUTS[name].inputs)
    return tally


def test_reports_seeded_fast():
    tally = run_reports(5000, 1)
    assert tally["taken"] and tally["rejected"]


# --- hid-recorder files ---------------------------------------------------------------------


def _sample_recording(rng: random.Random) -> str:
    name = rng.choice(sorted(DEVICES))
    layout = LAYOUTS[name]
    rid = rng.choice(sorted(layout.input_report_lengths))
    prefix = bytes([rid]) if layout.uses_report_ids else b""
    lines = [
        "# usb2rc fuzz",
        "D: 0",
        f"R: {len(DEVICES[name])} " + " ".join(f"{b:02x}" for b in DEVICES[name]),
        f"N: {name}",
        "P: usb-0000:00:14.0-1/input0",
        "I: 3 044f b10a",
    ]
    for i in range(rng.randint(0, 4)):
        report = prefix + rng.randbytes(layout.input_report_lengths[rid])
        lines.append(f"E: {i * 0.01:.6f} {len(report)} " + " ".join(f"{b:02x}" for b in report))
    return "\n".join(lines) + "\n"


def _mutate_text(text: str, rng: random.Random) -> str:
    """Line-level and character-level mutations of a text file."""
    lines = text.split("\n")
    for _ in range(rng.randint(1, 4)):
        op = rng.randrange(8)
        i = rng.randrange(len(lines))
        if op == 0:
            del lines[i]
        elif op == 1:
            lines.insert(i, lines[rng.randrange(len(lines))])
        elif op == 2:
            lines[i] = lines[i][: rng.randrange(len(lines[i]) + 1)]
        elif op == 3:
            lines[i] = " " * rng.randint(1, 4) + lines[i]
        elif op == 4 and lines[i]:
            j = rng.randrange(len(lines[i]))
            lines[i] = lines[i][:j] + rng.choice(":-#[]{}&*!|>'\"%@`,?\\ \t0x") + lines[i][j + 1 :]
        elif op == 5:
            lines[i] = lines[i].replace(" ", "", 1)
        elif op == 6:
            lines[i] = lines[i].replace("0", rng.choice(("-1", "99999999999", "1e9", "nan")), 1)
        else:
            encoded = mutate(lines[i].encode(), rng, max_ops=2)
            lines[i] = encoded.decode("ascii", errors="ignore")
    return "\n".join(lines)


def run_recordings(n: int, seed: int) -> dict[str, int]:
    rng = random.Random(seed)
    tally = {"recordings": 0, "parsed": 0, "recording_errors": 0}
    for _ in range(n):
        text = _mutate_text(_sample_recording(rng), rng)
        tally["recordings"] += 1
        try:
            rec = parse_recording(text.splitlines(), source="fuzz.hid")
        except RecordingError as exc:
            assert str(exc).startswith("fuzz.hid"), exc
            tally["recording_errors"] += 1
            continue
        tally["parsed"] += 1
        again = parse_recording(format_recording(rec).splitlines())
        assert again.descriptor == rec.descriptor and len(again.events) == len(rec.events)
        for a, b in zip(again.events, rec.events, strict=True):  # times print with 6 decimals
            assert a.report == b.report
            assert math.isclose(a.time_s, b.time_s, abs_tol=1e-6) or str(a.time_s) == str(b.time_s)
    return tally


def test_recordings_seeded_fast():
    tally = run_recordings(1500, 1)
    assert tally["parsed"] and tally["recording_errors"]


def test_replay_directory_of_mutants(tmp_path):
    rng = random.Random(4)
    for i in range(60):
        text = _mutate_text(_sample_recording(rng), rng)
        (tmp_path / f"m{i:02d}.hid").write_bytes(
            mutate(text.encode(), rng, 2) if i % 5 else text.encode()
        )
    (tmp_path / "binary.hid").write_bytes(bytes(range(256)) * 4)
    backend = ReplayBackend(tmp_path, speed=1000.0)
    infos = backend.enumerate(all=True)
    assert len(infos) + len(backend.problems) == 61
    assert all("not a hid-recorder file" in p for p in backend.problems)
    # Events are parsed as they are played: a device plays to its end, or its read fails
    # (EIO, naming the line) at a bad one, and its file is a problem from then on.
    failed = []
    for info in infos:
        device = backend.open(info)
        try:
            while device.read(0.05) is not None:
                pass
        except OSError as exc:
            assert exc.errno == errno.EIO and info.path in str(exc), exc
            failed.append(info.path)
        device.close()
    assert failed, "no mutant with a bad event line: the test checks nothing there"
    left = {i.path for i in backend.enumerate(all=True)}
    assert left == {i.path for i in infos} - set(failed)
    assert len(backend.problems) == 61 - len(left)


# --- YAML configs ---------------------------------------------------------------------------


def _classify(text: str, tally: dict[str, int]) -> None:
    try:
        load_config_text(text, "fuzz.yaml")
    except ConfigError as exc:
        assert exc.errors, "a ConfigError without errors"
        for error in exc.errors:
            assert ERROR_LINE.match(error), f"not file:line: message: {error!r}"
            assert error.startswith("fuzz.yaml:")
        for problem in exc.problems:
            assert problem.source == "fuzz.yaml" and problem.line is not None, problem
        tally["config_errors"] += 1
        return
    except Exception as exc:
        raise AssertionError(f"{type(exc).__name__}: {exc}\n--- config ---\n{text}") from exc
    tally["accepted"] += 1


def run_configs(n: int, seed: int) -> dict[str, int]:
    rng = random.Random(seed)
    seeds = list(GOOD_CONFIGS.values()) + list(BROKEN_CONFIGS.values())
    tally = {"configs": 0, "accepted": 0, "config_errors": 0}
    for _ in range(n):
        text = _mutate_text(rng.choice(seeds), rng)
        tally["configs"] += 1
        _classify(text, tally)
    return tally


def test_configs_seeded_fast():
    tally = run_configs(600, 1)
    assert tally["accepted"] and tally["config_errors"]


def _check_cli(path: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "usb2rc", "check", "--config", str(path)],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=ROOT,
    )


def run_cli(n: int, seed: int, tmp_path: Path) -> dict[str, int]:
    rng = random.Random(seed)
    seeds = list(GOOD_CONFIGS.values())
    tally = {"check_runs": 0, "exit_0": 0, "exit_2": 0}
    for i in range(n):
        while True:
            text = _mutate_text(rng.choice(seeds), rng)
            probe: dict[str, int] = {"accepted": 0, "config_errors": 0}
            _classify(text, probe)
            break
        path = tmp_path / f"c{i}.yaml"
        path.write_text(text)
        proc = _check_cli(path)
        tally["check_runs"] += 1
        assert proc.returncode in (0, 2), proc.stderr
        assert "Traceback" not in proc.stderr
        if proc.returncode == 2:
            assert any(ERROR_LINE.match(ln) for ln in proc.stderr.splitlines()), proc.stderr
        tally[f"exit_{proc.returncode}"] += 1
    return tally


# --- the slow suite -------------------------------------------------------------------------


@pytest.mark.slow
def test_inputs_long(request, tmp_path):
    seed = env_int("USB2RC_FUZZ_SEED", 20240601)
    t0 = time.monotonic()
    data = {
        "reports": run_reports(env_int("USB2RC_FUZZ_REPORTS", 200_000), seed),
        "recordings": run_recordings(env_int("USB2RC_FUZZ_RECORDINGS", 20_000), seed),
        "configs": run_configs(env_int("USB2RC_FUZZ_CONFIGS", 20_000), seed),
        "cli": run_cli(env_int("USB2RC_FUZZ_CLI_CONFIGS", 40), seed, tmp_path),
        "seconds": round(time.monotonic() - t0, 1),
    }
    figures(request, "fuzz-inputs", data)


# --- config.py bugs the fuzzing found (fixed) ----------------------------


def test_config_with_a_control_character_is_a_config_error():
    with pytest.raises(ConfigError):
        load_config_text("devices:\n  - name: a\x01b\n", "c.yaml")


def test_config_file_not_utf8_is_a_config_error(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_bytes(b"devices:\n  - name: a\xff\xfeb\n")
    with pytest.raises(ConfigError):
        load_config(str(path))


@pytest.mark.parametrize("value", ["!!int abc", "!!float abc", "!!timestamp abc"])
def test_config_explicit_tag_with_bad_value_is_a_config_error(value):
    with pytest.raises(ConfigError):
        load_config_text(f"outputs:\n  - protocol: c2-16b\n    baudrate: {value}\n", "c.yaml")


def test_config_nested_too_deep_is_a_config_error():
    with pytest.raises(ConfigError):
        load_config_text("devices: " + "[" * 3000 + "]" * 3000, "c.yaml")


def test_check_cli_on_a_control_character_exits_2(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("devices:\n  - name: a\x01b\n")
    proc = _check_cli(path)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
