# First thing, before usb2rc.cli and its imports, and before the command is known: the
# daemon's handlers (usb2rc.service.signals), so no signal from here on kills `usb2rc run`.
# `cli.main` gives the other commands their usual handlers back.
from usb2rc.service.signals import install_daemon_signals

install_daemon_signals()

from usb2rc.cli import main  # noqa: E402 - after the handlers, so the imports are covered

raise SystemExit(main())
