"""Compiling the generated sources with gcc/g++: the five ``lib/`` libraries and the extension modules."""

from __future__ import annotations

import os
import subprocess
import sysconfig
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from .common import BuildError, Layout, log
from .definitions import DEPENDENCIES, PACKAGE, TYPESUPPORTS

# The C runtime every tf2_msgs library links against, after its own generator_c library.
_COMMON_C = [
    f"{PACKAGE}__rosidl_generator_c",
    *(f"{dep}__rosidl_generator_c" for dep in DEPENDENCIES),
    "rosidl_runtime_c",
    "rcutils",
]


def compile_package(layout: Layout, build: Path, tools: dict[str, str]) -> Path:
    """Compile the generated sources (``build/gen``); return the staging root (mirrors the prefix).

    The libraries go to ``stage/lib``, the extension modules to ``stage/site-packages/tf2_msgs``.
    """
    gen = build / "gen"
    stage = build / "stage"
    stage_lib = stage / "lib"
    stage_pkg = stage / "site-packages" / PACKAGE
    stage_lib.mkdir(parents=True)
    stage_pkg.mkdir(parents=True)
    compiler = _Compiler(tools, _include_flags(layout, gen, tools), [stage_lib, layout.lib], gen, stage_lib)
    _compile_libraries(compiler)
    pkg_rpath = "$ORIGIN/" + os.path.relpath(layout.lib, layout.site_packages / PACKAGE)
    ext_suffix = sysconfig.get_config_var("EXT_SUFFIX") or ".so"
    for ts in ("rosidl_typesupport_c", *TYPESUPPORTS):
        source = gen / "rosidl_generator_py" / PACKAGE / f"_{PACKAGE}_s.ep.{ts}.c"
        module = stage_pkg / f"{PACKAGE}_s__{ts}{ext_suffix}"
        log(f"compiling {module.name}")
        compiler.link([source], module, [f"{PACKAGE}__rosidl_generator_py", f"{PACKAGE}__{ts}", *_COMMON_C], pkg_rpath)
    return stage


def _dep_libs(suffix: str) -> list[str]:
    return [f"{dep}__{suffix}" for dep in DEPENDENCIES]


def _compile_libraries(c: _Compiler) -> None:
    """The generator and type-support libraries, in link order (each needs the ones before)."""
    c.library("rosidl_generator_c", "detail/*.c", [*_dep_libs("rosidl_generator_c"), "rosidl_runtime_c", "rcutils"])
    c.library(
        "rosidl_typesupport_fastrtps_c",
        "detail/*.cpp",
        [
            *_dep_libs("rosidl_typesupport_fastrtps_c"),
            "rosidl_typesupport_fastrtps_cpp",
            "rosidl_typesupport_fastrtps_c",
            "rmw",
            "rosidl_dynamic_typesupport",
            ":libfastcdr.so.2",
            *_COMMON_C,
        ],
    )
    c.library(
        "rosidl_typesupport_introspection_c",
        "detail/*.c",
        [*_dep_libs("rosidl_typesupport_introspection_c"), "rosidl_typesupport_introspection_c", *_COMMON_C],
    )
    c.library("rosidl_typesupport_c", "*.cpp", [*_dep_libs("rosidl_typesupport_c"), "rosidl_typesupport_c", *_COMMON_C])
    # Python symbols stay undefined and resolve against the interpreter, as in the ROS wheels.
    c.library(
        "rosidl_generator_py",
        "_*_s.c",
        [
            f"{PACKAGE}__rosidl_typesupport_c",
            *_dep_libs("rosidl_generator_py"),
            *_dep_libs("rosidl_typesupport_c"),
            "rosidl_typesupport_c",
            *_COMMON_C,
        ],
        dll=False,
    )


def _include_flags(layout: Layout, gen: Path, tools: dict[str, str]) -> list[str]:
    dirs = [
        gen / "rosidl_generator_c",
        gen / "rosidl_typesupport_c",
        gen / "rosidl_typesupport_fastrtps_c",
        gen / "rosidl_typesupport_introspection_c",
        layout.include,
    ]
    # ROS 2 installs headers as include/<pkg>/<pkg>/...; a few vendored ones are flat (include/fastcdr/...).
    dirs += sorted(p for p in layout.include.iterdir() if p.is_dir() and (p / p.name).is_dir())
    dirs += [Path(tools["python_include"]), Path(tools["numpy_include"])]
    return [f"-I{d}" for d in dirs]


@dataclass(frozen=True)
class _Compiler:
    """gcc/g++ with the include flags and library folders of this build."""

    tools: dict[str, str]
    cflags: Sequence[str]
    lib_dirs: Sequence[Path]
    gen: Path
    stage_lib: Path

    def library(self, kind: str, pattern: str, libs: Sequence[str], *, dll: bool = True) -> None:
        """Compile generator ``kind``'s sources matching ``pattern`` into ``stage/lib/libtf2_msgs__<kind>.so``.

        With ``dll``, defines ``<KIND>_BUILDING_DLL_tf2_msgs`` (the generated visibility macros).
        """
        output = self.stage_lib / f"lib{PACKAGE}__{kind}.so"
        log(f"compiling {output.name}")
        sources = sorted((self.gen / kind / PACKAGE / "msg").glob(pattern))
        if not sources:
            raise BuildError(f"generator {kind} produced no {pattern}")
        self.link(sources, output, libs, "$ORIGIN", [f"{kind.upper()}_BUILDING_DLL_{PACKAGE}"] if dll else [])

    def link(
        self, sources: Sequence[Path], output: Path, libs: Sequence[str], rpath: str, defines: Sequence[str] = ()
    ) -> None:
        """Compile and link ``sources`` into the shared object ``output`` (C++ if any source is .cpp)."""
        cxx = any(s.suffix == ".cpp" for s in sources)
        cmd = [
            self.tools["g++" if cxx else "gcc"],
            "-std=c++17" if cxx else "-std=gnu11",
            "-O2",
            "-fPIC",
            "-shared",
            "-w",
            *self.cflags,
            *(f"-D{d}" for d in defines),
            *map(str, sources),
            "-o",
            str(output),
            f"-Wl,-soname,{output.name}",
            f"-Wl,-rpath,{rpath}",
            *(f"-L{d}" for d in self.lib_dirs),
            *(f"-l{lib}" for lib in libs),
        ]
        if os.environ.get("VERBOSE"):
            log(" ".join(cmd))
        proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
        if proc.returncode != 0:
            raise BuildError(f"compiling {output.name} failed:\n{' '.join(cmd)}\n{proc.stdout}{proc.stderr}")
