"""Input data of the Vive desk calibration: contact samples, the fixture model and the noise model.

Frames (seed 001, docs/design.md naming): ``base`` = the Vive base station (lighthouse / OpenVR universe)
frame, ``desktop`` = the desk frame (FLU: x forward, y left, z up), ``tracker`` = the Vive tracker,
``tcp`` = the tool centre point rigidly attached to the tracker.

One *contact sample* i says: the TCP was held by the fixture at the desk position
``q_i = desk_point_i + tcp_offset_desktop_i`` (seed: ``tcp_offset = (0, 0, contact_offset_z)``)
with the orientation ``R_desktop_tcp_i`` (the fixture orientation; the seed uses one orientation for
all points) while the tracker reported ``T_base_tracker_i``. A sample may also have a *free*
orientation (``orientation_known = False``): the TCP tip sits in a socket at ``q_i`` but the tool
may be turned (pivot style); such samples constrain positions only.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from plugins.calibration.pose_lsq import as_rotation_stack, finite_array

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class ViveNoiseModel:
    """Standard deviations of the measurement errors (SI units).

    ``tracker_position_sigma_m``   Vive position jitter per axis in the base frame (typ. 0.3-1 mm).
    ``tracker_rotation_sigma_rad`` Vive orientation jitter (typ. 0.1 deg), isotropic.
    ``fixture_rotation_sigma_rad`` how far the real tool orientation scatters about the nominal
                                   fixture orientation, a rotation about the TCP (seed: < 0.5 deg with
                                   a good fixture, 3-10 deg by hand). 0 means "exactly the fixture's".
    ``desk_point_sigma_m``         placement error of each contact point + offset, per desk axis.
    """

    tracker_position_sigma_m: float = 0.5e-3
    tracker_rotation_sigma_rad: float = float(np.radians(0.1))
    fixture_rotation_sigma_rad: float = float(np.radians(0.3))
    desk_point_sigma_m: float = 0.0

    def __post_init__(self) -> None:
        for name in (
            "tracker_position_sigma_m",
            "tracker_rotation_sigma_rad",
            "fixture_rotation_sigma_rad",
            "desk_point_sigma_m",
        ):
            v = getattr(self, name)
            if not np.isfinite(v) or v < 0:
                raise ValueError(f"noise model {name} must be finite and >= 0, got {v}")
        if self.tracker_position_sigma_m <= 0 or self.tracker_rotation_sigma_rad <= 0:
            raise ValueError("tracker noise standard deviations must be > 0 (they weight the residuals)")


@dataclass(frozen=True)
class TrackerTcpPrior:
    """Optional prior knowledge of T_tracker_tcp (CAD drawing, caliper; seed method A).

    With one fixture orientation the lever arm is not identifiable from the contacts (see
    docs/vive_and_tcp.md); a prior with an honest ``sigma_position_m`` makes the problem well posed.
    ``sigma_rotation_rad = None`` puts no prior on the rotation.
    """

    T_tracker_tcp: F64
    sigma_position_m: float
    sigma_rotation_rad: float | None = None


@dataclass
class ViveDeskData:
    """N contact samples as arrays (SI units). Build with :meth:`from_contacts`."""

    desk_points: F64  # (N, 3) contact points in the desk frame
    T_base_tracker: F64  # (N, 4, 4)
    tcp_offsets_desktop: F64  # (N, 3) TCP minus contact point, desk frame
    R_desktop_tcp: F64  # (N, 3, 3) nominal fixture orientation (ignored where orientation is free)
    orientation_known: NDArray[np.bool_]  # (N,)
    noise: ViveNoiseModel = field(default_factory=ViveNoiseModel)
    labels: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)  # repairs made while loading (reported by the solver)

    @property
    def n(self) -> int:
        return int(self.desk_points.shape[0])

    @property
    def tcp_positions_desktop(self) -> F64:
        """q_i: where the fixture puts the TCP, in the desk frame (N, 3)."""
        return self.desk_points + self.tcp_offsets_desktop

    @classmethod
    def from_contacts(
        cls,
        desk_points: ArrayLike,
        T_base_tracker: ArrayLike,
        *,
        contact_offset_z: float = 0.12,
        tcp_offsets_desktop: ArrayLike | None = None,
        R_desktop_tcp: ArrayLike | None = None,
        orientation_known: ArrayLike | None = None,
        noise: ViveNoiseModel | None = None,
        labels: list[str] | None = None,
    ) -> ViveDeskData:
        """Validate shapes, finiteness and rotations; broadcast the seed's single fixture.

        ``R_desktop_tcp`` may be one 3x3 (the seed's fixed fixture; default identity) or (N, 3, 3)
        per sample. ``tcp_offsets_desktop`` overrides ``(0, 0, contact_offset_z)`` per sample.
        """
        P = finite_array("desk_points", desk_points, (None, 3))
        n = P.shape[0]
        T = finite_array("T_base_tracker", T_base_tracker, (n, 4, 4))
        for i, Ti in enumerate(T):
            if not np.allclose(Ti[3], (0, 0, 0, 1), atol=1e-9):
                raise ValueError(f"T_base_tracker[{i}] last row must be [0, 0, 0, 1], got {Ti[3]}")
        R_trk, dev_trk = as_rotation_stack("T_base_tracker rotation", T[:, :3, :3])
        T = T.copy()
        T[:, :3, :3] = R_trk
        if tcp_offsets_desktop is None:
            off_z = float(finite_array("contact_offset_z", contact_offset_z, ()))
            offsets = np.tile([0.0, 0.0, off_z], (n, 1))
        else:
            offsets = finite_array("tcp_offsets_desktop", tcp_offsets_desktop, (n, 3))
        if R_desktop_tcp is None:
            R_fix = np.tile(np.eye(3), (n, 1, 1))
        else:
            R_in = finite_array("R_desktop_tcp", R_desktop_tcp)
            if R_in.shape == (3, 3):
                R_in = np.tile(R_in, (n, 1, 1))
            if R_in.shape != (n, 3, 3):
                raise ValueError(f"R_desktop_tcp must be 3x3 or ({n}, 3, 3), got {R_in.shape}")
            R_fix, dev_fix = as_rotation_stack("R_desktop_tcp", R_in)
            dev_trk = max(dev_trk, dev_fix)
        known = (
            np.ones(n, dtype=bool)
            if orientation_known is None
            else np.asarray(orientation_known, dtype=bool).reshape(n)
        )
        notes = []
        if dev_trk > 1e-6:
            notes.append(
                f"rotations deviated from orthonormal by up to {dev_trk:.1e} (text rounding); "
                "replaced by the nearest rotation"
            )
        return cls(
            desk_points=P,
            T_base_tracker=T,
            tcp_offsets_desktop=offsets,
            R_desktop_tcp=R_fix,
            orientation_known=known,
            noise=noise or ViveNoiseModel(),
            labels=list(labels) if labels is not None else [f"P{i + 1}" for i in range(n)],
            notes=notes,
        )
