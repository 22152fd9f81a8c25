"""A plugin that claims a model-effect name vgr's catalog already has (``backlash``): an error."""

from __future__ import annotations

from engine.hookspecs import hookimpl


class AnotherBacklash:
    name = "backlash"
    description = "a second effect family with a taken name"
    requires: tuple[str, ...] = ()

    def candidates(self, problem) -> list:
        return []


@hookimpl
def vgr_model_effects() -> list[type]:
    return [AnotherBacklash]
