"""The most a compiled node step and compiled frames could save: the daemon beside itself with
both made free, measured by bench_hot_path.py.

    .venv/bin/python bench/bench_engine_bound.py [--tree .] [--only c2 five] [--rounds 3]
        [--seconds 10] [--together] [--free step frames]

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
would take first). Everything else runs as it is: the loop, its wake-ups and sleeps, every
reader's pull (the reports are still read and decoded), each link followed, every write. The
copy's frames do not change (C2-16B's rolling code stands still): the far ends here only read
and drop them.

The ratio (copy over tree) is the bound: no compiled step and frames can do better on this
host. bench/README.md, "Where issue 40 stands", has the figures.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
WARM_STEPS = 100  # node steps as they are, before the step becomes free
WARM_TICKS = 50  # each session's ticks as they are, before its tick becomes free

PARTS = ("step", "frames")
BOUND_HOOK = '''"""bench_engine_bound.py's hook: a free node step and free frames, once warm."""

import importlib.abc
import importlib.machinery
import sys

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


FREE = {free!r}
PATCHES = {{}}
if "step" in FREE:
    PATCHES["usb2rc.nodes.table"] = _free_step
if "frames" in FREE:
    PATCHES["usb2rc.protocols.c2_16b.session"] = lambda m: _free_tick(m.C2Session)
    PATCHES["usb2rc.lines.session"] = lambda m: _free_tick(m.ChannelSession)
    PATCHES["usb2rc.protocols.mavlink.session"] = lambda m: _free_tick(m.MavlinkSession)


class _PatchAfterImport(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        patch = PATCHES.get(name)
        if patch is None:
            return None
        spec = importlib.machinery.PathFinder.find_spec(name, path)
        if spec is None or spec.loader is None:
            return spec
        run_module = spec.loader.exec_module

        def exec_module(module):
            run_module(module)
            patch(module)

        spec.loader.exec_module = exec_module
        return spec


sys.meta_path.insert(0, _PatchAfterImport())
'''


def bound_copy(tree: Path, directory: Path, free: tuple[str, ...] = PARTS) -> Path:
    """`tree`'s usb2rc (its built C loops too) with the hook beside it, making `free` free."""
    copy = directory / "bound"
    shutil.copytree(tree / "usb2rc", copy / "usb2rc", ignore=shutil.ignore_patterns("__pycache__"))
    hook = BOUND_HOOK.format(free=tuple(free), warm_steps=WARM_STEPS, warm_ticks=WARM_TICKS)
    (copy / "sitecustomize.py").write_text(hook)
    return copy


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tree", type=Path, default=ROOT, help="the source tree (this one)")
    parser.add_argument("--only", nargs="+", default=["c2", "five"], help="bench_hot_path's")
    parser.add_argument("--rounds", default="3")
    parser.add_argument("--seconds", default="10")
    parser.add_argument("--together", action="store_true", help="bench_hot_path's --together")
    parser.add_argument(
        "--free", nargs="+", choices=PARTS, default=list(PARTS), help="what is free (both)"
    )
    args = parser.parse_args()
    tree = args.tree.resolve()
    with tempfile.TemporaryDirectory(prefix="usb2rc-bound-") as tmp:
        copy = bound_copy(tree, Path(tmp), tuple(args.free))
        command = [
            sys.executable, str(ROOT / "bench" / "bench_hot_path.py"), "--trees", str(tree),
            str(copy), "--only", *args.only, "--rounds", args.rounds, "--seconds", args.seconds,
        ]  # fmt: skip
        if args.together:
            command.append("--together")
        free = " and ".join(args.free)
        print(f"{tree}: as it is; {copy}: its {free} free once warmed up", flush=True)
        sys.exit(subprocess.run(command).returncode)


if __name__ == "__main__":
    main()
