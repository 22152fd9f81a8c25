"""The effect families the loaded plugins contribute to the model-gap catalog (``vgr_model_effects``)."""

from __future__ import annotations

from typing import Any


def families_from_registry(extra_modules: tuple[str, ...] = ()) -> list[Any]:
    """The effect families every loaded plugin contributes through ``vgr_model_effects``, sorted by name."""
    from engine.plugin_manager import load_registry

    registry = load_registry(extra_modules)
    return [f() if isinstance(f, type) else f for _, f in sorted(registry.effects.items())]
