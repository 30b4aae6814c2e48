"""The sumd package."""
