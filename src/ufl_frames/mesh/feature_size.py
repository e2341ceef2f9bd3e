r"""The geometry's local feature size: a cap on the default triangle size that resolves
the shape.

A frame field is only as good as the triangles that carry it. Two parts of a shape are
missed by a size chosen from its area or set by a file:

* **thin parts** (a neck between a hole and the outline, a wall between two slots): with
  one or two triangles across, the boundary-aligned crosses on either side meet in one
  triangle and the singularities the index theorem needs there have nowhere to sit;
* **tightly curved boundary** (an airfoil's nose of radius 0.016 in a chord of 1): the
  cross turns by 4× the boundary's turn between two boundary vertices, and once that
  passes 180° the discrete index misses it.

:func:`feature_caps` measures both at points along the model's curves: the local width
t(p) (the distance to the nearest point of the boundary across the domain) and the
curvature κ(p). The cap at a sample p is

.. math::  c(p) = \min\Big(\frac{t(p)}{n_{\text{across}}},\;
           \frac{2\pi}{n_{\text{turn}}\,\kappa(p)}\Big),

with :data:`ELEMENTS_ACROSS` elements across and :data:`POINTS_PER_TURN` per full turn,
never below :data:`FLOOR_SHARE` of the reference size h_ref (the automatic size, or a
file's largest); :class:`FeatureSize` grades it into the domain, h_cap(x) = min_p (c(p) +
g |x − p|) with the grading g = :data:`GRADING`, where that is below h_ref (no cap
elsewhere), and :func:`install` hands it to Gmsh as a size callback that only ever
lowers the size Gmsh would use (the file's, or the automatic one). Sizes given
explicitly (``--mesh-size``) are not capped (:func:`ufl_frames.mesh.meshing.mesh_model`).

A pair of boundary points counts as "across the domain" when the midpoint of the
segment between them is inside a surface and the way between them along the boundary
is at least :data:`DETOUR` times their distance (points on the same curve or on two
curves meeting at a corner: so a wedge counts only below about 39°, and a disk, a
corner or a hole's opposite sides not at all).
"""

import math
from dataclasses import dataclass

import numpy as np

#: Elements across a thin part of the domain asked for (issue: "at least ~3").
ELEMENTS_ACROSS = 3.0
#: Triangle edges per full turn of a curved boundary: 30° of boundary turn per edge, 120°
#: of cross turn (below the 180° at which the discrete index misses it), as
#: :data:`ufl_frames.mesh.meshing.CURVE_POINTS_PER_TURN` for circles.
POINTS_PER_TURN = 12.0
#: Growth of the cap away from the boundary point that sets it (size per unit distance).
GRADING = 0.3
#: The way along the boundary between two points of a "thin part" is at least this many
#: times their distance (below that they are neighbours along the boundary, not sides).
DETOUR = 3.0
#: The cap is never below this share of the reference size (a sharp wedge would ask for
#: sizes going to zero at its tip).
FLOOR_SHARE = 1.0 / 32.0
#: Gmsh's ``Mesh.LcIntegrationPrecision`` while the cap is in place (its default 1e-9
#: made Gmsh ask the Python callback for 3·10⁶ sizes along the curves of a rotor sector).
INTEGRATION_PRECISION = 1e-4
#: Samples along the curves per reference size, and at most this many in all.
SAMPLES_PER_SIZE = 4.0
MAX_SAMPLES = 40_000
#: A sample is dropped from the callback's list when the others already cap its point
#: within this factor of its own cap (the graded cap is then at most this much larger).
_PRUNE_SLACK = 1.1
#: Samples closer than this share of the reach are one point (a corner where two curves
#: meet is a sample of each).
_SAME_POINT = 1e-9


@dataclass(frozen=True)
class Samples:
    """Points along the model's curves (all arrays of one length n, curve order).

    Attributes:
        points: (n, 2) coordinates.
        curve: (n,) the index of each point's curve in ``ends``.
        arc: (n,) arc length from the curve's start.
        length: (n,) the whole length of each point's curve.
        curvature: (n,) the curve's curvature there (0 on lines).
        ends: (m, 2) the model points at the start and end of each curve (−1: none).
        closed: (m,) whether each curve is closed.
        step: (n,) the length of boundary each point stands for.
    """

    points: np.ndarray
    curve: np.ndarray
    arc: np.ndarray
    length: np.ndarray
    curvature: np.ndarray
    ends: np.ndarray
    closed: np.ndarray
    step: np.ndarray


def boundary_way(samples: Samples, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """The length of the way along the curves between samples i and j (arrays): along
    their curve if they share one (the shorter way round a closed one), through the
    shared end if their curves meet, else infinite."""
    ci, cj = samples.curve[i], samples.curve[j]
    si, sj, li, lj = samples.arc[i], samples.arc[j], samples.length[i], samples.length[j]
    way = np.full(i.shape, np.inf)
    same = ci == cj
    d = np.abs(si - sj)
    way[same] = np.where(samples.closed[ci[same]], np.minimum(d, li - d)[same], d[same])
    to_end = (si, li - si)  # to the start (end 0) and to the end (end 1) of i's curve
    from_end = (sj, lj - sj)
    for a in (0, 1):
        for b in (0, 1):
            meet = (~same & (samples.ends[ci, a] >= 0)
                    & (samples.ends[ci, a] == samples.ends[cj, b]))
            way[meet] = np.minimum(way[meet], (to_end[a] + from_end[b])[meet])
    return way


def widths(samples: Samples, inside, reach: float) -> np.ndarray:
    """The local width t(p) of the domain at every sample: the distance to the nearest
    other sample across the domain (module docstring), up to ``reach`` (inf beyond).

    Args:
        samples: The points along the curves.
        inside: ``inside(points) -> bool array``: whether points (k, 2) are in the domain.
        reach: Widths above this are not looked for (they ask for no refinement).

    Returns:
        (n,) widths; ``inf`` where none is within ``reach``.
    """
    from scipy.spatial import cKDTree

    points = samples.points
    n = len(points)
    found = np.full(n, np.inf)
    if n < 2:
        return found
    tree = cKDTree(points)
    todo = np.arange(n)
    k = min(32, n)
    while todo.size:
        dist, nb = tree.query(points[todo], k=k, distance_upper_bound=reach)
        dist, nb = dist.reshape(len(todo), k), nb.reshape(len(todo), k)
        valid = np.isfinite(dist) & (nb < n) & (nb != todo[:, None])
        rows, cols = np.nonzero(valid)
        i, j = todo[rows], nb[rows, cols]
        d = dist[rows, cols]
        far = (d > _SAME_POINT * reach) & (boundary_way(samples, i, j) > DETOUR * d)
        rows, cols, i, j = rows[far], cols[far], i[far], j[far]
        if rows.size:
            across = inside(0.5 * (points[i] + points[j]))
            best = np.full(len(todo), np.inf)
            np.minimum.at(best, rows[across], dist[rows[across], cols[across]])
            found[todo] = best
        # Rows whose k neighbours all lie within reach and gave nothing: look further.
        again = ~np.isfinite(found[todo]) & np.isfinite(dist[:, -1])
        if k >= n or not again.any():
            break
        todo, k = todo[again], min(4 * k, n)
    return found


def feature_caps(samples: Samples, inside, reference: float) -> np.ndarray:
    """The cap c(p) at every sample (module docstring's formula), not below
    :data:`FLOOR_SHARE` · ``reference``; ``inf`` where nothing asks for one.

    Args:
        samples: The points along the curves.
        inside: As for :func:`widths`.
        reference: The size the cap is compared with: widths above
            :data:`ELEMENTS_ACROSS` times it are not looked for.
    """
    t = widths(samples, inside, ELEMENTS_ACROSS * reference)
    with np.errstate(divide="ignore"):
        bend = np.where(samples.curvature > 0,
                        2 * np.pi / (POINTS_PER_TURN * np.abs(samples.curvature)), np.inf)
    caps = np.minimum(t / ELEMENTS_ACROSS, bend)
    return np.where(np.isfinite(caps), np.maximum(caps, FLOOR_SHARE * reference), np.inf)


@dataclass(frozen=True)
class FeatureSize:
    """The graded cap h_cap(x) = min_p (c(p) + g |x − p|) over the kept samples, where
    that is below ``reach`` (inf elsewhere: no cap).

    Attributes:
        points: (k, 2) the samples that cap something (the others are dominated).
        caps: (k,) their caps c(p).
        grading: g.
        reach: Caps from here up are none.
    """

    points: np.ndarray
    caps: np.ndarray
    grading: float = GRADING
    reach: float = math.inf

    @classmethod
    def of(cls, points: np.ndarray, caps: np.ndarray, grading: float = GRADING,
           below: float = math.inf) -> "FeatureSize":
        """The cap of the samples ``points`` with caps ``caps``, keeping only the samples
        whose cap is below ``below`` and not already given (within a factor
        :data:`_PRUNE_SLACK`) by the ones kept before them, smallest first."""
        points, caps = np.asarray(points, float).reshape(-1, 2), np.asarray(caps, float)
        useful = np.flatnonzero(np.isfinite(caps) & (caps < below))
        order = useful[np.argsort(caps[useful], kind="stable")]
        kept: list[int] = []
        for i in order:
            if kept:
                k = np.asarray(kept)
                have = np.min(caps[k] + grading * np.hypot(*(points[k] - points[i]).T))
                if have <= _PRUNE_SLACK * caps[i]:
                    continue
            kept.append(int(i))
        k = np.asarray(kept, dtype=int)
        return cls(points[k], caps[k], grading, below)

    def near(self, box) -> "FeatureSize":
        """The samples whose graded cap is below ``reach`` somewhere in the box
        (x0, y0, x1, y1): the same cap there, from fewer samples."""
        x0, y0, x1, y1 = box
        dx = np.maximum(np.maximum(x0 - self.points[:, 0], self.points[:, 0] - x1), 0.0)
        dy = np.maximum(np.maximum(y0 - self.points[:, 1], self.points[:, 1] - y1), 0.0)
        keep = self.caps + self.grading * np.hypot(dx, dy) < self.reach
        return FeatureSize(self.points[keep], self.caps[keep], self.grading, self.reach)

    def __call__(self, x, y) -> np.ndarray:
        """h_cap at the points (x, y) (arrays or floats; inf without samples)."""
        x, y = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float))
        out = np.full(x.shape, np.inf)
        for start in range(0, len(self.caps), 4096):
            p, c = self.points[start:start + 4096], self.caps[start:start + 4096]
            d = np.hypot(x[..., None] - p[:, 0], y[..., None] - p[:, 1])
            out = np.minimum(out, np.min(c + self.grading * d, axis=-1, initial=np.inf))
        return np.where(out < self.reach, out, np.inf)


def extra_triangles(caps: np.ndarray, step: np.ndarray, size: float,
                    grading: float = GRADING) -> float:
    """About how many triangles the cap adds to a mesh of uniform ``size``.

    Each sample stands for ``step`` of boundary, along which the graded cap c + g ρ is
    below ``size`` out to ρ = (size − c)/g; per unit length that adds
    ∫_0^ρ (1/(c + g r)² − 1/size²) dr = 1/(g c) − 1/(g size) − ρ/size² equilateral
    triangles' worth of area. An upper estimate: both sides of a thin part are counted,
    and the strip is taken as straight.

    Args:
        caps: (n,) the caps at the samples (inf: none).
        step: (n,) the boundary length each sample stands for.
        size: The uniform size the cap lowers.
        grading: g.
    """
    c = np.asarray(caps, float)
    keep = c < size
    c, ds = c[keep], np.asarray(step, float)[keep]
    if c.size == 0:
        return 0.0
    rho = (size - c) / grading
    per_length = 1 / (grading * c) - 1 / (grading * size) - rho / size**2
    return float(np.sum(ds * per_length) / (math.sqrt(3) / 4))


# --- the current Gmsh model -------------------------------------------------------------

def _model_curves() -> list[int]:
    """The curves the 2D mesh conforms to: the surfaces' boundaries and embedded curves."""
    import gmsh

    curves = set()
    for _, surface in gmsh.model.getEntities(2):
        boundary = gmsh.model.getBoundary([(2, surface)], combined=False, oriented=False)
        curves |= {abs(int(t)) for d, t in boundary if d == 1}
        curves |= {int(t) for d, t in gmsh.model.mesh.getEmbedded(2, surface) if d == 1}
    return sorted(curves)


def _polyline(curve: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(n, 2) points of a curve equally spaced in its parameter, and the parameters."""
    import gmsh

    lo, hi = (float(v[0]) for v in gmsh.model.getParametrizationBounds(1, curve))
    u = np.linspace(lo, hi, n)
    xyz = np.asarray(gmsh.model.getValue(1, curve, u), dtype=float).reshape(-1, 3)
    return xyz[:, :2], u


def model_samples(spacing: float) -> tuple[Samples, dict[int, np.ndarray]]:
    """:class:`Samples` along the current model's curves about ``spacing`` apart (fewer
    where more than :data:`MAX_SAMPLES` would be needed), and each curve's polyline.

    Returns:
        The samples, and {curve tag: (k, 2) polyline} of the same points.
    """
    import gmsh

    curves = _model_curves()
    coarse, lengths = {}, {}
    for c in curves:
        line = gmsh.model.getType(1, c) == "Line"
        coarse[c] = _polyline(c, 2 if line else 129)[0]
        lengths[c] = float(np.linalg.norm(np.diff(coarse[c], axis=0), axis=1).sum())
    total = sum(lengths.values())
    spacing = max(spacing, total / MAX_SAMPLES)
    parts, lines = [], {}
    ends = np.full((len(curves), 2), -1, dtype=np.int64)
    closed = np.zeros(len(curves), dtype=bool)
    for k, c in enumerate(curves):
        n = int(min(max(math.ceil(lengths[c] / spacing) + 1, 3), MAX_SAMPLES))
        points, u = _polyline(c, n)
        curved = gmsh.model.getType(1, c) != "Line"
        kappa = (np.abs(np.asarray(gmsh.model.getCurvature(1, c, u), dtype=float))
                 if curved else np.zeros(n))
        kappa = np.where(np.isfinite(kappa), kappa, 0.0)
        arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
        step = np.gradient(arc) if n > 1 else np.zeros(n)
        tags = [int(t) for d, t in gmsh.model.getBoundary([(1, c)], oriented=False) if d == 0]
        size = max(float(arc[-1]), 1e-300)
        closed[k] = (len(tags) < 2 or tags[0] == tags[-1]
                     or np.linalg.norm(points[0] - points[-1]) < 1e-9 * size)
        if not closed[k]:
            first = np.asarray(gmsh.model.getValue(0, tags[0], []), dtype=float)[:2]
            ends[k] = tags if (np.linalg.norm(first - points[0])
                               <= np.linalg.norm(first - points[-1])) else tags[::-1]
        parts.append((points, np.full(n, k), arc, np.full(n, arc[-1]), kappa, step))
        lines[c] = points
    fields = [np.concatenate([p[i] for p in parts]) for i in range(6)]
    return Samples(fields[0], fields[1].astype(np.int64), fields[2], fields[3], fields[4],
                   ends, closed, fields[5]), lines


def model_inside(lines: dict[int, np.ndarray]):
    """``inside(points) -> bool array``: whether points (k, 2) lie in a surface of the
    current model (even-odd rule against the polylines ``lines`` of its boundary curves,
    at most 256 points each)."""
    import gmsh

    polygons = []
    for _, surface in gmsh.model.getEntities(2):
        boundary = gmsh.model.getBoundary([(2, surface)], combined=False, oriented=False)
        segments = []
        for tag in sorted({abs(int(t)) for d, t in boundary if d == 1}):
            p = lines[tag]
            if len(p) > 256:
                p = p[np.unique(np.linspace(0, len(p) - 1, 256).round().astype(int))]
            segments.append(np.hstack([p[:-1], p[1:]]))
        if segments:
            polygons.append(np.vstack(segments))

    def inside(points):
        points = np.asarray(points, float).reshape(-1, 2)
        result = np.zeros(len(points), dtype=bool)
        for seg in polygons:
            x1, y1, x2, y2 = seg.T
            chunk = max(1, 4_000_000 // max(len(seg), 1))
            for start in range(0, len(points), chunk):
                px = points[start:start + chunk, :1]
                py = points[start:start + chunk, 1:]
                straddle = (y1 > py) != (y2 > py)
                with np.errstate(divide="ignore", invalid="ignore"):
                    x_cut = x1 + (py - y1) * (x2 - x1) / (y2 - y1)
                odd = np.count_nonzero(straddle & (px < x_cut), axis=1) % 2 == 1
                result[start:start + chunk] |= odd
        return result

    return inside


def measure(reference: float) -> tuple[FeatureSize, np.ndarray, np.ndarray]:
    """The local feature size of the current model (:func:`feature_caps` at
    :func:`model_samples` about ``reference`` / :data:`SAMPLES_PER_SIZE` apart).

    Args:
        reference: The size the caps are measured against (the automatic size, or the
            file's largest).

    Returns:
        The graded cap (the samples whose cap is below ``reference``), the caps at all
        samples and the boundary length each stands for (for :func:`extra_triangles`).
    """
    samples, lines = model_samples(reference / SAMPLES_PER_SIZE)
    caps = feature_caps(samples, model_inside(lines), reference)
    return FeatureSize.of(samples.points, caps, below=reference), caps, samples.step


def install(field: FeatureSize, scale: float, notes: list[str]) -> None:
    """Cap the sizes Gmsh will use for the current model: a size callback returning
    min(lc, ``scale`` · h_cap(x)) (lc: the size Gmsh would use otherwise), and a note;
    nothing when ``field`` caps nothing.

    Args:
        field: The graded cap (:func:`measure`).
        scale: Multiplies the caps as the sizes are multiplied (the size factor and
            2^refinements, divided by the ``Mesh.MeshSizeFactor`` Gmsh applies itself).
        notes: The loader's notes.
    """
    import gmsh

    if not len(field.caps):
        return

    # Gmsh asks for sizes millions of times along curves (it integrates 1/size along
    # each): every entity gets the samples that can cap it, once.
    local: dict[tuple[int, int], FeatureSize] = {}

    def size(dim, tag, x, y, z, lc):
        if (dim, tag) not in local:
            x0, y0, _, x1, y1, _ = gmsh.model.getBoundingBox(dim, tag) if dim > 0 else (
                x, y, 0, x, y, 0)
            local[dim, tag] = field.near((x0, y0, x1, y1)) if dim > 0 else field
        near = local[dim, tag]
        if not len(near.caps):
            return float(lc)
        return float(min(lc, scale * near(x, y)))

    gmsh.model.mesh.setSizeCallback(size)
    gmsh.option.setNumber("Mesh.LcIntegrationPrecision",
                          max(gmsh.option.getNumber("Mesh.LcIntegrationPrecision"),
                              INTEGRATION_PRECISION))
    notes.append(f"sizes capped near {len(field.caps)} boundary points by the shape's local "
                 f"feature size ({ELEMENTS_ACROSS:g} elements across thin parts, "
                 f"{POINTS_PER_TURN:g} per turn of curves; smallest cap "
                 f"{field.caps.min():.3g} at size factor 1)")


def uninstall() -> None:
    """Remove the size callback of :func:`install`."""
    import gmsh

    gmsh.model.mesh.removeSizeCallback()
