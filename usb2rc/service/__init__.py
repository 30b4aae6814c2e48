"""The process as a systemd service: signals, readiness and watchdog, the sandbox."""
