"""A distributed P1 frame field gathered onto one rank as global arrays (collective).

The cut graph and the seamless map are global problems on a 2D mesh (their cost is that of
one sparse solve); :func:`gather_field` collects the vertex coordinates, the triangles and
the frame of every vertex, numbered by the mesh's input node indices, on rank 0;
:func:`gather_features` the model entities on the same numbering
(:class:`~ufl_frames.param.features.Features`).
"""

from ufl_frames.bootstrap import init_petsc

init_petsc()

import numpy as np  # noqa: E402

from ufl_frames.fem.gather import gather_rows  # noqa: E402
from ufl_frames.frames2d import odeco  # noqa: E402

__all__ = ["gather_features", "gather_field"]


def gather_field(q, root: int = 0):
    """(x (n, 2), cells (m, 3), q (n, 5)) of the P1 field ``q`` on rank ``root``, in input
    node order with unused numbers dropped; (None, None, None) on the other ranks."""
    V = q.function_space
    mesh = V.mesh
    if mesh.topology.dim != 2 or V.dofmap.index_map_bs != odeco.NUM_COEFFICIENTS:
        raise ValueError("gather_field needs a P1 frame field (5 coefficients) on triangles")
    comm = mesh.comm
    owned = mesh.topology.index_map(2).size_local
    nodes = mesh.geometry.dofmaps[0][:owned]  # geometry nodes of the owned cells
    ids = np.asarray(mesh.geometry.input_global_indices, dtype=np.int64)
    rows = q.x.array.reshape(-1, odeco.NUM_COEFFICIENTS)
    dofs = V.dofmap.list[:owned]  # P1: a cell's dofs are its vertices, in node order
    cells = gather_rows(comm, ids[nodes], root=root)
    x_all = gather_rows(comm, mesh.geometry.x[nodes.ravel(), :2], root=root)
    q_all = gather_rows(comm, rows[dofs.ravel()], root=root)
    if comm.rank != root:
        return None, None, None
    flat = cells.ravel()
    numbers, first, inverse = np.unique(flat, return_index=True, return_inverse=True)
    return x_all[first], inverse.reshape(-1, 3), q_all[first]


def gather_features(domain, root: int = 0):
    """The model entities of ``domain`` (a :class:`~ufl_frames.mesh.Domain`) on rank
    ``root`` as a :class:`~ufl_frames.param.features.Features`, numbered as
    :func:`gather_field` numbers the nodes and the cells of a field on the same mesh
    (collective); None on the other ranks.

    ``cell_region`` is the surface of every cell, ``curve_edges`` the facets on model
    curves (boundary and interior, a facet once), ``point_nodes`` the vertices at model
    points; a domain without model tags gives :meth:`Features.none`.
    """
    from ufl_frames.bootstrap import init_petsc

    init_petsc()
    import dolfinx.mesh

    from ufl_frames.param.features import Features

    mesh = domain.mesh
    comm = mesh.comm
    owned = mesh.topology.index_map(2).size_local
    nodes = mesh.geometry.dofmaps[0][:owned]
    ids = np.asarray(mesh.geometry.input_global_indices, dtype=np.int64)
    cells = gather_rows(comm, ids[nodes], root=root)

    def owned_tagged(tags, dim):
        """(input node ids (k, dim + 1), values (k,)) of the owned entities of ``tags``."""
        if tags is None:
            return np.zeros((0, dim + 1), dtype=np.int64), np.zeros(0, dtype=np.int64)
        size = mesh.topology.index_map(dim).size_local
        keep = tags.indices < size
        entities = tags.indices[keep].astype(np.int32)
        mesh.topology.create_connectivity(dim, 2)
        geometry = dolfinx.mesh.entities_to_geometry(mesh, dim, entities)
        return (ids[np.asarray(geometry).reshape(-1, dim + 1)],  # P1: the entity's vertices
                tags.values[keep].astype(np.int64))

    region = np.zeros(owned, dtype=np.int64)
    if domain.cell_tags is not None:
        keep = domain.cell_tags.indices < owned
        region[domain.cell_tags.indices[keep]] = domain.cell_tags.values[keep]
    edges, edge_curve = owned_tagged(domain.curve_tags, 1)
    points, point_tag = owned_tagged(domain.point_tags, 0)
    parts = [gather_rows(comm, a, root=root)
             for a in (region, edges, edge_curve, points[:, 0], point_tag)]
    if comm.rank != root:
        return None
    if domain.cell_tags is None:
        return Features.none(cells.shape[0])
    region, edges, edge_curve, points, point_tag = parts
    numbers = np.unique(cells.ravel())
    return Features(cell_region=region,
                    curve_edges=np.searchsorted(numbers, edges).reshape(-1, 2),
                    edge_curve=edge_curve,
                    point_nodes=np.searchsorted(numbers, points),
                    point_tag=point_tag)
