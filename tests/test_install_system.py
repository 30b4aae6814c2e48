"""`usb2rc install-system`: the wheel carries the service files, the command puts them in place.

The wheel is built from the tree (`pip wheel --no-deps`), unpacked into a directory that goes
first on PYTHONPATH, and its own `usb2rc install-system --root DIR` writes into a scratch root:
what a `pip install usb2rc` on a Pi does, without a clone.
"""

from __future__ import annotations

import os
import shlex
import shutil
import stat
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from usb2rc.commands.install_system import (
    BY_NAME,
    FILES,
    TEMPLATE_PROGRAM,
    running_program,
    systemd_quote,
    unit_text,
)

ROOT = Path(__file__).resolve().parent.parent
PACKAGED = {
    f.name: ROOT / "usb2rc" / "data" / f.package_dir / f.name
    for f in BY_NAME.values()
    if not f.generated  # network.conf is written from the config
}
HAVE_SYSUSERS = shutil.which("systemd-sysusers") is not None


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("wheel")
    # the service files are what is tested: no mypyc build of the hot path (a minute of CPU;
    # tests/test_wheel_journey.py builds the whole wheel)
    result = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(out), str(ROOT)],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
        env={**os.environ, "USB2RC_NO_MYPYC": "1"},
    )
    assert result.returncode == 0, result.stderr[-3000:]
    (built,) = out.glob("usb2rc-*.whl")
    return built


@pytest.fixture(scope="module")
def unpacked(wheel: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    site = tmp_path_factory.mktemp("site")
    with zipfile.ZipFile(wheel) as archive:
        archive.extractall(site)
    return site


def from_wheel(site: Path | None, *args: str) -> subprocess.CompletedProcess[str]:
    """`python -m usb2rc ARGS` with the wheel's usb2rc first on the path (not the tree's);
    site None: the tree's, from the repository root."""
    env = dict(os.environ, PYTHONPATH=str(site)) if site else None
    return subprocess.run(
        [sys.executable, "-m", "usb2rc", *args],
        capture_output=True,
        text=True,
        env=env,
        cwd=site or ROOT,
        timeout=60,
        check=False,
    )


def test_wheel_holds_unit_rule_sysusers_and_configs(wheel: Path) -> None:
    with zipfile.ZipFile(wheel) as archive:
        names = set(archive.namelist())
        for name, source in PACKAGED.items():
            member = f"usb2rc/data/{source.parent.name}/{name}"
            assert member in names, f"{member} missing from {wheel.name}"
            assert archive.read(member) == source.read_bytes()


def test_the_wheel_runs_not_the_tree(unpacked: Path) -> None:
    result = from_wheel(unpacked, "install-system", "--print", "70-usb2rc.rules")
    assert result.returncode == 0, result.stderr
    assert result.stdout == PACKAGED["70-usb2rc.rules"].read_text()
    probe = subprocess.run(
        [sys.executable, "-c", "import usb2rc; print(usb2rc.__file__)"],
        capture_output=True,
        text=True,
        env=dict(os.environ, PYTHONPATH=str(unpacked)),
        cwd=unpacked.parent,
        check=True,
    )
    assert Path(probe.stdout.strip()).is_relative_to(unpacked)


def test_install_into_a_scratch_root_from_the_wheel(unpacked: Path, tmp_path: Path) -> None:
    root = tmp_path / "pi"
    result = from_wheel(unpacked, "install-system", "--root", str(root))
    assert result.returncode == 0, result.stdout + result.stderr
    program = running_program_of_subprocess()
    for file in FILES:
        installed = root / file.target.lstrip("/")
        assert installed.is_file(), f"{file.target} not written"
        assert stat.S_IMODE(installed.stat().st_mode) == file.mode, file.target
        expected = PACKAGED[file.name].read_text()
        if file.name == "usb2rc.service":
            expected = unit_text(expected, program)
        assert installed.read_text() == expected, file.target
    assert {
        "/etc/systemd/system/usb2rc.service",
        "/etc/udev/rules.d/70-usb2rc.rules",
        "/usr/lib/sysusers.d/usb2rc.conf",
        "/etc/usb2rc/usb2rc.yaml",
    } <= {f.target for f in FILES}
    unit = (root / "etc/systemd/system/usb2rc.service").read_text()
    assert f"ExecStart={program[0]} run --config /etc/usb2rc/usb2rc.yaml" in unit
    assert stat.S_IMODE((root / "etc/usb2rc").stat().st_mode) == 0o755


@pytest.mark.skipif(not HAVE_SYSUSERS, reason="systemd-sysusers missing")
def test_install_creates_the_service_user_and_gives_it_the_config(
    unpacked: Path, tmp_path: Path
) -> None:
    result = from_wheel(unpacked, "install-system", "--root", str(tmp_path))
    assert result.returncode == 0, result.stderr
    passwd = (tmp_path / "etc" / "passwd").read_text()
    assert any(line.startswith("usb2rc:") for line in passwd.splitlines())
    (group,) = [g for g in (tmp_path / "etc" / "group").read_text().splitlines() if "usb2rc" in g]
    config = (tmp_path / "etc/usb2rc/usb2rc.yaml").stat()
    if os.geteuid() == 0:
        assert (config.st_uid, config.st_gid) == (0, int(group.split(":")[2]))
    else:
        assert "chown root:usb2rc" in result.stderr


def test_an_existing_config_is_kept(tmp_path: Path) -> None:
    config = tmp_path / "etc" / "usb2rc" / "usb2rc.yaml"
    config.parent.mkdir(parents=True)
    config.write_text("# mine\n")
    result = run_here("install-system", "--root", str(tmp_path))
    assert "kept" in result.stdout and str(config) in result.stdout
    assert config.read_text() == "# mine\n"
    again = run_here("install-system", "--root", str(tmp_path))
    assert again.returncode == result.returncode
    assert again.stdout.count("unchanged") == len(FILES) - 1  # every file but the kept config


def test_install_a_given_config_only_if_it_passes_check(tmp_path: Path) -> None:
    good = PACKAGED["hotas.yaml"]
    result = run_here("install-system", "--root", str(tmp_path / "a"), "--config", str(good))
    assert (tmp_path / "a/etc/usb2rc/usb2rc.yaml").read_text() == good.read_text(), result.stderr
    bad = tmp_path / "bad.yaml"
    bad.write_text("outputs:\n  - protocl: sumd\n")
    result = run_here("install-system", "--root", str(tmp_path / "b"), "--config", str(bad))
    assert result.returncode == 2
    assert f"{bad}:2:" in result.stderr and "not installing" in result.stderr
    assert not (tmp_path / "b").exists()


def test_print_shows_the_unit_as_installed() -> None:
    result = run_here("install-system", "--print", "usb2rc.service", "--exec", "/opt/x/bin/usb2rc")
    assert result.returncode == 0
    assert "ExecStart=/opt/x/bin/usb2rc run --config /etc/usb2rc/usb2rc.yaml\n" in result.stdout
    assert TEMPLATE_PROGRAM not in result.stdout


def test_print_rejects_an_unknown_name() -> None:
    result = run_here("install-system", "--print", "nope.service")
    assert result.returncode == 2 and "usb2rc.service" in result.stderr


def test_exec_start_names_the_running_usb2rc() -> None:
    # Run as `python -m usb2rc`: the usb2rc script beside this Python (the venv's bin/).
    beside = Path(os.path.abspath(sys.executable)).parent / "usb2rc"
    if os.access(beside, os.X_OK):
        assert running_program_of_subprocess() == [str(beside)]
    assert running_program()[0].startswith("/")


def test_a_relative_exec_is_a_usage_error(tmp_path: Path) -> None:
    result = run_here("install-system", "--root", str(tmp_path), "--exec", "bin/usb2rc")
    assert result.returncode == 2 and "--exec needs an absolute path" in result.stderr
    assert not any(tmp_path.iterdir())


def test_a_program_under_home_is_warned_about(tmp_path: Path) -> None:
    result = run_here("install-system", "--root", str(tmp_path), "--exec", "/home/pi/v/usb2rc")
    assert "ProtectHome" in result.stderr


def test_systemd_quote() -> None:
    assert systemd_quote("/opt/usb2rc/venv/bin/usb2rc") == "/opt/usb2rc/venv/bin/usb2rc"
    assert systemd_quote("/opt/my venv/usb2rc") == '"/opt/my venv/usb2rc"'


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze missing")
def test_installed_unit_verifies_with_its_real_exec_start(tmp_path: Path) -> None:
    # Here ExecStart= names this venv's usb2rc, which exists: verify needs no stand-in.
    result = run_here("install-system", "--root", str(tmp_path))
    unit = tmp_path / "etc/systemd/system/usb2rc.service"
    assert unit.is_file(), result.stderr
    check = subprocess.run(
        ["systemd-analyze", "verify", str(unit)], capture_output=True, text=True, check=False
    )
    assert check.returncode == 0 and check.stdout + check.stderr == "", check.stderr


def run_here(*args: str) -> subprocess.CompletedProcess[str]:
    return from_wheel(None, *args)


def running_program_of_subprocess() -> list[str]:
    """What `python -m usb2rc` (argv[0] is __main__.py) picks: the script beside Python."""
    code = "from usb2rc.commands.install_system import running_program as r; print(*r(), sep='\\n')"
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT
    )
    return out.stdout.splitlines()


def test_next_steps_name_the_installed_program(capsys: pytest.CaptureFixture[str]) -> None:
    from usb2rc.commands.install_system import _print_advice

    _print_advice(Path("/"), ["/opt/usb2rc/venv/bin/usb2rc"], [])
    out = capsys.readouterr().out
    assert "sudo /opt/usb2rc/venv/bin/usb2rc check --config /etc/usb2rc/usb2rc.yaml" in out
    assert "systemctl daemon-reload" in out and "udevadm trigger" in out


# --------------------------------------------------------------------------- issue 19 point 7


def installed(root: Path, target: str) -> Path:
    return root / target.lstrip("/")


UNIT = "/etc/systemd/system/usb2rc.service"


def test_an_edited_unit_is_kept_with_its_diff_until_force(tmp_path: Path) -> None:
    assert run_here("install-system", "--root", str(tmp_path)).returncode == 0
    unit = installed(tmp_path, UNIT)
    edited = unit.read_text().replace("RestartSec=1", "RestartSec=5")
    unit.write_text(edited)
    again = run_here("install-system", "--root", str(tmp_path))
    assert again.returncode == 1
    assert unit.read_text() == edited  # before: silently reverted
    assert "-RestartSec=5\n+RestartSec=1\n" in again.stderr
    assert f"{unit} differs from this usb2rc's usb2rc.service and was kept" in again.stderr
    assert "--force" in again.stderr
    forced = run_here("install-system", "--root", str(tmp_path), "--force")
    assert forced.returncode == 0, forced.stderr
    assert "RestartSec=1\n" in unit.read_text()


def test_a_masked_unit_stays_masked(tmp_path: Path) -> None:
    unit = installed(tmp_path, UNIT)
    unit.parent.mkdir(parents=True)
    unit.symlink_to("/dev/null")
    result = run_here("install-system", "--root", str(tmp_path))
    assert result.returncode == 1 and f"{unit} is a symlink to /dev/null" in result.stderr
    assert unit.is_symlink()


def test_a_dangling_config_link_is_refused_naming_its_target(tmp_path: Path) -> None:
    config = installed(tmp_path, "/etc/usb2rc/usb2rc.yaml")
    config.parent.mkdir(parents=True)
    config.symlink_to("/mnt/usb/usb2rc.yaml")
    result = run_here("install-system", "--root", str(tmp_path))
    assert result.returncode == 1
    assert f"{config} is a symlink to /mnt/usb/usb2rc.yaml, which does not exist" in result.stderr
    assert config.is_symlink() and os.readlink(config) == "/mnt/usb/usb2rc.yaml"  # before: a file
    assert not Path("/mnt/usb/usb2rc.yaml").exists()


def test_a_given_config_is_named_as_the_source(tmp_path: Path) -> None:
    mine = tmp_path / "my.yaml"
    mine.write_text(PACKAGED["hotas.yaml"].read_text())
    result = run_here("install-system", "--root", str(tmp_path / "r"), "--config", str(mine))
    assert f"usb2rc.yaml (from {mine})" in result.stdout  # before: (from default.yaml)
    assert "(from default.yaml)" not in result.stdout


SHIPPED = [
    "default.yaml",
    "hotas.yaml",
    "mavlink.yaml",
    "usb2rc.service",
    "70-usb2rc.rules",
    "usb2rc.sysusers",
    "SERVICE.md",
    "network.conf",
]


@pytest.mark.parametrize("name", SHIPPED)
def test_print_offers_every_shipped_file(name: str) -> None:
    result = run_here("install-system", "--print", name)
    assert result.returncode == 0, result.stderr
    if name in PACKAGED and name != "usb2rc.service":
        assert result.stdout == PACKAGED[name].read_text()
    assert name in run_here("install-system", "--help").stdout


def test_print_network_conf_for_a_config(tmp_path: Path) -> None:
    result = run_here("install-system", "--print", "network.conf", "--config", MAVLINK)
    assert "RestrictAddressFamilies=AF_INET AF_INET6\n" in result.stdout
    assert "IPAddressAllow=127.0.0.1\n" in result.stdout
    plain = run_here("install-system", "--print", "network.conf")
    assert "[Service]" not in plain.stdout and "nothing to allow" in plain.stdout


# --------------------------------------------------------------------------- issue 20 point 1

MAVLINK = str(PACKAGED["mavlink.yaml"])
DROP_IN = "/etc/systemd/system/usb2rc.service.d/network.conf"
HAVE_ANALYZE = shutil.which("systemd-analyze") is not None
MAX_EXPOSURE = 2.0


def analyze(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        ["systemd-analyze", *args], capture_output=True, text=True, check=False, timeout=60
    )


@pytest.mark.skipif(not HAVE_ANALYZE, reason="systemd-analyze missing")
def test_a_mavlink_udp_config_gets_a_drop_in_that_verifies(tmp_path: Path) -> None:
    result = run_here("install-system", "--root", str(tmp_path), "--config", MAVLINK)
    assert result.returncode == 0, result.stdout + result.stderr
    drop_in = installed(tmp_path, DROP_IN)
    text = drop_in.read_text()  # before: no drop-in, udpout:127.0.0.1:14550 blocked
    assert "RestrictAddressFamilies=AF_INET AF_INET6\nIPAddressAllow=127.0.0.1\n" in (
        text.replace("# outputs[0] udpout:127.0.0.1:14550\n", "")
    )
    assert stat.S_IMODE(drop_in.stat().st_mode) == 0o644
    unit = installed(tmp_path, UNIT)
    # verify loads the drop-ins beside a unit file's directory; clean means no output at all.
    check = analyze("verify", str(unit))
    assert check.returncode == 0 and check.stdout + check.stderr == "", check.stderr
    report = analyze("security", "--offline=true", "--no-pager", str(unit))
    assert "RestrictAddressFamilies=~AF_(INET|INET6)" in report.stdout  # the drop-in was read
    assert "allow list with only localhost entries" in report.stdout
    exposure = float(
        report.stdout.rsplit("Overall exposure level for usb2rc.service:", 1)[1].split()[0]
    )
    assert exposure <= MAX_EXPOSURE, report.stdout


def test_a_serial_config_gets_no_drop_in(tmp_path: Path) -> None:
    result = run_here("install-system", "--root", str(tmp_path))
    assert result.returncode == 0, result.stderr
    assert not installed(tmp_path, DROP_IN).exists()


def test_the_drop_in_follows_the_kept_config_not_the_given_one(tmp_path: Path) -> None:
    """The service runs what is at /etc/usb2rc/usb2rc.yaml: a kept MAVLink config still
    gets its drop-in when install-system runs again without --config."""
    first = run_here("install-system", "--root", str(tmp_path), "--config", MAVLINK)
    assert first.returncode == 0, first.stderr
    installed(tmp_path, DROP_IN).unlink()
    again = run_here("install-system", "--root", str(tmp_path))
    assert again.returncode == 0, again.stderr
    assert "IPAddressAllow=127.0.0.1" in installed(tmp_path, DROP_IN).read_text()


def test_an_edited_drop_in_is_kept(tmp_path: Path) -> None:
    mine = tmp_path / "in.yaml"
    mine.write_text(
        PACKAGED["mavlink.yaml"].read_text().replace("udpout:127.0.0.1", "udpin:0.0.0.0")
    )
    first = run_here("install-system", "--root", str(tmp_path / "r"), "--config", str(mine))
    assert first.returncode == 0, first.stderr
    assert "takes datagrams from any host" in first.stderr  # the udpin:0.0.0.0 warning
    drop_in = installed(tmp_path / "r", DROP_IN)
    assert "IPAddressAllow=any\n" in drop_in.read_text()
    narrowed = drop_in.read_text().replace("IPAddressAllow=any", "IPAddressAllow=192.168.4.2")
    drop_in.write_text(narrowed)
    again = run_here("install-system", "--root", str(tmp_path / "r"))
    assert again.returncode == 1 and drop_in.read_text() == narrowed
    assert "-IPAddressAllow=192.168.4.2\n+IPAddressAllow=any\n" in again.stderr


# --------------------------------------------------------------------------- issue 39 point 5


def test_install_ends_with_the_next_steps_that_make_its_config_pass_check(tmp_path: Path) -> None:
    root = tmp_path / "pi"
    result = run_here("install-system", "--root", str(root))
    assert result.returncode == 0, result.stderr
    config = installed(root, "/etc/usb2rc/usb2rc.yaml")
    steps = result.stdout.split("next:\n", 1)[1].splitlines()  # before: nothing under --root
    assert steps[0].startswith(f"  set the serial port in {config}: `port:` under `outputs:`")
    assert "outputs[0] has none" in steps[0]
    check = next(step.strip() for step in steps if " check --config " in step)
    assert check.endswith(f"check --config {config}")
    assert steps.index(f"  {check}") < steps.index(
        "  sudo systemctl daemon-reload && sudo systemctl enable --now usb2rc"
    )
    master, slave = os.openpty()
    try:
        port = os.ttyname(slave)
        given = run_here("check", "--config", str(config), "--port", port)
        assert given.returncode == 0, given.stderr  # the config passes once a port is given
        text = config.read_text()
        assert "# port: /dev/serial0" in text  # where the step says the port goes
        config.write_text(text.replace("# port: /dev/serial0", f"port: {port}"))
        as_printed = subprocess.run(
            shlex.split(check), capture_output=True, text=True, timeout=60, check=False
        )
        assert as_printed.returncode == 0, as_printed.stderr
        assert as_printed.stdout.endswith(f"{config}: OK\n")
    finally:
        os.close(master)
        os.close(slave)
    again = run_here("install-system", "--root", str(root))  # the kept config has its port
    assert "set the serial port" not in again.stdout and "next:" in again.stdout
