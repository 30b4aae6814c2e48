"""Command line: `usb2rc [run] --config FILE`, plus one small module per subcommand.

Each module in `usb2rc.commands` exposes `add_parser(subparsers)` which registers its
sub-parser and sets `func=run` on it; `run(args) -> int` returns the exit status
(0 ok, 1 runtime failure, 2 usage or config error).
"""

from __future__ import annotations

import argparse
import difflib
import importlib
import os
import sys
import threading

from usb2rc import __version__
from usb2rc.service.signals import install_command_signals, install_daemon_signals

# Subcommand name -> module in usb2rc.commands. `run` is the default when none is given.
COMMANDS: dict[str, str] = {
    "run": "run",
    "demo": "demo",
    "decode": "decode",
    "list": "list_devices",
    "describe": "describe",
    "check": "check",
    "icd": "icd",
    "monitor": "monitor",
    "record": "record",
    "init": "init",
    "calibrate": "calibrate",
    "install-system": "install_system",
    "example": "example",
    "web": "web",
    "doctor": "doctor",
}


def _stop_within(exc: BaseException) -> BaseException | None:
    """A stop (SystemExit, KeyboardInterrupt) a signal handler raised while a command's
    module loaded, which Python wrapped (3.11 wraps what `__set_name__` raises in a class
    body in RuntimeError): it is raised again, never reported as a broken command."""
    inner = exc.__cause__ or exc.__context__
    while inner is not None:
        if not isinstance(inner, Exception):
            return inner
        inner = inner.__cause__ or inner.__context__
    return None


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The whole command line, or with `only` one command's parser: a command imports its own
    module and what it needs, not every other command's (`usb2rc run` starts sooner by the
    ~25 ms the others take to import, and a broken other command cannot stop it)."""
    parser = argparse.ArgumentParser(
        prog="usb2rc",
        description="USB joysticks, HOTAS and pedals to RC command streams: SERaero C2-16B, "
        "HoTT SUMD, CRSF, SBUS, iBus and MAVLink (serial lines; MAVLink also over UDP).",
        epilog="Without a subcommand, usb2rc runs the daemon (same options as `usb2rc run`).",
    )
    parser.add_argument("--version", action="version", version=f"usb2rc {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, module_name in COMMANDS.items():
        if only is not None and name != only:
            continue
        try:
            module = importlib.import_module(f"usb2rc.commands.{module_name}")
        except ModuleNotFoundError as exc:
            if exc.name != f"usb2rc.commands.{module_name}":
                sys.stderr.write(f"usb2rc: the `{name}` command is unavailable: {exc!r}\n")
            continue
        except Exception as exc:  # one broken command must not take the others down
            stop = _stop_within(exc)
            if stop is not None:
                raise stop from None
            sys.stderr.write(f"usb2rc: the `{name}` command is unavailable: {exc!r}\n")
            continue
        module.add_parser(subparsers)
    return parser


def _with_default_command(argv: list[str], known: set[str]) -> list[str]:
    """`usb2rc --config x.yaml` means `usb2rc run --config x.yaml`."""
    if any(arg in ("-h", "--help", "--version") for arg in argv[:1]):
        return argv
    first_positional = next((arg for arg in argv if not arg.startswith("-")), None)
    if first_positional in known:
        return argv
    return ["run", *argv]


def _unknown_command(argv: list[str], known: set[str]) -> str | None:
    """The error for `usb2rc bogus`: a first word that is no option and no command (the
    default command `run` takes no positional argument, so it cannot be meant for it)."""
    if not argv or argv[0].startswith("-") or argv[0] in known:
        return None
    close = difflib.get_close_matches(argv[0], sorted(known), n=1)
    hint = f" (did you mean {close[0]!r}?)" if close else ""
    return f"unknown command {argv[0]!r}{hint}; commands: {', '.join(known_in_order(known))}"


def _unrecognized(extras: list[str], parsers: list[argparse.ArgumentParser]) -> str:
    """argparse's "unrecognized arguments" with a did-you-mean for each misspelt option
    (`--prot` -> `--port`), from the options of the command and of `usb2rc` itself."""
    options = sorted({opt for p in parsers for opt in p._option_string_actions})
    words = []
    for word in extras:
        close = difflib.get_close_matches(word.split("=", 1)[0], options, n=1)
        hint = f" (did you mean {close[0]}?)" if word.startswith("-") and close else ""
        words.append(word + hint)
    return "unrecognized arguments: " + " ".join(words)


def command_of(argv: list[str]) -> str | None:
    """The command a command line names (`run` when it names none), or None when it needs
    them all: the help and version of `usb2rc` itself, and a first word that is no command
    (its error lists them)."""
    known = set(COMMANDS)
    if _unknown_command(argv, known) is not None:
        return None
    words = _with_default_command(argv, known)
    command = next((word for word in words if not word.startswith("-")), None)
    return command if command in known else None


def known_in_order(known: set[str]) -> list[str]:
    return [name for name in COMMANDS if name in known]


def _install_early_signals(args_list: list[str]) -> None:
    """Before anything slow (build_parser imports the command's module, then the config is read).

    The daemon gets its handlers for good (usb2rc.service.signals; usb2rc/__main__.py, the
    entry point, has already put them in); the other commands keep the usual Ctrl-C
    (KeyboardInterrupt) and SIGHUP, and only SIGTERM becomes a clean stop.
    """
    if threading.current_thread() is not threading.main_thread():
        return
    if _with_default_command(args_list, set(COMMANDS))[:1] == ["run"]:
        install_daemon_signals()
    else:
        install_command_signals()


def main(argv: list[str] | None = None) -> int:
    args_list = list(sys.argv[1:] if argv is None else argv)
    _install_early_signals(args_list)
    command = command_of(args_list)
    parser = build_parser(only=command)
    subparsers = next(
        action for action in parser._actions if isinstance(action, argparse._SubParsersAction)
    )
    known = set(subparsers.choices)
    if command is not None:  # the others were not imported: known unless they fail to
        known |= set(COMMANDS) - {command}
    unknown = _unknown_command(args_list, known)
    if unknown is not None:
        parser.error(unknown)  # exit 2
    if "run" in known:
        args_list = _with_default_command(args_list, known)
    args, extras = parser.parse_known_args(args_list)
    if extras:
        command_parser = subparsers.choices.get(args.command or "", parser)
        command_parser.error(_unrecognized(extras, [parser, command_parser]))  # exit 2
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:  # `usb2rc ... | head`: whoever read the output has gone
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
