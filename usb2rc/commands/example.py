"""`usb2rc example [NAME]`: print a file the package ships, to start from or to try things on.

Without NAME, lists them. With NAME (the file's name or its stem: `hotas` or `hotas.yaml`),
writes that file's bytes to stdout: `usb2rc example hotas > hotas.yaml` gives a config to
edit, from any folder, with the package installed from a wheel. The demo recordings are also
a `--replay` folder by name: `--replay demo`.
"""

from __future__ import annotations

import argparse
import sys

from usb2rc.examples import EXAMPLES, example_bytes, find_example


def add_parser(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "example",
        help="print a shipped config, recording or line sample (`example hotas > hotas.yaml`)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("name", metavar="NAME", nargs="?", help="which file (none: list them)")
    parser.set_defaults(func=run)


def listing() -> str:
    width = max(len(e.name) for e in EXAMPLES)
    lines = [f"{e.name:<{width}}  {e.about}" for e in EXAMPLES]
    lines.append("")
    lines.append("usb2rc example NAME > FILE   copies one (NAME: the file name or its stem)")
    lines.append("--replay demo                the built-in recordings folder (stick, throttle)")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    if not args.name:
        print(listing())
        return 0
    example = find_example(args.name)
    if example is None:
        names = ", ".join(e.stem for e in EXAMPLES)
        print(f"usb2rc example: no example {args.name!r}; there are: {names}", file=sys.stderr)
        return 2
    sys.stdout.buffer.write(example_bytes(example))
    sys.stdout.flush()
    return 0
