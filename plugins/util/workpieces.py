"""Workpieces generated in code: watertight triangle meshes with their named features.

This module owns the geometry of the demo parts: the simulated cell shows them to its sensors, and
the ``target_pose`` stage takes one by name as its model (a real cell gives a mesh file instead). Every part is built
by constructive solid geometry with `manifold3d <https://github.com/elalish/manifold>`_ (robust booleans
whose output is guaranteed manifold, i.e. watertight with consistent outward orientation) in
millimetres, scaled to metres, and handed out as an ``open3d.geometry.TriangleMesh``.  No mesh file is
shipped.  Open3D's own (VTK) booleans were tried first and left self-intersecting, non-watertight
results on a plate-minus-hole difference, which is why manifold3d is used.

Parts (all frames: metres, Z up, origin at the centre of the bottom face's bounding box):

``feature_part``
    ~150 x 100 x 60 mm block with two steps, a tower, a chamfered boss with a bore, a through hole, a
    blind hole, an oblique slot and 45 degree chamfers whose normals point to +X, +Y, -Y and +X+Y, so
    point-to-plane ICP is well conditioned in all six degrees of freedom even from a top-down view.
``planar_plate`` (seed 004)
    200 x 150 x 8 mm plate with an irregular, non-symmetric contour and two locating pins (dia 5 mm,
    10 mm tall) on its top face.  X points from pin1 to pin2.
``symmetric_plate``
    200 x 150 x 8 mm rectangle with two pins placed point-symmetrically: a rotation of 180 degrees
    about Z maps the part onto itself, so its pose is truly ambiguous.
``base_plate`` (seed 004)
    400 x 320 x 15 mm assembly base with two blind holes dia 6 mm, 12 mm deep, that receive
    planar_plate's pins (0.5 mm radial clearance = the paper's 0.5 mm assembly tolerance), plus two
    more locating holes in a non-symmetric pattern.  The seed calls the base a "square trough"; the
    rim of the trough is not modelled, only the plate with its holes.

Features: ``pinN`` is the centre of the pin's root circle on the plate's top face, ``pinN_tip`` the
centre of its top; ``holeN`` is the centre of the hole's entry circle.  Axes point out of the material
(pin: from root to tip; hole: out of the hole).  A correctly assembled planar_plate therefore has
``T_base_part @ pinN == holeN`` and anti-parallel pin and hole axes: see :func:`assembled_plate_pose`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cache

import manifold3d as mf
import numpy as np
import open3d as o3d

from engine.transforms import T_from_Rt, as_transform, transform_points
from plugins.util.mesh_surface import sample_surface

__all__ = [
    "PLANAR_PLATE_THICKNESS_M",
    "Workpiece",
    "assembled_plate_pose",
    "list_workpieces",
    "make_workpiece",
]

MM = 1e-3
PLANAR_PLATE_THICKNESS_M = 8.0 * MM
BASE_PLATE_THICKNESS_M = 15.0 * MM
PIN_DIAMETER_M = 5.0 * MM
PIN_HEIGHT_M = 10.0 * MM
BASE_HOLE_DIAMETER_M = 6.0 * MM
BASE_HOLE_DEPTH_M = 12.0 * MM

# Segments per full circle: chord error r (1 - cos(pi / n)) is 5 um for the 2.5 mm pins at n = 48
# and 7 um for the 15 mm boss at n = 96.
_SEGMENTS_SMALL = 48
_SEGMENTS_LARGE = 96


@dataclass
class Workpiece:
    """A simulated part: its mesh in the part frame and its named features (all in metres)."""

    name: str
    mesh: o3d.geometry.TriangleMesh
    features: dict[str, np.ndarray]
    feature_radii: dict[str, float]
    feature_axes: dict[str, np.ndarray]
    symmetric: bool
    description: str
    size_m: np.ndarray = field(default_factory=lambda: np.zeros(3))  # bounding-box extent (x, y, z)

    def vertices(self) -> np.ndarray:
        """(V, 3) float64 vertex positions in the part frame (a copy)."""
        return np.asarray(self.mesh.vertices, dtype=float).copy()

    def triangles(self) -> np.ndarray:
        """(F, 3) int32 vertex indices of the triangles (outward counter-clockwise winding)."""
        return np.asarray(self.mesh.triangles, dtype=np.int32).copy()

    def sample_points(self, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """``n`` points uniformly distributed over the surface (area-weighted) and their normals.

        Drawn with the caller's generator, so the sample is reproducible (Open3D's samplers use a
        global seed instead).  Returns (points (n, 3), outward unit normals (n, 3)) in the part frame.
        """
        return sample_surface(self.mesh.vertices, self.mesh.triangles, n, rng)

    def transformed_features(self, T_frame_part: np.ndarray) -> dict[str, np.ndarray]:
        """Feature points expressed in another frame: ``p_frame = T_frame_part @ p_part``."""
        T = as_transform(T_frame_part, name="T_frame_part")
        return {k: transform_points(T, v)[0] for k, v in self.features.items()}


# --------------------------------------------------------------------------- CSG helpers (mm)


def _prism_xy(polygon_xy: list[tuple[float, float]], z0: float, z1: float) -> mf.Manifold:
    """Extrusion of a counter-clockwise XY polygon from z0 to z1."""
    return mf.CrossSection([np.asarray(polygon_xy, dtype=float)]).extrude(z1 - z0).translate((0, 0, z0))


def _prism_along_y(polygon_xz: list[tuple[float, float]], y0: float, y1: float) -> mf.Manifold:
    """Extrusion along Y of a polygon given in (x, z): a profile whose edges run along Y."""
    prism = mf.CrossSection([np.asarray(polygon_xz, dtype=float)]).extrude(y1 - y0)
    # proper rotation (u, v, w) -> (u, -w, v): w in [0, h] lands on y in [-h, 0]
    M = np.array([[1.0, 0, 0, 0], [0, 0, -1.0, y1], [0, 1.0, 0, 0]])
    return prism.transform(M)


def _prism_along_x(polygon_yz: list[tuple[float, float]], x0: float, x1: float) -> mf.Manifold:
    """Extrusion along X of a polygon given in (y, z): a profile whose edges run along X."""
    prism = mf.CrossSection([np.asarray(polygon_yz, dtype=float)]).extrude(x1 - x0)
    # cyclic permutation (u, v, w) -> (w, u, v) is a proper rotation
    M = np.array([[0, 0, 1.0, x0], [1.0, 0, 0, 0], [0, 1.0, 0, 0]])
    return prism.transform(M)


def _cylinder(cx: float, cy: float, z0: float, z1: float, r: float, segments: int) -> mf.Manifold:
    return mf.Manifold.cylinder(z1 - z0, r, r, segments).translate((cx, cy, z0))


def _to_open3d(solid: mf.Manifold) -> o3d.geometry.TriangleMesh:
    """Manifold in mm -> Open3D mesh in metres, with merged vertices and outward normals."""
    if solid.status() != mf.Error.NoError or solid.is_empty():
        raise RuntimeError(f"workpiece CSG failed: {solid.status()}")
    mesh = solid.to_mesh()
    V = np.array(mesh.vert_properties, dtype=float)[:, :3] * MM
    F = np.array(mesh.tri_verts, dtype=np.int32)
    out = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(V), o3d.utility.Vector3iVector(F))
    out.remove_duplicated_vertices()
    out.remove_unreferenced_vertices()
    out.compute_triangle_normals()
    out.compute_vertex_normals()
    return out


# --------------------------------------------------------------------------- the parts


def _feature_part() -> tuple[mf.Manifold, dict, dict, dict]:
    # Slab 150 x 100 x 20 with a vertical 10 mm chamfer at the (+x, +y) corner, a 6 mm chamfer on the
    # top +X edge and a 4 mm chamfer on the top -Y edge.
    outline = [(-75, -50), (75, -50), (75, 40), (65, 50), (-75, 50)]
    slab = (
        _prism_xy(outline, 0, 20)
        ^ _prism_along_y([(-80, -1), (75, -1), (75, 14), (69, 20), (-80, 20)], -60, 60)
        ^ _prism_along_x([(-50, -1), (60, -1), (60, 20), (-46, 20), (-50, 16)], -80, 80)
    )
    # Step on the -X half up to z = 40 with a 5 mm chamfer on its top +Y edge.
    step = _prism_xy([(-75, -50), (0, -50), (0, 50), (-75, 50)], 19, 40) ^ _prism_along_x(
        [(-60, 0), (50, 0), (50, 35), (45, 40), (-60, 40)], -80, 80
    )
    # Tower in the (-x, -y) corner up to z = 60 with a 3 mm chamfer on its top +X edge.
    tower = _prism_xy([(-75, -50), (-40, -50), (-40, 10), (-75, 10)], 39, 60) ^ _prism_along_y(
        [(-80, 0), (-40, 0), (-40, 57), (-43, 60), (-80, 60)], -60, 60
    )
    # Boss dia 30 at (35, -15) from the slab top to z = 45, the last 3 mm a 45 degree cone.
    boss_c = (35.0, -15.0)
    boss = _cylinder(*boss_c, 19, 42, 15, _SEGMENTS_LARGE) + mf.Manifold.cylinder(3, 15, 12, _SEGMENTS_LARGE).translate(
        (*boss_c, 42)
    )
    solid = slab + step + tower + boss
    # Bore dia 10, 15 mm deep, in the boss; through hole dia 10; blind hole dia 8, 12 mm deep in the step;
    # oblique slot 25 x 8 x 5 mm in the step, rotated 30 degrees about Z.
    bore = _cylinder(*boss_c, 30, 46, 5, _SEGMENTS_SMALL)
    through = _cylinder(40, 28, -1, 21, 5, _SEGMENTS_SMALL)
    blind = _cylinder(-20, -25, 28, 41, 4, _SEGMENTS_SMALL)
    slot_c = (-25.0, 25.0)
    slot = mf.Manifold.cube((25, 8, 6), center=True).rotate((0, 0, 30)).translate((*slot_c, 40 - 5 + 3))
    solid = solid - bore - through - blind - slot
    z = np.array([0.0, 0.0, 1.0])
    features = {
        "boss_top": np.array([*boss_c, 45.0]) * MM,
        "bore": np.array([*boss_c, 45.0]) * MM,
        "hole1": np.array([40.0, 28.0, 20.0]) * MM,
        "hole2": np.array([-20.0, -25.0, 40.0]) * MM,
        "slot": np.array([*slot_c, 40.0]) * MM,
        "tower_top": np.array([-57.5, -20.0, 60.0]) * MM,
    }
    radii = {"boss_top": 12.0 * MM, "bore": 5.0 * MM, "hole1": 5.0 * MM, "hole2": 4.0 * MM}
    axes = {k: z.copy() for k in radii}
    return solid, features, radii, axes


# planar_plate: irregular contour (mm) whose bounding box is centred on the origin, pins on y = -35.
_PLATE_CONTOUR = [
    (-100, -55),
    (-30, -75),
    (70, -75),
    (100, -45),
    (100, 20),
    (75, 75),
    (5, 75),
    (-25, 40),
    (-70, 50),
    (-100, 30),
]
_PLATE_PINS = {"pin1": (-60.0, -35.0), "pin2": (65.0, -35.0)}


def _plate_with_pins(
    contour: list[tuple[float, float]], pins: dict[str, tuple[float, float]], thickness: float
) -> tuple[mf.Manifold, dict, dict, dict]:
    solid = _prism_xy(contour, 0, thickness)
    r = PIN_DIAMETER_M / MM / 2.0
    h = PIN_HEIGHT_M / MM
    for x, y in pins.values():
        solid = solid + _cylinder(x, y, thickness - 1.0, thickness + h, r, _SEGMENTS_SMALL)
    z = np.array([0.0, 0.0, 1.0])
    features: dict[str, np.ndarray] = {}
    radii: dict[str, float] = {}
    axes: dict[str, np.ndarray] = {}
    for name, (x, y) in pins.items():
        features[name] = np.array([x, y, thickness]) * MM
        features[f"{name}_tip"] = np.array([x, y, thickness + h]) * MM
        for key in (name, f"{name}_tip"):
            radii[key] = PIN_DIAMETER_M / 2.0
            axes[key] = z.copy()
    return solid, features, radii, axes


def _planar_plate() -> tuple[mf.Manifold, dict, dict, dict]:
    return _plate_with_pins(_PLATE_CONTOUR, _PLATE_PINS, PLANAR_PLATE_THICKNESS_M / MM)


def _symmetric_plate() -> tuple[mf.Manifold, dict, dict, dict]:
    rect = [(-100, -75), (100, -75), (100, 75), (-100, 75)]
    return _plate_with_pins(rect, {"pin1": (-60.0, -40.0), "pin2": (60.0, 40.0)}, 8.0)


# Where the assembled planar_plate sits on the base (mm): pin face down, rotated 180 deg about X.
_ASSEMBLY_OFFSET_XY = (30.0, 20.0)


def assembled_plate_pose() -> np.ndarray:
    """T_base_part of a correctly assembled planar_plate on base_plate (both in their part frames).

    The plate is turned over (180 degrees about its X axis, so X still points from pin1 to pin2 and
    the pins point down into the holes), its pin face lies on the base's top face (z = 15 mm) and its
    frame origin is at (30, 20, 23) mm in the base frame.  Then ``T_base_part @ pinN == holeN``.
    """
    R = np.diag([1.0, -1.0, -1.0])
    t = np.array([*_ASSEMBLY_OFFSET_XY, (BASE_PLATE_THICKNESS_M + PLANAR_PLATE_THICKNESS_M) / MM]) * MM
    return T_from_Rt(R, t)


def _base_plate() -> tuple[mf.Manifold, dict, dict, dict]:
    thick = BASE_PLATE_THICKNESS_M / MM
    solid = _prism_xy([(-200, -160), (200, -160), (200, 160), (-200, 160)], 0, thick)
    T = assembled_plate_pose()
    holes: dict[str, tuple[float, float]] = {}
    for i, pin in enumerate(("pin1", "pin2"), start=1):
        x, y, _ = np.array([*_PLATE_PINS[pin], PLANAR_PLATE_THICKNESS_M / MM])
        p = T[:3, :3] @ np.array([x, y, PLANAR_PLATE_THICKNESS_M / MM]) + T[:3, 3] / MM
        holes[f"hole{i}"] = (float(p[0]), float(p[1]))
    # two more locating holes for other parts, placed so the hole pattern has no symmetry
    holes["hole3"] = (-150.0, 110.0)
    holes["hole4"] = (-60.0, 125.0)
    r = BASE_HOLE_DIAMETER_M / MM / 2.0
    depth = BASE_HOLE_DEPTH_M / MM
    for x, y in holes.values():
        solid = solid - _cylinder(x, y, thick - depth, thick + 1.0, r, _SEGMENTS_SMALL)
    z = np.array([0.0, 0.0, 1.0])
    features = {k: np.array([x, y, thick]) * MM for k, (x, y) in holes.items()}
    features["top_centre"] = np.array([0.0, 0.0, thick]) * MM
    radii = {k: BASE_HOLE_DIAMETER_M / 2.0 for k in holes}
    axes = {k: z.copy() for k in holes}
    return solid, features, radii, axes


_BUILDERS = {
    "feature_part": (
        _feature_part,
        False,
        "Feature-rich asymmetric block ~150 x 100 x 60 mm: steps, tower, chamfered boss with bore, "
        "through and blind holes, oblique slot, 45 deg chamfers; ICP is well conditioned in 6 DOF.",
    ),
    "planar_plate": (
        _planar_plate,
        False,
        "Seed 004 planar weak-geometry plate 200 x 150 x 8 mm, irregular non-symmetric contour, two "
        "pins dia 5 mm x 10 mm on the top face; X from pin1 to pin2.",
    ),
    "symmetric_plate": (
        _symmetric_plate,
        True,
        "Rectangular plate 200 x 150 x 8 mm with two point-symmetric pins: 180 deg about Z maps it "
        "onto itself (truly ambiguous pose).",
    ),
    "base_plate": (
        _base_plate,
        False,
        "Seed 004 assembly base 400 x 320 x 15 mm with holes dia 6 mm x 12 mm; hole1/hole2 receive "
        "planar_plate's pins at assembled_plate_pose().",
    ),
}


@cache
def _build_arrays(name: str) -> tuple[np.ndarray, np.ndarray, dict, dict, dict]:
    builder = _BUILDERS[name][0]
    solid, features, radii, axes = builder()
    mesh = _to_open3d(solid)
    V = np.asarray(mesh.vertices).copy()
    F = np.asarray(mesh.triangles).copy()
    V.setflags(write=False)
    F.setflags(write=False)
    return V, F, features, radii, axes


def list_workpieces() -> list[str]:
    """Names accepted by :func:`make_workpiece`."""
    return list(_BUILDERS)


def make_workpiece(name: str) -> Workpiece:
    """Build the named workpiece (a fresh mesh each call; the CSG itself is cached)."""
    if name not in _BUILDERS:
        raise ValueError(f"unknown workpiece {name!r}; known: {', '.join(_BUILDERS)}")
    V, F, features, radii, axes = _build_arrays(name)
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(V.copy()), o3d.utility.Vector3iVector(F.copy()))
    mesh.compute_triangle_normals()
    mesh.compute_vertex_normals()
    _, symmetric, description = _BUILDERS[name]
    return Workpiece(
        name=name,
        mesh=mesh,
        features={k: v.copy() for k, v in features.items()},
        feature_radii=dict(radii),
        feature_axes={k: v.copy() for k, v in axes.items()},
        symmetric=symmetric,
        description=description,
        size_m=V.max(axis=0) - V.min(axis=0),
    )
