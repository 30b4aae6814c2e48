"""The most a compiled node step and compiled frames could save: the daemon beside itself with
both made free, measured by bench_hot_path.py.

    .venv/bin/python bench/bench_engine_bound.py [--tree .] [--only c2 five] [--rounds 3]
        [--seconds 10] [--together]

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
Everything else runs as it is: the loop, its wake-ups and sleeps, every reader's pull (the
reports are still read and decoded), each link followed, every write. The copy's frames do not
change (C2-16B's rolling code stands still): the far ends here only read and drop them.

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

BOUND_HOOK = f'''"""bench_engine_bound.py's hook: a free node step and free frames, once warm."""

import importlib.abc
import importlib.machinery
import sys

WARM_STEPS = {WARM_STEPS}
WARM_TICKS = {WARM_TICKS}


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


PATCHES = {{
    "usb2rc.nodes.table": _free_step,
    "usb2rc.protocols.c2_16b.session": lambda m: _free_tick(m.C2Session),
    "usb2rc.lines.session": lambda m: _free_tick(m.ChannelSession),
    "usb2rc.protocols.mavlink.session": lambda m: _free_tick(m.MavlinkSession),
}}


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


def bound_copy(tree: Path, directory: Path) -> Path:
    """`tree`'s usb2rc (its built C loops too) with the hook beside it."""
    copy = directory / "bound"
    shutil.copytree(tree / "usb2rc", copy / "usb2rc", ignore=shutil.ignore_patterns("__pycache__"))
    (copy / "sitecustomize.py").write_text(BOUND_HOOK)
    return copy


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tree", type=Path, default=ROOT, help="the source tree (this one)")
    parser.add_argument("--only", nargs="+", default=["c2", "five"], help="bench_hot_path's")
    parser.add_argument("--rounds", default="3")
    parser.add_argument("--seconds", default="10")
    parser.add_argument("--together", action="store_true", help="bench_hot_path's --together")
    args = parser.parse_args()
    tree = args.tree.resolve()
    with tempfile.TemporaryDirectory(prefix="usb2rc-bound-") as tmp:
        copy = bound_copy(tree, Path(tmp))
        command = [
            sys.executable, str(ROOT / "bench" / "bench_hot_path.py"), "--trees", str(tree),
            str(copy), "--only", *args.only, "--rounds", args.rounds, "--seconds", args.seconds,
        ]  # fmt: skip
        if args.together:
            command.append("--together")
        print(f"{tree}: as it is; {copy}: its step and frames free once warmed up", flush=True)
        sys.exit(subprocess.run(command).returncode)


if __name__ == "__main__":
    main()
