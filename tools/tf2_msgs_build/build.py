"""The whole build, in a temporary folder: prerequisites, generation, compilation, staging, install."""

from __future__ import annotations

import shutil
import tempfile
import time
from pathlib import Path

from .common import Layout, log
from .compile import compile_package
from .generate import generate
from .install import install
from .prerequisites import check_prerequisites
from .stage import stage_files


def build_and_install(layout: Layout, keep_build: bool) -> None:
    """Build tf2_msgs and install it into ``layout``; raises BuildError (common) when a step fails."""
    tools = check_prerequisites(layout)
    build = Path(tempfile.mkdtemp(prefix="vgr_tf2_msgs_"))
    try:
        started = time.monotonic()
        log(f"generating sources in {build}")
        generate(layout, build)
        stage = compile_package(layout, build, tools)
        stage_files(build, stage)
        installed = install(layout, stage)
        log(f"installed {len(installed)} files into {layout.prefix} in {time.monotonic() - started:.1f} s")
    finally:
        if keep_build:
            log(f"kept build folder {build}")
        else:
            shutil.rmtree(build, ignore_errors=True)
