"""The bench scripts run in a tiny configuration and print well-formed output.

Performance is never asserted here (the machine may be busy): only that each script works
and that what it prints is what bench/run parses.
"""

from __future__ import annotations

import importlib
import json
import os
import re
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path
from types import ModuleType

import pytest

from usb2rc.hid import speedups

ROOT = Path(__file__).resolve().parent.parent
BENCH = ROOT / "bench"


def run(*args: str, timeout: float = 60) -> str:
    env = dict(os.environ, PYTHONPATH=str(ROOT), PYTHON=sys.executable)
    proc = subprocess.run(
        [*args], cwd=ROOT, env=env, capture_output=True, text=True, timeout=timeout, check=False
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stdout


def last_json(text: str) -> dict:
    return json.loads(text.strip().splitlines()[-1])


def test_codecs() -> None:
    out = run(sys.executable, "bench/bench_codecs.py", "--runs", "1", "--calls", "50")
    line = r"^(encode_data|Decoder\.feed|encode_sumd|SumdDecoder\.feed)\b.* ([0-9.]+) µs$"
    times = re.findall(line, out, re.MULTILINE)
    assert {name for name, _ in times} == {
        "encode_data",
        "Decoder.feed",
        "encode_sumd",
        "SumdDecoder.feed",
    }


def test_hid_decode() -> None:
    pytest.importorskip("hidtools")
    out = run(sys.executable, "bench/bench_hid_decode.py", "--reports", "20", "--runs", "1")
    result = last_json(out)
    assert result["bench"] == "hid_decode" and result["rows"]
    for row in result["rows"]:
        assert row["usb2rc_feed_state_us"] > 0 and row["hidtools_us"] > 0


def test_hotplug() -> None:
    out = run(sys.executable, "bench/bench_hotplug.py", "--trials", "1")
    assert re.search(r"^plug -> \S+\s+median\s+[0-9.]+ ms\s+max", out, re.MULTILINE)
    assert re.search(r"^unplug -> \S+\s+median\s+[0-9.]+ ms\s+max", out, re.MULTILINE)


def test_hot_paths() -> None:
    out = run(
        sys.executable, "bench/bench_hot_paths.py", "--ticks", "20", "--paced", "4",
        "--runs", "1",
    )  # fmt: skip
    result = last_json(out)
    assert result["bench"] == "hot_paths" and result["nodes"] == 4
    for key in ("tick_hot_us", "tick_paced_us", "collect_paced_us", "session_paced_us",
                "write_paced_us", "reader_pull_hot_us", "reader_pull_paced_us",
                "replay_pull_python_paced_us"):  # fmt: skip
        assert result["figures"][key] > 0, key
    assert re.search(r"^tick_hot_us\s+[0-9.]+ µs$", out, re.MULTILINE)


def test_fd_pull() -> None:
    """A step's pulls of devices read on an fd, through each read path; where the C loops
    are not built it says so."""
    out = run(sys.executable, "bench/bench_fd_pull.py", "--samples", "3")
    result = last_json(out)
    assert result["bench"] == "fd_pull"
    if speedups.compiled() is None:
        assert "the C loops are not built here" in out
        return
    for path in ("c", "python", "hidapi"):
        assert result["figures"][f"{path}_after_sleep_20ms_us"] > 0, path
    line = r"^c +4 pulls, 20 reports each, after a sleep of 20 ms: +[0-9.]+ µs$"
    assert re.search(line, out, re.MULTILINE)


def test_cold() -> None:
    """The same pull after each pause, spun and slept, in Python and (where built) in C;
    a step's pulls with reports due; one call by what it touches, where gcc can build it."""
    out = run(sys.executable, "bench/bench_cold.py", "--samples", "2", "--due", "--touch")
    result = last_json(out)
    assert result["bench"] == "cold"
    for pause in ("spin", "sleep"):
        assert result["figures"][f"python_after_{pause}_10ms_us"] > 0
    assert result["figures"]["due_python_after_sleep_20ms_us"] > 0
    assert re.search(r"^python +pull after a sleep of +20 ms: +[0-9.]+ µs$", out, re.MULTILINE)
    headers = Path(sysconfig.get_paths()["include"]) / "Python.h"
    if shutil.which("gcc") is None or not headers.exists():  # a machine that cannot build it
        assert "--touch: no gcc or no Python headers here: not measured" in out
        return
    for work in ("call", "compact_fields", "object_attrs"):
        assert result["figures"][f"touch_{work}_after_sleep_20ms_us"] > 0
    assert re.search(r"^object_attrs +after a sleep of +20 ms: +[0-9.]+ µs$", out, re.MULTILINE)


def test_tick_budget() -> None:
    """Every protocol's tick, the C2-16B codec alone, their allocations, the readers."""
    out = run(
        sys.executable, "bench/bench_tick_budget.py", "--ticks", "20", "--runs", "1",
        "--devices", "2", "--seconds", "0.5",
    )  # fmt: skip
    result = last_json(out)
    assert result["bench"] == "tick_budget"
    figures = result["figures"]
    cases = ("c2_4_nodes", "sumd_16", "crsf_16", "sbus_16", "ibus_14", "mavlink_override",
             "c2_encode_data_4")  # fmt: skip
    for case in cases:
        for figure in ("tick_us", "alloc_peak_b", "retained_b"):
            assert isinstance(figures[f"{figure}_{case}"], float | int), (figure, case)
    assert figures["reader_devices"] == 2
    for key in ("reader_pulls_per_s", "reader_reports_per_s", "reader_us_per_pull"):
        assert isinstance(figures[key], float), key
    assert re.search(r"^tick_us_c2_4_nodes\s+[0-9.]+ µs$", out, re.MULTILINE)


def test_plug_cost() -> None:
    out = run(
        sys.executable, "bench/bench_plug_cost.py", "--devices", "2", "--seconds", "0.2",
    )  # fmt: skip
    result = last_json(out)
    assert result["bench"] == "plug_cost"
    figures = result["figures"]
    for kind in ("first", "replug"):
        for step in ("scan", "lifecycle"):
            assert figures[f"plug_{kind}_{step}_cpu_ms_median"] > 0
        assert figures[f"plug_{kind}_gc_collections"] >= 0
    assert figures["plug_lifecycle_longest_c_call"]
    assert figures["replay_first_lap_us_per_report"] > 0
    assert re.search(r"^plug_first_scan_cpu_ms_median\s+[0-9.]+$", out, re.MULTILINE)


@pytest.mark.slow  # a long journey: the fast suite keeps shorter ones of its kind
def test_daemon(tmp_path: Path) -> None:
    json_path = tmp_path / "daemon.json"
    out = run(
        sys.executable, "bench/bench_daemon.py", "--seconds", "2", "--cpu-seconds", "1",
        "--warmup", "0.3", "--starts", "1", "--plug-seconds", "1", "--plug-rounds", "1",
        "--crsf-seconds", "1", "--json", str(json_path), timeout=300,
    )  # fmt: skip
    result = last_json(out)
    assert result == json.loads(json_path.read_text())
    figures = result["figures"]
    for key in (
        "period_p99_error_ms",
        "period_mean_ms",
        "latency_mean_ms",
        "latency_max_ms",
        "cpu_pct",
        "cpu_replay_pct",
        "cpu_without_replay_pct",
        "rss_mb",
        "reports_per_s_min",
        "start_first_frame_s",
        "stop_s_max",
        "plug_quiet_max_interval_ms",
        "plug_live_max_interval_ms",
        "plug_live_excess_ms",
        "cpu_real_pct",
        "cpu_real_replay_pct",
        "cpu_idle_pct",
        "rss_real_mb",
        "crsf500_p99_error_ms",
        "crsf500_c2_p99_error_ms",
    ):
        assert isinstance(figures[key], float | int), key
    assert figures["real_devices"] == 4  # the four real descriptors, each read
    assert 15 < figures["period_mean_ms"] < 25
    assert figures["latency_reports"] > 10
    assert figures["devices"] == 4
    assert figures["plug_devices"] == 5
    assert figures["crsf500_ticks"] > 0
    assert "p99 |period - 20 ms|" in out


def test_daemon_cpu_with_every_extra_output(tmp_path: Path) -> None:
    """--extra-outputs takes every protocol, MAVLink on UDP to a local socket included."""
    out = run(
        sys.executable, "bench/bench_daemon.py", "--only", "cpu", "--cpu-seconds", "1",
        "--warmup", "0.3", "--extra-outputs", "sumd", "crsf", "sbus", "mavlink",
    )  # fmt: skip
    result = last_json(out)
    assert "outputs c2-16b + sumd + crsf + sbus + mavlink" in out
    assert result["figures"]["extra_outputs_bytes"] > 0
    assert isinstance(result["figures"]["cpu_pct"], float)


@pytest.mark.slow  # bench_umockdev waits 5 s for frames, too short beside two CPU hogs
def test_umockdev() -> None:
    """Figures on the real hidapi path, or (no umockdev here) why not; never a crash."""
    from umockdev_harness import require_umockdev

    require_umockdev()  # skips with a reason, or fails under CI
    out = run(sys.executable, "bench/bench_umockdev.py", "--reports", "15")
    result = last_json(out)
    assert result["bench"] == "umockdev" and "skipped" not in result
    figures = result["figures"]
    # On a loaded machine two reports can land in one tick: the first is never carried by a
    # frame (unmatched). A smoke test needs well-formed figures, not a quiet machine.
    matched, unmatched = figures["umockdev_latency_reports"], figures["umockdev_latency_unmatched"]
    assert matched >= 1 and matched + unmatched == 15
    assert 0 < figures["umockdev_latency_mean_ms"] <= figures["umockdev_latency_max_ms"]
    assert re.search(r"^report -> frame \(real hidapi, umockdev\)\s+mean [0-9.]+ ms", out, re.M)


def test_run_show_and_compare(tmp_path: Path) -> None:
    """bench/run: a quick run of the fast scripts, then --show with --compare."""
    out_path = tmp_path / "latest.json"
    run(str(BENCH / "run"), "--quick", "--only", "codecs", "hotplug", "tick_budget", "--out",
        str(out_path), timeout=120)  # fmt: skip
    result = json.loads(out_path.read_text())
    assert result["runs"] == 1 and "encode_c2_us" in result["figures"]
    assert "tick_us_crsf_16" in result["figures"]
    assert "hotplug_plug_ms" in result["figures"]
    baseline = json.loads(json.dumps(result))
    baseline["figures"]["encode_c2_us"] *= 2
    (tmp_path / "base.json").write_text(json.dumps(baseline))
    shown = run(
        str(BENCH / "run"), "--show", str(out_path), "--compare", str(tmp_path / "base.json")
    )
    line = next(ln for ln in shown.splitlines() if ln.startswith("encode_data"))
    assert "-50.0" in line
    assert any(ln.startswith("tick CRSF, 16 ch") for ln in shown.splitlines())


def test_baseline_is_well_formed() -> None:
    baseline = json.loads((BENCH / "baseline.json").read_text())
    assert baseline["runs"] >= 1 and baseline["machine"]["cores"]
    for key in ("period_p99_error_ms", "latency_mean_ms", "cpu_pct", "decode_us_median"):
        assert key in baseline["figures"], key


def test_live_recordings_rest_where_each_guard_wants() -> None:
    """bench_hot_path.py --live: each device's first reports satisfy its zero-config neutral
    guard (so its node goes live), and the random ones come after."""
    from daemon_harness import _real_devices, _rest_reports

    from usb2rc.hid.descriptor import parse_descriptor
    from usb2rc.nodes import known_devices
    from usb2rc.nodes.binding import default_binding

    checked = 0
    for device in _real_devices():
        layout = parse_descriptor(bytes.fromhex(device["hex"]))
        if not layout.inputs:
            continue
        known = known_devices.lookup(int(device["vid"], 16), int(device["pid"], 16))
        binding = default_binding(layout, device["name"], known=known)
        decoder = layout.make_decoder()
        for report in _rest_reports(device).values():
            assert decoder.feed(report)
        state = decoder.state()
        assert binding.guard.waiting_for(binding.apply(state).axes) == [], device["name"]
        assert state.buttons == 0
        checked += bool(binding.guard.axes)
    assert checked >= 8  # most real devices guard some axis


def test_hot_path_trees_together(tmp_path: Path) -> None:
    """bench_hot_path.py --together: two trees' daemons at once, one window each round, a
    figure per tree and the ratio (here two copies of this tree, C2-16B with no device)."""
    trees = [tmp_path / "a", tmp_path / "b"]
    for tree in trees:
        shutil.copytree(
            ROOT / "usb2rc", tree / "usb2rc", ignore=shutil.ignore_patterns("__pycache__")
        )
    out = run(
        sys.executable, "bench/bench_hot_path.py", "--trees", *map(str, trees),
        "--rounds", "1", "--seconds", "1", "--only", "idle", "--together",
        timeout=180,
    )  # fmt: skip
    result = last_json(out)
    assert result["together"] is True and set(result["trees"]) == set(map(str, trees))
    idle = result["scenarios"]["idle"]
    for tree in trees:
        (figures,) = idle["trees"][str(tree)]["rounds"]
        assert figures["cpu_pct"] > 0 and figures["rss_mb"] > 0
    assert idle["ratio_last_first"]["cpu_pct"] is not None


def test_floor() -> None:
    """Both loops tick and write: wake-ups at the five outputs' moments, CPU measured."""
    out = run(sys.executable, "bench/bench_floor.py", "--rounds", "1", "--seconds", "1")
    medians = last_json(out)["medians"]
    assert set(medians) == ({"python", "c"} if shutil.which("gcc") else {"python"})
    for figures in medians.values():
        # 300 starts and 300 writes a second (fewer on a busy host: late ticks are skipped)
        assert 100 < figures["wakes_per_s"] < 1000 and figures["cpu_pct"] > 0


def engine_bound() -> ModuleType:
    """bench/bench_engine_bound.py as a module (the benches are scripts, not a package)."""
    sys.path.insert(0, str(BENCH))
    try:
        return importlib.import_module("bench_engine_bound")
    finally:
        sys.path.remove(str(BENCH))


def python_in(copy: Path, code: str, **env: str) -> str:
    """`code` run by this interpreter with `copy` first on its path (its sitecustomize)."""
    environ = dict(os.environ, PYTHONPATH=str(copy), **env)
    proc = subprocess.run(
        [sys.executable, "-c", code], cwd=copy, env=environ, capture_output=True, text=True
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stdout


@pytest.mark.parametrize("free", [("step", "frames"), ("step",), ("frames",), ()])
def test_engine_bound_copy_makes_what_it_is_asked_free(
    tmp_path: Path, free: tuple[str, ...]
) -> None:
    """The bound's copy imports its own usb2rc with the hook in place: the step and each
    session's tick are the hook's when asked for, the tree's own otherwise (a copy without
    the hook would measure the tree twice)."""
    copy = engine_bound().bound_copy(ROOT, tmp_path, free)
    probe = (
        "import usb2rc, usb2rc.nodes.table as t, usb2rc.lines.session as s, "
        "usb2rc.protocols.c2_16b.session as c, usb2rc.protocols.mavlink.session as m; "
        "print(usb2rc.__file__); print(t.NodeTable._step_locked.__qualname__); "
        "print(*(k.tick.__qualname__ for k in (s.ChannelSession, c.C2Session, m.MavlinkSession)))"
    )
    where, step, ticks = python_in(copy, probe).splitlines()
    assert Path(where).is_relative_to(copy)
    free_step, free_tick = "_free_step.<locals>.step", "_free_tick.<locals>.tick"
    assert (step == free_step) == ("step" in free)
    own_ticks = ["ChannelSession.tick", "C2Session.tick", "MavlinkSession.tick"]
    assert ticks.split() == ([free_tick] * 3 if "frames" in free else own_ticks)


@pytest.mark.parametrize("free", [("between", "quiet"), ()])
def test_engine_bound_copy_takes_the_steps_between_and_the_quiet_ticks_away(
    tmp_path: Path, free: tuple[str, ...]
) -> None:
    copy = engine_bound().bound_copy(ROOT, tmp_path, free)
    probe = (
        "import usb2rc.lines.driver as d, usb2rc.protocols.crsf.session as c, "
        "usb2rc.protocols.mavlink.session as m; print(d.DriverThread._begin.__qualname__); "
        "print(c.CrsfSession.next_due.__qualname__, m.MavlinkSession.next_due.__qualname__)"
    )
    batch, quiet = python_in(copy, probe).splitlines()
    assert (batch == "_no_step_between.<locals>.batch") == ("between" in free)
    once = "_once_a_second.<locals>.<lambda>"
    assert quiet.split() == [once, once] if "quiet" in free else once not in quiet


def test_engine_bound_runs_the_hot_path_bench() -> None:
    out = run(
        sys.executable, "bench/bench_engine_bound.py", "--only", "idle", "--rounds", "1",
        "--seconds", "1", "--together", timeout=180,
    )  # fmt: skip
    idle = last_json(out)["scenarios"]["idle"]
    assert len(idle["trees"]) == 2 and idle["ratio_last_first"]["cpu_pct"] is not None


def test_engine_bound_phases_are_written_at_exit(tmp_path: Path) -> None:
    """With the phases' directory set, the copy's drivers' thread and readers are timed and
    each process writes what its parts cost when it exits."""
    bench = engine_bound()
    copy = bench.bound_copy(ROOT, tmp_path / "tree", ("step",))
    phases = tmp_path / "phases"
    phases.mkdir()
    probe = (
        "import usb2rc.lines.driver as d, usb2rc.hid.reader as r, usb2rc.nodes.table as t; "
        "print(d.LineDriver._send.__qualname__, r.DeviceReader.pull.__qualname__, "
        "t.NodeTable.step_if_due.__qualname__, t.NodeTable._step_locked.__qualname__)"
    )
    out = python_in(copy, probe, **{bench.PHASES_ENV: str(phases)})
    # the table's step timed, and its `_step_locked` still the free one: both changes made
    assert out.split() == ["_timed.<locals>.timed"] * 3 + ["_free_step.<locals>.step"]
    (written,) = phases.glob("*.json")
    record = json.loads(written.read_text())
    assert record["parts"] == {} and record["seconds"] > 0
