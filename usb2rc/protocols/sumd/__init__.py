"""The HoTT SUMD output protocol: its line session."""
