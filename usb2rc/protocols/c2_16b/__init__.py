"""The C2-16B output protocol: its line session."""
