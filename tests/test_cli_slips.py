"""Usage slips exit 2 with a message that says what to type instead; decode says when it
found nothing. Each through the real command line (`python -m usb2rc`)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from cli_harness import usb2rc

from usb2rc.cli import COMMANDS, command_of
from usb2rc.config.port_url import url_problem

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


@pytest.mark.parametrize(
    ("argv", "command"),
    [
        ([], "run"),
        (["--config", "x.yaml"], "run"),
        (["check", "--config", "x.yaml"], "check"),
        (["run", "-h"], "run"),
        (["-h"], None),
        (["--version"], None),
        (["chek"], None),
    ],
)
def test_a_command_line_names_the_one_command_it_needs(
    argv: list[str], command: str | None
) -> None:
    assert command_of(argv) == command


def test_a_command_imports_its_own_module_and_not_the_others() -> None:
    """`usb2rc run` must not wait for `monitor`'s or `web`'s imports before its first frame;
    `usb2rc --help` lists them all."""
    probe = (
        "import sys; from usb2rc import cli; import contextlib, io\n"
        "with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):\n"
        "    cli.main(sys.argv[1:])\n"
        "print(sorted(m for m in sys.modules if m.startswith('usb2rc.commands.')))"
    )

    def imported(*argv: str) -> set[str]:
        result = subprocess.run(
            [sys.executable, "-c", probe, *argv], capture_output=True, text=True, check=True
        )
        return set(json.loads(result.stdout.strip().replace("'", '"')))

    alone = imported("icd", "--help")
    assert "usb2rc.commands.icd" in alone
    assert not alone & {"usb2rc.commands.monitor", "usb2rc.commands.web"}
    assert {f"usb2rc.commands.{module}" for module in COMMANDS.values()} <= imported("--help")


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


def test_help_texts_name_the_five_protocols() -> None:
    texts = {
        "usb2rc --help": usb2rc("--help").stdout,
        "usb2rc run --help": usb2rc("run", "--help").stdout,
        "usb2rc icd --help": usb2rc("icd", "--help").stdout,
        "pyproject description": next(
            line
            for line in (ROOT / "pyproject.toml").read_text().splitlines()
            if line.startswith("description")
        ),
        "daemon.py docstring": (ROOT / "usb2rc" / "daemon.py").read_text().split('"""')[1],
        "unit header": (ROOT / "usb2rc" / "data" / "system" / "usb2rc.service")
        .read_text()
        .splitlines()[0],
    }
    for where, text in texts.items():
        flat = " ".join(text.split())  # argparse wraps help text
        for protocol in ("C2-16B", "SUMD", "CRSF", "SBUS", "MAVLink"):
            assert protocol in flat, (where, protocol)


# --- misspelt options ----------------------------------------------------------------------


@pytest.mark.parametrize(
    ("argv", "hint"),
    [
        (["--prot", "/dev/ttyUSB0"], "unrecognized arguments: --prot (did you mean --port?)"),
        (["run", "--confg", "x.yaml"], "--confg (did you mean --config?)"),
        (["check", "--jsn"], "--jsn (did you mean --json?)"),
        (["list", "--replay=demo", "--alll"], "--alll (did you mean --all?)"),
    ],
)
def test_a_misspelt_option_gets_a_suggestion(argv: list[str], hint: str) -> None:
    result = usb2rc(*argv)
    assert result.returncode == 2
    assert hint in result.stderr


# --- config problems that are really another kind of file or many of one ------------------


def test_a_recording_given_as_config_is_named_as_such() -> None:
    recording = str(DEMO / "stick.hid")
    for command in ("check", "run"):
        result = usb2rc(command, "--config", recording)
        assert result.returncode == 2, (command, result.stderr)
        assert "this is a hid-recorder file" in result.stderr
        assert "--replay DIR" in result.stderr
        assert "unknown key" not in result.stderr


def test_the_same_problem_on_17_lines_is_shown_once_with_its_count(tmp_path: Path) -> None:
    config = tmp_path / "many.yaml"
    entries = "".join("  - {match: {vid: 1}, node_id: 300}\n" for _ in range(17))
    config.write_text("devices:\n" + entries)
    result = usb2rc("check", "--config", str(config))
    assert result.returncode == 2
    lines = result.stderr.splitlines()
    assert lines[0] == (
        f"{config}:2: devices[*].node_id: 300 is out of range (allowed: 0..254) "
        "(17 times: lines 2, 3, 4, 5, 6 and 12 more)"
    )
    assert lines[1:] == ["17 error(s)"]


def test_a_file_that_is_one_list_names_the_top_level(tmp_path: Path) -> None:
    config = tmp_path / "list.yaml"
    config.write_text("- outputs\n- devices\n")
    result = usb2rc("check", "--config", str(config))
    assert result.returncode == 2
    assert f"{config}:1: (top level): expected a mapping, got a list" in result.stderr


# --- shipped files by name, from any folder ------------------------------------------------


def usb2rc_in(folder: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return usb2rc(*args, cwd=folder)


def test_replay_demo_is_the_built_in_recordings_from_any_folder(tmp_path: Path) -> None:
    result = usb2rc_in(tmp_path, "list", "--replay", "demo", "--json")
    assert result.returncode == 0, result.stderr
    products = {device["product"] for device in json.loads(result.stdout)["devices"]}
    assert products == {"Thrustmaster T.16000M", "Thrustmaster TWCS Throttle"}
    assert result.stderr == ""


def test_a_demo_folder_here_wins_and_says_so(tmp_path: Path) -> None:
    (tmp_path / "demo").mkdir()  # empty: no devices
    result = usb2rc_in(tmp_path, "list", "--replay", "demo", "--json")
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout)["devices"] == []
    assert "--replay demo: the folder ./demo here, not the built-in recordings" in result.stderr


def test_example_copies_a_shipped_file_and_lists_them(tmp_path: Path) -> None:
    shipped = ROOT / "usb2rc" / "data" / "config" / "hotas.yaml"
    for name in ("hotas", "hotas.yaml"):
        assert usb2rc_in(tmp_path, "example", name).stdout == shipped.read_text()
    sample = subprocess.run(
        [sys.executable, "-m", "usb2rc", "example", "c2-16b-sample"],
        capture_output=True,
        cwd=tmp_path,
        timeout=60,
        check=True,
    )
    assert (
        sample.stdout == (ROOT / "usb2rc" / "data" / "samples" / "c2-16b-sample.bin").read_bytes()
    )
    listing = usb2rc_in(tmp_path, "example").stdout
    assert "hotas.yaml" in listing and "stick.hid" in listing and "--replay demo" in listing
    missing = usb2rc_in(tmp_path, "example", "hotass")
    assert missing.returncode == 2 and "no example 'hotass'; there are: hotas" in missing.stderr


def test_list_without_devices_hints_at_the_built_in_recordings() -> None:
    from usb2rc.commands.list_devices import no_devices_hint

    hint = no_devices_hint(None)
    assert "usb2rc list --replay demo" in hint and "usb2rc/data" not in hint


# --- what usb2rc says it does ----------------------------------------------------------------


def test_help_and_the_package_description_name_every_output_protocol() -> None:
    import tomllib

    from usb2rc.outputs import PROTOCOLS

    result = usb2rc("--help")
    assert result.returncode == 0, result.stderr
    helped = " ".join(result.stdout.split()).lower()  # argparse wraps the description
    described = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["description"]
    for protocol in PROTOCOLS.values():
        assert protocol.title.lower() in helped, (protocol.title, result.stdout)
        assert protocol.title.lower() in described.lower(), (protocol.title, described)
