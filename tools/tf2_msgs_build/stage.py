"""Laying out the non-compiled files in the staging tree: Python package, headers, definitions, ament index."""

from __future__ import annotations

import shutil
from pathlib import Path

from .definitions import MESSAGES, PACKAGE


def stage_files(build: Path, stage: Path) -> None:
    """Copy the generated Python modules, headers and definitions from ``build`` into ``stage``."""
    gen = build / "gen"
    stage_pkg = stage / "site-packages" / PACKAGE
    # Python package
    py_gen = gen / "rosidl_generator_py" / PACKAGE
    shutil.copytree(py_gen / "msg", stage_pkg / "msg", ignore=shutil.ignore_patterns("*.c", "__pycache__"))
    (stage_pkg / "__init__.py").write_text("", encoding="utf-8")
    # Headers (include/<pkg>/<pkg>/..., as the ROS wheels lay them out)
    stage_inc = stage / "include" / PACKAGE / PACKAGE
    for kind in ("rosidl_generator_c", "rosidl_typesupport_fastrtps_c", "rosidl_typesupport_introspection_c"):
        for header in (gen / kind / PACKAGE).rglob("*.h"):
            target = stage_inc / header.relative_to(gen / kind / PACKAGE)
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(header, target)
    _stage_definitions(build, stage)


def _stage_definitions(build: Path, stage: Path) -> None:
    """The ``.msg``/``.idl``/``.json`` definitions under share/tf2_msgs, and the ament index markers."""
    gen = build / "gen"
    stage_share = stage / "share" / PACKAGE / "msg"
    stage_share.mkdir(parents=True)
    interfaces: list[str] = []
    for name in MESSAGES:
        for suffix in (".msg", ".idl"):
            shutil.copy2(build / "src" / "msg" / f"{name}{suffix}", stage_share / f"{name}{suffix}")
            interfaces.append(f"msg/{name}{suffix}")
        shutil.copy2(gen / "type_description" / PACKAGE / "msg" / f"{name}.json", stage_share / f"{name}.json")
    index = stage / "share" / "ament_index" / "resource_index"
    for resource, content in (("packages", ""), ("rosidl_interfaces", "\n".join(interfaces) + "\n")):
        (index / resource).mkdir(parents=True)
        (index / resource / PACKAGE).write_text(content, encoding="utf-8")
