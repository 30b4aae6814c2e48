"""What usb2rc.service lets a network output reach (issue 20 point 1): the drop-in
install-system writes, and the warning `check` gives while the installed unit blocks one."""

from __future__ import annotations

from pathlib import Path

import pytest
from cli_harness import usb2rc
from daemon_harness import ROOT

from usb2rc.cli import main
from usb2rc.configfile import load_config_text
from usb2rc.service.sandbox import (
    DROP_IN,
    UNIT,
    Peers,
    drop_in_text,
    endpoint,
    installed_sandbox,
    network_peers,
)

MAVLINK = ROOT / "usb2rc" / "data" / "config" / "mavlink.yaml"


def config_with(*ports: str) -> str:
    outputs = "".join(
        f"  - {{protocol: mavlink, port: '{p}', channels: [node0.x]}}\n" for p in ports
    )
    return f"outputs:\n{outputs}"


def peers(*ports: str, root: Path = Path("/nonexistent")) -> list[Peers]:
    return network_peers(load_config_text(config_with(*ports), "x.yaml"), root)


def test_each_network_scheme_names_its_host() -> None:
    assert endpoint("/dev/ttyUSB0") is None and endpoint(None) is None
    assert endpoint("udpout:10.0.0.2:14550").host == "10.0.0.2"  # type: ignore[union-attr]
    assert endpoint("udpin:0.0.0.0:14550").listening  # type: ignore[union-attr]
    assert endpoint("socket://192.168.4.1:5760").host == "192.168.4.1"  # type: ignore[union-attr]
    assert endpoint("rfc2217://[::1]:2217?logging=debug").host == "::1"  # type: ignore[union-attr]


def test_what_each_output_needs_allowed() -> None:
    found = peers(
        "udpout:10.0.0.2:14550",
        "udpin:127.0.0.1:14551",
        "udpin:0.0.0.0:14552",
        "udpout:localhost:14553",
    )
    assert [p.allow for p in found] == [("10.0.0.2",), ("localhost",), ("any",), ("127.0.0.1",)]
    assert [bool(p.warning) for p in found] == [False, False, True, True]
    assert "narrow IPAddressAllow=" in found[2].warning


def test_a_named_host_also_allows_the_resolvers(tmp_path: Path) -> None:
    (tmp_path / "etc").mkdir()
    (tmp_path / "etc/resolv.conf").write_text("search lan\nnameserver 192.168.4.1\n")
    (found,) = peers("udpout:localhost:14550", root=tmp_path)
    assert found.allow == ("127.0.0.1", "192.168.4.1")
    assert "IPAddressAllow=127.0.0.1 192.168.4.1\n" in drop_in_text([found], "x.yaml")


def test_a_name_that_does_not_resolve_is_said() -> None:
    (found,) = peers("udpout:no-such-host.invalid:14550")
    assert found.allow == () and "does not resolve" in found.warning
    settings = [line for line in drop_in_text([found], "x.yaml").splitlines() if "=" in line]
    assert [s for s in settings if not s.startswith("#")] == [
        "RestrictAddressFamilies=AF_INET AF_INET6"
    ]  # no IPAddressAllow= guessed; the comment says to add the address


def install_unit(root: Path, config: Path = MAVLINK) -> None:
    result = usb2rc("install-system", "--root", str(root), "--config", str(config))
    assert result.returncode == 0, result.stderr


def check_warnings(
    root: Path, config: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> str:
    monkeypatch.setattr("usb2rc.service.sandbox.SYSTEM_ROOT", root)
    assert main(["check", "--config", str(config)]) == 0
    return capsys.readouterr().err


def test_check_warns_while_the_installed_unit_blocks_an_output(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    install_unit(tmp_path)
    (tmp_path / DROP_IN.lstrip("/")).unlink()  # as a unit installed before the drop-in existed
    err = check_warnings(tmp_path, MAVLINK, monkeypatch, capsys)
    line = next(w for w in err.splitlines() if "usb2rc.service" in w)
    assert line.startswith(f"{MAVLINK}:7: outputs[0].port: warning: usb2rc.service as installed")
    assert "cannot open udpout:127.0.0.1:14550: it allows no AF_INET socket" in line
    assert "`sudo usb2rc install-system` writes" in line
    install_unit(tmp_path)  # the config is kept, the drop-in written for it
    assert "usb2rc.service" not in check_warnings(tmp_path, MAVLINK, monkeypatch, capsys)


def test_check_says_nothing_without_an_installed_unit(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    assert "usb2rc.service" not in check_warnings(tmp_path, MAVLINK, monkeypatch, capsys)


def test_a_drop_in_for_another_host_still_blocks(tmp_path: Path) -> None:
    install_unit(tmp_path)
    drop_in = tmp_path / DROP_IN.lstrip("/")
    drop_in.write_text(
        drop_in.read_text().replace("IPAddressAllow=127.0.0.1", "IPAddressAllow=10.0.0.9")
    )
    sandbox = installed_sandbox(tmp_path)
    assert sandbox is not None and sandbox.family_allowed("AF_INET")
    assert not sandbox.reaches("127.0.0.1") and sandbox.reaches("10.0.0.9")
    assert (tmp_path / UNIT.lstrip("/")).is_file()
