"""The node model every config, binding and wire format names.

docs/ICD.md, "C2-16B data frame" and "Node-IDs", define it.

A node has ten axis slots, 56 buttons (group 1: buttons 1..24 and the hat; group 2: buttons
25..56) and a hat; Node-IDs run 0..0xFE (0xFF is the controller's own, the startup frame's).
One definition here: the codecs, the config and the node state import it from here.
"""

from __future__ import annotations

AXIS_NAMES = ("x", "y", "z", "slider", "rx", "ry", "rz", "dial", "aux1", "aux2")
AXIS_COUNT = len(AXIS_NAMES)
NODE_BUTTONS = 56  # node buttons 1..24 -> group 1 bits 0..23, 25..56 -> group 2 bits 0..31
GROUP1_BUTTONS = 24
HAT1_SHIFT = 24  # hat1: group 1 bits 24..31, one per direction
STARTUP_NODE_ID = 0xFF  # the controller's own ID: the startup frame's, no node's
MAX_NODE_ID = STARTUP_NODE_ID - 1
