"""What a user does about a hidraw node they may not open: the udev rule, in words."""

from __future__ import annotations

UDEV_RULES_INSTALLED = "/etc/udev/rules.d/70-usb2rc.rules"
# Installs the rule the package ships (usb2rc/commands/install_system.py): no source tree needed.
INSTALL_RULE = (
    f"`usb2rc install-system` (as root; it writes {UDEV_RULES_INSTALLED} and the service files)"
)


def permission_message(node: str) -> str:
    return (
        f"permission denied on {node}: install the udev rule with {INSTALL_RULE} and run "
        "`sudo udevadm control --reload && sudo udevadm trigger --subsystem-match=hidraw`, "
        f"or add your user to the group that owns {node} (see `ls -l {node}`) and log in again"
    )
