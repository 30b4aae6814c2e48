"""Feedback: what the far end and the vehicle say, driven back into the pilot's devices
(LEDs, rumble, force, displays). Telemetry from the line sessions and the node snapshot is
judged by the config's `feedback:` rules into each device's wanted output state, which a
device's output driver turns into the writes its reader thread makes (docs/ICD.md
"Downlink", docs/CONFIG.md "Feedback")."""
