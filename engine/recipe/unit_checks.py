"""Values implausible for the unit their parameter's name carries: millimetres typed into ``*_m``
keys, metres into ``*_mm`` keys.

vgr names a length parameter with its unit (``xyz_m``, ``max_step_mm``); a recipe that says
``xyz_m: [-490, -80, 0]`` means millimetres and would otherwise run with a part half a kilometre
away ("current cloud is empty"). `vgr validate` and `vgr run` refuse such values before anything
starts, naming the parameter and the likely unit. The bounds are loose on purpose: nothing in a
robot cell is farther than :data:`MAX_CELL_LENGTH_M` from its origin, and no length a recipe gives
in millimetres is below a micron.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from typing import Any

MAX_CELL_LENGTH_M = 20.0  # larger is a length in millimetres typed into a metre parameter
MIN_LENGTH_MM = 1e-3  # smaller (and not 0) is a length in metres typed into a millimetre parameter


def _numbers(value: Any) -> list[float]:
    if isinstance(value, bool):
        return []
    if isinstance(value, int | float):
        return [float(value)]
    if isinstance(value, list | tuple):
        return [float(v) for v in value if isinstance(v, int | float) and not isinstance(v, bool)]
    return []


def implausible_lengths(params: Mapping[str, Any], path: tuple[str | int, ...] = ()) -> Iterator[tuple[tuple, str]]:
    """(path of the key, why) for each length whose value does not fit the unit in its key's name."""
    for key, value in params.items():
        here = (*path, key)
        if isinstance(value, Mapping):
            yield from implausible_lengths(value, here)
            continue
        if isinstance(value, list) and any(isinstance(v, Mapping) for v in value):
            for i, item in enumerate(value):
                if isinstance(item, Mapping):
                    yield from implausible_lengths(item, (*here, i))
            continue
        name = str(key)
        nums = _numbers(value)
        if name.endswith("_m") and any(abs(v) > MAX_CELL_LENGTH_M for v in nums):
            worst = max(nums, key=abs)
            yield (
                here,
                (
                    f"{worst:g} m is farther than anything in a robot cell ({MAX_CELL_LENGTH_M:g} m): "
                    f"were these millimetres? {name} is in metres"
                ),
            )
        elif name.endswith("_mm") and any(0.0 < abs(v) < MIN_LENGTH_MM for v in nums):
            worst = min((v for v in nums if v), key=abs)
            yield here, f"{worst:g} mm is below a micron: were these metres? {name} is in millimetres"
