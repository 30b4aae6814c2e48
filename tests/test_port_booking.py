"""One output per line: `check` and `run` refuse two outputs on one port, whether the file or
`--port` puts them there, and `check --port` shows the ports that will be used. A port
another process holds names that process. Each through the real command line on real ptys.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from cli_harness import usb2rc
from daemon_harness import PtyLine, run_daemon, stats_until, wait_until

ROOT = Path(__file__).resolve().parent.parent
DEMO = ROOT / "usb2rc" / "data" / "demo"
WAIT_S = 60.0  # generous: the machine may be busy


@pytest.fixture
def ptys() -> Iterator[list[str]]:
    """Three pty slaves (real serial lines as far as the daemon knows)."""
    pairs = [os.openpty() for _ in range(3)]
    try:
        yield [os.ttyname(slave) for _, slave in pairs]
    finally:
        for pair in pairs:
            for fd in pair:
                os.close(fd)


def two_outputs(tmp_path: Path, first: str, second: str) -> Path:
    config = tmp_path / "two.yaml"
    config.write_text(
        "outputs:\n"
        f"  - protocol: c2-16b\n    port: {first}\n"
        f"  - protocol: sumd\n    port: {second}\n"
    )
    return config


def check_and_run(*args: str) -> dict[str, subprocess.CompletedProcess[str]]:
    """`check ARGS` and `run ARGS --replay demo`: each must end by itself (a refused config
    opens nothing; a run that started is stopped by the harness's timeout)."""
    return {
        "check": usb2rc("check", *args),
        "run": usb2rc("run", *args, "--replay", str(DEMO)),
    }


def test_port_onto_the_second_outputs_line_is_refused_by_check_and_run(
    tmp_path: Path, ptys: list[str]
) -> None:
    first, second, _ = ptys
    config = two_outputs(tmp_path, first, second)
    results = check_and_run("--config", str(config), "--port", second)
    for command, result in results.items():
        assert result.returncode == 2, (command, result.stdout, result.stderr)
        error = result.stderr.splitlines()[0]
        assert error.startswith(f"--port: {second} would carry two outputs"), (command, error)
        given = f"outputs[0] (c2-16b, {config}:2), to which --port gives it in place of {first}"
        assert given in error
        assert f"outputs[1] (sumd, {config}:4), whose `port:` it is" in error
    verdicts = [r.stderr.splitlines()[0] for r in results.values()]
    assert verdicts[0] == verdicts[1]  # one verdict: one function judges it for both


def test_two_outputs_on_one_port_in_the_file_are_refused(tmp_path: Path, ptys: list[str]) -> None:
    first = ptys[0]
    link = tmp_path / "serial0"
    link.symlink_to(first)  # another name for the same line (as /dev/serial0 is)
    for second, same in ((first, ""), (str(link), f" (both are {first})")):
        config = two_outputs(tmp_path, first, second)
        for command, result in check_and_run("--config", str(config)).items():
            assert result.returncode == 2, (command, result.stderr)
            expected = (
                f"{config}:4: outputs[1].port: {second}{same} would carry two outputs: "
                f"outputs[0] (c2-16b, {config}:2) and outputs[1] (sumd, {config}:4)"
            )
            assert result.stderr.startswith(expected), (command, result.stderr)


def test_check_port_shows_the_ports_that_will_be_used(tmp_path: Path, ptys: list[str]) -> None:
    first, second, given = ptys
    config = two_outputs(tmp_path, first, second)
    text = usb2rc("check", "--config", str(config), "--port", given)
    assert text.returncode == 0, text.stderr
    assert f"  c2-16b  {given} (from --port; the config's {first})  115200 baud" in text.stdout
    assert f"  sumd    {second}  115200 baud" in text.stdout
    assert first not in text.stdout.replace(f"the config's {first}", "")
    document = json.loads(
        usb2rc("check", "--config", str(config), "--port", given, "--json").stdout
    )
    ports = [(o["port"], o["config_port"], o["port_from"]) for o in document["outputs"]]
    assert ports == [(given, first, "--port"), (second, second, "config")]


def test_a_port_another_process_holds_names_it(tmp_path: Path, line: PtyLine) -> None:
    holder_code = (
        "import fcntl, os, sys\n"
        f"fd = os.open({line.path!r}, os.O_RDWR | os.O_NOCTTY)\n"
        "fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)\n"
        "print('locked', flush=True)\n"
        "sys.stdin.read()\n"
    )
    holder = subprocess.Popen(
        [sys.executable, "-c", holder_code],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    daemon = None
    try:
        assert holder.stdout is not None and holder.stdout.readline() == "locked\n"
        replay = tmp_path / "replay"
        replay.mkdir()
        daemon = run_daemon(tmp_path, line.path, replay)
        logged = wait_until(
            lambda: next((s for s in daemon.log().splitlines() if "in use by" in s), None),
            "the log line of the held port",
            WAIT_S,
        )
        assert f"serial port {line.path} is in use by another process" in logged
        assert "[Errno 11]" in logged
        assert f"locked by pid {holder.pid} ({sys.executable} -c import fcntl, os, sys" in logged
        assert "A usb2rc service may be running: `sudo systemctl stop usb2rc`" in logged
        assert logged.endswith("or give this usb2rc another port; retrying every 1 s")
        stats = stats_until(daemon, r"output1-c2-16b \S+: .*", WAIT_S).group(0)
        assert "line losses 0" in stats and "lost 0x" not in stats
    finally:
        if daemon is not None:
            daemon.stop()
        holder.kill()
        holder.communicate()


def test_a_missing_port_s_log_line_has_no_stray_full_stop(tmp_path: Path) -> None:
    replay = tmp_path / "replay"
    replay.mkdir()
    daemon = run_daemon(tmp_path, str(tmp_path / "ttyNONE"), replay)
    try:
        logged = wait_until(
            lambda: next((s for s in daemon.log().splitlines() if "is not there" in s), None),
            "the log line of the missing port",
            WAIT_S,
        )
    finally:
        daemon.stop()
    assert logged.endswith("or give another one with --port; retrying every 1 s"), logged
