import signal


def _stop_early(_signum: int, _frame: object) -> None:
    # A SIGTERM while usb2rc is still starting (imports, config) is a clean stop too; the
    # daemon installs its own handler once it runs.
    raise SystemExit(0)


signal.signal(signal.SIGTERM, _stop_early)

from usb2rc.cli import main  # noqa: E402 - after the handler, so the imports are covered

raise SystemExit(main())
