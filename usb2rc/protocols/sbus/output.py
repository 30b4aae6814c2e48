"""The SBUS output protocol: its codec and its line session, and what else is its own."""
