r"""The built-in geometries: the research note's test cases (*A tensor formulation for
integrable frame fields*, §4, Fig. 1).

- :func:`annulus`: the ring :math:`r_i \le |x| \le r_o` (default 0.5 and 1, area
  :math:`3\pi/4`). A boundary-aligned cross field on it has no singularity.
- :func:`piano`: a grand-piano outline, 2 × 1.2, whose smooth boundary-aligned cross
  field has exactly one +1/4 singularity in its left part and one −1/4 in its right
  part (the note does not give its exact shape; this one is ours).

  Counter-clockwise from the origin: the straight keyboard (0, 0)–(2, 0); the straight
  treble cheek (2, 0)–(2, 0.6); the concave bentside, a quarter circle of radius 0.6
  centred at (2, 1.2) from (2, 0.6) to (1.4, 1.2); the straight top (1.4, 1.2)–(0.8, 1.2);
  the convex tail, a quarter circle of radius 0.8 centred at (0.8, 0.4) from (0.8, 1.2)
  to (0, 0.4), tangent to the top and to the straight bass side (0, 0.4)–(0, 0).

  The four corners ((0, 0), (2, 0), (2, 0.6), (1.4, 1.2)) are right angles, so the
  interior indices sum to 1 − Σ_corners (2 − k_c)/4 = 0 (corner angles k_c·90°). The
  tail turns the boundary by +90° without a corner, which puts a +1/4 singularity
  under it, near (0.41, 0.79); the bentside turns it by −90°, which puts a −1/4 one
  beside it, near (1.43, 0.63) (harmonic 4θ field; ``meshes/README.md``).
"""

import math

from ufl_frames.bootstrap import init_petsc

init_petsc()

import gmsh  # noqa: E402
from mpi4py import MPI  # noqa: E402

from ufl_frames.mesh.distribute import create  # noqa: E402
from ufl_frames.mesh.domain import (  # noqa: E402
    Domain,
    GeometryError,
    check_mesh_size,
    check_refinements,
    is_real,
)
from ufl_frames.mesh.meshing import MAX_TRIANGLES, Sizing, mesh_model  # noqa: E402

#: Mesh size of the built-in geometries when none is given.
BUILTIN_MESH_SIZE = 0.05

# The piano outline (see the module docstring).
PIANO_WIDTH = 2.0
PIANO_HEIGHT = 1.2
PIANO_CONVEX_RADIUS = 0.8  # the rounded tail, top left
PIANO_CONCAVE_RADIUS = 0.6  # the bentside, top right


def annulus(
    comm: MPI.Comm,
    mesh_size: float = BUILTIN_MESH_SIZE,
    r_inner: float = 0.5,
    r_outer: float = 1.0,
    refinements: int = 0,
    max_triangles: float = MAX_TRIANGLES,
) -> Domain:
    """Triangle mesh of the annulus r_inner ≤ |x| ≤ r_outer centred at the origin.

    Args:
        comm: The communicator the mesh is distributed over (collective).
        mesh_size: The largest element size.
        r_inner: The inner radius.
        r_outer: The outer radius.
        refinements: As for :func:`~ufl_frames.mesh.build`.
        max_triangles: A size that would give more triangles is refused before meshing.

    Returns:
        The distributed domain.
    """
    h = check_mesh_size(mesh_size)
    refinements = check_refinements(refinements)
    for name, r in (("r_inner", r_inner), ("r_outer", r_outer)):
        if not is_real(r) or not math.isfinite(r) or r <= 0:
            raise GeometryError(f"{name} must be a positive finite number, got {r!r}")
    if not r_inner < r_outer:
        raise GeometryError(f"r_inner must be smaller than r_outer, got {r_inner} >= {r_outer}")

    def make(notes):
        annulus_model(r_inner, r_outer)
        return mesh_model(Sizing(h, max_triangles=max_triangles, refinements=refinements), notes)

    return create(comm, make, "annulus", cad=True)


def annulus_model(r_inner: float = 0.5, r_outer: float = 1.0) -> None:
    """The annulus' CAD model (OpenCASCADE) in the current Gmsh model, not meshed."""
    occ = gmsh.model.occ
    outer = occ.addDisk(0.0, 0.0, 0.0, r_outer, r_outer)
    inner = occ.addDisk(0.0, 0.0, 0.0, r_inner, r_inner)
    occ.cut([(2, outer)], [(2, inner)])
    occ.synchronize()


def piano(comm: MPI.Comm, mesh_size: float = BUILTIN_MESH_SIZE, refinements: int = 0,
          max_triangles: float = MAX_TRIANGLES) -> Domain:
    """Triangle mesh of the 'piano' outline (module docstring, ``meshes/piano.geo``).

    Args:
        comm: The communicator the mesh is distributed over (collective).
        mesh_size: The largest element size.
        refinements: As for :func:`~ufl_frames.mesh.build`.
        max_triangles: As for :func:`annulus`.

    Returns:
        The distributed domain.
    """
    h = check_mesh_size(mesh_size)
    refinements = check_refinements(refinements)

    def make(notes):
        piano_model()
        return mesh_model(Sizing(h, max_triangles=max_triangles, refinements=refinements), notes)

    return create(comm, make, "piano", cad=True)


def piano_model() -> None:
    """The piano's CAD model (OpenCASCADE) in the current Gmsh model, not meshed."""
    occ = gmsh.model.occ
    pts = [occ.addPoint(x, y, 0.0) for x, y in piano_points()]
    p_bass, p_treble, p_cheek, p_top_right, p_top_left, p_tail, c_concave, c_convex = pts
    curves = [
        occ.addLine(p_bass, p_treble),  # keyboard
        occ.addLine(p_treble, p_cheek),  # treble cheek
        occ.addCircleArc(p_cheek, c_concave, p_top_right),  # concave bentside
        occ.addLine(p_top_right, p_top_left),  # top
        occ.addCircleArc(p_top_left, c_convex, p_tail),  # convex tail
        occ.addLine(p_tail, p_bass),  # bass side
    ]
    loop = occ.addCurveLoop(curves)
    occ.addPlaneSurface([loop])
    occ.synchronize()


def piano_points() -> list[tuple[float, float]]:
    """The points of the piano outline: its six boundary vertices in counter-clockwise
    order from the origin, then the centres of the concave and the convex arc."""
    w, top = PIANO_WIDTH, PIANO_HEIGHT
    r1, r2 = PIANO_CONCAVE_RADIUS, PIANO_CONVEX_RADIUS
    return [
        (0.0, 0.0),
        (w, 0.0),
        (w, top - r1),
        (w - r1, top),
        (r2, top),
        (0.0, top - r2),
        (w, top),
        (r2, top - r2),
    ]


def piano_area() -> float:
    """Exact area of the piano outline."""
    w, top = PIANO_WIDTH, PIANO_HEIGHT
    r1, r2 = PIANO_CONCAVE_RADIUS, PIANO_CONVEX_RADIUS
    # The rectangle less a quarter disc at the top right and the corner piece outside
    # the rounded tail at the top left.
    return w * top - r1 * r1 * math.pi / 4 - r2 * r2 * (1 - math.pi / 4)


def piano_perimeter() -> float:
    """Exact boundary length of the piano outline."""
    w, top = PIANO_WIDTH, PIANO_HEIGHT
    r1, r2 = PIANO_CONCAVE_RADIUS, PIANO_CONVEX_RADIUS
    return 2 * w + 2 * top - 2 * (r1 + r2) + math.pi / 2 * (r1 + r2)


#: Built-in geometry names accepted by :func:`build`.
KNOWN_GEOMETRIES = {"annulus": annulus, "piano": piano}
#: Their CAD models with the default parameters (:mod:`ufl_frames.mesh.cad`).
BUILTIN_MODELS = {"annulus": annulus_model, "piano": piano_model}
