"""A transmitter's mixer and a ground station's buttons (issue 23, docs/CONFIG.md "Switches",
"Mixes and curves", "Throttle cut", "MAVLink actions").

- `model`: the config's dataclasses (read by `usb2rc.config.controls`);
- `curves`: expo and point curves, and a mix's sum (pure arithmetic);
- `switches`: the switches' positions, stepped once per node step from the readers' press
  logs (`SwitchBank`, owned by the node table);
- `actions`: MAVLink button actions, sans-IO (`ActionRunner`).
"""
