"""The MAVLink output protocol: its line session."""
