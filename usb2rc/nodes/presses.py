"""A held button is not a press: which of a device's held buttons may act as pressed.

A press counts only from a rising edge seen while the button's node is live (docs/ICD.md,
"A held button is not a press"). A stick plugged with its arm button held, a thumb resting
on a button while a missing device comes back, or a reload that remaps a held button must
not fire what that button triggers: the pilot releases it first.

The node table keeps one `PressGate` per attached device and steps it once per node step,
after the node's failsafe is decided (`PressGate.step`):

- the gate is *closed* while the node is in failsafe (which covers a first plug and a replug,
  the neutral guard, a device missing, bad reports), and when a reload changes how the
  device's buttons map (`close`);
- at the first live step after that it *opens*: every button held then is held over, and so
  is every press the reader logged up to then (`counts_from`);
- a held-over button counts again once a step sees it released, or the reader's press log
  shows it pressed anew (a release and a press between two steps still count).

What the gate decides, per device view: `DeviceView.held_over` (the node buttons held over;
`DeviceView.pressed` those held now that went down while the node was live: a MAVLink
action's trigger), `counts_from` (the press serial after which presses count: switches,
trims), and the handover button, which asks for `&` only once pressed while live.
Held-over buttons still *show* as held: a C2-16B button bit, a SUMD or CRSF channel
reading a node button are states, never presses.
"""

from __future__ import annotations

from dataclasses import dataclass

from usb2rc.nodes.binding import DeviceBinding
from usb2rc.nodes.step import DeviceView

Groups = tuple[int, int]  # node buttons: (group 1 bits, group 2 bits)
NO_BUTTONS: Groups = (0, 0)

SINCE_PLUG = "the plug"
SINCE_FAILSAFE = "the failsafe"
SINCE_RELOAD = "the reload"


@dataclass
class PressGate:
    """One attached device's gate (see the module docstring); owned by the node table and
    stepped under its lock."""

    is_open: bool = False
    since: str = SINCE_PLUG  # why it was closed last, for the log line
    counts_from: int = 0  # presses with a serial after this one count
    held_hid: int = 0  # HID buttons held over (not released since the gate opened)
    held_groups: Groups = NO_BUTTONS  # node buttons held over
    last_serial: int = 0  # the press serial the last step saw

    def close(self, since: str) -> None:
        """Every button held at the next live step is held over (a reload remapped them)."""
        if self.is_open:
            self.is_open, self.since = False, since

    def step(self, view: DeviceView, node_live: bool) -> tuple[DeviceView, str | None]:
        """The device's view with what is held over, and a log line when the gate opens on
        held buttons (once per opening). A view already made with this gate's state (the
        common step: open, nothing held over) is returned as it is."""
        record = view.record
        note = None
        if not node_live:  # closed: everything held is held over, no press counts
            if self.is_open:
                self.is_open, self.since = False, SINCE_FAILSAFE
            self.counts_from = self.last_serial = record.press_serial
            self.held_hid = record.state.buttons
            self.held_groups = (view.inputs.group1, view.inputs.group2)
            return view, None  # a node in failsafe acts on no press: its view as it is
        if not self.is_open:
            note = self._open(view)
        elif self.held_hid or self.held_groups != NO_BUTTONS:
            self._released(view)
        return self._gated(view), note

    def _open(self, view: DeviceView) -> str | None:
        record = view.record
        self.is_open = True
        self.counts_from = self.last_serial = record.press_serial
        self.held_hid = record.state.buttons
        self.held_groups = (view.inputs.group1, view.inputs.group2)
        if not self.held_hid and self.held_groups == NO_BUTTONS:
            return None
        return _held_note(view, self.held_hid, self.since)

    def _released(self, view: DeviceView) -> None:
        """Forget what a step sees released, or the press log shows pressed again."""
        record, binding = view.record, view.binding
        again = record.pressed_since(self.last_serial)
        self.last_serial = record.press_serial
        self.held_hid &= record.state.buttons & ~again
        again_groups = binding.button_groups(again) if again else NO_BUTTONS
        shown = (view.inputs.group1, view.inputs.group2)
        self.held_groups = (
            self.held_groups[0] & shown[0] & ~again_groups[0],
            self.held_groups[1] & shown[1] & ~again_groups[1],
        )

    def _gated(self, view: DeviceView) -> DeviceView:
        inputs = view.inputs
        if inputs.handover and view.binding.holds_handover(self.held_hid):
            inputs = inputs._replace(handover=False)  # `&` only from a press while live
        same = (view.counts_from, view.held_over) == (self.counts_from, self.held_groups)
        if same and inputs is view.inputs:
            return view
        return view._replace(
            inputs=inputs, counts_from=self.counts_from, held_over=self.held_groups
        )


def _held_note(view: DeviceView, held_hid: int, since: str) -> str:
    name = view.binding.name or "device"
    numbers = [str(bit + 1) for bit in range(held_hid.bit_length()) if held_hid >> bit & 1]
    if not numbers:  # a hat pushed, feeding node buttons
        return f"{name}: a hat held since {since}: centre it first (it is not a press)"
    what = f"button {numbers[0]}" if len(numbers) == 1 else f"buttons {', '.join(numbers)}"
    them = "it" if len(numbers) == 1 else "them"
    return f"{name}: {what} held since {since}: release {them} first (not a press)"


def button_mapping_changed(before: DeviceBinding, after: DeviceBinding) -> bool:
    """A reload's new binding maps the device's buttons otherwise (see `PressGate.close`)."""
    return not before.same_buttons(after)
