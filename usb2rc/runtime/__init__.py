"""What every stage runs on: the worker thread shape, wake flags, file writes, log text."""
