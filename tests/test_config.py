"""Config loading: defaults, every key parsed, errors with file:line and suggestions."""

from __future__ import annotations

import pytest

from usb2rc.configfile import Calibration, Config, ConfigError, OutputConfig, load_config_text


def errors(text: str) -> list[str]:
    with pytest.raises(ConfigError) as exc:
        load_config_text(text, "c.yaml")
    return exc.value.errors


def test_zero_config_and_empty_file() -> None:
    default = Config.default()
    assert default.outputs == (OutputConfig(),)
    assert default.defaults is True and default.devices == ()
    out = default.outputs[0]
    assert (out.protocol, out.port, out.baudrate, out.rate_hz) == ("c2-16b", None, 115200, 50)
    assert (out.line_feed, out.service_status) == (True, "ascii")
    # An empty file is not zero config: an editor's save (truncate, then write) must not
    # switch a running daemon to it on a reload (docs/CONFIG.md, "Reload").
    for text in ("", "# only a comment\n", "\n\n"):
        (error,) = errors(text)
        assert error.startswith("c.yaml: empty (no YAML document)")


def test_sumd_defaults_and_options() -> None:
    config = load_config_text("outputs: [{protocol: sumd, extended: true, port: loop://}]")
    out = config.outputs[0]
    assert (out.rate_hz, out.extended, out.channels, out.port) == (100, True, None, "loop://")


def test_axis_options_parsed() -> None:
    config = load_config_text(
        """
devices:
  - match: {vid: 0x044f, pid: 0xb10a, product: "T.16*"}
    node_id: 1
    axes:
      rz: {usage: Rz, calibration: {min: 12, center: 128, max: 250}, deadband: 0.05,
           expo: 0.3, invert: true, trim: -0.1, unsigned: true, failsafe: 65535}
      aux1: {hat: HatSwitch, axis: y, occurrence: 1}
      aux2: {buttons: [3, 4]}
    buttons: {"1-2": "25-26", 9: 56}
    hats: [{to: hat1}]
"""
    )
    (device,) = config.devices
    assert device.name == "device1" and device.node_id == 1 and not device.default_layout
    assert (device.match.vid, device.match.pid, device.match.product) == (0x044F, 0xB10A, "T.16*")
    rz, aux1, aux2 = device.axes
    assert rz.usage == 0x00010035 and rz.calibration == Calibration(12, 128, 250)
    assert (rz.deadband, rz.expo, rz.invert, rz.trim, rz.unsigned, rz.failsafe) == (
        0.05, 0.3, True, -0.1, True, 65535,
    )  # fmt: skip
    assert (aux1.hat, aux1.hat_axis, aux1.occurrence) == (0x00010039, "y", 1)
    assert aux2.buttons == (3, 4)
    assert [(r.hid, r.node) for r in device.buttons] == [(1, 25), (2, 26), (9, 56)]
    assert device.hats[0].to == "hat1" and device.hats[0].usage == 0x00010039
    assert rz.where.line == 6 and rz.where.key == "devices[0].axes.rz"


def test_entry_without_maps_uses_default_layout() -> None:
    config = load_config_text("devices: [{match: {vid: 1}, node_id: 4}]")
    assert config.devices[0].default_layout


def test_all_errors_reported_sorted_by_line() -> None:
    got = errors(
        """outputs:
  - protocol: c2-16b
    rate: 50
devices:
  - name: s
    match: {vid: 1}
    axes: {x: {usage: X, expo: 1.5}, y: {usage: Y, invert: yes please}}
"""
    )
    assert got == [
        "c.yaml:3: outputs[0].rate: unknown key 'rate'; did you mean 'rate_hz'? (allowed: "
        "protocol, port, baudrate, rate_hz, channels, line_feed, service_status, extended, "
        "follow_module, address, message, system_id, component_id, target_system, "
        "target_component, allow, signing_key_file, actions)",
        "c.yaml:7: devices[0].axes.x.expo: 1.5 is out of range (allowed: 0.0..1.0)",
        "c.yaml:7: devices[0].axes.y.invert: expected true or false, got 'yes please' "
        "(allowed: true, false)",
    ]


def test_unsigned_failsafe_range_and_duplicate_key() -> None:
    got = errors(
        """devices:
  - match: {vid: 1}
    axes:
      x: {usage: X, unsigned: true, failsafe: -1}
      x: Y
"""
    )
    assert got == [
        "c.yaml:4: devices[0].axes.x.failsafe: -1 is out of range (allowed: 0..65535)",
        "c.yaml:5: devices[0].axes.x: duplicate key",
    ]


def test_usage_by_hex_code_and_unknown_usage() -> None:
    config = load_config_text("devices: [{match: {vid: 1}, axes: {x: 0xFF000021}}]")
    assert config.devices[0].axes[0].usage == 0xFF000021
    (err,) = errors("devices: [{match: {vid: 1}, axes: {x: Throttel}}]")
    assert err.startswith("c.yaml:1: devices[0].axes.x: unknown usage 'Throttel' (allowed:")


def test_channel_count_limits() -> None:
    (err,) = errors("outputs: [{protocol: sumd, channels: [node0.x]}]")
    assert err == "c.yaml:1: outputs[0].channels: 1 channels (allowed: 2..32)"


def test_merge_on_one_node_without_overlap_is_fine() -> None:
    config = load_config_text(
        """devices:
  - {name: a, match: {vid: 1}, node_id: 1, axes: {x: X}, buttons: {1-16: 1-16}}
  - {name: b, match: {vid: 2}, node_id: 1, axes: {z: Z}, buttons: {1-14: 25-38}}
"""
    )
    assert [d.node_id for d in config.devices] == [1, 1]
