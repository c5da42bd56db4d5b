"""Angles in degrees or radians, chosen once per tab (issue 12: "units (deg/rad) chosen once").

The server's variables are SI (rad, rad/s); the pendants take degrees. The plots and the values read
at the time cursor show angles in what the user picked in the plots dock, degrees until then (as the
pendants: one unit the user sees everywhere); the tab remembers it over reloads. Parameters, CSV
files and recordings stay SI: they are what the server stores.
"""

from __future__ import annotations

import math

ANGLES = ("rad", "deg")
#: An angular unit and its counterpart in degrees.
_IN_DEGREES = {"rad": "deg", "rad/s": "deg/s", "rad/s^2": "deg/s^2"}


def labelled(name: str, unit: str) -> str:
    """`name [unit]`, or the bare name for a number without a unit ('' or '-')."""
    return f"{name} [{unit}]" if unit and unit != "-" else name


def shown(unit: str, angles: str) -> tuple[str, float]:
    """The unit a value of `unit` is shown in, and the factor from the server's value to it."""
    if angles == "deg" and unit in _IN_DEGREES:
        return _IN_DEGREES[unit], 180.0 / math.pi
    return unit, 1.0
