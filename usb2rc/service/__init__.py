"""The process as a service: signals, systemd, log escaping, statistics text, threads."""
