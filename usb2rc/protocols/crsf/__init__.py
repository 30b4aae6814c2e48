"""The CRSF output protocol: its line session."""
