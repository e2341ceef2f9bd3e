"""The geometry's model entities as rank-0 arrays: what the map and the quads must respect.

A :class:`Features` record is what the seamless map, its quantisation and the quad mesh
receive of the file's model beside the triangles: the surface (region) of every triangle,
the edges that lie on a model curve (boundary curves, interfaces between two surfaces,
curves embedded in a surface) with the curve's tag, and the nodes at model points (corners,
ends of curves, embedded points) with the point's tag. Node numbers are those of the
gathered arrays (:func:`ufl_frames.param.gather.gather_field`: input node order, unused
numbers dropped).

Interior curve edges (two triangles) are where the map's coordinate across the curve is
constant and integer, as on the boundary; model points are quad vertices.
"""

from dataclasses import dataclass

import numpy as np

__all__ = ["Features"]


@dataclass(frozen=True)
class Features:
    """Model entities of a planar geometry on the gathered triangle mesh (rank 0).

    Args:
        cell_region: (m,) surface tag of every triangle.
        curve_edges: (k, 2) node pairs of the mesh edges that lie on a model curve.
        edge_curve: (k,) the curve tag of each.
        point_nodes: (p,) nodes at model points.
        point_tag: (p,) the point tag of each.
    """

    cell_region: np.ndarray
    curve_edges: np.ndarray
    edge_curve: np.ndarray
    point_nodes: np.ndarray
    point_tag: np.ndarray

    @classmethod
    def none(cls, num_cells: int) -> "Features":
        """One region (tag 0), no curves and no points: a bare triangle mesh."""
        return cls(cell_region=np.zeros(num_cells, dtype=np.int64),
                   curve_edges=np.zeros((0, 2), dtype=np.int64),
                   edge_curve=np.zeros(0, dtype=np.int64),
                   point_nodes=np.zeros(0, dtype=np.int64),
                   point_tag=np.zeros(0, dtype=np.int64))

    def interior_curve_edges(self, cells: np.ndarray) -> np.ndarray:
        """Mask of the curve edges that two triangles of ``cells`` share (interfaces and
        embedded curves; the rest lie on the boundary)."""
        n = int(max(cells.max(initial=-1), self.curve_edges.max(initial=-1))) + 1
        directed = np.concatenate([cells[:, [0, 1]], cells[:, [1, 2]], cells[:, [2, 0]]])
        keys = np.minimum(directed[:, 0], directed[:, 1]) * n + np.maximum(directed[:, 0],
                                                                            directed[:, 1])
        unique, counts = np.unique(keys, return_counts=True)
        e = self.curve_edges
        wanted = np.minimum(e[:, 0], e[:, 1]) * n + np.maximum(e[:, 0], e[:, 1])
        pos = np.minimum(np.searchsorted(unique, wanted), max(unique.size - 1, 0))
        return (unique.size > 0) & (unique[pos] == wanted) & (counts[pos] == 2)
