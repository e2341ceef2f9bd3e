r"""From a frame field on a triangle mesh to a combed field on a topological disk.

The parametrisation (U, V) of a frame field with singularities or holes is multivalued:
it needs a cut. Here, all on global NumPy arrays (pure NumPy/SciPy):

1. :func:`face_frames`: one frame per triangle (angle t, lengths l1, l2) from the P1 field's
   vertex frames, each matched to the triangle's first vertex modulo 90° (a cross has four
   labellings: turning the labels by 90° maps (t, l1, l2) to (t + π/2, l2, l1));
2. :func:`matchings`: for every interior edge the label turn k ∈ Z₄ that best aligns the
   frame of one triangle with that of its neighbour;
3. :func:`singular_vertices`: interior vertices around which the turns do not add up to 0
   modulo 4 — the singularities of the face-based field, at vertices;
4. :func:`cut_graph`: mesh edges that, cut open, leave a topological disk: shortest paths
   (Dijkstra on edge lengths) from every inner boundary loop and then from every singular
   vertex to what is cut already, starting from the outer boundary — a greedy Steiner tree,
   short by construction;
5. :func:`comb`: a label turn r_f per triangle along a spanning tree of the cut mesh's dual
   graph, so that neighbours agree everywhere except across the cut; there the jump
   j_e = r_g − r_f − k_fg (mod 4) is what the seam's transition rotates by;
6. :func:`wedges`: the corners of the triangles grouped into the vertices of the cut mesh
   (a vertex on a cut has one copy per side).
"""

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse import csgraph

from ufl_frames.frames2d import odeco
from ufl_frames.param.features import Features

__all__ = ["CutMesh", "cancel_pairs", "comb", "counterclockwise", "cut_graph", "cut_mesh",
           "face_frames", "face_frames_with", "junction_frames", "matchings",
           "singular_vertices", "triangle_components", "wedges"]

QUARTER = np.pi / 2


def _wrap(angle):
    """Angles into (−π, π]."""
    return np.pi - np.mod(np.pi - angle, 2 * np.pi)


def relabel(angle, l1, l2, k):
    """The frame (angle, l1, l2) with its labels turned k quarter turns (k may be an array).

    Args:
        angle: the angle of the first branch, in radians (an array or a scalar).
        l1: the length along ``angle``, broadcastable with ``angle``.
        l2: the other length, likewise.
        k: the quarter turns (any integers, taken mod 4).

    Returns:
        (angle + k·π/2, l1, l2) with l1 and l2 swapped where k is odd.
    """
    k = np.mod(k, 4)
    odd = (k % 2) == 1
    return angle + k * QUARTER, np.where(odd, l2, l1), np.where(odd, l1, l2)


def counterclockwise(x: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """``cells`` (m, 3) with the clockwise triangles of ``x`` (n, 2) turned over."""
    e1, e2 = x[cells[:, 1]] - x[cells[:, 0]], x[cells[:, 2]] - x[cells[:, 0]]
    clockwise = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] < 0
    return np.where(clockwise[:, None], cells[:, [0, 2, 1]], cells)


def face_frames(cells: np.ndarray, q: np.ndarray, frames=None):
    """Per triangle (angle, l1, l2): the vertex frames matched to the first vertex's labels
    (nearest quarter turn) and averaged (angle by the mean difference, lengths by the mean).
    ``frames``: ``odeco.q_to_frames(q)`` if the caller has it already."""
    lengths, angles = odeco.q_to_frames(q) if frames is None else frames
    t = angles[cells]  # (m, 3)
    l1, l2 = lengths[cells, 0], lengths[cells, 1]
    k = np.rint((t[:, :1] - t) / QUARTER).astype(np.int64)
    t, l1, l2 = relabel(t, l1, l2, k)
    angle = t[:, 0] + np.mean(_wrap(t - t[:, :1]), axis=1)
    return angle, l1.mean(axis=1), l2.mean(axis=1)


def face_frames_with(cells: np.ndarray, q: np.ndarray, given=None, frames=None):
    """:func:`face_frames`, but ``given`` = (triangles, angle, l1, l2) where set: the
    frames of those triangles taken as they are (a lifted field, continuous where the
    vertex crosses of a triangle are more than 45° apart: at a sharp corner)."""
    angle, l1, l2 = face_frames(cells, q, frames)
    if given is not None:
        triangles, a, b, c = given
        angle, l1, l2 = angle.copy(), l1.copy(), l2.copy()
        angle[triangles], l1[triangles], l2[triangles] = a, b, c
    return angle, l1, l2


def junction_frames(cells: np.ndarray, nodes: np.ndarray, frames, given=None):
    """The frames of the triangles at the junctions ``nodes`` of interior curves, from
    their other vertices' crosses, as ``given`` frames (:func:`face_frames_with`):
    (triangles, angle, l1, l2), with ``given``'s own triangles left as they were.

    A junction's vertex cross is held to the average of its curves' (on the boundary:
    the two boundary edges', as at a corner), which fits none of the sectors between the
    curves: at deal.II step-49's slit tip the slit's cross is 45° off the interfaces'.
    A sector one triangle wide then has the frame of three crosses up to 60° apart, and
    its two curve edges, a quad corner apart, can both take the same constant coordinate
    in the map (the sector folds flat). Its two other vertices lie on the two curves,
    each cross aligned with its own: their mean turns the short way between them, as
    the quad corner does. A triangle with one other vertex takes that one's frame.

    Args:
        cells: triangles (m, 3).
        nodes: the junctions' vertices.
        frames: ``odeco.q_to_frames(q)`` (lengths (n, 2), angles (n,)).
        given: (triangles, angle, l1, l2) already given (kept), or None.

    Returns:
        The given frames with the junctions' triangles added (``given`` where none).
    """
    lengths, angles = frames
    at = np.isin(cells, np.asarray(nodes, dtype=np.int64))
    fan = np.flatnonzero(at.any(axis=1) & ~at.all(axis=1))
    if given is not None:
        fan = np.setdiff1d(fan, given[0])
    if fan.size == 0:
        return given
    other = ~at[fan]  # (t, 3): the vertices that count
    first = cells[fan, np.argmax(other, axis=1)]
    t = angles[cells[fan]]
    k = np.rint((angles[first][:, None] - t) / QUARTER).astype(np.int64)
    t, l1, l2 = relabel(t, lengths[cells[fan], 0], lengths[cells[fan], 1], k)
    w = other / other.sum(axis=1, keepdims=True)
    angle = angles[first] + np.sum(w * _wrap(t - angles[first][:, None]), axis=1)
    mine = (fan, angle, np.sum(w * l1, axis=1), np.sum(w * l2, axis=1))
    if given is None:
        return mine
    return tuple(np.concatenate([g, m]) for g, m in zip(given, mine, strict=True))


def interior_edges(cells: np.ndarray):
    """The edges of the mesh: edges (E, 2) sorted, and faces (E, 2) holding the one or two
    triangles of each (−1 for none: a boundary edge)."""
    m = cells.shape[0]
    local = np.array([[1, 2], [2, 0], [0, 1]])  # edge opposite vertex i
    pairs = cells[:, local].reshape(-1, 2)
    key_pairs = np.sort(pairs, axis=1)
    n = int(cells.max()) + 1
    keys = key_pairs[:, 0] * n + key_pairs[:, 1]
    order = np.argsort(keys, kind="stable")
    unique, first, counts = np.unique(keys[order], return_index=True, return_counts=True)
    if np.any(counts > 2):
        raise ValueError("an edge is shared by more than two triangles")
    face = np.repeat(np.arange(m), 3)[order]
    faces = np.full((unique.size, 2), -1, dtype=np.int64)
    faces[:, 0] = face[first]
    two = counts == 2
    faces[two, 1] = face[first[two] + 1]
    edges = np.stack([unique // n, unique % n], axis=1)
    return edges, faces


def matchings(angle: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """k_fg ∈ Z₄ per edge (f, g = faces[:, 0], faces[:, 1]): turning g's labels by k_fg
    brings its frame closest to f's (0 for boundary edges)."""
    k = np.zeros(faces.shape[0], dtype=np.int64)
    inner = faces[:, 1] >= 0
    f, g = faces[inner, 0], faces[inner, 1]
    k[inner] = np.mod(np.rint((angle[f] - angle[g]) / QUARTER), 4).astype(np.int64)
    return k


def singular_vertices(cells, angle, edges, faces, k=None) -> tuple[np.ndarray, np.ndarray]:
    """Interior vertices whose fan of triangles turns the frame by a nonzero multiple of 90°,
    and that turn in quarters (the index is −turn/4 … here: the winding of 4t around the
    vertex divided by 2π, in quarters: the vertex's index times 4).

    ``k``: the matchings (:func:`matchings`, the default); across edge e the frame turns by
    angle_g − angle_f + k_e · 90°, so a matching one off the nearest moves a quarter turn
    from one end of the edge to the other (:func:`cancel_pairs`).

    Args:
        cells: triangles (m, 3), counter-clockwise.
        angle: the frame angle per triangle (m,) (:func:`face_frames`).
        edges: the edge table (E, 2) (:func:`interior_edges`).
        faces: the triangles of every edge (E, 2), −1 for none.
        k: the matchings (E,) (None: :func:`matchings` of ``angle``).

    Returns:
        (singular, turns): the singular interior vertices and their turns in quarters,
        both (s,) int.
    """
    n = int(cells.max()) + 1
    boundary = np.zeros(n, bool)
    on_boundary = faces[:, 1] < 0
    boundary[edges[on_boundary].ravel()] = True
    # Winding of the face angles around each vertex: Σ over the fan's edges of the wrapped
    # difference (mod 90°) between the two faces, oriented by the edge's direction around
    # the vertex (counter-clockwise fans: cells are taken counter-clockwise).
    inner = ~on_boundary
    f, g = faces[inner, 0], faces[inner, 1]
    if k is None:
        k = matchings(angle, faces)
    step = _wrap(angle[g] - angle[f] + k[inner] * QUARTER)  # g relative to f, labels turned
    winding = np.zeros(n)
    e = edges[inner]
    # Going around vertex a counter-clockwise crosses edge (a, b) from the face on its
    # right to the face on its left. For face f, edge (a, b) is f's edge in cyclic order if
    # b follows a in f: then f is on the left of a→b.
    f_cells = cells[f]
    pos_a = np.argmax(f_cells == e[:, :1], axis=1)
    b_follows_a = f_cells[np.arange(f.size), (pos_a + 1) % 3] == e[:, 1]
    # f on the left of a→b: around a (ccw) we go g → f across it; around b the other way.
    sign_a = np.where(b_follows_a, -1.0, 1.0)
    np.add.at(winding, e[:, 0], sign_a * step)
    np.add.at(winding, e[:, 1], -sign_a * step)
    turns = np.rint(winding / QUARTER).astype(np.int64)
    singular = np.flatnonzero((turns != 0) & ~boundary)
    return singular, turns[singular]


def cancel_pairs(x, cells, edges, faces, k, singular, turns, within: float):
    """The matchings with every pair of opposite singular vertices closer than ``within``
    cancelled (closest pairs first, each vertex once), and every other singular vertex
    closer than ``within``/2 to the boundary moved onto it: along the shortest path of interior
    edges from one to the other, each edge's matching is turned by one quarter, which
    moves the quarter turn of the first vertex along the path onto the second, where it
    cancels. The field itself is not changed: its combing jumps by 90° across the path
    instead, and the map absorbs that where the pair sat closer than a quad.

    Args:
        x: vertex coordinates (n, 2).
        cells: triangles (m, 3), counter-clockwise.
        edges: the edge table (E, 2) (:func:`interior_edges`).
        faces: the triangles of every edge (E, 2), −1 for none.
        k: the matchings (E,) (:func:`matchings`); not modified.
        singular: the singular vertices (s,) (:func:`singular_vertices`).
        turns: their turns in quarters (s,); pairs are of +1 and −1.
        within: the distance below which a pair is cancelled (half of it: a vertex moved
            onto the boundary).

    Returns:
        (k, cancelled): the new matchings (E,) and the number of pairs cancelled plus
        vertices moved onto the boundary.
    """
    k = k.copy()
    positive, negative = singular[turns == 1], singular[turns == -1]
    distance = np.linalg.norm(x[positive][:, None] - x[negative][None], axis=2)
    candidates = sorted((distance[i, j], i, j) for i, j in zip(*np.nonzero(distance < within),
                                                                strict=True))
    graph, edge_id = _interior_graph(x, edges, faces)
    used, cancelled = set(), 0
    for _, i, j in candidates:
        a, b = int(positive[i]), int(negative[j])
        if a in used or b in used:
            continue
        _, predecessors = csgraph.dijkstra(graph, directed=False, indices=a,
                                           return_predecessors=True)
        if predecessors[b] < 0:
            continue
        v = b
        while v != a:  # the path b <- ... <- a, edge (u, v): move a's quarter from u to v
            u = int(predecessors[v])
            e = int(edge_id[u, v]) - 1
            k[e] = _moved(cells, edges, faces, e, u, k[e])
            v = u
        used.update((a, b))
        cancelled += 1
    k, glued = glue_to_boundary(x, cells, edges, faces, k, singular, turns, within / 2,
                                skip=used)
    return k, cancelled + glued


def _interior_graph(x, edges, faces):
    """(graph, edge_id): the interior edges as a symmetric sparse graph weighted by their
    lengths, and the edge index + 1 of each (u, v) (0: no interior edge)."""
    n = x.shape[0]
    inner = np.flatnonzero(faces[:, 1] >= 0)
    length = np.linalg.norm(x[edges[inner, 1]] - x[edges[inner, 0]], axis=1)
    graph = sp.csr_matrix((length, (edges[inner, 0], edges[inner, 1])), shape=(n, n))
    edge_id = sp.csr_matrix((inner + 1.0, (edges[inner, 0], edges[inner, 1])), shape=(n, n))
    return graph + graph.T, edge_id + edge_id.T


def glue_to_boundary(x, cells, edges, faces, k, singular, turns, within, skip=(),
                     keep=()) -> tuple[np.ndarray, int]:
    """The matchings with every singular vertex closer than ``within`` to the boundary
    (along interior edges) moved onto the nearest boundary vertex: each edge's matching on
    the shortest path turned by the vertex's quarters, which become that boundary
    vertex's, a corner of the grid (its two boundary edges get different constant
    coordinates: a boundary vertex of valence 3 or 5). The field is not changed.

    Args:
        x, cells, edges, faces, k, singular, turns: as for :func:`cancel_pairs`.
        within: the distance, a number or one per vertex (n,) (the singular vertex's).
        skip: singular vertices left where they are.
        keep: boundary vertices that take none (the model's required points: their
            quad corners are the model's).

    Returns:
        (k, glued): the new matchings (E,) and the number of vertices moved.
    """
    k = k.copy()
    n = x.shape[0]
    graph, edge_id = _interior_graph(x, edges, faces)
    on_boundary = np.zeros(n, dtype=bool)
    on_boundary[edges[faces[:, 1] < 0].ravel()] = True
    on_boundary[np.asarray(keep, dtype=np.int64)] = False
    boundary = np.flatnonzero(on_boundary)
    reach = np.broadcast_to(np.asarray(within, dtype=np.float64), (n,))
    skip, glued = set(int(v) for v in skip), 0
    if boundary.size == 0:
        return k, 0
    for a in (int(v) for v in singular if int(v) not in skip):
        distance, predecessors = csgraph.dijkstra(graph, directed=False, indices=a,
                                                  limit=float(reach[a]),
                                                  return_predecessors=True)
        b = int(boundary[np.argmin(distance[boundary])])
        if not distance[b] < reach[a]:
            continue
        turn = int(turns[np.flatnonzero(singular == a)[0]])
        v = b
        while v != a:
            u = int(predecessors[v])
            e = int(edge_id[u, v]) - 1
            for _ in range(abs(turn)):
                k[e] = _moved(cells, edges, faces, e, u, k[e], np.sign(turn))
            v = u
        glued += 1
    return k, glued


def _moved(cells, edges, faces, e, u, k_e, turn: int = 1):
    """k_e turned so that a turn of ``turn`` = ±1 quarter (as :func:`singular_vertices`
    counts them) moves from vertex u of edge e to its other end."""
    f = int(faces[e, 0])
    a, b = int(edges[e, 0]), int(edges[e, 1])
    pos_a = int(np.flatnonzero(cells[f] == a)[0])
    b_follows_a = cells[f][(pos_a + 1) % 3] == b
    sign_a = -1.0 if b_follows_a else 1.0  # winding[a] += sign_a * step, winding[b] −=
    # step grows by 90° per unit of k: winding at a changes by sign_a, at b by −sign_a.
    # To take the quarter from u (and give it to the other end): change u's by −turn.
    sign_u = sign_a if u == a else -sign_a
    return (k_e - int(turn * sign_u)) % 4


def _boundary_loops(edges, faces, n):
    """Vertex sets of the boundary's connected components, the outer (longest) first."""
    b = edges[faces[:, 1] < 0]
    graph = sp.csr_matrix((np.ones(b.shape[0]), (b[:, 0], b[:, 1])), shape=(n, n))
    _, label = csgraph.connected_components(graph, directed=False)
    on = np.unique(b.ravel())  # every other vertex is a component of its own
    order = np.argsort(label[on], kind="stable")
    grouped = on[order]
    starts = np.flatnonzero(np.diff(label[grouped], prepend=-1))
    return np.split(grouped, starts[1:])


def triangle_components(faces, m: int) -> tuple[int, np.ndarray]:
    """The connected components of the mesh (triangles joined across interior edges):
    their number and the component of every triangle (m,)."""
    inner = faces[:, 1] >= 0
    f, g = faces[inner, 0], faces[inner, 1]
    graph = sp.csr_matrix((np.ones(f.size), (f, g)), shape=(m, m))
    count, label = csgraph.connected_components(graph, directed=False)
    return int(count), label


def cut_graph(x, cells, edges, faces, singular) -> tuple[np.ndarray, int]:
    """Edge ids (into ``edges``) to cut along, and the number of cut paths.

    Shortest paths over the interior edges: from each inner boundary loop (the loops
    other than the longest of their component) and then from each singular vertex to the
    set cut so far, which starts as the longest boundary loop of every component of the
    mesh and grows by every path and loop added.

    Args:
        x: vertex coordinates (n, 2).
        cells: triangles (m, 3).
        edges: the edge table (E, 2) (:func:`interior_edges`).
        faces: the triangles of every edge (E, 2), −1 for none.
        singular: the vertices every cut must reach (s,).

    Returns:
        (cut, paths): the sorted edge ids to cut (int) and the number of paths added.

    Raises:
        ValueError: a loop or a singular vertex cannot be reached (the mesh is not
            connected).
    """
    n = x.shape[0]
    length = np.linalg.norm(x[edges[:, 1]] - x[edges[:, 0]], axis=1)
    total = float(length.sum())  # no path is longer
    inner = faces[:, 1] >= 0
    ids = np.flatnonzero(inner)
    graph = sp.csr_matrix((length[ids], (edges[ids, 0], edges[ids, 1])), shape=(n, n))
    graph = graph + graph.T
    edge_id = sp.csr_matrix((ids + 1.0, (edges[ids, 0], edges[ids, 1])), shape=(n, n))
    edge_id = edge_id + edge_id.T
    loops = _boundary_loops(edges, faces, n)
    perimeter = [length[np.isin(edges[:, 0], loop) & np.isin(edges[:, 1], loop)
                        & ~inner].sum() for loop in loops]
    count, triangle_label = triangle_components(faces, cells.shape[0])
    vertex_label = np.full(n, -1, dtype=np.int64)
    vertex_label[cells.ravel()] = np.repeat(triangle_label, 3)
    order = np.argsort(perimeter, kind="stable")[::-1]
    in_cut = np.zeros(n, bool)
    outer = {}  # the longest loop of each component
    for i in order:
        outer.setdefault(int(vertex_label[loops[i][0]]), int(i))
    for i in outer.values():
        in_cut[loops[i]] = True
    cut, paths = [], 0
    targets = ([loops[i] for i in order if int(i) not in outer.values()]
               + [np.array([v]) for v in singular])
    radius = 16.0 * float(length.max(initial=0.0))
    for target in targets:
        if in_cut[target].all():
            continue
        # from the target outwards, within a radius that doubles until the cut is in
        # reach: the shortest path to the cut (as from the cut to the target), its cost
        # that of the ball it searches, not of the whole mesh
        limit = radius
        while True:
            distance, predecessors, _ = csgraph.dijkstra(
                graph, directed=False, indices=target, return_predecessors=True,
                min_only=True, limit=limit)
            reached = np.flatnonzero(in_cut & np.isfinite(distance))
            if reached.size or not np.isfinite(limit):
                break
            limit = 2 * limit if 0 < limit <= 2 * total else np.inf
        if not reached.size:
            raise ValueError("the mesh is not connected: no path to cut along")
        v = int(reached[np.argmin(distance[reached])])
        while predecessors[v] >= 0:  # from the cut back to the target
            u = int(predecessors[v])
            cut.append(int(edge_id[u, v]) - 1)
            in_cut[u] = True
            v = u
        in_cut[target] = True
        paths += 1
    return np.array(sorted(set(cut)), dtype=np.int64), paths


def comb(angle, faces, k, cut) -> np.ndarray:
    """Label turn r_f per triangle: r_g = r_f + k_fg across the edges of a spanning tree of
    the dual graph without the cut edges (breadth first from the first triangle of every
    component of the mesh).

    Args:
        angle: the frame angle per triangle (m,) (only its length is used).
        faces: the triangles of every edge (E, 2), −1 for none.
        k: the matchings (E,).
        cut: the cut edge ids (:func:`cut_graph`).

    Returns:
        r (m,), the turns in 0..3.

    Raises:
        ValueError: the cut splits a component of the mesh.
    """
    m = angle.size
    inner = faces[:, 1] >= 0
    allowed = inner.copy()
    allowed[cut] = False
    ids = np.flatnonzero(allowed)
    f, g = faces[ids, 0], faces[ids, 1]
    graph = sp.csr_matrix((ids + 1.0, (f, g)), shape=(m, m))
    graph = graph + graph.T
    count, label = csgraph.connected_components(graph, directed=False)
    pieces, _ = triangle_components(faces, m)
    if count != pieces:
        raise ValueError(f"the cut splits the mesh into {count} pieces")
    r = np.zeros(m, dtype=np.int64)
    for root in (int(np.flatnonzero(label == c)[0]) for c in range(count)):
        order, predecessors = csgraph.breadth_first_order(graph, root, directed=False,
                                                          return_predecessors=True)
        _comb_tree(r, order, predecessors, graph, faces, k)
    return np.mod(r, 4)


def _comb_tree(r, order, predecessors, graph, faces, k) -> None:
    """Turns ``r`` of a breadth-first tree's triangles (``order``, root first) from the
    root's, across the dual edges ``graph`` (edge id + 1) by the matchings ``k``."""
    children = order[1:]
    parents = predecessors[children]
    e = np.asarray(graph[parents, children]).ravel().astype(np.int64) - 1
    # k aligns faces[:, 1] to faces[:, 0]: a child that is faces[e, 0] takes the inverse
    step = np.where(faces[e, 0] == parents, k[e], -k[e]).tolist()
    turn = r.tolist()
    for child, parent, d in zip(children.tolist(), parents.tolist(), step, strict=True):
        turn[child] = turn[parent] + d  # breadth first: the parent is done
    r[:] = turn


def jumps(faces, k, r) -> np.ndarray:
    """j_e = r_g − r_f − k_fg (mod 4) per edge: g's combed frame is f's turned by j_e
    (0 wherever the combing is consistent; boundary edges 0).

    Args:
        faces: the triangles of every edge (E, 2), −1 for none.
        k: the matchings (E,).
        r: the combing's turn per triangle (m,) (:func:`comb`).

    Returns:
        j (E,), in 0..3.
    """
    j = np.zeros(faces.shape[0], dtype=np.int64)
    inner = faces[:, 1] >= 0
    f, g = faces[inner, 0], faces[inner, 1]
    j[inner] = np.mod(r[g] - r[f] - k[inner], 4)
    return j


def wedges(cells, edges, faces, cut) -> np.ndarray:
    """Vertex of the cut mesh of every triangle corner, shape (m, 3): corners of one vertex
    are joined across every interior edge that is not cut.

    Args:
        cells: triangles (m, 3).
        edges: the edge table (E, 2) (:func:`interior_edges`).
        faces: the triangles of every edge (E, 2), −1 for none.
        cut: the cut edge ids (:func:`cut_graph`).

    Returns:
        The cut-mesh vertex (wedge) of every corner (m, 3), numbered 0..W−1.
    """
    m = cells.shape[0]
    inner = faces[:, 1] >= 0
    joined = inner.copy()
    joined[cut] = False
    ids = np.flatnonzero(joined)
    corner = lambda face, vertex: 3 * face + np.argmax(cells[face] == vertex[:, None], axis=1)  # noqa: E731
    rows, cols = [], []
    for end in (0, 1):
        v = edges[ids, end]
        rows.append(corner(faces[ids, 0], v))
        cols.append(corner(faces[ids, 1], v))
    rows, cols = np.concatenate(rows), np.concatenate(cols)
    graph = sp.csr_matrix((np.ones(rows.size), (rows, cols)), shape=(3 * m, 3 * m))
    _, label = csgraph.connected_components(graph, directed=False)
    return label.reshape(m, 3)


@dataclass(frozen=True)
class CutMesh:
    """A triangle mesh cut into a disk, with its combed frame field (all global arrays).

    ``x`` (n, 2), ``cells`` (m, 3) counter-clockwise; ``angle``, ``l1``, ``l2`` the combed
    frame per triangle (labels turned by ``r``); ``edges``/``faces`` the edge table;
    ``cut`` the cut edge ids, ``jump`` per edge; ``corners`` (m, 3) the cut-mesh vertex of
    each corner; ``singular`` the singular vertices and their turns; ``paths`` the number
    of cut paths; ``features`` the geometry's model entities on the mesh (regions, curves,
    points: :class:`~ufl_frames.param.features.Features`), None for a bare mesh.
    """

    x: np.ndarray
    cells: np.ndarray
    angle: np.ndarray
    l1: np.ndarray
    l2: np.ndarray
    edges: np.ndarray
    faces: np.ndarray
    cut: np.ndarray
    jump: np.ndarray
    corners: np.ndarray
    singular: np.ndarray
    turns: np.ndarray
    paths: int
    cancelled: int = 0
    vertex_angle: np.ndarray | None = None
    features: Features | None = None

    @property
    def num_wedges(self) -> int:
        return int(self.corners.max()) + 1

    @property
    def cut_length(self) -> float:
        e = self.edges[self.cut]
        return float(np.linalg.norm(self.x[e[:, 1]] - self.x[e[:, 0]], axis=1).sum())


def cut_mesh(x, cells, q, cancel_within: float | None = None,
             features: Features | None = None, given_frames=None,
             glue_within=None) -> CutMesh:
    """:class:`CutMesh` of the P1 frame field ``q`` (n, 5) on the mesh ``x``, ``cells``;
    with ``cancel_within``, opposite singular vertices closer than that are cancelled
    (:func:`cancel_pairs`); ``features`` kept on the record (the map's interior curves and
    model points, :mod:`~ufl_frames.param.seamless` and :mod:`~ufl_frames.param.quantise`).

    Args:
        x: vertex coordinates (n, 2 or 3); only x and y are used.
        cells: triangles (m, 3), either orientation (turned counter-clockwise here).
        q: the P1 frame field's coefficients (n, 5).
        cancel_within: the distance of :func:`cancel_pairs` (None or 0: nothing cancelled).
        features: the geometry's regions, curves and points on this mesh, or None.
        given_frames: (triangles, angle, l1, l2), frames of those triangles to take as
            they are (:func:`face_frames_with`), or None.
        glue_within: singular vertices closer than this to the boundary (a number or
            one per vertex (n,)) are moved onto it (:func:`glue_to_boundary`; not onto
            the features' required points); None: none. Counted in ``cancelled``.

    Returns:
        The :class:`CutMesh`, with the combed frames and the field's vertex angles.

    Raises:
        ValueError: the features do not give one region per triangle.
    """
    x = np.asarray(x, dtype=np.float64)[:, :2]
    cells = np.asarray(cells, dtype=np.int64)
    if features is not None and np.shape(features.cell_region) != (cells.shape[0],):
        raise ValueError(f"the features give {np.size(features.cell_region)} regions for "
                         f"{cells.shape[0]} triangles")
    cells = counterclockwise(x, cells)
    q = np.asarray(q, dtype=np.float64)
    frames = odeco.q_to_frames(q)
    if features is not None and len(features.junction_nodes) + len(features.tie_corners):
        held = np.union1d(features.junction_nodes, features.tie_corners)
        given_frames = junction_frames(cells, held, frames, given_frames)
    angle, l1, l2 = face_frames_with(cells, q, given_frames, frames)
    edges, faces = interior_edges(cells)
    k = matchings(angle, faces)
    singular, turns = singular_vertices(cells, angle, edges, faces, k)
    cancelled = 0
    if cancel_within:
        k, cancelled = cancel_pairs(x, cells, edges, faces, k, singular, turns, cancel_within)
        singular, turns = singular_vertices(cells, angle, edges, faces, k)
    if glue_within is not None and singular.size:
        keep = () if features is None else features.required_points
        k, glued = glue_to_boundary(x, cells, edges, faces, k, singular, turns, glue_within,
                                    keep=keep)
        if glued:
            cancelled += glued
            singular, turns = singular_vertices(cells, angle, edges, faces, k)
    cut, paths = cut_graph(x, cells, edges, faces, singular)
    r = comb(angle, faces, k, cut)
    angle, l1, l2 = relabel(angle, l1, l2, r)
    jump = jumps(faces, k, r)
    corners = wedges(cells, edges, faces, cut)
    return CutMesh(x=x, cells=cells, angle=angle, l1=l1, l2=l2, edges=edges, faces=faces,
                   cut=cut, jump=jump, corners=corners, singular=singular, turns=turns,
                   paths=paths, cancelled=cancelled,
                   vertex_angle=frames[1],
                   features=features)
