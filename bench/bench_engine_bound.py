"""The most a compiled node step and compiled frames could save: the daemon beside itself with
both made free, measured by bench_hot_path.py.

    .venv/bin/python bench/bench_engine_bound.py [--tree .] [--only c2 five] [--rounds 3]
        [--seconds 10] [--together] [--free step frames | --free none] [--phases]

The question it answers: how much of the daemon's CPU is the interpreted work of a tick (the
node step, each output's frames), and how much the rest of the drivers' thread (its loop and
sleeps, the links followed and written, the readers pulled, the replay backend). A compiled
tick engine can remove at most the first part.

It copies the tree's `usb2rc/` into a temporary directory beside a `sitecustomize.py` (below,
BOUND_HOOK) and runs `bench_hot_path.py --trees TREE COPY` with the other arguments. In the
copy, once warmed up (the first WARM_STEPS steps and each session's first WARM_TICKS ticks run
as they are), a node step computes nothing (`NodeTable._step_locked` keeps the last snapshot)
and every session's tick returns its last bytes (`tick` of C2Session, ChannelSession and
MavlinkSession): what a compiled step and compiled frames taking no time at all would leave.
`--free step` or `--free frames` makes only that part free (which of the two a compiled engine
would take first); `--free none` leaves the copy as the tree is. Two more parts, never free by
default, say what a tick's work costs by what it is for: `between`, the steps between
C2-16B's (a batch C2-16B is not in, SUMD's and SBUS's at the 10 ms mark of five outputs,
takes the last batch's snapshot: no pull, no step); `quiet`, the ticks of CRSF and MAVLink
(once a second instead of every 20 ms: in `five` the nodes wait in the guard, CRSF sends
nothing and MAVLink only its heartbeat). `--phases` (one scenario) also
prints what each part of the copy's drivers' thread costs (thread CPU clocks around its loop's
calls, the node table's step and each reader's pull, written by each daemon at its exit; a
driver's parts per protocol); the clocks cost the copy CPU of their own, so its ratio is read
from a run without it.
Everything else runs as it is: the loop, its wake-ups and sleeps, every reader's pull (the
reports are still read and decoded), each link followed, every write. The copy's frames do not
change (C2-16B's rolling code stands still): the far ends here only read and drop them.

The ratio (copy over tree) is the bound: no compiled step and frames can do better on this
host. bench/README.md, "Where issue 40 stands", has the figures.

Both sides run the interpreted hot path (USB2RC_NO_MYPYC=1, in the environment of
bench_hot_path.py and so of every daemon it starts; the copy's hook also sets it in its own
process, whoever starts it): the hook replaces methods of the hot path's classes, which the
classes compiled at install (mypyc, usb2rc.compiled_path) refuse, and the tree beside the copy
runs the same path, so the ratio compares like with like. The C loops (the HID drain, the
steady node step) stay on: the figures are those of the daemon before its mypyc build.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
WARM_STEPS = 100  # node steps as they are, before the step becomes free
WARM_TICKS = 50  # each session's ticks as they are, before its tick becomes free

PARTS = ("step", "frames")
MORE_PARTS = ("between", "quiet")  # never free by default: what a tick's work is for
NOTHING = "none"  # --free none: the copy is the tree as it is (for --phases)
PHASES_ENV = "USB2RC_BOUND_PHASES"  # --phases: the directory the copy's daemons write to
PURE_ENV = "USB2RC_NO_MYPYC"  # usb2rc.compiled_path's: both sides run the interpreted path
INTERPRETED = (
    f"interpreted hot path ({PURE_ENV}=1): both trees' daemons, as the copy's hook needs"
    " (compiled classes refuse its patches), so the ratio compares like with like; the C"
    " loops stay on"
)
BOUND_HOOK = '''"""bench_engine_bound.py's hook: a free step and frames; --phases: parts timed."""

import atexit
import importlib.abc
import importlib.machinery
import json
import os
import sys
import time

# The changes below replace methods of the hot path's classes, which compiled classes refuse:
# this process (and every one it starts) runs the interpreted hot path, as the tree beside it.
os.environ["{pure_env}"] = "1"

WARM_STEPS = {warm_steps}
WARM_TICKS = {warm_ticks}


def _free_step(module):
    real = module.NodeTable._step_locked
    steps = [0]

    def step(self, period, now, due):
        steps[0] += 1
        return real(self, period, now, due) if steps[0] <= WARM_STEPS else []

    module.NodeTable._step_locked = step


def _free_tick(cls):
    real = cls.tick

    def tick(self, now, snapshot):
        ticks = self.__dict__.get("_bound_ticks", 0) + 1
        self._bound_ticks = ticks
        if ticks <= WARM_TICKS:
            self._bound_last = real(self, now, snapshot)
        return self._bound_last

    cls.tick = tick


def _no_step_between(module):
    """A batch C2-16B is not in takes the last batch's snapshot (no pull, no step)."""
    real_batch, real_begin, last = module.DriverThread._begin, module.LineDriver.begin, [None]

    def begin(self, snapshot, step_s=0.0):
        last[0] = snapshot
        return real_begin(self, snapshot, step_s)

    def batch(self, now):
        waiting = [d for d in self.drivers if d._held is None]
        starting = [d for d in waiting if d.next_moment <= now + module.SAME_TICK_S]
        if starting and last[0] is not None:
            due = module._due_with(waiting, [d._deadline for d in starting])
            if not any(type(d.session).__name__ == "C2Session" for d in due):
                for driver in due:
                    driver.begin(last[0], 0.0)
                return
        real_batch(self, now)

    module.LineDriver.begin, module.DriverThread._begin = begin, batch


def _once_a_second(cls):
    cls.next_due = lambda self, due, now: due + 1.0


FREE = {free!r}
PATCHES = {{}}  # module -> what is done to it once imported, in order


def _patch(module_name, change):
    PATCHES.setdefault(module_name, []).append(change)


if "step" in FREE:
    _patch("usb2rc.nodes.table", _free_step)
if "frames" in FREE:
    _patch("usb2rc.protocols.c2_16b.session", lambda m: _free_tick(m.C2Session))
    _patch("usb2rc.lines.session", lambda m: _free_tick(m.ChannelSession))
    _patch("usb2rc.protocols.mavlink.session", lambda m: _free_tick(m.MavlinkSession))
if "between" in FREE:
    _patch("usb2rc.lines.driver", _no_step_between)
if "quiet" in FREE:
    _patch("usb2rc.protocols.crsf.session", lambda m: _once_a_second(m.CrsfSession))
    _patch("usb2rc.protocols.mavlink.session", lambda m: _once_a_second(m.MavlinkSession))


# --phases: each daemon writes the thread CPU of the drivers' thread's parts to this directory
PHASES_DIR = os.environ.get("{phases_env}", "")
_spent = {{}}  # part -> [thread CPU ns, calls]
_began = time.monotonic()


def _timed(cls, name, by_session=False):
    """`cls.name` timed; `by_session`: a driver's method, one part per protocol (its
    session's class in brackets)."""
    real, clock, key = getattr(cls, name), time.thread_time_ns, f"{{cls.__name__}}.{{name}}"

    def timed(self, *args, **kwargs):
        began = clock()
        try:
            return real(self, *args, **kwargs)
        finally:
            part = f"{{key}}[{{type(self.session).__name__}}]" if by_session else key
            spent = _spent.setdefault(part, [0, 0])
            spent[0] += clock() - began
            spent[1] += 1

    setattr(cls, name, timed)


def _time_driver(module):
    for name in ("_begin", "_wait"):
        _timed(module.DriverThread, name)
    for name in ("begin", "_follow_link", "_follow_backpressure", "_send", "finish"):
        _timed(module.LineDriver, name, by_session=True)


def _write_phases():
    record = {{"seconds": time.monotonic() - _began, "parts": _spent}}
    with open(os.path.join(PHASES_DIR, f"{{os.getpid()}}.json"), "w") as out:
        json.dump(record, out)


if PHASES_DIR:
    _patch("usb2rc.lines.driver", _time_driver)
    _patch("usb2rc.hid.reader", lambda m: _timed(m.DeviceReader, "pull"))
    _patch("usb2rc.nodes.table", lambda m: _timed(m.NodeTable, "step_if_due"))
    atexit.register(_write_phases)


class _PatchAfterImport(importlib.abc.MetaPathFinder):
    """Finds a module to change as the finders after it would (usb2rc.compiled_path's, which
    loads the hot path from its source, first among them), and changes it once run."""

    def find_spec(self, name, path, target=None):
        changes = PATCHES.get(name)
        if changes is None:
            return None
        spec = None
        for finder in sys.meta_path[sys.meta_path.index(self) + 1 :]:
            find = getattr(finder, "find_spec", None)
            spec = find(name, path, target) if find is not None else None
            if spec is not None:
                break
        if spec is None or spec.loader is None:
            return spec
        run_module = spec.loader.exec_module

        def exec_module(module):
            run_module(module)
            for change in changes:
                change(module)

        spec.loader.exec_module = exec_module
        return spec


# usb2rc's own finder goes first in sys.meta_path once `import usb2rc` has chosen the path
# (the source, as set above): imported here, so that this finder goes before it.
import usb2rc

sys.meta_path.insert(0, _PatchAfterImport())
'''


def bound_copy(tree: Path, directory: Path, free: tuple[str, ...] = PARTS) -> Path:
    """`tree`'s usb2rc (its built parts too: the hook's USB2RC_NO_MYPYC=1 leaves the mypyc
    modules unused) with the hook beside it, making `free` free."""
    copy = directory / "bound"
    shutil.copytree(tree / "usb2rc", copy / "usb2rc", ignore=shutil.ignore_patterns("__pycache__"))
    hook = BOUND_HOOK.format(
        free=tuple(free),
        warm_steps=WARM_STEPS,
        warm_ticks=WARM_TICKS,
        phases_env=PHASES_ENV,
        pure_env=PURE_ENV,
    )
    (copy / "sitecustomize.py").write_text(hook)
    return copy


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0], epilog=INTERPRETED)
    parser.add_argument("--tree", type=Path, default=ROOT, help="the source tree (this one)")
    parser.add_argument("--only", nargs="+", default=["c2", "five"], help="bench_hot_path's")
    parser.add_argument("--rounds", default="3")
    parser.add_argument("--seconds", default="10")
    parser.add_argument("--together", action="store_true", help="bench_hot_path's --together")
    parser.add_argument(
        "--free",
        nargs="+",
        choices=[*PARTS, *MORE_PARTS, NOTHING],
        default=list(PARTS),
        help=f"what is free (step and frames; {NOTHING}: nothing, the tree's parts timed with"
        " --phases)",
    )
    parser.add_argument(
        "--phases",
        action="store_true",
        help="also the copy's drivers' thread CPU per part (one scenario)",
    )
    args = parser.parse_args()
    if args.phases and len(args.only) != 1:
        parser.error("--phases: one scenario (--only)")
    tree = args.tree.resolve()
    with tempfile.TemporaryDirectory(prefix="usb2rc-bound-") as tmp:
        free_parts = tuple(part for part in args.free if part != NOTHING)
        copy = bound_copy(tree, Path(tmp), free_parts)
        phases = Path(tmp) / "phases"
        phases.mkdir()
        command = [
            sys.executable, str(ROOT / "bench" / "bench_hot_path.py"), "--trees", str(tree),
            str(copy), "--only", *args.only, "--rounds", args.rounds, "--seconds", args.seconds,
        ]  # fmt: skip
        if args.together:
            command.append("--together")
        free = " and ".join(free_parts) or "nothing"
        print(INTERPRETED, flush=True)
        print(f"{tree}: as it is; {copy}: {free} free once warmed up", flush=True)
        env = dict(os.environ)
        env[PURE_ENV] = "1"  # both trees' daemons (and the copy's hook sets it too)
        if args.phases:
            env[PHASES_ENV] = str(phases)
        code = subprocess.run(command, env=env).returncode
        if args.phases:
            print_phases(phases)
        sys.exit(code)


def print_phases(directory: Path) -> None:
    """Each part of the copy's drivers' thread: thread CPU per call and calls a second
    (medians over its daemons, each over its whole run, warm-up included); the parts nest
    (`LineDriver.begin` holds `_follow_link`, `_follow_backpressure` and the free tick)."""
    runs = [json.loads(path.read_text()) for path in sorted(directory.glob("*.json"))]
    runs = [run for run in runs if run["parts"]]  # not the tree's `import usb2rc` checks
    if not runs:
        print("phases: no daemon wrote its parts")
        return
    print(f"\nthe copy's drivers' thread by part ({len(runs)} daemons; medians)")
    print(f"  {'part':34} {'µs a call':>10} {'calls/s':>9} {'% of a core':>12}")
    for part in sorted({part for run in runs for part in run["parts"]}):
        spent = [(run["parts"][part], run["seconds"]) for run in runs if part in run["parts"]]
        per_call = statistics.median(ns / calls / 1e3 for (ns, calls), _ in spent)
        rate = statistics.median(calls / s for (_, calls), s in spent)
        share = statistics.median(ns / s / 1e7 for (ns, _), s in spent)
        print(f"  {part:34} {per_call:10.1f} {rate:9.0f} {share:12.2f}")


if __name__ == "__main__":
    main()
