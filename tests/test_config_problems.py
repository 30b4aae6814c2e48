"""Config problems as records (file, line, key path, allowed values) and SUMD channel refs."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from usb2rc.commands.check import load_or_default
from usb2rc.configfile import (
    ChannelRef,
    ConfigError,
    OutputConfig,
    Problem,
    Where,
    load_config,
    load_config_text,
)
from usb2rc.nodes.mapping import compile_mapping

BROKEN = sorted((Path(__file__).parent / "data" / "configs" / "broken").glob("*.yaml"))


def problems(text: str) -> list[Problem]:
    with pytest.raises(ConfigError) as exc:
        load_config_text(text, "c.yaml")
    return exc.value.problems


# --------------------------------------------------------------------------- Problem records


def test_unknown_key_record_has_suggestion_and_allowed_keys() -> None:
    (p,) = problems("outputs:\n  - protocol: c2-16b\n    rate: 50\n")
    assert (p.source, p.line, p.key) == ("c.yaml", 3, "outputs[0].rate")
    assert p.message == "unknown key 'rate'" and p.suggestion == "rate_hz"
    assert p.allowed.split(", ")[:4] == ["protocol", "port", "baudrate", "rate_hz"]
    assert p.format().startswith(
        "c.yaml:3: outputs[0].rate: unknown key 'rate'; did you mean 'rate_hz'? (allowed: "
    )


def test_range_and_type_records() -> None:
    got = problems(
        "devices:\n"
        "  - match: {vid: 1}\n"
        "    node_id: 255\n"
        "    axes: {x: {usage: X, expo: 1.5}, y: {usage: Y, invert: maybe}}\n"
    )
    assert [(p.line, p.key, p.message, p.allowed) for p in got] == [
        (3, "devices[0].node_id", "255 is out of range", "0..254"),
        (4, "devices[0].axes.x.expo", "1.5 is out of range", "0.0..1.0"),
        (4, "devices[0].axes.y.invert", "expected true or false, got 'maybe'", "true, false"),
    ]
    assert all(p.suggestion is None for p in got)


def test_cross_check_records_name_the_second_place() -> None:
    got = problems(
        "devices:\n"
        "  - {name: a, match: {vid: 1}, node_id: 1, axes: {x: X}}\n"
        "  - {name: a, match: {vid: 2}, node_id: 1, axes: {x: Y}}\n"
    )
    assert [(p.line, p.key, p.message) for p in got] == [
        (3, "devices[1].name", "duplicate device name 'a' (first at line 2)"),
        (3, "devices[1].axes.x", "node 1 axis x is already fed by device 'a' (line 2)"),
    ]


def test_channel_records() -> None:
    got = problems(
        "outputs:\n"
        "  - protocol: sumd\n"
        "    channels:\n"
        "      - node1.x\n"
        "      - node1.wheel\n"
        "defaults: false\n"
    )
    assert [(p.line, p.key, p.message) for p in got] == [
        (
            4,
            "outputs[0].channels[0]",
            "node1.x: no device is pinned to node 1 and defaults is false",
        ),
        (5, "outputs[0].channels[1]", "bad channel 'node1.wheel'"),
    ]
    assert got[1].allowed.startswith("nodeN.x, .y")


def test_yaml_and_file_problems_have_no_key() -> None:
    (p,) = problems("outputs:\n  - protocol: c2-16b\n    port: [unclosed\n")
    assert p.key is None and p.line == 4 and p.message.startswith("not valid YAML")
    assert p.format().startswith("c.yaml:4: not valid YAML")
    with pytest.raises(ConfigError) as exc:
        load_or_default("/no/such/dir/c.yaml")
    (p,) = exc.value.problems
    assert (p.source, p.line, p.key) == ("/no/such/dir/c.yaml", None, None)
    assert exc.value.errors == [f"/no/such/dir/c.yaml: {p.message}"]
    assert p.message.startswith("cannot read: ")


def test_not_utf8_names_the_line(tmp_path: Path) -> None:
    path = tmp_path / "c.yaml"
    path.write_bytes(b"devices:\n  - name: a\xff\n")
    with pytest.raises(ConfigError) as exc:
        load_config(str(path))
    (p,) = exc.value.problems
    assert (p.source, p.line, p.key) == (str(path), 2, None)


def test_problem_format_variants_and_error_lines() -> None:
    full = Problem("f.yaml", 7, "a.b", "bad", "1..2", "c")
    assert full.format() == str(full) == "f.yaml:7: a.b: bad; did you mean 'c'? (allowed: 1..2)"
    assert Problem("f.yaml", 7, None, "oops").format() == "f.yaml:7: oops"
    assert Problem("f.yaml", None, None, "gone").format() == "f.yaml: gone"
    assert Where("f.yaml", 3, "x").problem("m", key_suffix=".y") == Problem("f.yaml", 3, "x.y", "m")
    error = ConfigError([full, Problem("f.yaml", 9, "k", "m")])
    assert error.errors == [full.format(), "f.yaml:9: k: m"]
    assert str(error) == "\n".join(error.errors)


@pytest.mark.parametrize("path", BROKEN, ids=lambda p: p.stem)
def test_broken_configs_records_carry_the_expected_lines(path: Path) -> None:
    """The `# expect: LINE: text` comments, checked on the records, in process."""
    expected = re.findall(r"^# expect: (\d+): (.*)$", path.read_text(), re.MULTILINE)
    with pytest.raises(ConfigError) as exc:
        load_config(str(path))
    got = exc.value.problems
    assert [p.line for p in got] == [int(line) for line, _ in expected]
    assert [p.line for p in got] == sorted(p.line or 0 for p in got)
    for problem, (_, text) in zip(got, expected, strict=True):
        assert problem.source == str(path)
        if problem.key is None:
            assert problem.message.startswith(text)
        else:
            assert text.startswith(f"{problem.key}: ")


# --------------------------------------------------------------------------- ChannelRef


@pytest.mark.parametrize(
    ("name", "ref"),
    [
        ("node1.x", ChannelRef(1, "axis", 0, "node1.x")),
        ("Node2.RZ", ChannelRef(2, "axis", 6, "Node2.RZ")),
        ("node0.aux2", ChannelRef(0, "axis", 9, "node0.aux2")),
        (" node254.button56 ", ChannelRef(254, "button", 56, " node254.button56 ")),
        ("node3.button1", ChannelRef(3, "button", 1, "node3.button1")),
    ],
)
def test_channel_ref_parse(name: str, ref: ChannelRef) -> None:
    assert ChannelRef.parse(name) == ref


@pytest.mark.parametrize(
    "name",
    ["node255.x", "node1.wheel", "node1.button0", "node1.button57", "x", "node.x", "node1.", ""],
)
def test_channel_ref_parse_rejects(name: str) -> None:
    assert ChannelRef.parse(name) is None


def test_channel_ref_slot_and_axis() -> None:
    ref = ChannelRef.axis(4, "slider")
    assert ref == ChannelRef(4, "axis", 3, "node4.slider") and ref.slot == "slider"


def test_channels_are_parsed_once_at_load(monkeypatch: pytest.MonkeyPatch) -> None:
    config = load_config_text(
        "outputs:\n"
        "  - protocol: sumd\n"
        "    channels: [node1.rz, node1.button3]\n"
        "devices:\n"
        "  - {match: {vid: 1}, node_id: 1, axes: {rz: {usage: Rz, unsigned: true}},"
        " buttons: {3: 3}}\n",
        "c.yaml",
    )
    (out,) = config.outputs
    assert out.channels == (
        ChannelRef(1, "axis", 6, "node1.rz"),
        ChannelRef(1, "button", 3, "node1.button3"),
    )
    assert [(w.line, w.key) for w in out.channel_wheres] == [
        (3, "outputs[0].channels[0]"),
        (3, "outputs[0].channels[1]"),
    ]

    def no_parsing(name: str) -> None:
        raise AssertionError(f"parsed {name!r} again")

    monkeypatch.setattr(ChannelRef, "parse", no_parsing)
    sources = compile_mapping(config).sumd_channels(out)
    assert [(s.node_id, s.kind, s.index, s.unsigned, s.name) for s in sources] == [
        (1, "axis", 6, True, "node1.rz"),
        (1, "button", 3, False, "node1.button3"),
    ]
    default = compile_mapping(config).sumd_channels(OutputConfig(protocol="sumd"))
    assert [s.name for s in default][:3] == ["node1.x", "node1.y", "node1.z"]


def test_output_config_built_in_code_takes_channel_names() -> None:
    out = OutputConfig(protocol="sumd", channels=("node0.x", "node0.button2"))  # type: ignore[arg-type]
    assert out.channels == (
        ChannelRef(0, "axis", 0, "node0.x"),
        ChannelRef(0, "button", 2, "node0.button2"),
    )
    with pytest.raises(ValueError, match=r"bad SUMD channel name 'node0\.wheel'"):
        OutputConfig(protocol="sumd", channels=("node0.wheel",))  # type: ignore[arg-type]
