"""Usage slips exit 2 with a message that says what to type instead; decode says when it
found nothing. Each through the real command line (`python -m usb2rc`)."""

from __future__ import annotations

from pathlib import Path

import pytest
from cli_harness import usb2rc

from usb2rc.cli import COMMANDS
from usb2rc.port_url import url_problem

ROOT = Path(__file__).resolve().parent.parent
SAMPLES = ROOT / "usb2rc" / "data" / "samples"
DEMO = ROOT / "usb2rc" / "data" / "demo"


# --- port names pyserial cannot parse: usage errors, not a missing cable --------------------


@pytest.mark.parametrize(
    ("url", "reason"),
    [
        ("foo://bar", "protocol 'foo' not known"),
        ("socket://host", "expected host:port"),
        ("rfc2217://host", "expected host:port"),
        ("socket://host:1?nosuch", "unknown option"),
    ],
)
def test_url_problem_names_what_is_wrong(url: str, reason: str) -> None:
    problem = url_problem(url)
    assert problem is not None and reason in problem


@pytest.mark.parametrize(
    "port",
    [
        "/dev/ttyUSB9",  # absent now: a missing cable, retried by the daemon
        "COM3",
        "loop://",
        "socket://localhost:5760",
        "spy:///dev/ttyUSB0?file=/nonexistent/dir/log.txt",  # nothing opened while checking
        "hwgrep://no-such-adapter",  # no search while checking
    ],
)
def test_url_problem_accepts_what_pyserial_can_parse(port: str) -> None:
    assert url_problem(port) is None


def test_run_with_an_unknown_url_scheme_exits_2() -> None:
    result = usb2rc("run", "--replay", str(DEMO), "--port", "foo://bar")
    assert result.returncode == 2
    assert "--port: 'foo://bar' is not a port pyserial can open" in result.stderr
    assert "protocol 'foo' not known" in result.stderr


def test_a_config_port_pyserial_cannot_parse_is_a_config_error(tmp_path: Path) -> None:
    config = tmp_path / "bad.yaml"
    config.write_text("outputs:\n  - protocol: c2-16b\n    port: foo://bar\n")
    expected = f"{config}:3: outputs[0].port: 'foo://bar' is not a port pyserial can open"
    for command in ("check", "run"):
        result = usb2rc(command, "--config", str(config), "--replay", str(DEMO))
        assert result.returncode == 2, (command, result.stderr)
        assert result.stderr.startswith(expected), (command, result.stderr)


def test_init_with_an_unknown_url_scheme_exits_2(tmp_path: Path) -> None:
    result = usb2rc("init", "--replay", str(DEMO), "--port", "foo://bar", "-o", str(tmp_path / "x"))
    assert result.returncode == 2 and "--port: 'foo://bar' is not a port" in result.stderr
    assert not (tmp_path / "x").exists()


def test_decode_with_an_unknown_url_scheme_exits_2() -> None:
    result = usb2rc("decode", "foo://bar")
    assert result.returncode == 2
    assert "protocol 'foo' not known" in result.stderr


# --- --replay with a directory that is not there -----------------------------------------


@pytest.mark.parametrize(
    "command",
    [
        ["run", "--port", "loop://"],
        ["monitor", "--seconds", "1", "--plain"],
        ["list"],
        ["init"],
        ["check"],
        ["icd"],
        ["record", "044f:b10a"],
    ],
)
def test_replay_of_a_missing_directory_exits_2(command: list[str], tmp_path: Path) -> None:
    missing = tmp_path / "no-such-dir"
    result = usb2rc(*command, "--replay", str(missing))
    assert result.returncode == 2, result.stdout
    assert f"--replay: {missing}: no such directory" in result.stderr


def test_replay_of_a_file_exits_2() -> None:
    result = usb2rc("list", "--replay", str(DEMO / "throttle.hid"))
    assert result.returncode == 2
    assert "throttle.hid: not a directory" in result.stderr


# --- unknown subcommands ------------------------------------------------------------------


def test_unknown_command_lists_the_valid_ones() -> None:
    result = usb2rc("frobnicate")
    assert result.returncode == 2
    assert "unknown command 'frobnicate'" in result.stderr
    for name in COMMANDS:
        assert name in result.stderr


def test_a_misspelt_command_gets_a_suggestion() -> None:
    result = usb2rc("chek", "--config", "x.yaml")
    assert result.returncode == 2
    assert "did you mean 'check'?" in result.stderr


def test_options_alone_still_mean_run() -> None:
    result = usb2rc("--replay", str(DEMO), "--port", "foo://bar")
    assert result.returncode == 2 and "usb2rc run: error: argument --port" in result.stderr


# --- decode that finds nothing ----------------------------------------------------------


@pytest.mark.parametrize(
    ("protocol", "sample", "hint"),
    [
        ("c2-16b", "sumd-sample.bin", "110 SUMD frame(s): try `usb2rc decode --protocol sumd "),
        ("sumd", "c2-16b-sample.bin", "C2-16B frame(s): try `usb2rc decode --protocol c2-16b "),
    ],
)
def test_decode_without_frames_suggests_the_other_protocol(
    protocol: str, sample: str, hint: str
) -> None:
    result = usb2rc("decode", "--protocol", protocol, str(SAMPLES / sample))
    assert result.returncode == 1
    assert result.stdout == ""
    assert f"no {'SUMD' if protocol == 'sumd' else 'C2-16B'} frame found" in result.stderr
    assert hint in result.stderr


def test_decode_of_noise_says_no_frame_of_either(tmp_path: Path) -> None:
    noise = tmp_path / "noise.bin"
    noise.write_bytes(bytes(range(256)) * 4)
    result = usb2rc("decode", str(noise))
    assert result.returncode == 1
    assert "no C2-16B frame found" in result.stderr and "nor a frame" in result.stderr


# --- help -------------------------------------------------------------------------------


def test_run_help_has_a_description() -> None:
    result = usb2rc("run", "--help")
    assert result.returncode == 0
    body = result.stdout.split("\n\n")[1]  # after the usage block
    assert "Run the daemon" in body and "Exit 0" in body
