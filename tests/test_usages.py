from __future__ import annotations

import pytest

from usb2rc.hid import usages as u


def test_usage_ints_are_page_and_id() -> None:
    assert u.GD_X == 0x00010030
    assert u.GD_HAT_SWITCH == 0x00010039
    assert u.SIM_THROTTLE == 0x000200BB
    assert u.make_usage(u.BUTTON_PAGE, 5) == 0x00090005
    assert (u.usage_page(u.SIM_RUDDER), u.usage_id(u.SIM_RUDDER)) == (0x02, 0xBA)


@pytest.mark.parametrize(
    ("usage", "name"),
    [
        (u.GD_X, "X"),
        (u.GD_RZ, "Rz"),
        (u.GD_HAT_SWITCH, "HatSwitch"),
        (u.SIM_THROTTLE, "Throttle"),
        (u.SIM_TOE_BRAKE, "ToeBrake"),
        (u.SIM_FLIGHT_CONTROL_STICK, "FlightControlStick"),
        (0x00090005, "Button 5"),
        (0xFF000021, "0xFF000021"),
        (0x00090000, "0x00090000"),
    ],
)
def test_usage_name_round_trips(usage: int, name: str) -> None:
    assert u.usage_name(usage) == name
    assert u.usage_from_name(name) == usage


@pytest.mark.parametrize(
    ("name", "usage"),
    [
        ("x", u.GD_X),
        ("HATSWITCH", u.GD_HAT_SWITCH),
        ("hat switch", u.GD_HAT_SWITCH),
        ("hat_switch", u.GD_HAT_SWITCH),
        ("toe-brake", u.SIM_TOE_BRAKE),
        ("button5", 0x00090005),
        ("BUTTON 12", 0x0009000C),
        ("0xff000021", 0xFF000021),
        ("0x00010030", u.GD_X),
    ],
)
def test_usage_from_name_is_lenient_about_case_and_spacing(name: str, usage: int) -> None:
    assert u.usage_from_name(name) == usage


@pytest.mark.parametrize("name", ["", "nope", "Button 0", "Button -1", "Button x", "0x", "0xZZ"])
def test_usage_from_name_unknown_raises_key_error(name: str) -> None:
    with pytest.raises(KeyError):
        u.usage_from_name(name)


def test_every_named_usage_round_trips() -> None:
    for usage, name in u._NAMES.items():
        assert u.usage_from_name(name) == usage
        assert u.usage_from_name(name.upper()) == usage


@pytest.mark.parametrize(
    ("application", "name"),
    [
        (u.GD_JOYSTICK, "JOYSTICK"),
        (u.GD_GAMEPAD, "GAMEPAD"),
        (u.GD_MULTI_AXIS, "MULTIAXIS"),
        (u.SIM_FLIGHT_SIMULATION, "FLIGHTSIM"),
        (u.SIM_FLIGHT_YOKE, "YOKE"),
        (0x000200FF, "SIMULATION"),
        (0xFF000001, "VENDOR"),
        (0x000C0001, "000C:0001"),
    ],
)
def test_device_type_name(application: int, name: str) -> None:
    assert u.device_type_name(application) == name


def test_device_type_names_fit_the_service_frame() -> None:
    for application in [*u._DEVICE_TYPES, 0, 0xFFFFFFFF, 0x000200FF, 0x12345678]:
        name = u.device_type_name(application)
        assert 0 < len(name) <= 12 and name.isascii()


def test_is_joystick_like() -> None:
    for application in (u.GD_JOYSTICK, u.GD_GAMEPAD, u.GD_MULTI_AXIS, u.SIM_FLIGHT_SIMULATION):
        assert u.is_joystick_like(application)
    for application in (u.GD_MOUSE, u.GD_KEYBOARD, u.GD_POINTER, 0x000C0001, 0xFF000001, 0):
        assert not u.is_joystick_like(application)


def test_axis_usages() -> None:
    assert {u.GD_X, u.GD_SLIDER, u.GD_WHEEL, u.SIM_RUDDER, u.SIM_BRAKE} <= u.AXIS_USAGES
    assert u.is_axis(u.SIM_THROTTLE)
    assert not u.is_axis(u.GD_HAT_SWITCH)
    assert not u.is_axis(0x00090001)
