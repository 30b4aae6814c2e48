"""The SBUS output protocol: its line session."""
