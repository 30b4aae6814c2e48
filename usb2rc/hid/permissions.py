"""What a user does about a hidraw node they may not open: the udev rule, in words."""

from __future__ import annotations

UDEV_RULES_FILE = "systemd/70-usb2rc.rules"
UDEV_RULES_INSTALLED = "/etc/udev/rules.d/70-usb2rc.rules"


def permission_message(node: str) -> str:
    return (
        f"permission denied on {node}: install the udev rule {UDEV_RULES_FILE} to "
        f"{UDEV_RULES_INSTALLED} and run `sudo udevadm control --reload && "
        "sudo udevadm trigger --subsystem-match=hidraw`, or add your user to the group that "
        f"owns {node} (see `ls -l {node}`) and log in again"
    )
