"""The mavlink package."""
