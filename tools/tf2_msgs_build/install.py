"""Installing the staged tree into the environment with a dist-info (RECORD), and uninstalling it."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

from .common import Layout, log
from .definitions import PACKAGE

# Only for the dist-info (pip show / pip uninstall ros-tf2-msgs); marks the package as built here.
PACKAGE_VERSION = "0.0.0+vgrlocal"
DIST_NAME = "ros_tf2_msgs"


def dist_info_dir(layout: Layout) -> Path:
    return layout.site_packages / f"{DIST_NAME}-{PACKAGE_VERSION}.dist-info"


def install(layout: Layout, stage: Path) -> list[Path]:
    """Copy the staged files into the environment; the Python package last."""
    uninstall(layout, quiet=True)
    roots = {
        "lib": layout.lib,
        "include": layout.include,
        "share": layout.share,
        "site-packages": layout.site_packages,
    }
    installed: list[Path] = []
    for top in ("lib", "include", "share", "site-packages"):
        for path in sorted((stage / top).rglob("*")):
            if path.is_dir():
                continue
            target = roots[top] / path.relative_to(stage / top)
            target.parent.mkdir(parents=True, exist_ok=True)
            tmp = target.with_name(target.name + ".tmp-build_tf2_msgs")
            shutil.copy2(path, tmp)
            os.replace(tmp, target)
            installed.append(target)
    _write_dist_info(layout, installed)
    return installed


def _write_dist_info(layout: Layout, installed: list[Path]) -> None:
    """The ``ros_tf2_msgs-*.dist-info`` whose RECORD lists every installed file (for pip and uninstall)."""
    dist_info = dist_info_dir(layout)
    dist_info.mkdir(exist_ok=True)
    (dist_info / "METADATA").write_text(
        "Metadata-Version: 2.1\n"
        f"Name: {DIST_NAME.replace('_', '-')}\n"
        f"Version: {PACKAGE_VERSION}\n"
        "Summary: tf2_msgs (TFMessage, TF2Error) built locally by vgr tools/build_tf2_msgs.py\n"
        "License: BSD-3-Clause\n",
        encoding="utf-8",
    )
    (dist_info / "INSTALLER").write_text("vgr-build_tf2_msgs\n", encoding="utf-8")
    (dist_info / "top_level.txt").write_text(f"{PACKAGE}\n", encoding="utf-8")
    record = [*installed, dist_info / "METADATA", dist_info / "INSTALLER", dist_info / "top_level.txt"]
    lines = [f"{os.path.relpath(p, layout.site_packages)},," for p in record]
    lines.append(f"{os.path.relpath(dist_info / 'RECORD', layout.site_packages)},,")
    (dist_info / "RECORD").write_text("\n".join(lines) + "\n", encoding="utf-8")


def uninstall(layout: Layout, *, quiet: bool = False) -> None:
    """Remove what an earlier run (of any version of this script) installed, per its RECORD."""
    dist_infos = sorted(layout.site_packages.glob(f"{DIST_NAME}-*.dist-info"))
    records = [d / "RECORD" for d in dist_infos if (d / "RECORD").is_file()]
    if not records:
        if not quiet:
            log(f"nothing to uninstall (no {DIST_NAME}-*.dist-info/RECORD in {layout.site_packages})")
        return
    for record in records:
        for line in record.read_text(encoding="utf-8").splitlines():
            rel = line.split(",", 1)[0]
            if rel:
                (layout.site_packages / rel).unlink(missing_ok=True)
    for directory in (layout.site_packages / PACKAGE, layout.include / PACKAGE, layout.share / PACKAGE, *dist_infos):
        shutil.rmtree(directory, ignore_errors=True)
    if not quiet:
        log("uninstalled tf2_msgs")
