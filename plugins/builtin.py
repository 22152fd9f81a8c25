"""vgr's own plugin: registers the built-in stage types through the ``vgr`` entry-point group,
exactly as a third-party package would (pyproject: ``[project.entry-points.vgr] builtin = ...``)."""

from __future__ import annotations

from engine.hookspecs import hookimpl


@hookimpl
def vgr_stage_types() -> list[type]:
    from plugins.util.cloud_stages import CloudStats, SyntheticCloud, TransformCloud

    return [SyntheticCloud, TransformCloud, CloudStats]
