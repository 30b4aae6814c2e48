"""Configs written by `calibrate` and `init` stay the user's files (issue 19 point 7).

The service reads /etc/usb2rc/usb2rc.yaml as group usb2rc (root:usb2rc 0640). A `sudo usb2rc
calibrate` that replaced it with root:root 0640 stopped the next start (exit 2); one that
replaced a symlinked config with a regular file cut the user's indirection. Real files in
tmp_path; as root here, the group kept is 65534 (nogroup), the service group's stand-in.
"""

from __future__ import annotations

import os
import stat
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest
from cli_harness import usb2rc
from daemon_harness import ROOT

from usb2rc.commands.calibrate import write_results
from usb2rc.config.calibration import AxisResult, AxisTarget
from usb2rc.config.model import Calibration
from usb2rc.runtime.textfile import DanglingLink, write_atomically

SERVICE_GID = 65534  # nogroup: a group root is not in, as usb2rc on a Pi
CONFIG = """\
outputs:
  - {protocol: c2-16b, port: /dev/ttyUSB0}
devices:
  - name: stick
    match: {vid: 0x044f, pid: 0xb10a}
    axes:
      x: X   # roll
"""
needs_root = pytest.mark.skipif(os.geteuid() != 0, reason="chown to another group needs root")


def service_config(directory: Path) -> Path:
    """A config as install-system leaves it: root:<service group> 0640."""
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / "usb2rc.yaml"
    path.write_text(CONFIG)
    os.chown(path, 0, SERVICE_GID)
    path.chmod(0o640)
    return path


def owner_group_mode(path: Path) -> tuple[int, int, int]:
    st = path.stat()
    return st.st_uid, st.st_gid, stat.S_IMODE(st.st_mode)


def calibrated_x() -> list[AxisResult]:
    target = AxisTarget(0, "stick", "x", "X", 0, 0, 16383)
    return [AxisResult(target, Calibration(12, 8190, 16370), 0.0, 0.0)]


@needs_root
def test_calibrate_keeps_the_configs_group_and_mode(tmp_path: Path) -> None:
    config = service_config(tmp_path / "etc")
    write_results(str(config), CONFIG, calibrated_x())
    assert "calibration: {min: 12, center: 8190, max: 16370}" in config.read_text()
    assert owner_group_mode(config) == (0, SERVICE_GID, 0o640)  # before: (0, 0, 0o640)
    assert [p.name for p in config.parent.iterdir()] == ["usb2rc.yaml"]  # no temporary left


@needs_root
def test_calibrate_writes_the_file_a_symlinked_config_points_to(tmp_path: Path) -> None:
    target = service_config(tmp_path / "data")
    link = tmp_path / "etc" / "usb2rc.yaml"
    link.parent.mkdir()
    link.symlink_to(target)
    write_results(str(link), CONFIG, calibrated_x())
    assert link.is_symlink() and os.readlink(link) == str(target)  # before: a regular file
    assert "calibration:" in target.read_text()
    assert owner_group_mode(target) == (0, SERVICE_GID, 0o640)
    assert [p.name for p in target.parent.iterdir()] == ["usb2rc.yaml"]  # no temporary left
    assert [p.name for p in link.parent.iterdir()] == ["usb2rc.yaml"]


def test_a_dangling_symlink_is_refused_naming_link_and_target(tmp_path: Path) -> None:
    link = tmp_path / "usb2rc.yaml"
    link.symlink_to(tmp_path / "mnt" / "config.yaml")
    with pytest.raises(DanglingLink) as refused:
        write_atomically(link, CONFIG)
    assert str(link) in str(refused.value) and str(tmp_path / "mnt/config.yaml") in str(
        refused.value
    )
    assert link.is_symlink() and not (tmp_path / "mnt").exists()  # before: a regular file


@needs_root
def test_a_file_this_user_cannot_give_back_is_not_replaced() -> None:
    """Not root and not its owner: a copy would change hands, so nothing is written."""
    code = (
        "import os, sys; from usb2rc.runtime.textfile import write_atomically; "
        "os.setgid(65534); os.setuid(65534); write_atomically(sys.argv[1], 'x')"
    )
    with tempfile.TemporaryDirectory(dir="/tmp") as scratch:  # reachable by uid 65534
        os.chmod(scratch, 0o777)  # the temporary can be made beside the config
        config = Path(scratch) / "usb2rc.yaml"
        config.write_text(CONFIG)
        config.chmod(0o666)  # writable by anyone, owned by root
        result = subprocess.run(
            [sys.executable, "-c", code, str(config)],
            capture_output=True,
            text=True,
            cwd=ROOT,
            check=False,
        )
        assert "OwnerNotKept" in result.stderr, result.stderr
        assert "belongs to uid 0 gid 0" in result.stderr
        assert config.read_text() == CONFIG and config.stat().st_uid == 0
        assert [p.name for p in Path(scratch).iterdir()] == ["usb2rc.yaml"]


@needs_root
def test_init_force_over_a_symlinked_service_config(tmp_path: Path) -> None:
    """Black box: `usb2rc init -o LINK --force` as root keeps the link, group and mode."""
    target = service_config(tmp_path / "data")
    link = tmp_path / "usb2rc.yaml"
    link.symlink_to(target)
    result = usb2rc("init", "--replay", "usb2rc/data/demo", "--force", "-o", str(link))
    assert result.returncode == 0, result.stderr
    assert link.is_symlink() and "thrustmaster" in target.read_text()
    assert owner_group_mode(target) == (0, SERVICE_GID, 0o640)


def test_init_refuses_a_dangling_output_link(tmp_path: Path) -> None:
    link = tmp_path / "usb2rc.yaml"
    link.symlink_to("/nonexistent/usb2rc.yaml")
    result = usb2rc("init", "--replay", "usb2rc/data/demo", "-o", str(link))
    assert result.returncode == 1
    assert f"{link} is a symlink to /nonexistent/usb2rc.yaml, which does not exist" in (
        result.stderr
    )
    assert link.is_symlink()
