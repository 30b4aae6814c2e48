"""The daemon's CPU cost on its hot path, several source trees in turn in one run.

    .venv/bin/python bench/bench_hot_path.py --trees /tmp/base . [--rounds 3] [--seconds 10]
        [--only c2 five five-live five16 idle] [--live] [--together] [--json PATH]

Each tree runs its own code: `python -m usb2rc run --replay DIR --config CFG --status-socket
off --log-level info` with that tree as cwd and PYTHONPATH (this interpreter). For each round,
for each scenario, the trees run one after the other (A, B, A, B ...), so drift of a busy host
hits every tree alike. The recordings are written once per run and shared by every tree:
real descriptors (tests/daemon_harness.py) with random reports at 1 kHz each; there are 12
of them, so 16 devices are those and the first four again.

- c2: 4 devices, C2-16B on a pty.
- five: 4 devices, C2-16B, SUMD, CRSF and SBUS on ptys, MAVLink `udpout:` to a local UDP
  socket, each at its default rate.
- five-live: the five outputs, every node live (as `--live` below): the state a pilot
  flies in, where every output sends (in `five`, every node waits in the neutral guard).
- five16: the five outputs with 16 devices.
- idle: C2-16B on a pty, no device.

With `--together` every tree's daemon runs at once and one window measures them all: on a
host whose speed drifts by a third within minutes (this VM), the trees in turn each meet
another host, while daemons side by side meet the same one. Two copies of one tree, four
rounds of 10 s: ratios 0.96-1.05 this way, where one tree in turn with another ranged from
5.6 to 11.6 % of a core within half an hour. The figures
are not those of a daemon alone (they share the CPUs and caches): use it for the ratio of
a change, and the trees in turn for the issue's figures.

With `--live` (every scenario; `five-live` always) every device rests for its first second
(its guarded axes where its guard wants them) and its node goes live before the window: the
frames carry the values, CRSF and MAVLink send (random reports never rest, so without it
every node waits in the neutral guard, CRSF is silent and MAVLink releases its overrides).

The far ends (pty masters, the UDP socket) are read and dropped by a thread here. Once the
daemon logs its first frame, and after a warm-up, a window of --seconds is measured from
outside: the CPU of all its threads (sum of /proc/PID/task/*/schedstat, ns resolution: idle
costs a few tenths of a percent), their voluntary context switches (wake-ups) and VmRSS at
the end. A SIGUSR1 stats dump at each end of the window gives the replay backend's own
`backend busy` time per device (its share of the CPU figure; 0 for a tree that prints none),
the reports consumed, and the late and missed ticks summed over the outputs.

Prints, per scenario, each tree's median over the rounds with the rounds' values, and the
ratio of the last tree's median to the first's; then one JSON line ({"bench": "hot_path",
...}), also written to --json PATH.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Sequence
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

from bench_daemon import STATS_BUSY_RE, STATS_DEV_RE, STATS_OUT_RE, OutputDrain  # noqa: E402
from daemon_harness import live_device_recordings, real_device_recordings  # noqa: E402

FIVE = ("c2-16b", "sumd", "crsf", "sbus", "mavlink")
CHANNELS = "[node0.x, node0.y, node1.x, node2.x]"  # the four outputs other than C2-16B
REPORT_HZ = 1000.0
RECORDING_S = 90.0  # at least: the replay must not run out before the window ends
WARMUP_S = 3.0
START_TIMEOUT_S = 60.0  # generous: other engineers load this host
STATS_TIMEOUT_S = 20.0
STOP_TIMEOUT_S = 10.0


@dataclass(frozen=True)
class Scenario:
    devices: int
    protocols: tuple[str, ...]
    live: bool = False  # every node live (devices rest first), whatever --live says


SCENARIOS = {
    "c2": Scenario(4, ("c2-16b",)),
    "five": Scenario(4, FIVE),
    "five-live": Scenario(4, FIVE, live=True),
    "five16": Scenario(16, FIVE),
    "idle": Scenario(0, ("c2-16b",)),
}

# figure: (label, digits); ratios are the last tree's median over the first's
FIGURES = {
    "cpu_pct": ("CPU, % of a core", 2),
    "replay_pct": ("  of which the replay backend", 2),
    "cpu_without_replay_pct": ("  without the replay backend", 2),
    "wakes_per_s": ("wake-ups/s (voluntary switches)", 0),
    "rss_mb": ("VmRSS, MB", 1),
    "reports_per_s": ("reports/s consumed, all devices", 0),
    "late_ticks": ("late ticks, all outputs", 0),
    "missed_ticks": ("missed ticks, all outputs", 0),
}


# --- the daemon of one tree -------------------------------------------------------------------


def tree_env(tree: Path) -> dict[str, str]:
    return dict(os.environ, PYTHONPATH=str(tree), PYTHONUNBUFFERED="1")


def tree_revision(tree: Path) -> str:
    """The tree's git revision. ValueError if the tree's own usb2rc is not what its daemon
    would import (a wrong path would measure the venv's install twice)."""
    found = subprocess.run(
        [sys.executable, "-c", "import usb2rc; print(usb2rc.__file__)"],
        cwd=tree, env=tree_env(tree), capture_output=True, text=True,
    )  # fmt: skip
    if found.returncode != 0 or not Path(found.stdout.strip()).resolve().is_relative_to(tree):
        seen = (found.stdout.strip() + found.stderr.strip()[-300:]) or "nothing"
        raise ValueError(f"{tree} has no usb2rc of its own to run (it imports {seen})")
    git = ["git", "-C", str(tree), "describe", "--always", "--dirty"]
    return subprocess.run(git, capture_output=True, text=True).stdout.strip() or "?"


@dataclass
class Stats:
    """One SIGUSR1 dump: when it was asked for, and its counters."""

    at: float
    late_missed: dict[str, tuple[int, int]]  # output -> late, missed ticks
    reports: dict[str, int]  # device port -> reports read
    busy_s: dict[str, float]  # device port -> the replay backend's own time


class DaemonRun:
    """A running `usb2rc run` of one tree; its log (stdout and stderr) in a file."""

    def __init__(self, tree: Path, replay_dir: Path, config: Path, log_path: Path) -> None:
        self.log_path = log_path
        with open(log_path, "wb") as log:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "usb2rc", "run", "--replay", str(replay_dir),
                 "--config", str(config), "--status-socket", "off", "--log-level", "info"],
                stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                cwd=tree, env=tree_env(tree),
            )  # fmt: skip

    def log_lines(self) -> list[str]:
        """The complete lines logged so far."""
        text = self.log_path.read_text(errors="replace")
        return text[: text.rfind("\n") + 1].splitlines()

    def failure(self, what: str) -> RuntimeError:
        tail = "\n".join(self.log_lines()[-20:])
        return RuntimeError(f"{what} (daemon pid {self.proc.pid}); its log ends:\n{tail}")

    def wait_for_log(self, text: str, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while not any(text in line for line in self.log_lines()):
            if self.proc.poll() is not None:
                raise self.failure(f"the daemon exited {self.proc.returncode}")
            if time.monotonic() > deadline:
                raise self.failure(f"no {text!r} after {timeout:g} s")
            time.sleep(0.05)

    def stats(self, outputs: int, devices: int) -> Stats:
        """SIGUSR1, then wait for the dump's line of every output and device."""
        before = sum(1 for line in self.log_lines() if "stats: " in line)
        at = time.monotonic()
        self.proc.send_signal(signal.SIGUSR1)
        deadline = at + STATS_TIMEOUT_S
        while True:
            lines = [line for line in self.log_lines() if "stats: " in line][before:]
            out = [m for line in lines if (m := STATS_OUT_RE.search(line))]
            dev = [m for line in lines if (m := STATS_DEV_RE.search(line))]
            if len(out) >= outputs and len(dev) >= devices:
                break
            if time.monotonic() > deadline:
                raise self.failure(f"{len(out)}/{outputs} output and {len(dev)}/{devices} "
                                   "device stats lines after SIGUSR1")  # fmt: skip
            time.sleep(0.05)
        busy = [m for line in lines if (m := STATS_BUSY_RE.search(line))]
        return Stats(
            at=at,
            late_missed={m[1]: (int(m[4]), int(m[5])) for m in out},
            reports={m[1]: int(m[2]) for m in dev},
            busy_s={m[1]: float(m[2]) / 1000 for m in busy},
        )

    def stop(self) -> None:
        """SIGTERM, then SIGKILL if it has not exited in time."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        try:
            self.proc.wait(STOP_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()


@contextmanager
def daemon_running(tree: Path, replay_dir: Path, config: Path, log: Path) -> Iterator[DaemonRun]:
    daemon = None
    try:
        daemon = DaemonRun(tree, replay_dir, config, log)
        yield daemon
    finally:
        if daemon is not None:
            daemon.stop()


def threads_now(pid: int) -> dict[str, tuple[int, int]]:
    """Each thread's CPU time (ns) and voluntary context switches so far."""
    now = {}
    for tid in os.listdir(f"/proc/{pid}/task"):
        try:
            cpu_ns = int(Path(f"/proc/{pid}/task/{tid}/schedstat").read_text().split()[0])
            status = Path(f"/proc/{pid}/task/{tid}/status").read_text()
        except (FileNotFoundError, ProcessLookupError):  # the thread has just exited
            continue
        switches = next(ln for ln in status.splitlines() if ln.startswith("voluntary_ctxt"))
        now[tid] = (cpu_ns, int(switches.split()[1]))
    return now


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise RuntimeError(f"no VmRSS for pid {pid}")


# --- one measured run ------------------------------------------------------------------------


def config_text(protocols: Sequence[str], ports: Sequence[str]) -> str:
    lines = ["outputs:"]
    for protocol, port in zip(protocols, ports, strict=True):
        channels = "" if protocol == "c2-16b" else f", channels: {CHANNELS}"
        lines.append(f"  - {{protocol: {protocol}, port: '{port}'{channels}}}")
    return "\n".join(lines) + "\n"


@contextmanager
def warmed_up(
    tree: Path, scenario: Scenario, replay_dir: Path, workdir: Path, live: bool, tag: str = ""
) -> Iterator[DaemonRun]:
    """The tree's daemon started, its far ends drained, its first frame written (`live`:
    every node live); stopped after, and its exit checked."""
    drain = OutputDrain(scenario.protocols)
    try:
        config = workdir / f"config{tag}.yaml"
        config.write_text(config_text(scenario.protocols, drain.ports))
        with daemon_running(tree, replay_dir, config, workdir / f"daemon{tag}.log") as daemon:
            daemon.wait_for_log("first frame written", START_TIMEOUT_S)
            for node in range(scenario.devices if live else 0):  # one node per device
                daemon.wait_for_log(f"node {node} leaves failsafe", START_TIMEOUT_S)
            yield daemon
        if daemon.proc.returncode != 0:
            raise daemon.failure(f"SIGTERM: the daemon exited {daemon.proc.returncode}")
    finally:
        drain.close()


def window(
    daemons: Sequence[DaemonRun], scenario: Scenario, seconds: float
) -> list[dict[str, float]]:
    """After the warm-up, one window of `seconds` measured on every daemon at once."""
    outputs, devices = len(scenario.protocols), scenario.devices
    time.sleep(WARMUP_S)
    s0 = [daemon.stats(outputs, devices) for daemon in daemons]
    a, t0 = [threads_now(daemon.proc.pid) for daemon in daemons], time.monotonic()
    time.sleep(seconds)
    b, t1 = [threads_now(daemon.proc.pid) for daemon in daemons], time.monotonic()
    rss = [rss_mb(daemon.proc.pid) for daemon in daemons]
    s1 = [daemon.stats(outputs, devices) for daemon in daemons]
    return [figures(*each, t1 - t0) for each in zip(a, b, s0, s1, rss, strict=True)]


def figures(
    a: dict[str, tuple[int, int]],
    b: dict[str, tuple[int, int]],
    s0: Stats,
    s1: Stats,
    rss: float,
    dt: float,
) -> dict[str, float]:
    """One daemon's figures over a window: threads (CPU ns, wake-ups) and stats dumps at
    each end of it, its RSS at the end."""
    if set(a) - set(b):  # its CPU in the window is lost: say so rather than under-count quietly
        print(f"  note: {len(set(a) - set(b))} thread(s) exited in the window", file=sys.stderr)
    stats_dt = s1.at - s0.at
    cpu_s = sum(ns - a.get(tid, (0, 0))[0] for tid, (ns, _) in b.items()) / 1e9
    wakes = sum(n - a.get(tid, (0, 0))[1] for tid, (_, n) in b.items())
    busy_s = sum(s - s0.busy_s.get(port, 0.0) for port, s in s1.busy_s.items())
    reports = sum(n - s0.reports.get(port, 0) for port, n in s1.reports.items())
    before = {k: s0.late_missed.get(k, (0, 0)) for k in s1.late_missed}
    late = sum(n - before[k][0] for k, (n, _) in s1.late_missed.items())
    missed = sum(n - before[k][1] for k, (_, n) in s1.late_missed.items())
    cpu_pct, replay_pct = cpu_s / dt * 100, busy_s / stats_dt * 100
    return {
        "cpu_pct": cpu_pct,
        "replay_pct": replay_pct,
        "cpu_without_replay_pct": cpu_pct - replay_pct,
        "wakes_per_s": wakes / dt,
        "rss_mb": rss,
        "reports_per_s": reports / stats_dt,
        "late_ticks": late,
        "missed_ticks": missed,
    }


def measure(
    tree: Path, scenario: Scenario, replay_dir: Path, seconds: float, workdir: Path, live: bool
) -> dict[str, float]:
    """The tree's daemon alone: started, warmed up, one window measured, stopped."""
    with warmed_up(tree, scenario, replay_dir, workdir, live) as daemon:
        return window([daemon], scenario, seconds)[0]


def measure_together(
    trees: Sequence[Path],
    scenario: Scenario,
    replay_dir: Path,
    seconds: float,
    workdir: Path,
    live: bool,
) -> list[dict[str, float]]:
    """Every tree's daemon at once, one window over all of them (`--together`): a host
    whose speed drifts within minutes slows them alike, so their ratio holds where the
    trees in turn each meet another host. Each daemon has less of the machine to itself
    (its caches, a CPU), so the absolute figures are not those of one alone."""
    with ExitStack() as stack:
        daemons = [
            stack.enter_context(warmed_up(tree, scenario, replay_dir, workdir, live, f"-{i}"))
            for i, tree in enumerate(trees)
        ]
        return window(daemons, scenario, seconds)


def write_recordings(workdir: Path, devices: int, seconds: float, live: bool) -> Path:
    """`devices` recordings in a directory of their own. There are fewer real descriptors
    than 16 (12 with inputs, the T.16000M aside): past them, the first ones again. `live`:
    each rests first, so its node goes live (daemon_harness.live_device_recordings)."""
    replay_dir = workdir / f"replay{devices}{'-live' if live else ''}"
    replay_dir.mkdir()
    recordings = live_device_recordings if live else real_device_recordings
    texts = recordings(devices, seconds, REPORT_HZ) if devices else []
    for i in range(devices):  # (a count of 0 would have got every descriptor)
        (replay_dir / f"dev{i}.hid").write_text(texts[i % len(texts)])
    return replay_dir


# --- the report ------------------------------------------------------------------------------


def median_figures(rounds: list[dict[str, float]]) -> dict[str, float]:
    return {key: statistics.median(r[key] for r in rounds) for key in rounds[0]}


def ratio(b: float, a: float) -> float | None:
    return b / a if a else None


def print_scenario(name: str, results: dict[str, list[dict[str, float]]]) -> None:
    scenario = SCENARIOS[name]
    devices = f"{scenario.devices} devices x {REPORT_HZ:g} Hz" if scenario.devices else "no device"
    nodes = ", every node live" if scenario.live else ""
    print(f"\n{name}: {devices}, {' + '.join(scenario.protocols)}{nodes}")
    trees = list(results)
    medians = {tree: median_figures(results[tree]) for tree in trees}
    print(f"  {'figure':34}" + "".join(f" {tree[-28:]:>30}" for tree in trees) + "   last/first")
    for key, (label, digits) in FIGURES.items():
        cells = []
        for tree in trees:
            values = " ".join(f"{r[key]:.{digits}f}" for r in results[tree])
            cells.append(f" {f'{medians[tree][key]:.{digits}f} ({values})':>30}")
        r = ratio(medians[trees[-1]][key], medians[trees[0]][key])
        print(f"  {label:34}" + "".join(cells) + ("   -" if r is None else f"   x{r:.2f}"))


def rounded(figures: dict[str, float]) -> dict[str, float]:
    return {key: round(value, 4) for key, value in figures.items()}


def scenario_json(results: dict[str, list[dict[str, float]]]) -> dict[str, Any]:
    """Each tree's medians and rounds, and the last tree's medians over the first's."""
    medians = {tree: median_figures(rounds) for tree, rounds in results.items()}
    first, last = medians[next(iter(medians))], medians[list(medians)[-1]]
    ratios = {key: ratio(last[key], first[key]) for key in FIGURES}
    return {
        "trees": {
            tree: {"median": rounded(medians[tree]), "rounds": [rounded(r) for r in rounds]}
            for tree, rounds in results.items()
        },
        "ratio_last_first": {key: None if r is None else round(r, 4) for key, r in ratios.items()},
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--trees", nargs="+", type=Path, required=True, help="source trees; ratios: last/first"
    )
    parser.add_argument("--rounds", type=int, default=3, help="rounds (3)")
    parser.add_argument("--seconds", type=float, default=10.0, help="measured window (10 s)")
    parser.add_argument("--only", nargs="+", choices=SCENARIOS, default=list(SCENARIOS))
    parser.add_argument("--json", metavar="PATH", help="also write the JSON line here")
    parser.add_argument(
        "--live", action="store_true", help="devices rest first: every node live (flight)"
    )
    parser.add_argument(
        "--together",
        action="store_true",
        help="every tree's daemon at once, one window (an A/B on a host that drifts)",
    )
    args = parser.parse_args()
    if args.rounds < 1 or args.seconds <= 0:
        parser.error("--rounds must be >= 1 and --seconds > 0")
    trees = [tree.resolve() for tree in args.trees]
    if len(set(trees)) != len(trees):
        parser.error("--trees: each tree once")
    try:
        revisions = {str(tree): tree_revision(tree) for tree in trees}
    except ValueError as exc:
        parser.error(str(exc))
    results: dict[str, dict[str, list[dict[str, float]]]] = {
        name: {str(tree): [] for tree in trees} for name in args.only
    }
    with tempfile.TemporaryDirectory(prefix="usb2rc-hot-path-") as tmp:
        workdir = Path(tmp)
        recording_s = max(RECORDING_S, args.seconds + 60.0)
        live_of = {name: args.live or SCENARIOS[name].live for name in args.only}
        replay_dirs = {
            (n, live): write_recordings(workdir, n, recording_s, live)
            for n, live in sorted({(SCENARIOS[name].devices, live_of[name]) for name in args.only})
        }
        for round_no in range(1, args.rounds + 1):
            for name in args.only:
                scenario, live = SCENARIOS[name], live_of[name]
                replay_dir = replay_dirs[scenario.devices, live]
                if args.together:  # every other round started in the reverse order
                    order = trees if round_no % 2 else trees[::-1]
                    measured = measure_together(
                        order, scenario, replay_dir, args.seconds, workdir, live
                    )
                    runs = list(zip(order, measured, strict=True))
                else:
                    runs = [
                        (tree, measure(tree, scenario, replay_dir, args.seconds, workdir, live))
                        for tree in trees
                    ]
                for tree, figures_of_tree in runs:
                    results[name][str(tree)].append(figures_of_tree)
                    print(f"round {round_no}/{args.rounds} {name} {tree}: "
                          f"{json.dumps(rounded(figures_of_tree))}", file=sys.stderr)  # fmt: skip
    print(
        f"hot path bench: {args.rounds} round(s), window {args.seconds:g} s after "
        f"{WARMUP_S:g} s warm-up, {'live nodes' if args.live else 'random reports'}"
        f"{' (five-live: live nodes)' if 'five-live' in args.only and not args.live else ''}, "
        f"{'the trees at once' if args.together else 'the trees in turn'}, "
        f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} "
        "cores; per tree: median (each round)"
    )
    for tree, revision in revisions.items():
        print(f"  {tree}: {revision}")
    for name, by_tree in results.items():
        print_scenario(name, by_tree)
    scenarios = {
        name: {"live": args.live or SCENARIOS[name].live, **scenario_json(by_tree)}
        for name, by_tree in results.items()
    }
    result = {
        "bench": "hot_path",
        "trees": revisions,
        "rounds": args.rounds,
        "seconds": args.seconds,
        "warmup_s": WARMUP_S,
        "live": args.live,
        "together": args.together,
        "loadavg": round(os.getloadavg()[0], 2),
        "scenarios": scenarios,
    }
    print(json.dumps(result))
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
