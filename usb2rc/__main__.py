"""The entry point of `python -m usb2rc` and of the `usb2rc` script ([project.scripts]).

Its first line blocks the daemon's signals, before any other import: a SIGTERM (or SIGINT,
SIGHUP, SIGUSR1) that arrives while usb2rc's modules load waits, pending, until
usb2rc.service.signals has its handlers in, and is handled then (a stop: exit 0). Only a
signal before this line, while Python itself starts, gets its default action.
"""

import signal

# The signals usb2rc.service.signals handles (its REQUESTS; a test holds the two together).
# Windows has no SIGHUP nor SIGUSR1 (nor the mask).
HELD_UNTIL_HANDLED = [
    getattr(signal, name)
    for name in ("SIGTERM", "SIGINT", "SIGHUP", "SIGUSR1")
    if hasattr(signal, name)
]


def main() -> int:
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_BLOCK, HELD_UNTIL_HANDLED)
    # The daemon's handlers (they unblock the signals), before the command is known:
    # `cli.main` gives the other commands their usual handlers back.
    from usb2rc.service.signals import install_daemon_signals

    install_daemon_signals()
    from usb2rc.cli import main as command_line

    return command_line()


if __name__ == "__main__":
    raise SystemExit(main())
