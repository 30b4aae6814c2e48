"""The files the package ships for trying usb2rc, by short names that work from any folder.

A wheel installs `usb2rc/data/` somewhere under site-packages, so a path such as
`usb2rc/data/config/hotas.yaml` exists only inside a clone. Users name these files instead:

- `usb2rc example NAME > FILE` copies one shipped file (a config, a recording, a line sample)
  to FILE; the copy is the user's to edit. NAME is the file's name, or its stem.
- `--replay demo` is the built-in recordings folder (stick and throttle). A folder named
  `demo` in the current directory wins: a path means a path everywhere else too, and the
  command says which one it took (see `resolve_replay`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

DEMO_REPLAY = "demo"  # the `--replay` name of the built-in recordings


@dataclass(frozen=True)
class Example:
    name: str  # the file name, e.g. "hotas.yaml"
    folder: str  # under usb2rc/data/
    about: str  # one line for `usb2rc example`

    @property
    def stem(self) -> str:
        return self.name.split(".", 1)[0]


EXAMPLES: tuple[Example, ...] = (
    Example(
        "hotas.yaml",
        "config",
        "a T.16000M stick + TWCS throttle (node 1), TFRP pedals (node 2); C2-16B and SUMD outputs",
    ),
    Example(
        "hotas-demo.yaml", "config", "hotas.yaml without the pedals: all live on `--replay demo`"
    ),
    Example("default.yaml", "config", "zero config spelled out: every stick, default layout"),
    Example("mavlink.yaml", "config", "a stick and throttle to MAVLink autopilots (UDP, serial)"),
    Example("stick.hid", "demo", "hid-recorder file: the demo's Thrustmaster T.16000M"),
    Example("throttle.hid", "demo", "hid-recorder file: the demo's Thrustmaster TWCS"),
    Example("c2-16b-sample.bin", "samples", "a captured C2-16B line, for `usb2rc decode`"),
    Example("sumd-sample.bin", "samples", "a captured SUMD line, for `usb2rc decode`"),
)


def data_dir(folder: str) -> Path:
    """A folder of the installed package's data (a real directory: wheels install unzipped)."""
    return Path(str(resources.files("usb2rc").joinpath("data", folder)))


def find_example(name: str) -> Example | None:
    """The example called `name` (file name or stem), or None."""
    return next((e for e in EXAMPLES if name in (e.name, e.stem)), None)


def example_bytes(example: Example) -> bytes:
    return (data_dir(example.folder) / example.name).read_bytes()


def resolve_replay(value: str) -> tuple[str, str | None]:
    """`--replay` as a folder path, and a note when the name `demo` was ambiguous.

    `demo` names the built-in recordings unless the current directory has a `demo` folder
    (then that folder, with a note naming the choice, so the shadowing is never silent).
    """
    if value != DEMO_REPLAY:
        return value, None
    builtin = str(data_dir("demo"))
    if os.path.isdir(value):
        note = (
            f"--replay demo: the folder ./demo here, not the built-in recordings "
            f"(those are in {builtin})"
        )
        return value, note
    return builtin, None
