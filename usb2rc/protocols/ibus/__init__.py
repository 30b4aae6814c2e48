"""The ibus package."""
