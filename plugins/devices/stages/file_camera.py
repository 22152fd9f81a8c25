"""``file_camera``: a depth camera that plays PLY/PCD/NPZ frames from a folder (camera contract).

Each ``capture`` returns the next file's cloud in the camera frame (metres) and publishes it on
``cloud``; NPZ frames with ``depth`` and ``K`` also publish ``depth`` and ``camera_info`` (file
format: :mod:`plugins.devices.frame_files`). After the last file it starts over when ``loop`` is
set, otherwise ``capture`` fails saying that every frame was played. A recipe switches between
this stage, ``sim_camera`` and ``realsense_camera`` by ``type:`` and parameters only. ``frames``
carries the mount, ``parent_frame -> frame_id`` = ``T_parent_cam`` (default: identity in ``world``),
at set-up and with every capture (:mod:`plugins.devices.camera_output`).
"""

from __future__ import annotations

from typing import Any

from pydantic import Field

from engine.messages import PointCloud
from engine.stage import input_file
from plugins.devices.camera_output import DepthCameraAdapter, DepthCameraParams, publish_capture, publish_mount
from plugins.devices.frame_files import FrameFileError, list_frame_files, load_frame


class FileCameraParams(DepthCameraParams):
    """Parameters of ``file_camera``."""

    folder: str = input_file(description="folder holding the frame files (.ply, .pcd, .npz); relative: to the recipe")
    pattern: str = Field("*", description="glob of the files to play inside the folder, e.g. 'scan_*.pcd'")
    loop: bool = Field(False, description="start over after the last file (else capture fails)")
    unit_scale_m: float = Field(1.0, gt=0.0, description="metres per file unit (0.001 for files in mm)")


class FileCamera(DepthCameraAdapter):
    """Plays PLY/PCD/NPZ point-cloud frames from a folder, one per capture, in name order."""

    type_name = "file_camera"
    Params = FileCameraParams

    def setup(self) -> None:
        p: FileCameraParams = self.params  # type: ignore[assignment]
        self.files = list_frame_files(self.ctx.input_path(p.folder), p.pattern)
        self.next_index = 0
        self.ctx.event("info", "frames_found", f"{len(self.files)} frame files in {p.folder}", count=len(self.files))
        publish_mount(self.ctx, p)

    def on_request(self, service: str, request: Any) -> PointCloud:
        p: FileCameraParams = self.params  # type: ignore[assignment]
        if self.next_index >= len(self.files):
            if not p.loop:
                raise FrameFileError(
                    f"all {len(self.files)} frames of {p.folder} were played (set loop: true to start over)"
                )
            self.next_index = 0
        path = self.files[self.next_index]
        self.next_index += 1
        return publish_capture(self.ctx, p, load_frame(path, p.unit_scale_m))
