"""What `usb2rc check` warns about a CRSF output's far end (docs/CONFIG.md, "CRSF and SBUS
outputs"): the config is good either way (exit 0), but a flight controller would not read it.

- `address: flight_controller` (0xC8) wires usb2rc to an FC's receiver UART, where an
  ExpressLRS receiver would be. Betaflight and PX4 read that UART at 420000 baud (what a
  receiver sends at); usb2rc's CRSF default, 400000, is the handset-to-module rate, 5 % off:
  more than a UART's sampling tolerates.
- Any address byte but 0xEE and 0xC8: Betaflight drops RC frames not sent to 0xC8, and an
  ExpressLRS module is addressed as 0xEE; another byte is for another far end.
"""

from __future__ import annotations

from usb2rc.config.model import OutputConfig
from usb2rc.config.yamlnodes import Problem, Where
from usb2rc.protocols.crsf import codec as crsf

FLIGHT_CONTROLLER_BAUDRATE = 420000  # a receiver's CRSF UART, as Betaflight and PX4 read it


def address_warnings(output: OutputConfig) -> list[Problem]:
    """The warnings for one output (none unless it is a CRSF output)."""
    if output.protocol != "crsf":
        return []
    address = int(output.option("address"))
    where = _where(output)
    if address == crsf.ADDRESS_FLIGHT_CONTROLLER and output.baudrate != FLIGHT_CONTROLLER_BAUDRATE:
        text = (
            f"address flight_controller at {output.baudrate} baud: Betaflight and PX4 read a "
            f"receiver's CRSF at {FLIGHT_CONTROLLER_BAUDRATE} baud; set `baudrate: "
            f"{FLIGHT_CONTROLLER_BAUDRATE}` unless the flight controller is set to this rate"
        )
        return [where.problem(f"warning: {text}")]
    if address not in (crsf.ADDRESS_MODULE, crsf.ADDRESS_FLIGHT_CONTROLLER):
        text = (
            f"address 0x{address:02X}: Betaflight takes RC frames only to 0xC8 "
            "(`flight_controller`) and a transmitter module is 0xEE (`module`)"
        )
        return [where.problem(f"warning: {text}")]
    return []


def _where(output: OutputConfig) -> Where:
    if output.where is None:  # a Config built in code
        return Where("<config>", 0, "outputs")
    return Where(output.where.source, output.where.line, output.where.key)
