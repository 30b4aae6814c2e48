"""The shipped systemd unit, udev rules and sysusers file.

The same checks as .ci/systemd-checks.sh (systemd-analyze verify / security, systemd-sysusers),
plus: the unit carries the directives the daemon depends on, the udev rules parse, and the
rules' joystick classifier (a shell pipeline over the HID report descriptor) picks the right
descriptors when run the way udev runs it.
"""

from __future__ import annotations

import ctypes
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SYSTEM = ROOT / "usb2rc" / "data" / "system"  # package data (usb2rc install-system)
UNIT = SYSTEM / "usb2rc.service"
RULES = SYSTEM / "70-usb2rc.rules"
SYSUSERS = SYSTEM / "usb2rc.sysusers"
CI_SCRIPT = ROOT / ".ci" / "systemd-checks.sh"
MAX_EXPOSURE = 1.2  # 1.0, and 0.2 for real-time priority (RestrictRealtime=no, sched_setscheduler)
SHIPPED_EXEC_START = "/opt/usb2rc/venv/bin/usb2rc run --config /etc/usb2rc/usb2rc.yaml"

needs_analyze = pytest.mark.skipif(
    shutil.which("systemd-analyze") is None,
    reason="systemd-analyze not installed (apt-get install systemd; see .ci/systemd-checks.sh)",
)


def directives(text: str) -> dict[tuple[str, str], list[str]]:
    """(section, key) -> values in order; repeated keys (DeviceAllow=) keep every value."""
    out: dict[tuple[str, str], list[str]] = {}
    section = ""
    for raw in text.splitlines():
        line = raw.strip()
        if not line or line.startswith(("#", ";")):
            continue
        if line.startswith("["):
            section = line.strip("[]")
            continue
        key, sep, value = line.partition("=")
        assert sep, f"not a key=value line: {raw!r}"
        out.setdefault((section, key.strip()), []).append(value.strip())
    return out


UNIT_DIRECTIVES = directives(UNIT.read_text())


def service(key: str) -> list[str]:
    return UNIT_DIRECTIVES.get(("Service", key), [])


# ---- the unit's directives ------------------------------------------------------------------


@pytest.mark.parametrize(
    ("key", "value"),
    [
        ("Type", "notify"),
        ("NotifyAccess", "main"),
        ("ExecStart", SHIPPED_EXEC_START),
        ("ExecReload", "/bin/kill -HUP $MAINPID"),
        ("WatchdogSec", "2"),
        ("Restart", "on-failure"),
        ("RestartSec", "1"),
        ("RestartPreventExitStatus", "2"),  # usage / config error: no restart loop
        ("User", "usb2rc"),
        ("Group", "usb2rc"),
        ("SupplementaryGroups", "dialout"),
        ("DynamicUser", "no"),
        ("NoNewPrivileges", "yes"),
        ("ProtectSystem", "strict"),
        ("ProtectHome", "yes"),
        ("PrivateTmp", "yes"),
        ("RestrictAddressFamilies", "AF_UNIX AF_NETLINK"),
        ("IPAddressDeny", "any"),
        ("SystemCallArchitectures", "native"),
        ("DevicePolicy", "closed"),
        ("ProtectKernelTunables", "yes"),
        ("ProtectKernelModules", "yes"),
        ("ProtectKernelLogs", "yes"),
        ("ProtectClock", "yes"),
        ("ProtectHostname", "yes"),
        ("ProtectControlGroups", "yes"),
        ("ProtectProc", "invisible"),
        ("ProcSubset", "pid"),
        ("LockPersonality", "yes"),
        ("MemoryDenyWriteExecute", "yes"),
        ("RestrictNamespaces", "yes"),
        ("RestrictRealtime", "no"),  # usb2rc/runtime/realtime.py, bounded by:
        ("LimitRTPRIO", "10"),
        ("RestrictSUIDSGID", "yes"),
        ("RemoveIPC", "yes"),
        ("CapabilityBoundingSet", ""),
        ("AmbientCapabilities", ""),
        ("UMask", "0077"),
        ("ConfigurationDirectory", "usb2rc"),
        ("StandardOutput", "journal"),
    ],
)
def test_unit_sets(key: str, value: str) -> None:
    assert service(key) == [value]


def test_unit_system_call_filter() -> None:
    assert service("SystemCallFilter")[0] == "@system-service"


def test_unit_device_allow_list() -> None:
    allowed = dict(entry.split() for entry in service("DeviceAllow"))
    assert allowed == {
        "char-hidraw": "rw",
        "char-ttyS": "rw",  # Pi mini UART (/dev/serial0 on models with Bluetooth)
        "char-ttyAMA": "rw",  # Pi PL011 UART
        "char-ttyUSB": "rw",
        "char-ttyACM": "rw",
        # the X52 Pro's MFD through pyusb; the udev rule grants only such devices' nodes
        "char-usb_device": "rw",
    }


def test_unit_keeps_udev_events_reachable() -> None:
    # A private network namespace cuts the service off from udev's netlink events (hot-plug),
    # and a private user namespace cannot map the supplementary group dialout.
    assert service("PrivateNetwork") in ([], ["no"])
    assert service("PrivateUsers") in ([], ["no"])
    assert "AF_NETLINK" in service("RestrictAddressFamilies")[0].split()


def test_unit_user_is_not_root() -> None:
    assert service("User") and service("User")[0] not in ("root", "0")


def test_unit_documentation_is_the_file_install_system_writes() -> None:
    from usb2rc.commands.install_system import BY_NAME

    (documentation,) = UNIT_DIRECTIVES[("Unit", "Documentation")]
    assert documentation == "file:" + BY_NAME["SERVICE.md"].target
    assert (SYSTEM / "SERVICE.md").is_file()


def test_unit_is_enabled_for_boot() -> None:
    assert UNIT_DIRECTIVES[("Install", "WantedBy")] == ["multi-user.target"]


# ---- systemd-analyze ------------------------------------------------------------------------


def verifiable_copy(tmp_path: Path) -> Path:
    """The unit with ExecStart pointing at /bin/true: verify insists the binary exists."""
    text = UNIT.read_text()
    copy = text.replace(
        f"ExecStart={SHIPPED_EXEC_START}",
        "ExecStart=/bin/true run --config /etc/usb2rc/usb2rc.yaml",
    )
    changed = [(a, b) for a, b in zip(text.splitlines(), copy.splitlines(), strict=True) if a != b]
    assert len(changed) == 1, "only the ExecStart path may differ from the shipped unit"
    path = tmp_path / "usb2rc.service"
    path.write_text(copy)
    return path


@needs_analyze
def test_systemd_analyze_verify_is_clean(tmp_path: Path) -> None:
    result = subprocess.run(
        ["systemd-analyze", "verify", str(verifiable_copy(tmp_path))],
        capture_output=True,
        text=True,
        check=False,
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout + result.stderr == ""


def exposure(unit: Path) -> float:
    result = subprocess.run(
        ["systemd-analyze", "security", "--offline=true", "--no-pager", str(unit)],
        capture_output=True,
        text=True,
        check=False,
    )
    match = re.search(r"Overall exposure level for \S+: (\d+(?:\.\d+)?)", result.stdout)
    assert match, result.stdout + result.stderr
    return float(match.group(1))


@needs_analyze
def test_systemd_analyze_security_exposure() -> None:
    assert exposure(UNIT) <= MAX_EXPOSURE


@needs_analyze
def test_security_check_notices_a_weaker_unit(tmp_path: Path) -> None:
    # The parser and the threshold can fail: drop the sandbox and the exposure must rise.
    weaker = tmp_path / "usb2rc.service"
    keep = ("Type=", "ExecStart=", "User=", "Group=", "[")
    weaker.write_text(
        "\n".join(line for line in UNIT.read_text().splitlines() if line.startswith(keep))
    )
    assert exposure(weaker) > MAX_EXPOSURE


@pytest.mark.skipif(shutil.which("systemd-sysusers") is None, reason="systemd-sysusers missing")
def test_sysusers_creates_the_service_user(tmp_path: Path) -> None:
    (tmp_path / "etc").mkdir()
    subprocess.run(
        ["systemd-sysusers", f"--root={tmp_path}", "-"],
        input=SYSUSERS.read_text(),
        capture_output=True,
        text=True,
        check=True,
    )
    passwd = (tmp_path / "etc" / "passwd").read_text()
    (entry,) = [line for line in passwd.splitlines() if line.startswith("usb2rc:")]
    _name, _pw, uid, gid, _gecos, _home, shell = entry.split(":")
    assert 0 < int(uid) < 1000 and 0 < int(gid) < 1000  # a system user
    assert shell == "/usr/sbin/nologin"


@needs_analyze  # with systemd-analyze present the script installs nothing
def test_ci_script_passes() -> None:
    result = subprocess.run(["sh", str(CI_SCRIPT)], capture_output=True, text=True, check=False)
    assert result.returncode == 0, result.stdout + result.stderr
    assert f"exposure {exposure(UNIT)}" in result.stdout


# ---- MemoryDenyWriteExecute= with this Python --------------------------------------------


def test_python_stack_runs_without_writable_executable_memory() -> None:
    """MemoryDenyWriteExecute=yes: the kernel's PR_SET_MDWE enforces the same rule (>= 6.3)."""
    libc = ctypes.CDLL(None, use_errno=True)
    probe = libc.prctl(67, 0, 0, 0, 0)  # PR_GET_MDWE
    if probe < 0:
        pytest.skip("kernel without PR_SET_MDWE (< 6.3): cannot emulate MemoryDenyWriteExecute")
    script = """
import ctypes, mmap
libc = ctypes.CDLL(None, use_errno=True)
assert libc.prctl(65, 1, 0, 0, 0) == 0, ctypes.get_errno()  # PR_SET_MDWE, REFUSE_EXEC_GAIN
try:
    mmap.mmap(-1, 4096, prot=mmap.PROT_READ | mmap.PROT_WRITE | mmap.PROT_EXEC)
except OSError:
    pass
else:
    raise SystemExit("MDWE not in force")
import hid, pyudev, serial, yaml  # C extensions and ctypes users the daemon loads
yaml.load("a: 1", Loader=yaml.CSafeLoader)
callback = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_int)(lambda x: x + 1)
assert callback(41) == 42  # libffi closures: static trampolines, no W+X page
import usb2rc.cli, usb2rc.service.sdnotify
print("ok")
"""
    result = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, check=False, cwd=ROOT
    )
    assert result.returncode == 0 and result.stdout.strip() == "ok", result.stderr


# ---- udev rules ---------------------------------------------------------------------------

MATCH_KEYS = {
    "ACTION", "DEVPATH", "KERNEL", "KERNELS", "SUBSYSTEM", "SUBSYSTEMS", "DRIVER", "DRIVERS",
    "ATTRS", "TAGS", "TEST", "PROGRAM", "RESULT", "CONST",
}  # fmt: skip
ASSIGN_KEYS = {
    "OWNER", "GROUP", "MODE", "SECLABEL", "RUN", "LABEL", "GOTO", "IMPORT", "OPTIONS",
}  # fmt: skip
BOTH_KEYS = {"NAME", "SYMLINK", "ATTR", "SYSCTL", "ENV", "TAG"}
TOKEN = re.compile(
    r"\s*(?P<key>[A-Z_]+)(?:\{(?P<attr>[^}]*)\})?\s*(?P<op>==|!=|\+=|-=|:=|=)\s*"
    r'"(?P<value>(?:[^"\\]|\\.)*)"\s*(?:,|$)'
)


def rule_lines(text: str) -> list[str]:
    lines = [line.strip() for line in text.splitlines()]
    return [line for line in lines if line and not line.startswith("#")]


def parse_rule(line: str) -> list[tuple[str, str, str]]:
    """A udev rule line to (key, operator, value); raises AssertionError on bad syntax."""
    tokens, pos = [], 0
    while pos < len(line):
        match = TOKEN.match(line, pos)
        assert match, f"cannot parse at column {pos}: {line!r}"
        key, op = match["key"], match["op"]
        if key in MATCH_KEYS:
            assert op in ("==", "!="), f"{key} is a match key: {line!r}"
        elif key in ASSIGN_KEYS:
            assert op not in ("==", "!="), f"{key} is an assignment key: {line!r}"
        else:
            assert key in BOTH_KEYS, f"unknown key {key}: {line!r}"
        tokens.append((key, op, match["value"]))
        pos = match.end()
    return tokens


def test_rules_parse_and_gotos_land() -> None:
    rules = [parse_rule(line) for line in rule_lines(RULES.read_text())]
    labels = {value for rule in rules for key, _, value in rule if key == "LABEL"}
    gotos = {value for rule in rules for key, _, value in rule if key == "GOTO"}
    assert gotos and gotos <= labels
    for rule in rules:
        for key, _, value in rule:
            if key == "MODE":
                assert re.fullmatch(r"0[0-7]{3}", value)


def test_rules_documented_vid_pid_example_parses() -> None:
    examples = [line.lstrip("# ") for line in RULES.read_text().splitlines() if "ATTRS{" in line]
    assert examples
    for example in examples:
        assert ("GROUP", "=", "usb2rc") in parse_rule(example)


def test_rules_grant_group_and_uaccess_before_seat_late() -> None:
    (program_rule,) = [
        r for r in map(parse_rule, rule_lines(RULES.read_text())) if r[0][0] == "PROGRAM"
    ]
    assert ("GROUP", "=", "usb2rc") in program_rule
    assert ("MODE", "=", "0660") in program_rule
    assert ("TAG", "+=", "uaccess") in program_rule
    # TAG+="uaccess" is turned into an ACL by 73-seat-late.rules: we must sort before it.
    assert RULES.name < "73-seat-late.rules"


@pytest.mark.skipif(shutil.which("udevadm") is None, reason="udevadm not installed")
def test_udevadm_verify() -> None:
    if subprocess.run(["udevadm", "verify", "--help"], capture_output=True).returncode != 0:
        pytest.skip("udevadm verify needs systemd >= 254")
    result = subprocess.run(["udevadm", "verify", str(RULES)], capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr


def classify(descriptor: bytes, tmp_path: Path) -> bool:
    """Run the rules' PROGRAM= as udev would for a hidraw node whose parent has `descriptor`."""
    (program,) = [
        value
        for rule in map(parse_rule, rule_lines(RULES.read_text()))
        for key, _, value in rule
        if key == "PROGRAM"
    ]
    syspath = tmp_path / "devices" / "hidraw0"
    (syspath / "device").mkdir(parents=True, exist_ok=True)
    (syspath / "device" / "report_descriptor").write_bytes(descriptor)
    # udev's substitutions: %S%p is the device's sysfs path, $$ a literal $; then it splits
    # the command on spaces, honouring single quotes - as shlex does for this string.
    assert "%" not in program.replace("%S%p", "")
    command = program.replace("%S%p", str(syspath)).replace("$$", "$")
    # udev runs PROGRAM without PATH in the environment: the tools must be named absolutely.
    result = subprocess.run(shlex.split(command), env={}, capture_output=True, check=False)
    assert result.returncode in (0, 1), result.stderr
    return result.returncode == 0


END = bytes([0xC0])
AXES = bytes.fromhex("15 00 26 ff 00 75 08 95 02 09 30 09 31 81 02")
JOYSTICK = bytes.fromhex("05 01 09 04 a1 01") + AXES + END
GAMEPAD = bytes.fromhex("05 01 09 05 a1 01") + AXES + END
MULTI_AXIS = bytes.fromhex("05 01 09 08 a1 01") + AXES + END
KEYBOARD = bytes.fromhex("05 01 09 06 a1 01 05 07 19 e0 29 e7 75 01 95 08 81 02") + END
KEYPAD = bytes.fromhex("05 01 09 07 a1 01 05 07 19 00 29 65 75 08 95 06 81 00") + END
MOUSE = bytes.fromhex("05 01 09 02 a1 01 09 01 a1 00") + AXES + END + END
CONSUMER = bytes.fromhex("05 0c 09 01 a1 01 85 02 19 00 2a 3c 02 75 10 95 01 81 00") + END
TOUCHSCREEN = bytes.fromhex("05 0d 09 04 a1 01") + AXES + END  # Digitizer page, usage 4
VOLUME_13 = bytes.fromhex("05 0c 09 01 a1 01 09 e9 09 ea 81 02 c0")  # 13 bytes: then the
# joystick header spans bytes 13..18, across od's default 16-byte line.


@pytest.mark.parametrize(
    ("descriptor", "granted"),
    [
        pytest.param(JOYSTICK, True, id="joystick"),
        pytest.param(GAMEPAD, True, id="gamepad"),
        pytest.param(MULTI_AXIS, True, id="multi-axis"),
        pytest.param(CONSUMER + JOYSTICK, True, id="joystick-after-consumer"),
        pytest.param(VOLUME_13 + JOYSTICK, True, id="header-across-od-line"),
        pytest.param(KEYBOARD, False, id="keyboard"),
        pytest.param(MOUSE, False, id="mouse"),
        pytest.param(CONSUMER, False, id="consumer"),
        pytest.param(TOUCHSCREEN, False, id="touchscreen-usage-4-other-page"),
        pytest.param(JOYSTICK + KEYBOARD, False, id="joystick-with-keyboard"),
        pytest.param(JOYSTICK + KEYPAD, False, id="joystick-with-keypad"),
        pytest.param(bytes.fromhex("00 50 10 90 4a 10 10"), False, id="nibble-misaligned"),
        pytest.param(b"", False, id="empty"),
    ],
)
def test_rules_classifier(descriptor: bytes, granted: bool, tmp_path: Path) -> None:
    assert classify(descriptor, tmp_path) is granted


def test_rules_classifier_reads_the_parent_descriptor(tmp_path: Path) -> None:
    # Same node, descriptor swapped: the decision follows the file, not a cached answer.
    assert classify(JOYSTICK, tmp_path)
    assert not classify(KEYBOARD, tmp_path)
