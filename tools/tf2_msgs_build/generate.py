"""Running the rosidl generators on tf2_msgs's definitions: C, type supports, Python, type hashes."""

from __future__ import annotations

import contextlib
import os
import shutil
import sys
from collections.abc import Iterator
from pathlib import Path

from .common import Layout
from .definitions import DEPENDENCIES, MESSAGES, PACKAGE, TYPESUPPORTS


@contextlib.contextmanager
def ament_prefix(prefix: Path) -> Iterator[None]:
    """Put the environment prefix on AMENT_PREFIX_PATH (the generators find their templates there)."""
    old = os.environ.get("AMENT_PREFIX_PATH")
    os.environ["AMENT_PREFIX_PATH"] = os.pathsep.join([str(prefix), *([old] if old else [])])
    try:
        yield
    finally:
        if old is None:
            os.environ.pop("AMENT_PREFIX_PATH", None)
        else:
            os.environ["AMENT_PREFIX_PATH"] = old


def generate(layout: Layout, build: Path) -> Path:
    """Run the rosidl generators; return the source folder (``build/src``).

    The generator extensions are called directly rather than through
    ``rosidl generate``: the wheels install both a dist-info and an egg-info per
    generator, so the CLI sees every entry point twice and refuses to run, and
    the CLI's .msg->.idl translation needs catkin_pkg, which is not installed.
    The generated sources go to ``build/gen/<generator>/tf2_msgs``.
    """
    import logging

    from rosidl_adapter.msg import convert_msg_to_idl

    logging.getLogger("rosidl_cli").setLevel(logging.ERROR)

    src = build / "src"
    (src / "msg").mkdir(parents=True)
    include_paths = [str(_copy_dependency_definitions(layout, build))]

    idl_files: list[str] = []
    with contextlib.ExitStack() as stack:
        # The generators print a line per file; keep them for VERBOSE=1 only.
        sink = sys.stderr if os.environ.get("VERBOSE") else stack.enter_context(open(os.devnull, "w"))
        stack.enter_context(contextlib.redirect_stdout(sink))
        for name, text in MESSAGES.items():
            (src / "msg" / f"{name}.msg").write_text(text, encoding="utf-8")
            convert_msg_to_idl(src, PACKAGE, Path("msg") / f"{name}.msg", src / "msg")
            idl_files.append(f"{src}:msg/{name}.idl")
        with ament_prefix(layout.prefix):
            _run_generators(idl_files, include_paths, build / "gen")
    return src


def _copy_dependency_definitions(layout: Layout, build: Path) -> Path:
    """Copy the dependency packages' ``msg/`` folders into ``build/deps_share``; return that folder.

    Only the dependencies, so that an earlier tf2_msgs in share/ cannot interfere; copied, not
    symlinked: the type-hash generator's glob skips symlinks.
    """
    deps_share = build / "deps_share"
    deps_share.mkdir()
    for dep in DEPENDENCIES:
        shutil.copytree(layout.share / dep / "msg", deps_share / dep / "msg")
    return deps_share


def _run_generators(idl_files: list[str], include_paths: list[str], out: Path) -> None:
    """Type hashes first (the C generator embeds them), then C, the C type supports and Python."""
    from rosidl_generator_c.cli import GenerateC
    from rosidl_generator_py.cli import GeneratePython
    from rosidl_generator_type_description.cli import HashTypeDescription
    from rosidl_typesupport_c.cli import GenerateCTypesupport
    from rosidl_typesupport_fastrtps_c.cli import GenerateFastRTPSCTypesupport
    from rosidl_typesupport_introspection_c.cli import GenerateIntrospectionCTypesupport

    type_descriptions = HashTypeDescription("type_description").generate_type_hashes(
        PACKAGE, idl_files, include_paths, output_path=out / "type_description" / PACKAGE
    )
    GenerateC("c").generate(
        PACKAGE,
        idl_files,
        include_paths,
        output_path=out / "rosidl_generator_c" / PACKAGE,
        type_description_files=type_descriptions,
    )
    for name, extension in (
        ("rosidl_typesupport_c", GenerateCTypesupport("c")),
        ("rosidl_typesupport_fastrtps_c", GenerateFastRTPSCTypesupport("fastrtps_c")),
        ("rosidl_typesupport_introspection_c", GenerateIntrospectionCTypesupport("introspection_c")),
    ):
        extension.generate(PACKAGE, idl_files, include_paths, output_path=out / name / PACKAGE)
    GeneratePython("py", typesupport_implementations=["rosidl_typesupport_c", *TYPESUPPORTS]).generate(
        PACKAGE, idl_files, include_paths, output_path=out / "rosidl_generator_py" / PACKAGE
    )
