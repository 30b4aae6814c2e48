"""The iBus output protocol: its line session."""
