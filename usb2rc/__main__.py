import signal

# First thing, before usb2rc.cli and its imports: a SIGTERM while starting is a clean stop.
# `cli.main` then installs the handlers of the command (usb2rc.signals for the daemon).
from usb2rc.signals import stop_at_once

signal.signal(signal.SIGTERM, stop_at_once)

from usb2rc.cli import main  # noqa: E402 - after the handler, so the imports are covered

raise SystemExit(main())
