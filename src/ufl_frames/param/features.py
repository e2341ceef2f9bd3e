"""The geometry's model entities as rank-0 arrays: what the map and the quads must respect.

A :class:`Features` record is what the seamless map, its quantisation and the quad mesh
receive of the file's model beside the triangles: the surface (region) of every triangle,
the edges that lie on a model curve (boundary curves, interfaces between two surfaces,
curves embedded in a surface) with the curve's tag, and the nodes at model points (corners,
ends of curves, embedded points) with the point's tag. Node numbers are those of the
gathered arrays (:func:`ufl_frames.param.gather.gather_field`: input node order, unused
numbers dropped).

Interior curve edges (two triangles) are where the map's coordinate across the curve is
constant and integer, as on the boundary; model points are quad vertices, except the
smooth joints (:func:`with_smooth_joints`): a point where two boundary curves meet and the
boundary turns by less than :data:`SMOOTH_TURN` (a polyline's vertices, say), which a quad
edge may span. The tie corners (:func:`with_tie_corners`, 135° and 225°) and the junctions
of interior curves (:func:`with_junctions`) are the points where no cross fits both curves:
the cut gives their triangles their other vertices' frames.
"""

from dataclasses import dataclass, field, replace

import numpy as np

__all__ = ["SMOOTH_TURN", "TIE", "Features", "with_junctions", "with_smooth_joints",
           "with_tie_corners"]

#: The largest turn of the boundary (radians, |interior angle − π|) at a model point that a
#: quad edge may span (:func:`with_smooth_joints`). The polyline airfoils' segment joints
#: turn by up to 21.1° (at the leading edge); deal.II step-49's notch and slit corners by
#: 30°, 33.7° and 45°, and at its 45° corners a quad edge across the point cut the corner
#: off (a quad corner of SJ 0 at quad size 0.46). 25° lies between.
SMOOTH_TURN = np.radians(25.0)

#: |cos 2α| under which a corner of angle α counts as a tie corner (135° or 225°:
#: :func:`with_tie_corners`); the mesh's angle sums are exact to round-off there too.
TIE = 1e-6


@dataclass(frozen=True)
class Features:
    """Model entities of a planar geometry on the gathered triangle mesh (rank 0).

    Args:
        cell_region: (m,) surface tag of every triangle.
        curve_edges: (k, 2) node pairs of the mesh edges that lie on a model curve.
        edge_curve: (k,) the curve tag of each.
        point_nodes: (p,) nodes at model points.
        point_tag: (p,) the point tag of each.
        joints: the model points of ``point_nodes`` that need not be quad vertices
            (:func:`with_smooth_joints`; none by default).
        junction_nodes: the nodes where interior curves end, turn or meet each other or
            the boundary (:func:`with_junctions`; none by default).
        tie_corners: the boundary corners of 135° or 225°, where no cross fits both
            curves (:func:`with_tie_corners`; none by default).
    """

    cell_region: np.ndarray
    curve_edges: np.ndarray
    edge_curve: np.ndarray
    point_nodes: np.ndarray
    point_tag: np.ndarray
    joints: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    junction_nodes: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    tie_corners: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    @property
    def required_points(self) -> np.ndarray:
        """The model points that must be quad vertices: ``point_nodes`` but the joints."""
        return np.asarray(self.point_nodes, dtype=np.int64)[
            ~np.isin(self.point_nodes, self.joints)]

    def curve_chains(self) -> dict:
        """{curve tag: the smallest tag of the curves joined to it through joints}: the
        curves a quad edge may run along as one."""
        parent = {int(c): int(c) for c in np.unique(self.edge_curve)}

        def root(c):
            while parent[c] != c:
                c = parent[c]
            return c

        e = np.asarray(self.curve_edges, dtype=np.int64).reshape(-1, 2)
        for v in np.asarray(self.joints, dtype=np.int64):
            tags = np.unique(self.edge_curve[(e == v).any(axis=1)])
            for t in tags[1:]:
                a, b = root(int(tags[0])), root(int(t))
                parent[max(a, b)] = min(a, b)
        return {c: root(c) for c in parent}

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


def _point_angles(features: Features, x, cells, corners=None) -> np.ndarray:
    """The domain's angle (radians) at every node: the CAD corner's at the model points
    where ``corners`` are given (π at a point where none sits), else the sum of the
    triangles' angles there (see :func:`with_smooth_joints`)."""
    n = x.shape[0]
    if corners is not None:
        angle = np.full(n, np.pi)
        points = np.asarray(features.point_nodes, dtype=np.int64)
        near = 1e-9 * max(1.0, float(np.abs(x).max(initial=0.0)))
        for c in corners:
            angle[points[np.linalg.norm(x[points] - (c.x, c.y), axis=1) <= near]] = c.angle
        return angle
    angle = np.zeros(n)
    p = x[cells]
    for i in range(3):
        a, b = p[:, (i + 1) % 3] - p[:, i], p[:, (i + 2) % 3] - p[:, i]
        cross = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
        np.add.at(angle, cells[:, i], np.arctan2(np.abs(cross), np.einsum("mk,mk->m", a, b)))
    return angle


def with_tie_corners(features: Features, x, cells, corners=None) -> Features:
    """``features`` with its tie corners: the model points on the boundary where the
    domain's angle is 135° or 225° (an odd multiple of 45°). The two curves' crosses are
    45° apart there and their mean is none (the CAD holds no cross at the point, as at a
    junction: :func:`~ufl_frames.mesh.arrays.cad_directions`); the field turns by 45° in
    the corner's fan, one triangle wide on a coarse mesh, and the map's boundary can take
    a quad corner at the fan's other boundary vertex, on the straight curve (deal.II
    step-49's notch at quad size 0.46: a quad corner of SJ 0 at (3.33, 2.01), next to the
    135° corner (3.5, 2.18)). The cut gives their triangles the frames of their other
    vertices, as at a junction (:func:`~ufl_frames.param.cut.junction_frames`).

    Args:
        features: the features of the triangle mesh.
        x: the mesh's nodes (n, 2+).
        cells: its triangles (m, 3).
        corners: the CAD model's corners, or None (as for :func:`with_smooth_joints`).

    Returns:
        The features with ``tie_corners`` set.
    """
    x = np.asarray(x, dtype=np.float64)[:, :2]
    cells = np.asarray(cells, dtype=np.int64)
    e = np.asarray(features.curve_edges, dtype=np.int64).reshape(-1, 2)
    if e.size == 0 or len(features.point_nodes) == 0:
        return features
    boundary = ~features.interior_curve_edges(cells)
    on_boundary = np.zeros(x.shape[0], dtype=bool)
    on_boundary[e[boundary].ravel()] = True
    points = np.unique(np.asarray(features.point_nodes, dtype=np.int64))
    angle = _point_angles(features, x, cells, corners)[points]
    tie = on_boundary[points] & (np.abs(np.cos(2 * angle)) < TIE)
    return replace(features, tie_corners=points[tie])


def with_smooth_joints(features: Features, x, cells, physical_groups=(),
                       corners=None) -> Features:
    """``features`` with its smooth joints: the model points where exactly two boundary
    curve edges meet, of two curves (or the two ends of one closed curve) in the same
    physical curve groups, no interior curve ends, the point in no physical point group,
    and the boundary turns there by less than :data:`SMOOTH_TURN` (the field takes the
    boundary as straight there). A quad edge may span them: at a quad size larger than a
    polyline's segments, every vertex a quad vertex would squeeze the quads there until
    they fold. A point where the boundary turns more stays a quad vertex, even where the
    field rounds its angle to two quarter turns (135°–225°): a quad edge across a 135°
    corner cuts it off.

    Args:
        features: the features of the triangle mesh.
        x: the mesh's nodes (n, 2+).
        cells: its triangles (m, 3).
        physical_groups: the file's :class:`~ufl_frames.mesh.domain.PhysicalGroup`
            records (those of dimension 0 and 1 count).
        corners: the boundary's corners from the CAD model (records with ``x``, ``y`` and
            the interior ``angle`` in radians: :attr:`ufl_frames.mesh.Domain.corners` of a
            model with curves); a point at none of them is smooth in the model (a circle's
            or spline's ends, whose mesh edges turn by the chords' angle). None: the turn is
            the triangles' angle sum's (exact where the mesh's boundary is the geometry:
            a ``.msh``, a polyline).

    Returns:
        The features with ``joints`` set.
    """
    x = np.asarray(x, dtype=np.float64)[:, :2]
    cells = np.asarray(cells, dtype=np.int64)
    e = np.asarray(features.curve_edges, dtype=np.int64).reshape(-1, 2)
    if e.size == 0 or len(features.point_nodes) == 0:
        return features
    named_points = {t for g in physical_groups if g.dim == 0 for t in g.entities}
    groups_of = {}
    for g in physical_groups:
        if g.dim == 1:
            for t in g.entities:
                groups_of.setdefault(abs(int(t)), set()).add(g.tag)
    boundary = ~features.interior_curve_edges(cells)
    n = x.shape[0]
    degree = np.bincount(e.ravel(), minlength=n)
    boundary_degree = np.bincount(e[boundary].ravel(), minlength=n)
    angle = _point_angles(features, x, cells, corners)
    joints = []
    for v, tag in zip(np.asarray(features.point_nodes, dtype=np.int64),
                      np.asarray(features.point_tag, dtype=np.int64), strict=True):
        if int(tag) in named_points or degree[v] != 2 or boundary_degree[v] != 2:
            continue
        if not abs(angle[v] - np.pi) < SMOOTH_TURN:
            continue
        tags = {int(t) for t in features.edge_curve[(e == v).any(axis=1)]}
        if len({frozenset(groups_of.get(t, ())) for t in tags}) == 1:
            joints.append(int(v))
    return replace(features, joints=np.asarray(joints, dtype=np.int64))


def with_junctions(features: Features, x, junctions) -> Features:
    """``features`` with the junctions of the interior curves (the points where they
    end, turn or meet each other or the boundary: :class:`~ufl_frames.mesh.domain.Junction`),
    each at the model point nearest to it.

    The cut gives the triangles around a junction the frames of their other vertices
    (:func:`~ufl_frames.param.cut.junction_frames`): the junction's own cross, held to the
    average of its curves', fits none of the sectors between them.

    Args:
        features: the features of the triangle mesh.
        x: the mesh's nodes (n, 2+).
        junctions: the model's :class:`~ufl_frames.mesh.domain.Junction` records.

    Returns:
        The features with ``junction_nodes`` set.
    """
    x = np.asarray(x, dtype=np.float64)[:, :2]
    points = np.asarray(features.point_nodes, dtype=np.int64)
    if not len(junctions) or points.size == 0:
        return features
    at = np.array([[j.x, j.y] for j in junctions])
    nearest = points[np.argmin(np.linalg.norm(x[points][None] - at[:, None], axis=2), axis=1)]
    return replace(features, junction_nodes=np.unique(nearest).astype(np.int64))
