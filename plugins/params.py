"""Recipe parameter types shared by stages of every role (poses written for people)."""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator
from scipy.spatial.transform import Rotation

from engine.transforms import T_from_Rt, as_transform


class PoseSpec(BaseModel):
    """A pose in a recipe: ``xyz_m`` and ``rpy_deg`` (R = Rz(yaw) Ry(pitch) Rx(roll)), or a 4x4 ``matrix``."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    xyz_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    matrix: tuple[tuple[float, float, float, float], ...] | None = Field(None, description="4x4, metres")

    @model_validator(mode="after")
    def _valid(self) -> PoseSpec:
        if self.matrix is not None and (any(self.xyz_m) or any(self.rpy_deg)):
            raise ValueError("give either 'matrix' or 'xyz_m'/'rpy_deg', not both")
        if not np.all(np.isfinite(self.xyz_m)) or not np.all(np.isfinite(self.rpy_deg)):
            raise ValueError("pose values must be finite")
        self.T()
        return self

    def T(self) -> np.ndarray:
        if self.matrix is not None:
            return as_transform(np.array(self.matrix, dtype=float), name="pose matrix")
        R = Rotation.from_euler("xyz", self.rpy_deg, degrees=True).as_matrix()
        return T_from_Rt(R, self.xyz_m)

    @classmethod
    def of(cls, T: np.ndarray) -> PoseSpec:
        T = as_transform(T)
        return cls(xyz_m=tuple(T[:3, 3]), rpy_deg=tuple(Rotation.from_matrix(T[:3, :3]).as_euler("xyz", degrees=True)))
