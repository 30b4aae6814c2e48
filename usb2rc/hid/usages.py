"""HID usages (HID Usage Tables 1.x): one int per usage, `(page << 16) | id`.

Only the pages a joystick daemon needs are named: Generic Desktop, Simulation Controls and
Button, and Battery Strength of the Generic Device Controls page (a wireless pad's battery,
for `%` frames). Every other usage still has a name, its hex form `0xPPPPUUUU`.
"""

from __future__ import annotations

import re

GENERIC_DESKTOP_PAGE = 0x01
SIMULATION_PAGE = 0x02
GENERIC_DEVICE_PAGE = 0x06
BUTTON_PAGE = 0x09
CONSUMER_PAGE = 0x0C
DIGITIZER_PAGE = 0x0D
VENDOR_PAGE_FIRST = 0xFF00


def make_usage(page: int, usage_id: int) -> int:
    return (page << 16) | usage_id


def usage_page(usage: int) -> int:
    return usage >> 16


def usage_id(usage: int) -> int:
    return usage & 0xFFFF


# Generic Device Controls page (0x06): what a wireless pad reports of its battery
GDC_BATTERY_STRENGTH = 0x00060020

# Generic Desktop page (0x01)
GD_POINTER = 0x00010001
GD_MOUSE = 0x00010002
GD_JOYSTICK = 0x00010004
GD_GAMEPAD = 0x00010005
GD_KEYBOARD = 0x00010006
GD_KEYPAD = 0x00010007
GD_MULTI_AXIS = 0x00010008
GD_X = 0x00010030
GD_Y = 0x00010031
GD_Z = 0x00010032
GD_RX = 0x00010033
GD_RY = 0x00010034
GD_RZ = 0x00010035
GD_SLIDER = 0x00010036
GD_DIAL = 0x00010037
GD_WHEEL = 0x00010038
GD_HAT_SWITCH = 0x00010039
GD_COUNTED_BUFFER = 0x0001003A
GD_BYTE_COUNT = 0x0001003B
GD_START = 0x0001003D
GD_SELECT = 0x0001003E
GD_VX = 0x00010040
GD_VY = 0x00010041
GD_VZ = 0x00010042
GD_VBRX = 0x00010043
GD_VBRY = 0x00010044
GD_VBRZ = 0x00010045
GD_VNO = 0x00010046
GD_SYSTEM_CONTROL = 0x00010080
GD_DPAD_UP = 0x00010090
GD_DPAD_DOWN = 0x00010091
GD_DPAD_RIGHT = 0x00010092
GD_DPAD_LEFT = 0x00010093

# Simulation Controls page (0x02)
SIM_FLIGHT_SIMULATION = 0x00020001
SIM_AUTOMOBILE_SIMULATION = 0x00020002
SIM_TANK_SIMULATION = 0x00020003
SIM_SPACESHIP_SIMULATION = 0x00020004
SIM_SUBMARINE_SIMULATION = 0x00020005
SIM_SAILING_SIMULATION = 0x00020006
SIM_MOTORCYCLE_SIMULATION = 0x00020007
SIM_SPORTS_SIMULATION = 0x00020008
SIM_AIRPLANE_SIMULATION = 0x00020009
SIM_HELICOPTER_SIMULATION = 0x0002000A
SIM_MAGIC_CARPET_SIMULATION = 0x0002000B
SIM_BICYCLE_SIMULATION = 0x0002000C
SIM_FLIGHT_CONTROL_STICK = 0x00020020
SIM_FLIGHT_STICK = 0x00020021
SIM_CYCLIC_CONTROL = 0x00020022
SIM_CYCLIC_TRIM = 0x00020023
SIM_FLIGHT_YOKE = 0x00020024
SIM_TRACK_CONTROL = 0x00020025
SIM_AILERON = 0x000200B0
SIM_AILERON_TRIM = 0x000200B1
SIM_ANTI_TORQUE_CONTROL = 0x000200B2
SIM_AUTOPILOT_ENABLE = 0x000200B3
SIM_CHAFF_RELEASE = 0x000200B4
SIM_COLLECTIVE_CONTROL = 0x000200B5
SIM_DIVE_BRAKE = 0x000200B6
SIM_ELECTRONIC_COUNTERMEASURES = 0x000200B7
SIM_ELEVATOR = 0x000200B8
SIM_ELEVATOR_TRIM = 0x000200B9
SIM_RUDDER = 0x000200BA
SIM_THROTTLE = 0x000200BB
SIM_FLIGHT_COMMUNICATIONS = 0x000200BC
SIM_FLARE_RELEASE = 0x000200BD
SIM_LANDING_GEAR = 0x000200BE
SIM_TOE_BRAKE = 0x000200BF
SIM_TRIGGER = 0x000200C0
SIM_WEAPONS_ARM = 0x000200C1
SIM_WEAPONS_SELECT = 0x000200C2
SIM_WING_FLAPS = 0x000200C3
SIM_ACCELERATOR = 0x000200C4
SIM_BRAKE = 0x000200C5
SIM_CLUTCH = 0x000200C6
SIM_SHIFTER = 0x000200C7
SIM_STEERING = 0x000200C8
SIM_TURRET_DIRECTION = 0x000200C9
SIM_BARREL_ELEVATION = 0x000200CA
SIM_DIVE_PLANE = 0x000200CB
SIM_BALLAST = 0x000200CC
SIM_BICYCLE_CRANK = 0x000200CD
SIM_HANDLE_BARS = 0x000200CE
SIM_FRONT_BRAKE = 0x000200CF
SIM_REAR_BRAKE = 0x000200D0

_NAMES: dict[int, str] = {
    GD_POINTER: "Pointer",
    GD_MOUSE: "Mouse",
    GD_JOYSTICK: "Joystick",
    GD_GAMEPAD: "Gamepad",
    GD_KEYBOARD: "Keyboard",
    GD_KEYPAD: "Keypad",
    GD_MULTI_AXIS: "MultiAxisController",
    GD_X: "X",
    GD_Y: "Y",
    GD_Z: "Z",
    GD_RX: "Rx",
    GD_RY: "Ry",
    GD_RZ: "Rz",
    GD_SLIDER: "Slider",
    GD_DIAL: "Dial",
    GD_WHEEL: "Wheel",
    GD_HAT_SWITCH: "HatSwitch",
    GD_COUNTED_BUFFER: "CountedBuffer",
    GD_BYTE_COUNT: "ByteCount",
    GD_START: "Start",
    GD_SELECT: "Select",
    GD_VX: "Vx",
    GD_VY: "Vy",
    GD_VZ: "Vz",
    GD_VBRX: "Vbrx",
    GD_VBRY: "Vbry",
    GD_VBRZ: "Vbrz",
    GD_VNO: "Vno",
    GD_SYSTEM_CONTROL: "SystemControl",
    GD_DPAD_UP: "DpadUp",
    GD_DPAD_DOWN: "DpadDown",
    GD_DPAD_RIGHT: "DpadRight",
    GD_DPAD_LEFT: "DpadLeft",
    SIM_FLIGHT_SIMULATION: "FlightSimulationDevice",
    SIM_AUTOMOBILE_SIMULATION: "AutomobileSimulationDevice",
    SIM_TANK_SIMULATION: "TankSimulationDevice",
    SIM_SPACESHIP_SIMULATION: "SpaceshipSimulationDevice",
    SIM_SUBMARINE_SIMULATION: "SubmarineSimulationDevice",
    SIM_SAILING_SIMULATION: "SailingSimulationDevice",
    SIM_MOTORCYCLE_SIMULATION: "MotorcycleSimulationDevice",
    SIM_SPORTS_SIMULATION: "SportsSimulationDevice",
    SIM_AIRPLANE_SIMULATION: "AirplaneSimulationDevice",
    SIM_HELICOPTER_SIMULATION: "HelicopterSimulationDevice",
    SIM_MAGIC_CARPET_SIMULATION: "MagicCarpetSimulationDevice",
    SIM_BICYCLE_SIMULATION: "BicycleSimulationDevice",
    SIM_FLIGHT_CONTROL_STICK: "FlightControlStick",
    SIM_FLIGHT_STICK: "FlightStick",
    SIM_CYCLIC_CONTROL: "CyclicControl",
    SIM_CYCLIC_TRIM: "CyclicTrim",
    SIM_FLIGHT_YOKE: "FlightYoke",
    SIM_TRACK_CONTROL: "TrackControl",
    SIM_AILERON: "Aileron",
    SIM_AILERON_TRIM: "AileronTrim",
    SIM_ANTI_TORQUE_CONTROL: "AntiTorqueControl",
    SIM_AUTOPILOT_ENABLE: "AutopilotEnable",
    SIM_CHAFF_RELEASE: "ChaffRelease",
    SIM_COLLECTIVE_CONTROL: "CollectiveControl",
    SIM_DIVE_BRAKE: "DiveBrake",
    SIM_ELECTRONIC_COUNTERMEASURES: "ElectronicCountermeasures",
    SIM_ELEVATOR: "Elevator",
    SIM_ELEVATOR_TRIM: "ElevatorTrim",
    SIM_RUDDER: "Rudder",
    SIM_THROTTLE: "Throttle",
    SIM_FLIGHT_COMMUNICATIONS: "FlightCommunications",
    SIM_FLARE_RELEASE: "FlareRelease",
    SIM_LANDING_GEAR: "LandingGear",
    SIM_TOE_BRAKE: "ToeBrake",
    SIM_TRIGGER: "Trigger",
    SIM_WEAPONS_ARM: "WeaponsArm",
    SIM_WEAPONS_SELECT: "WeaponsSelect",
    SIM_WING_FLAPS: "WingFlaps",
    SIM_ACCELERATOR: "Accelerator",
    SIM_BRAKE: "Brake",
    SIM_CLUTCH: "Clutch",
    SIM_SHIFTER: "Shifter",
    SIM_STEERING: "Steering",
    SIM_TURRET_DIRECTION: "TurretDirection",
    SIM_BARREL_ELEVATION: "BarrelElevation",
    SIM_DIVE_PLANE: "DivePlane",
    SIM_BALLAST: "Ballast",
    SIM_BICYCLE_CRANK: "BicycleCrank",
    SIM_HANDLE_BARS: "HandleBars",
    SIM_FRONT_BRAKE: "FrontBrake",
    SIM_REAR_BRAKE: "RearBrake",
    GDC_BATTERY_STRENGTH: "BatteryStrength",
}

# Extra spellings accepted by usage_from_name (after normalising, see _normalise).
_ALIASES: dict[str, int] = {
    "hat": GD_HAT_SWITCH,
    "multiaxis": GD_MULTI_AXIS,
    "toebrake": SIM_TOE_BRAKE,
    "battery": GDC_BATTERY_STRENGTH,
}


def _normalise(name: str) -> str:
    """Lower case, without spaces, underscores and hyphens: 'Hat Switch' -> 'hatswitch'."""
    return "".join(ch for ch in name.lower() if ch not in " _-")


_BY_NAME: dict[str, int] = {_normalise(n): u for u, n in _NAMES.items()} | _ALIASES

# Values that move continuously: what a mapping may scale onto an RC axis.
AXIS_USAGES: frozenset[int] = frozenset(
    {
        GD_X,
        GD_Y,
        GD_Z,
        GD_RX,
        GD_RY,
        GD_RZ,
        GD_SLIDER,
        GD_DIAL,
        GD_WHEEL,
        GD_VX,
        GD_VY,
        GD_VZ,
        GD_VBRX,
        GD_VBRY,
        GD_VBRZ,
        SIM_AILERON,
        SIM_AILERON_TRIM,
        SIM_ANTI_TORQUE_CONTROL,
        SIM_COLLECTIVE_CONTROL,
        SIM_DIVE_BRAKE,
        SIM_ELEVATOR,
        SIM_ELEVATOR_TRIM,
        SIM_RUDDER,
        SIM_THROTTLE,
        SIM_TOE_BRAKE,
        SIM_WING_FLAPS,
        SIM_ACCELERATOR,
        SIM_BRAKE,
        SIM_CLUTCH,
        SIM_STEERING,
        SIM_TURRET_DIRECTION,
        SIM_BARREL_ELEVATION,
        SIM_DIVE_PLANE,
        SIM_BALLAST,
        SIM_BICYCLE_CRANK,
        SIM_HANDLE_BARS,
        SIM_FRONT_BRAKE,
        SIM_REAR_BRAKE,
    }
)

# Top-level collection usages of devices usb2rc reads (plus the whole Simulation page).
JOYSTICK_LIKE_APPLICATIONS: frozenset[int] = frozenset({GD_JOYSTICK, GD_GAMEPAD, GD_MULTI_AXIS})

_DEVICE_TYPES: dict[int, str] = {
    GD_POINTER: "POINTER",
    GD_MOUSE: "MOUSE",
    GD_JOYSTICK: "JOYSTICK",
    GD_GAMEPAD: "GAMEPAD",
    GD_KEYBOARD: "KEYBOARD",
    GD_KEYPAD: "KEYPAD",
    GD_MULTI_AXIS: "MULTIAXIS",
    SIM_FLIGHT_SIMULATION: "FLIGHTSIM",
    SIM_AUTOMOBILE_SIMULATION: "AUTOSIM",
    SIM_TANK_SIMULATION: "TANKSIM",
    SIM_SPACESHIP_SIMULATION: "SPACESHIPSIM",
    SIM_SUBMARINE_SIMULATION: "SUBMARINESIM",
    SIM_SAILING_SIMULATION: "SAILINGSIM",
    SIM_MOTORCYCLE_SIMULATION: "MOTORBIKESIM",
    SIM_SPORTS_SIMULATION: "SPORTSSIM",
    SIM_AIRPLANE_SIMULATION: "AIRPLANESIM",
    SIM_HELICOPTER_SIMULATION: "HELISIM",
    SIM_MAGIC_CARPET_SIMULATION: "CARPETSIM",
    SIM_BICYCLE_SIMULATION: "BICYCLESIM",
    SIM_FLIGHT_CONTROL_STICK: "FLIGHTCTRL",
    SIM_FLIGHT_STICK: "FLIGHTSTICK",
    SIM_CYCLIC_CONTROL: "CYCLIC",
    SIM_FLIGHT_YOKE: "YOKE",
    SIM_TRACK_CONTROL: "TRACKCONTROL",
}


_HEX_RE = re.compile(r"0x([0-9a-f]{1,8})")
_BUTTON_RE = re.compile(r"button[ _]?([0-9]{1,5})")


def usage_name(usage: int) -> str:
    """'X', 'HatSwitch', 'Throttle', 'Button 5'; any other usage as '0xPPPPUUUU'."""
    name = _NAMES.get(usage)
    if name is not None:
        return name
    if usage_page(usage) == BUTTON_PAGE and usage_id(usage) > 0:
        return f"Button {usage_id(usage)}"
    return f"0x{usage:08X}"


def usage_from_name(name: str) -> int:
    """The usage a name stands for: a usage_name() result (any case, spaces/underscores/hyphens
    ignored), 'Button N' / 'ButtonN', or '0xPPPPUUUU'. Raises KeyError for anything else."""
    key = _normalise(name)
    if key in _BY_NAME:
        return _BY_NAME[key]
    text = name.strip().lower()
    match = _HEX_RE.fullmatch(text)
    if match:
        return int(match.group(1), 16)
    match = _BUTTON_RE.fullmatch(text)
    if match and 1 <= int(match.group(1)) <= 0xFFFF:
        return make_usage(BUTTON_PAGE, int(match.group(1)))
    raise KeyError(f"unknown HID usage name {name!r}")


def device_type_name(application: int) -> str:
    """A short ASCII device type (at most 12 characters) for the C2-16B service frame 7."""
    name = _DEVICE_TYPES.get(application)
    if name is not None:
        return name
    page = usage_page(application)
    if page == SIMULATION_PAGE:
        return "SIMULATION"
    if page >= VENDOR_PAGE_FIRST:
        return "VENDOR"
    return f"{page:04X}:{usage_id(application):04X}"


def is_joystick_like(application: int) -> bool:
    """True for the top-level collections usb2rc reads: Joystick, Gamepad, Multi-axis
    Controller, and any Simulation Controls collection."""
    return application in JOYSTICK_LIKE_APPLICATIONS or usage_page(application) == SIMULATION_PAGE


def is_axis(usage: int) -> bool:
    return usage in AXIS_USAGES


# How `usb2rc list` names a device's top-level collection (words, for people).
_TOP_LEVEL_NAMES: dict[int, str] = {
    GD_POINTER: "Pointer",
    GD_MOUSE: "Mouse",
    GD_KEYBOARD: "Keyboard",
    GD_KEYPAD: "Keypad",
    GD_SYSTEM_CONTROL: "System Control",
    GD_JOYSTICK: "Joystick",
    GD_GAMEPAD: "Gamepad",
    GD_MULTI_AXIS: "Multi-axis Controller",
}
_TOP_LEVEL_PAGE_NAMES = {CONSUMER_PAGE: "Consumer", DIGITIZER_PAGE: "Digitizer"}


def top_level_usage_name(application: int) -> str:
    """'Joystick', 'Simulation Controls 0x04', 'Consumer', else '0xPPPPUUUU'."""
    if application in _TOP_LEVEL_NAMES:
        return _TOP_LEVEL_NAMES[application]
    page = usage_page(application)
    if page == SIMULATION_PAGE:
        return f"Simulation Controls 0x{usage_id(application):02X}"
    if page in _TOP_LEVEL_PAGE_NAMES:
        return _TOP_LEVEL_PAGE_NAMES[page]
    return f"0x{application:08X}"
