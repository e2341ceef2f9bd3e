"""Where a P1 frame field is constrained: the rows whose orientation is fixed (boundary and
pinned vertices; later prescribed ones) with their directions, the lumped masses of all
vertices (note §3, "boundary conditions").

:func:`frame_constraints` finds them once per function space (local rows, owned and
ghost, of ``q.x.array``); :class:`~ufl_frames.fem.manifold.FrameManifold` applies them
pointwise. Found collectively; afterwards ghost rows agree with their owners.

Boundary orientation. At a boundary vertex one branch is aligned with the normal.
The normal is averaged in the 4-fold representation, e^{4iψ}, over the adjacent
boundary edges (weighted by length): at a right-angled corner both edges give the
same cross, at other corners the average is the cross closest to both.

Interior curves (interfaces between regions, curves embedded in a surface) hold the
cross the same way at their vertices that are not on the boundary
(:attr:`Fixed.PRESCRIBED`): one branch along the curve, averaged over the adjacent curve
facets, or the CAD curve's exact tangent where given. A vertex where curves meet with no
common cross (the 4-fold average vanishes: three curves at 120°) stays free.
"""

import enum
from dataclasses import dataclass, field, replace

from ufl_frames.bootstrap import init_petsc

init_petsc()

import dolfinx  # noqa: E402
import dolfinx.fem as fem  # noqa: E402
import numpy as np  # noqa: E402
import ufl  # noqa: E402
from mpi4py import MPI  # noqa: E402

from ufl_frames.frames2d.algebra import ALGEBRA, FrameAlgebra  # noqa: E402
from ufl_frames.frames2d.aspect import DEFAULT_MAX_ASPECT  # noqa: E402


class Fixed(enum.IntEnum):
    """Why a row's orientation is fixed (:attr:`FrameConstraints.kind`)."""

    #: Aligned with the domain's boundary (its normal).
    BOUNDARY = 0
    #: Held at its current orientation (the vertices around a singularity).
    PINNED = 1
    #: Given by the user (an interface, an embedded curve).
    PRESCRIBED = 2


@dataclass(frozen=True)
class FrameConstraints:
    """Where and how the frame field is constrained (local rows of the P1 space).

    ``fixed`` are the local vertex rows (owned and ghost) whose orientation is fixed,
    ``directions`` the unit direction one branch keeps there (nf, dim) and ``kind`` why
    (nf,) (:class:`Fixed`: boundary, pinned, prescribed); ``weights`` the lumped-mass
    weight of every local row; ``owned`` the number of owned rows; ``isotropic`` whether
    l1 = l2 everywhere; ``max_aspect`` the bound l_max/l_min of non-isotropic frames (None:
    unbounded; see :mod:`ufl_frames.frames2d.aspect`); ``algebra`` the frame algebra of
    the field (:data:`~ufl_frames.frames2d.algebra.ALGEBRA`: 2D frames).
    """

    fixed: np.ndarray
    directions: np.ndarray
    kind: np.ndarray
    weights: np.ndarray
    owned: int
    isotropic: bool
    comm: MPI.Comm
    max_aspect: float | None = None
    algebra: FrameAlgebra = field(default=ALGEBRA, repr=False)

    @property
    def free(self) -> np.ndarray:
        """The local rows whose orientation is free (not :attr:`fixed`)."""
        mask = np.ones(self.weights.size, dtype=bool)
        mask[self.fixed] = False
        return np.flatnonzero(mask)

    def fixed_as(self, kind: Fixed) -> np.ndarray:
        """The fixed rows of one ``kind``, e.g. ``Fixed.BOUNDARY``."""
        return self.fixed[self.kind == kind]

    def with_fixed(self, rows: np.ndarray, directions: np.ndarray,
                   kind: Fixed) -> "FrameConstraints":
        """These constraints with ``rows`` (not fixed yet) fixed to ``directions``.

        Args:
            rows: local rows (nr,) that are not fixed yet.
            directions: the unit direction one branch keeps at each row, (nr, dim).
            kind: why they are fixed, one :class:`Fixed` for all ``rows``.

        Returns:
            A new :class:`FrameConstraints` (this one is unchanged), ``rows`` appended.
        """
        return replace(
            self,
            fixed=np.concatenate([self.fixed, rows]),
            directions=np.concatenate([self.directions, directions]),
            kind=np.concatenate([self.kind, np.full(rows.size, kind, dtype=np.int8)]),
        )

    def for_frames(self, isotropic: bool, max_aspect: float | None) -> "FrameConstraints":
        """The same rows and directions for isotropic or general frames, the aspect bound
        set by its one rule (:func:`~ufl_frames.frames2d.aspect.aspect_bound`)."""
        return replace(self, isotropic=isotropic,
                       max_aspect=self.algebra.aspect_bound(isotropic, max_aspect))


def _vertex_rows_of_facets(V, facets):
    """Local P1 rows (vertex dofs) of the two vertices of each facet, shape (nf, 2)."""
    mesh = V.mesh
    tdim = mesh.topology.dim
    mesh.topology.create_connectivity(tdim - 1, tdim)
    f_to_c = mesh.topology.connectivity(tdim - 1, tdim)
    c_to_f = mesh.topology.connectivity(tdim, tdim - 1)
    dofmap = V.dofmap.list
    rows = np.empty((facets.size, 2), dtype=np.int32)
    # Local facet i of a triangle is opposite local vertex i: its dofs are the other two.
    for n, f in enumerate(facets):
        cell = f_to_c.links(f)[0]
        local = int(np.flatnonzero(c_to_f.links(cell) == f)[0])
        rows[n] = np.delete(dofmap[cell], local)
    return rows


def lumped_mass(V) -> np.ndarray:
    """The lumped mass ∫ φ_v dx of every local vertex row (owned and ghost) of the frame
    space ``V``, read off the first component of the blocked space (collective)."""
    count = V.dofmap.index_map_bs
    ones = ufl.as_vector([1.0] + [0.0] * (count - 1))
    lumped = fem.assemble_vector(fem.form(ufl.inner(ones, ufl.TestFunction(V)) * ufl.dx))
    lumped.scatter_reverse(dolfinx.la.InsertMode.add)
    lumped.scatter_forward()
    return lumped.array.reshape(-1, count)[:, 0].copy()


def frame_constraints(
    V,
    isotropic: bool = False,
    max_aspect: float | None = DEFAULT_MAX_ASPECT,
    boundary_angles: np.ndarray | None = None,
    algebra: FrameAlgebra = ALGEBRA,
    interior_facets: np.ndarray | None = None,
) -> FrameConstraints:
    """Boundary rows fixed to their normals, and lumped-mass weights, for the frame space
    ``V`` (collective).

    The cross at a boundary vertex is aligned with the mesh's boundary edges (module
    docstring), or, where ``boundary_angles`` gives one, with the CAD curve's exact
    tangent.

    Args:
        V: The P1 frame space (:func:`~ufl_frames.fem.energy.frame_space`).
        isotropic: Whether the frames are isotropic (l1 = l2).
        max_aspect: The bound l_max/l_min of non-isotropic frames (None or ``math.inf``:
            none).
        boundary_angles: One angle per local row, NaN where unknown (e.g.
            :meth:`ufl_frames.mesh.Domain.boundary_angles`), at the boundary rows and at
            the rows of ``interior_facets``.
        algebra: The frame algebra of ``V`` (a 2D one: the boundary normals are planar).
        interior_facets: Local facets inside the domain the cross is aligned to
            (:meth:`ufl_frames.mesh.Domain.interior_curve_facets`: interfaces, embedded
            curves; each facet on one rank only); None: none.

    Returns:
        The constraints, every boundary row fixed (:attr:`Fixed.BOUNDARY`), the other
        rows of ``interior_facets`` after them (:attr:`Fixed.PRESCRIBED`).
    """
    mesh = V.mesh
    tdim = mesh.topology.dim
    mesh.topology.create_connectivity(tdim - 1, tdim)
    mesh.topology.create_connectivity(tdim, tdim - 1)
    facets = dolfinx.mesh.exterior_facet_indices(mesh.topology)
    index_map = V.dofmap.index_map
    boundary, normals, _ = _facet_crosses(V, facets, boundary_angles)
    constraints = FrameConstraints(
        fixed=boundary,
        directions=normals,
        kind=np.full(boundary.size, Fixed.BOUNDARY, dtype=np.int8),
        weights=lumped_mass(V),
        owned=index_map.size_local,
        isotropic=isotropic,
        comm=mesh.comm,
        max_aspect=algebra.aspect_bound(isotropic, max_aspect),
        algebra=algebra,
    )
    if interior_facets is None:
        return constraints
    facets = np.asarray(interior_facets, dtype=np.int32)
    rows, directions, agree = _facet_crosses(V, facets, boundary_angles)
    keep = agree & ~np.isin(rows, boundary)
    return constraints.with_fixed(rows[keep], directions[keep], Fixed.PRESCRIBED)


def _facet_crosses(V, facets: np.ndarray, angles: np.ndarray | None):
    """The crosses of the vertices of ``facets`` (collective): the length-weighted
    average of e^{4iψ} of their facets' normals, summed across ranks, or the exact
    ``angles`` where finite.

    Returns:
        (rows (nr,), unit directions (nr, 2), whether each has a cross (nr,): an exact
        angle, or an average not cancelled out by facets of different crosses).
    """
    rows = _vertex_rows_of_facets(V, facets)
    x = V.tabulate_dof_coordinates()[:, :2]
    edge = x[rows[:, 1]] - x[rows[:, 0]]
    angle4 = 4 * np.arctan2(edge[:, 0], -edge[:, 1])  # normal (e_y, -e_x) up to sign
    length = np.linalg.norm(edge, axis=1)

    # Accumulate length-weighted e^{4iψ} at the vertices, summed across ranks.
    index_map = V.dofmap.index_map
    acc = dolfinx.la.vector(index_map, 3)
    values = acc.array.reshape(-1, 3)
    for k in range(2):
        np.add.at(values[:, 0], rows[:, k], length * np.cos(angle4))
        np.add.at(values[:, 1], rows[:, k], length * np.sin(angle4))
        np.add.at(values[:, 2], rows[:, k], length)
    marker = dolfinx.la.vector(index_map, 1)
    np.add.at(marker.array, rows.ravel(), 1.0)
    for vec in (acc, marker):
        vec.scatter_reverse(dolfinx.la.InsertMode.add)
        vec.scatter_forward()
    found = np.flatnonzero(marker.array > 0).astype(np.int32)
    c, s, total = values[found, 0], values[found, 1], values[found, 2]
    psi = np.arctan2(s, c) / 4
    agree = np.hypot(c, s) > 1e-6 * total
    if angles is not None:
        exact = np.asarray(angles, dtype=np.float64)[found]
        psi = np.where(np.isfinite(exact), exact, psi)
        agree |= np.isfinite(exact)
    return found, np.stack([np.cos(psi), np.sin(psi)], axis=1), agree


def pin_singularities(V, constraints: FrameConstraints, q: np.ndarray,
                      radius: float = 0.0) -> FrameConstraints:
    """Constraints that also fix the cross orientation at the vertices of singular triangles.

    The vertices of every triangle with a nonzero index (see
    :mod:`ufl_frames.frames2d.singularities`) are fixed like boundary vertices
    (:attr:`Fixed.PINNED`): orientation held at its current value, lengths free. The
    singularities then stay where the initial field put them — the solver can neither
    move nor annihilate them — which is the intended use of the MBO field as a template
    (note §3, "Initial condition"). Collective.

    Args:
        V: The P1 frame space.
        constraints: The constraints to add to (their fixed rows stay as they are).
        q: The local rows (N, count) of the field whose singularities are pinned.
        radius: With ``radius`` > 0 every vertex closer than that to a singular
            triangle's barycentre is held too.

    Returns:
        ``constraints`` with the pinned rows fixed to their current orientation.
    """
    from ufl_frames.frames2d.singularities import triangle_indices

    cells = V.dofmap.list
    x = V.tabulate_dof_coordinates()
    singular = cells[triangle_indices(cells, q, coords=x) != 0]
    marker = dolfinx.la.vector(V.dofmap.index_map, 1)
    marker.array[singular.ravel()] = 1.0
    if radius > 0.0:
        centres = np.concatenate(V.mesh.comm.allgather(x[singular, :2].mean(axis=1)))
        for c in centres:
            marker.array[np.sum((x[:, :2] - c) ** 2, axis=1) < radius**2] = 1.0
    marker.scatter_reverse(dolfinx.la.InsertMode.add)
    marker.scatter_forward()
    marker.array[constraints.fixed] = 0.0
    pinned = np.flatnonzero(marker.array > 0).astype(np.int32)
    directions = constraints.algebra.orientation(q[pinned])
    return constraints.with_fixed(pinned, directions, Fixed.PINNED)
