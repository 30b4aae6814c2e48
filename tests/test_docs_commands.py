"""Every `usb2rc ...` command shown in README.md and docs/*.md code blocks is exercised.

Each command line found in a fenced code block must parse with usb2rc's own parser (with the
default-command rule of `usb2rc.cli.main`). The ones that can run here, offline, run from an
empty folder (as a user with the package installed from a wheel would: no clone, so no
`usb2rc/data/...` paths) and must exit 0; a command the docs redirect to a file
(`usb2rc example hotas > hotas.yaml`) writes that file there first. The ones that need root
run against a scratch root (ROOTED); the rest (hardware, placeholders, endless) are listed as
parse-only with the reason. A command in the docs that is in no list fails the test, and so
does a listed command the docs no longer show: the lists and the docs move together.
tests/test_wheel_journey.py runs the same lists with a built wheel in a fresh venv.
"""

from __future__ import annotations

import argparse
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from usb2rc import cli

ROOT = Path(__file__).resolve().parent.parent
# The service notes ship in the package (usb2rc install-system writes them beside the unit).
SERVICE_NOTES = ROOT / "usb2rc" / "data" / "system" / "SERVICE.md"
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")), SERVICE_NOTES]

# Run offline from an empty folder; each must exit 0. The ones the docs redirect to a file
# run first, one by one (the others read those files).
RUN = {
    "usb2rc example hotas",
    "usb2rc example hotas-demo",
    "usb2rc check --config hotas-demo.yaml --replay demo",
    "usb2rc example throttle",
    "usb2rc example c2-16b-sample",
    "usb2rc example sumd-sample",
    "usb2rc init --replay demo",
    "usb2rc decode c2-16b-sample.bin",
    "usb2rc decode --protocol sumd sumd-sample.bin",
    "usb2rc icd --config hotas.yaml",
    "usb2rc check --config hotas.yaml",
    "usb2rc check --config hotas.yaml --replay demo",
    "usb2rc describe throttle.hid",
    "usb2rc list --replay demo",
    "usb2rc demo --seconds 2",
    "usb2rc monitor --replay demo --seconds 2 --plain",
    "usb2rc install-system --print 70-usb2rc.rules",
    "usb2rc check --config hotas.yaml --json",
    "usb2rc icd --config hotas.yaml --json",
    "usb2rc check --config hotas.yaml --port /dev/ttyUSB1",
}

# Shown with sudo, they write or read the system's files: here they run in this order
# against a scratch root (install-system gets --root, and each absolute /etc or /usr path
# moves under it), and must exit 0.
ROOTED = [
    "usb2rc install-system",
    "usb2rc install-system --web",
    "usb2rc check --config /etc/usb2rc/usb2rc.yaml",
]

HARDWARE = "needs a real joystick or serial port"
PLACEHOLDER = "names the reader's own file"
PARSE_ONLY = {
    "usb2rc web": "serves until stopped (tests/test_web_cli.py and test_web_browser.py run it)",
    "usb2rc demo --seconds 30": "30 s is too slow here; `demo --seconds 2` runs",
    "usb2rc --port /dev/ttyUSB0": HARDWARE,
    "usb2rc --config hotas.yaml": HARDWARE + " (/dev/serial0, /dev/ttyUSB0)",
    "usb2rc run --replay DIR --port PORT": PLACEHOLDER,
    "usb2rc decode /dev/ttyUSB1": HARDWARE,
    "usb2rc decode --json /dev/ttyUSB1": HARDWARE,
    "usb2rc decode --protocol sumd /dev/ttyUSB1": HARDWARE,
    "usb2rc decode --protocol mavlink udpin:127.0.0.1:14550": "listens until Ctrl-C "
    "(tests/test_mavlink_cli.py runs it)",
    "usb2rc list": HARDWARE,
    "usb2rc list --config hotas.yaml --json": PLACEHOLDER,
    "usb2rc describe rec.hid": PLACEHOLDER,
    "usb2rc describe stick.hid": PLACEHOLDER,
    "usb2rc check --config my.yaml": PLACEHOLDER,
    "usb2rc icd --config my.yaml": PLACEHOLDER,
    "usb2rc monitor": HARDWARE + "; runs until Ctrl-C",
    "usb2rc monitor --config my.yaml": PLACEHOLDER,
    "usb2rc monitor --config hotas.yaml": PLACEHOLDER,
    "usb2rc monitor --replay recordings/ --replay-loop": PLACEHOLDER + "; runs until Ctrl-C",
    "usb2rc record 044f:b10a --seconds 10": HARDWARE,
    "usb2rc --config hotas.yaml --port /dev/ttyUSB1": HARDWARE,
    "usb2rc init --port /dev/serial0 -o my.yaml": HARDWARE,
    "usb2rc calibrate --config my.yaml": HARDWARE + "; interactive (tests/test_calibrate_tmux.py)",
    "usb2rc calibrate --config demo.yaml --replay demo --replay-loop": (
        "interactive; tests/test_calibrate_tmux.py drives it in tmux"
    ),
    "usb2rc --config my.yaml": PLACEHOLDER,
    "usb2rc --config hotas.yaml --port /dev/ttyUSB1 --stats-interval 10": HARDWARE,
    "usb2rc --config hotas.yaml --stats-interval 10 --stats-format json": PLACEHOLDER
    + "; runs until stopped",
    "usb2rc --config hotas.yaml --port /dev/cu.usbserial-A10K1B2C": HARDWARE + " (macOS)",
    "usb2rc --config hotas.yaml --port COM3": HARDWARE + " (Windows)",
    "usb2rc --config hotas.yaml --port 'spy:///dev/ttyUSB1?file=/tmp/usb2rc-spy.txt'": HARDWARE,
}

FENCE = re.compile(r"^\s*(```|~~~)")
SEPARATORS = {"|", "||", "&&", ";", "&"}
REDIRECTS = re.compile(r"^\d*[<>]")


def code_lines(path: Path) -> list[tuple[int, str]]:
    lines, inside = [], False
    for number, line in enumerate(path.read_text().splitlines(), 1):
        if FENCE.match(line):
            inside = not inside
        elif inside:
            lines.append((number, line.strip().removeprefix("$ ")))
    return lines


def is_usb2rc(word: str) -> bool:
    return re.split(r"[/\\]", word)[-1] == "usb2rc"


def commands_in(line: str) -> list[list[str]]:
    """The argument lists of the usb2rc commands on one shell line (comments, pipes,
    redirections, `sudo` and VAR=value prefixes taken off)."""
    return [args for args, _ in shell_commands(line)]


def shell_commands(line: str) -> list[tuple[list[str], str | None]]:
    """Each usb2rc command on one shell line: its arguments, and the file its stdout is
    redirected to (`> FILE`), if any."""
    lexer = shlex.shlex(line, posix=True, punctuation_chars=True)
    lexer.whitespace_split = True
    tokens = list(lexer)
    found, segment = [], []
    for token in [*tokens, ";"]:
        if token not in SEPARATORS:
            segment.append(token)
            continue
        words = segment
        segment = []
        while words and (words[0] == "sudo" or re.match(r"^\w+=", words[0])):
            words = words[1:]
            while words and words[0].startswith("-"):  # sudo's options (-u USER)
                words = words[2:] if words[0] in ("-u", "-g") else words[1:]
        if not words or not is_usb2rc(words[0]):
            continue
        args: list[str] = []
        rest = words[1:]
        while rest and not REDIRECTS.match(rest[0]):
            args.append(rest.pop(0))
        target = rest[1] if rest[:1] == [">"] and len(rest) > 1 else None
        found.append((args, target))
    return found


def documented() -> dict[str, list[str]]:
    """'usb2rc ARGS' -> where it is shown (file:line)."""
    seen: dict[str, list[str]] = {}
    for path in DOCS:
        for number, line in code_lines(path):
            for args in commands_in(line):
                key = shlex.join(["usb2rc", *args])
                seen.setdefault(key, []).append(f"{path.relative_to(ROOT)}:{number}")
    return seen


def stdout_files() -> dict[str, str]:
    """'usb2rc ARGS' -> the file the docs write its output to (`> FILE`)."""
    targets: dict[str, str] = {}
    for path in DOCS:
        for _, line in code_lines(path):
            for args, target in shell_commands(line):
                if target is not None:
                    targets[shlex.join(["usb2rc", *args])] = target
    return targets


# Folders the docs name as placeholders: --replay wants a directory that exists.
PLACEHOLDER_DIRS = {"DIR", "recordings/"}


def parse(command: str, scratch: Path | None = None) -> argparse.Namespace:
    argv = shlex.split(command)[1:]
    if scratch is not None:
        argv = [str(scratch) if word in PLACEHOLDER_DIRS else word for word in argv]
    parser = cli.build_parser()
    subparsers = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    argv = cli._with_default_command(argv, set(subparsers.choices))
    try:
        return parser.parse_args(argv)
    except SystemExit as exc:
        raise AssertionError(f"{command!r} does not parse (exit {exc.code})") from None


def test_extraction_rules():
    assert commands_in(".venv/bin/pip install -e . && .venv/bin/usb2rc demo --seconds 30") == [
        ["demo", "--seconds", "30"]
    ]
    assert commands_in("usb2rc record 044f:b10a --seconds 10 > stick.hid  # note") == [
        ["record", "044f:b10a", "--seconds", "10"]
    ]
    assert commands_in("sudo -u usb2rc /opt/usb2rc/venv/bin/usb2rc list") == [["list"]]
    assert shell_commands("usb2rc example hotas > hotas.yaml  # a config") == [
        (["example", "hotas"], "hotas.yaml")
    ]
    assert commands_in("journalctl -u usb2rc -f") == []
    assert commands_in("sudo systemctl kill -s USR1 usb2rc") == []
    assert commands_in("sudo install -m 0644 systemd/usb2rc.service /etc/systemd/system/") == []


def test_every_documented_command_is_classified():
    seen = documented()
    assert seen, "no usb2rc command found in the docs"
    classified = [*RUN, *PARSE_ONLY, *ROOTED]
    assert len(classified) == len(set(classified)), "a command in two lists"
    unclassified = {cmd: where for cmd, where in seen.items() if cmd not in classified}
    assert not unclassified, f"add these to RUN, ROOTED or PARSE_ONLY: {unclassified}"
    stale = set(classified) - set(seen)
    assert not stale, f"no longer in the docs: {sorted(stale)}"


@pytest.mark.parametrize("command", sorted(RUN | set(PARSE_ONLY) | set(ROOTED)))
def test_documented_command_parses(command, tmp_path):
    args = parse(command, tmp_path)
    assert getattr(args, "func", None), command


def run_offline_commands(usb2rc: list[str], folder: Path) -> list[str]:
    """Run RUN in `folder` with `usb2rc` (the program as an argv prefix): first the commands
    whose output the docs keep in a file, writing that file, then the others side by side.
    Returns what failed."""
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    targets = stdout_files()
    writers = sorted(command for command in RUN if command in targets)
    readers = sorted(command for command in RUN if command not in targets)
    failures = []
    for command in writers:
        with open(folder / targets[command], "wb") as out:
            proc = subprocess.Popen(
                [*usb2rc, *shlex.split(command)[1:]],
                cwd=folder,
                env=env,
                stdin=subprocess.DEVNULL,
                stdout=out,
                stderr=subprocess.PIPE,
            )
            failures += _outcome(command, proc, folder / targets[command])
    procs = {
        command: subprocess.Popen(
            [*usb2rc, *shlex.split(command)[1:]],
            cwd=folder,
            env=env,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
        )
        for command in readers
    }
    for command, proc in procs.items():
        failures += _outcome(command, proc, None)
    return failures


def _outcome(command: str, proc: subprocess.Popen[bytes], written: Path | None) -> list[str]:
    try:
        out, err = proc.communicate(timeout=120)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
    if proc.returncode != 0:
        return [f"{command}: exit {proc.returncode}\n{err.decode()[-2000:]}"]
    printed = written.read_bytes() if written is not None else out
    return [] if printed.strip() else [f"{command}: printed nothing"]


def test_offline_commands_run_from_an_empty_folder_and_exit_0(tmp_path: Path) -> None:
    failures = run_offline_commands([sys.executable, "-m", "usb2rc"], tmp_path)
    assert not failures, "\n\n".join(failures)


def test_the_docs_name_no_file_of_a_clone() -> None:
    # usb2rc/data/... exists only in a clone: the docs name shipped files by
    # `usb2rc example NAME` and `--replay demo` (they work from a wheel, from any folder)
    clone_paths = [cmd for cmd in documented() if "usb2rc/data" in cmd]
    assert not clone_paths


def rooted(command: str, root: Path) -> list[str]:
    """The command's arguments with system paths under root (and --root for install-system)."""
    args = [
        str(root) + word if word.startswith(("/etc/", "/usr/")) else word
        for word in shlex.split(command)[1:]
    ]
    return [*args, "--root", str(root)] if args[:1] == ["install-system"] else args


def run_root_commands(usb2rc: list[str], root: Path, folder: Path) -> list[str]:
    """Run ROOTED in order from `folder` against the scratch `root`; returns what failed."""
    failures = []
    for command in ROOTED:
        if command.startswith("usb2rc check"):  # PI.md's step between: "set the port"
            installed = root / "etc" / "usb2rc" / "usb2rc.yaml"
            installed.write_text(installed.read_text().replace("# port:", "port:", 1))
        result = subprocess.run(
            [*usb2rc, *rooted(command, root)],
            cwd=folder,
            stdin=subprocess.DEVNULL,
            capture_output=True,
            text=True,
            timeout=120,
            check=False,
        )
        if result.returncode != 0:
            failures.append(f"{command}: exit {result.returncode}\n{result.stderr}")
    return failures


def test_root_commands_run_against_a_scratch_root(tmp_path: Path) -> None:
    (tmp_path / "cwd").mkdir()
    failures = run_root_commands([sys.executable, "-m", "usb2rc"], tmp_path, tmp_path / "cwd")
    assert not failures, "\n\n".join(failures)
    assert (tmp_path / "etc" / "usb2rc" / "usb2rc.yaml").is_file()


def test_laptop_creates_the_group_the_udev_rule_names():
    # udev skips GROUP= for a group that does not exist: the laptop steps must create it
    rules = (ROOT / "usb2rc" / "data" / "system" / "70-usb2rc.rules").read_text()
    named = set(re.findall(r'GROUP="([^"]+)"', rules))
    laptop = (ROOT / "docs" / "LAPTOP.md").read_text()
    created = set(re.findall(r"groupadd --system (\S+)", laptop))
    assert named and named == created


def test_install_docs_name_every_installed_path():
    from usb2rc.commands.install_system import FILES

    for doc in (ROOT / "docs" / "PI.md", SERVICE_NOTES):
        text = doc.read_text()
        missing = [f.target for f in FILES if f.target not in text]
        assert not missing, f"{doc.name} does not say where these go: {missing}"
