"""Pointwise projections applied to a whole P1 frame field (note §3, steps 2, 4 and 5).

The kernels are those of :mod:`ufl_frames.odeco`; this module knows which vertices
are on the boundary, the boundary orientation there, the lumped-mass weights of the
vertices, and works on the local rows (owned and ghost) of ``q.x.array``. Every
operation is pointwise and deterministic, so ghost rows stay equal to their owners'
without communication; only norms are reduced over MPI.

Boundary orientation. At a boundary vertex one branch is aligned with the normal.
The normal is averaged in the 4-fold representation, e^{4iψ}, over the adjacent
boundary edges (weighted by length): at a right-angled corner both edges give the
same cross, at other corners the average is the cross closest to both.
"""

from dataclasses import dataclass, replace

from ufl_frames.bootstrap import init_petsc

init_petsc()

import dolfinx  # noqa: E402
import dolfinx.fem as fem  # noqa: E402
import numpy as np  # noqa: E402
import ufl  # noqa: E402
from mpi4py import MPI  # noqa: E402

from ufl_frames import odeco  # noqa: E402


@dataclass(frozen=True)
class FrameConstraints:
    """Where and how the frame field is constrained (local rows of the P1 space).

    ``boundary`` are local vertex rows (owned and ghost) on the boundary, ``normals``
    their unit normals (nb, 2); ``weights`` the lumped-mass weight of every local
    row; ``owned`` the number of owned rows; ``isotropic`` whether l1 = l2 everywhere.
    """

    boundary: np.ndarray
    normals: np.ndarray
    weights: np.ndarray
    owned: int
    isotropic: bool
    comm: MPI.Comm
    max_aspect: float | None = None

    @property
    def interior(self) -> np.ndarray:
        mask = np.ones(self.weights.size, dtype=bool)
        mask[self.boundary] = False
        return np.flatnonzero(mask)


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


def frame_constraints(
    V,
    isotropic: bool = False,
    max_aspect: float | None = None,
    boundary_angles: np.ndarray | None = None,
) -> FrameConstraints:
    """Boundary rows, their normals and lumped-mass weights for the frame space ``V``.

    The cross at a boundary vertex is aligned with the mesh's boundary edges (module
    docstring), or, where ``boundary_angles`` (one angle per local row, NaN where
    unknown; e.g. :meth:`ufl_frames.geometry.Domain.boundary_angles`) gives one, with
    the CAD curve's exact tangent.
    """
    mesh = V.mesh
    tdim = mesh.topology.dim
    mesh.topology.create_connectivity(tdim - 1, tdim)
    mesh.topology.create_connectivity(tdim, tdim - 1)
    facets = dolfinx.mesh.exterior_facet_indices(mesh.topology)
    rows = _vertex_rows_of_facets(V, facets)
    x = V.tabulate_dof_coordinates()[:, :2]
    edge = x[rows[:, 1]] - x[rows[:, 0]]
    angle4 = 4 * np.arctan2(edge[:, 0], -edge[:, 1])  # normal (e_y, -e_x) up to sign
    length = np.linalg.norm(edge, axis=1)

    # Accumulate length-weighted e^{4iψ} at the vertices, summed across ranks.
    index_map = V.dofmap.index_map
    acc = dolfinx.la.vector(index_map, 2)
    values = acc.array.reshape(-1, 2)
    for k in range(2):
        np.add.at(values[:, 0], rows[:, k], length * np.cos(angle4))
        np.add.at(values[:, 1], rows[:, k], length * np.sin(angle4))
    marker = dolfinx.la.vector(index_map, 1)
    np.add.at(marker.array, rows.ravel(), 1.0)
    for vec in (acc, marker):
        vec.scatter_reverse(dolfinx.la.InsertMode.add)
        vec.scatter_forward()
    boundary = np.flatnonzero(marker.array > 0).astype(np.int32)
    c, s = values[boundary, 0], values[boundary, 1]
    psi = np.arctan2(s, c) / 4
    if boundary_angles is not None:
        exact = np.asarray(boundary_angles, dtype=np.float64)[boundary]
        psi = np.where(np.isfinite(exact), exact, psi)
    normals = np.stack([np.cos(psi), np.sin(psi)], axis=1)

    # Lumped mass ∫ φ_v dx of every vertex, read off the first component of the blocked space.
    ones = ufl.as_vector([1.0, 0.0, 0.0, 0.0, 0.0])
    lumped = fem.assemble_vector(fem.form(ufl.inner(ones, ufl.TestFunction(V)) * ufl.dx))
    lumped.scatter_reverse(dolfinx.la.InsertMode.add)
    lumped.scatter_forward()
    return FrameConstraints(
        boundary=boundary,
        normals=normals,
        weights=lumped.array.reshape(-1, odeco.NUM_COEFFICIENTS)[:, 0].copy(),
        owned=index_map.size_local,
        isotropic=isotropic,
        comm=mesh.comm,
        max_aspect=None if isotropic else max_aspect,
    )


def pin_singularities(V, constraints: FrameConstraints, q: np.ndarray) -> FrameConstraints:
    """Constraints that also fix the cross orientation at the vertices of singular triangles.

    The vertices of every triangle with a nonzero index (see
    :mod:`ufl_frames.singularities`) are treated like boundary vertices: orientation
    held at its current value, lengths free. The singularities then stay where the
    initial field put them — the solver can neither move nor annihilate them — which
    is the intended use of the MBO field as a template (note §3, "Initial condition").
    """
    from ufl_frames.singularities import triangle_indices

    cells = V.dofmap.list
    x = V.tabulate_dof_coordinates()
    singular = cells[triangle_indices(cells, q, coords=x) != 0]
    marker = dolfinx.la.vector(V.dofmap.index_map, 1)
    marker.array[singular.ravel()] = 1.0
    marker.scatter_reverse(dolfinx.la.InsertMode.add)
    marker.scatter_forward()
    marker.array[constraints.boundary] = 0.0
    pinned = np.flatnonzero(marker.array > 0).astype(np.int32)
    _, angles = odeco.q_to_frames(q[pinned])
    normals = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    return replace(
        constraints,
        boundary=np.concatenate([constraints.boundary, pinned]),
        normals=np.concatenate([constraints.normals, normals]),
    )


def project_rows(q: np.ndarray, constraints: FrameConstraints) -> np.ndarray:
    """Step 4 of note §3: Odeco projection inside, orientation-fixed projection on ∂Ω."""
    out = np.empty_like(q)
    interior = constraints.interior
    iso, aspect = constraints.isotropic, constraints.max_aspect
    out[interior] = odeco.project(q[interior], isotropic=iso, max_aspect=aspect)
    b = constraints.boundary
    out[b] = odeco.project_aligned(q[b], constraints.normals, isotropic=iso, max_aspect=aspect)
    return out


def tangent_basis_rows(
    q: np.ndarray, constraints: FrameConstraints, gradient: np.ndarray | None = None
) -> np.ndarray:
    """Orthonormal tangent basis (N, 5, 3) of the constraint set at q (zero columns: no dof).

    q must satisfy the constraints (be retracted): the frames are read off it directly.

    Interior: 3 dofs (total length e_s, length difference e_d, rotation); isotropic:
    e_s and rotation. Boundary: orientation fixed, so e_s and e_d (isotropic: e_s).
    With an aspect bound, frames at the bound that ``gradient`` pushes outwards lose
    e_d (see :func:`ufl_frames.odeco.tangent_basis`).
    """
    basis = odeco.tangent_basis(
        q, max_aspect=constraints.max_aspect, gradient=gradient, on_variety=True
    )
    basis[constraints.boundary, :, 2] = 0.0  # orientation held: no rotation
    if constraints.isotropic:
        basis[:, :, 1] = 0.0
    return basis


def tangent_project_rows(q: np.ndarray, dq: np.ndarray, constraints: FrameConstraints):
    """Step 2 of note §3: the part of ``dq`` tangent to the constraint set at q (on it).

    ``dq`` is a gradient here: it also decides the active aspect bounds.
    """
    basis = tangent_basis_rows(q, constraints, gradient=dq)
    return np.einsum("nik,nk->ni", basis, np.einsum("nik,ni->nk", basis, dq))


def weighted_norm2(q: np.ndarray, constraints: FrameConstraints) -> float:
    """Σ_v m_v |q_v|² over owned vertices (lumped L² norm squared), summed over ranks."""
    n = constraints.owned
    local = float(np.dot(constraints.weights[:n], np.einsum("ni,ni->n", q[:n], q[:n])))
    return constraints.comm.allreduce(local, op=MPI.SUM)


def normalise_rows(q: np.ndarray, constraints: FrameConstraints, norm2: float) -> np.ndarray:
    """Step 5 of note §3: scale q uniformly so that its lumped L² norm squared is ``norm2``."""
    return q * np.sqrt(norm2 / weighted_norm2(q, constraints))
