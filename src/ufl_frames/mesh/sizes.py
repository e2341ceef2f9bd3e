r"""Size targets h(x): the local edge length the quads are asked to have.

A :class:`SizeTarget` is what the sized frame problem (:mod:`ufl_frames.fem.energy`,
:func:`~ufl_frames.fem.energy.size_misfit_form`) and the reports need: h at any points,
known up to one global factor (the map's scale, or ``--quad-count``, fixes that factor).
It is one of

* uniform (the default: every frame of the same size, as far as integrability allows);
* a Python callable ``h(x, y)`` of NumPy arrays;
* a NumPy expression in ``x`` and ``y`` from the command line
  (``--size "0.02 + 0.1*hypot(x, y)"``), read by :func:`parse_size_expression`: the
  expression is parsed with :mod:`ast` and evaluated by walking its tree, allowing only
  numbers, ``x``, ``y``, ``pi``, ``e``, arithmetic and the NumPy functions of
  :data:`FUNCTIONS` (no ``eval``, no attributes, no subscripts, no keywords);
* samples (x, y, h) of a size known at points, such as the sizes Gmsh asks for when it
  meshes a file (:func:`file_size_samples`), interpolated linearly between them and
  by the nearest sample outside their hull.

:func:`quad_count_factor` scales a target to a number of quads, N ≈ ∫ 1/h² dx.

Pure NumPy and SciPy (Gmsh is imported only by :func:`file_size_samples`).
"""

import ast
import functools
import math
import operator
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

__all__ = ["DEFAULT_SIZE_SMOOTHING", "DEFAULT_SIZE_WEIGHT", "FUNCTIONS", "SIZE_SMOOTHING",
           "SIZE_WORDS",
           "TRIANGLES_PER_QUAD_EDGE",
           "SizeExpressionError", "SizeTarget", "file_size_samples", "parse_size_expression",
           "quad_count_factor", "read_file_sizes", "resolving_factor"]

#: w of the sized energy H + w H_s M (see :func:`ufl_frames.fem.energy.size_misfit_form`):
#: dimensionless, measured in ``docs/note-checks.md`` ("The sized problem").
DEFAULT_SIZE_WEIGHT = 0.3
#: s of the sized energy's smoothing term w H_s s Ŝ (``-frames_size_smoothing``; see
#: :func:`ufl_frames.fem.problem.size_term`): a Dirichlet energy relative to the misfit,
#: which charges each singularity ∝ log(1/mesh size). 0: no such term. Without it the
#: sized piano's minimisers grow ±1/4 pairs under refinement (38 singularities at 24 687
#: triangles unpinned); with 0.1 they keep 2 (0.05: 4); benchmarks/README, "A smoothing
#: term for the sized problem". The default (``-frames_size_smoothing 0`` turns it off).
SIZE_SMOOTHING = 0.1
DEFAULT_SIZE_SMOOTHING = SIZE_SMOOTHING

#: Triangle edges a quad edge of a sized mesh spans at least (see :func:`resolving_factor`).
#: Measured on ``benchmarks/shapes/l_shape_graded.geo`` at 400 quads: about one (the
#: file's own sizes) folds the map at the re-entrant corner; about two (size factors 0.5
#: and 0.48) once gave valid quads and once ± pairs of singularities a triangle from the
#: corner that fold it again; three (0.32, and 0.3 by hand) gave valid quads.
TRIANGLES_PER_QUAD_EDGE = 3.0
#: The share of the cells allowed to be coarser than that (a few cells where Gmsh's sizes
#: lag the target, e.g. next to a point size, should not refine the whole mesh).
_UNRESOLVED_SHARE = 0.05

#: The functions a size expression may call (the NumPy functions of the same name).
FUNCTIONS = {
    name: getattr(np, name)
    for name in ("sqrt", "exp", "log", "log10", "log2", "sin", "cos", "tan", "arcsin",
                 "arccos", "arctan", "arctan2", "sinh", "cosh", "tanh", "hypot", "abs",
                 "minimum", "maximum", "floor", "ceil")
}
FUNCTIONS.update({"min": np.minimum, "max": np.maximum})
_NAMES = {"pi": math.pi, "e": math.e}
#: The words ``--size`` takes besides an expression.
SIZE_WORDS = ("file", "uniform", "none")
_BINARY = {ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul,
           ast.Div: operator.truediv, ast.Pow: operator.pow, ast.Mod: operator.mod}
_UNARY = {ast.UAdd: operator.pos, ast.USub: operator.neg}
_MAX_LENGTH = 1000
_MAX_DEPTH = 100


class SizeExpressionError(ValueError):
    """A size expression that is not allowed or not valid (one line)."""


def _describe(node: ast.AST) -> str:
    text = ast.unparse(node) if hasattr(ast, "unparse") else type(node).__name__
    return text if len(text) <= 40 else text[:37] + "..."


def _check_tree(node: ast.AST, depth: int = 0) -> None:
    """Raise :class:`SizeExpressionError` at the first node a size expression may not use."""
    if depth > _MAX_DEPTH:
        raise SizeExpressionError(f"the size expression is nested more than {_MAX_DEPTH} "
                                  f"levels deep")
    depth += 1
    if isinstance(node, ast.Expression):
        _check_tree(node.body, depth)
    elif isinstance(node, ast.Constant):
        if isinstance(node.value, bool) or not isinstance(node.value, (int, float)):
            raise SizeExpressionError(f"only numbers are allowed as constants, got "
                                      f"{_describe(node)}")
    elif isinstance(node, ast.Name):
        if node.id not in ("x", "y") and node.id not in _NAMES:
            raise SizeExpressionError(f"unknown name '{node.id}' (allowed: x, y, pi, e and "
                                      f"the functions {', '.join(sorted(FUNCTIONS))})")
    elif isinstance(node, ast.BinOp):
        if type(node.op) not in _BINARY:
            raise SizeExpressionError(f"operator not allowed in {_describe(node)}")
        _check_tree(node.left, depth)
        _check_tree(node.right, depth)
    elif isinstance(node, ast.UnaryOp):
        if type(node.op) not in _UNARY:
            raise SizeExpressionError(f"operator not allowed in {_describe(node)}")
        _check_tree(node.operand, depth)
    elif isinstance(node, ast.Call):
        if not isinstance(node.func, ast.Name) or node.func.id not in FUNCTIONS:
            raise SizeExpressionError(f"only the functions {', '.join(sorted(FUNCTIONS))} "
                                      f"may be called, got {_describe(node.func)}")
        if node.keywords:
            raise SizeExpressionError(f"no keyword arguments allowed, got {_describe(node)}")
        if not node.args:
            raise SizeExpressionError(f"{node.func.id}() needs arguments")
        for argument in node.args:
            if isinstance(argument, ast.Starred):
                raise SizeExpressionError(f"no * arguments allowed, got {_describe(node)}")
            _check_tree(argument, depth)
    else:
        raise SizeExpressionError(f"'{_describe(node)}' is not allowed in a size expression "
                                  f"(only numbers, x, y, + - * / ** %, and NumPy functions)")


def _evaluate(node: ast.AST, values: dict) -> np.ndarray:
    if isinstance(node, ast.Expression):
        return _evaluate(node.body, values)
    if isinstance(node, ast.Constant):
        return np.float64(node.value)
    if isinstance(node, ast.Name):
        return values[node.id] if node.id in values else np.float64(_NAMES[node.id])
    if isinstance(node, ast.BinOp):
        return _BINARY[type(node.op)](_evaluate(node.left, values),
                                      _evaluate(node.right, values))
    if isinstance(node, ast.UnaryOp):
        return _UNARY[type(node.op)](_evaluate(node.operand, values))
    function = FUNCTIONS[node.func.id]
    return function(*(_evaluate(a, values) for a in node.args))


def parse_size_expression(text: str) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """The function h(x, y) of a NumPy expression in ``x`` and ``y``, checked.

    Args:
        text: the expression, e.g. ``"0.02 + 0.1*hypot(x, y)"``.

    Returns:
        A function of two arrays (the points' coordinates) returning h, shaped like them.

    Raises:
        SizeExpressionError: the text is not an expression, or uses anything but numbers,
            ``x``, ``y``, ``pi``, ``e``, arithmetic and the functions of :data:`FUNCTIONS`.
    """
    if not isinstance(text, str) or not text.strip():
        raise SizeExpressionError("the size expression is empty")
    if len(text) > _MAX_LENGTH:
        raise SizeExpressionError(f"the size expression is longer than {_MAX_LENGTH} "
                                  f"characters")
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except SyntaxError as exc:
        raise SizeExpressionError(f"the size expression {text!r} is not valid: "
                                  f"{exc.msg}") from None
    except (ValueError, RecursionError, MemoryError):
        raise SizeExpressionError(f"the size expression {text!r} is not valid") from None
    try:
        _check_tree(tree)
    except RecursionError:
        raise SizeExpressionError("the size expression is nested too deeply") from None

    def h(x, y):
        x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
        with np.errstate(all="ignore"):
            value = _evaluate(tree, {"x": x, "y": y})
        return np.broadcast_to(np.asarray(value, dtype=np.float64), np.broadcast(x, y).shape)

    return h


@dataclass(frozen=True)
class SizeTarget:
    """A target size h(x) of the quads, up to one global factor, and the weight w of its
    term in the sized frame problem.

    ``kind`` is ``"uniform"``, ``"expression"`` (``text`` holds it), ``"callable"``
    (``function``) or ``"samples"`` (``samples``: (k, 3) rows x, y, h).
    """

    kind: str = "uniform"
    text: str | None = None
    function: Callable | None = field(default=None, compare=False, repr=False)
    samples: np.ndarray | None = field(default=None, compare=False, repr=False)
    weight: float = DEFAULT_SIZE_WEIGHT

    def __post_init__(self):
        if self.kind not in ("uniform", "expression", "callable", "samples"):
            raise ValueError(f"unknown size target kind {self.kind!r}")
        if not (math.isfinite(self.weight) and self.weight >= 0):
            raise ValueError(f"the size weight must be finite and >= 0, got {self.weight}")
        if self.kind == "expression" and self.function is None:
            object.__setattr__(self, "function", parse_size_expression(self.text))
        if self.kind == "callable" and not callable(self.function):
            raise ValueError("a callable size target needs a function h(x, y)")
        if self.kind == "samples":
            samples = np.asarray(self.samples, dtype=np.float64)
            if samples.ndim != 2 or samples.shape[1] != 3 or len(samples) == 0:
                raise ValueError("size samples must be a non-empty (k, 3) array of x, y, h")
            if not (np.all(np.isfinite(samples)) and np.all(samples[:, 2] > 0)):
                raise ValueError("size samples must be finite with h > 0")
            object.__setattr__(self, "samples", samples)

    @functools.cached_property
    def _interpolator(self) -> "_SampleInterpolator":
        """The samples' interpolator, triangulated on first use and kept (a file's
        samples number 10⁴–10⁵ and the target is evaluated several times a run)."""
        return _SampleInterpolator(self.samples)

    def __getstate__(self):  # a pickled target is triangulated again where it is used
        return {k: v for k, v in self.__dict__.items() if k != "_interpolator"}

    @classmethod
    def uniform(cls, weight: float = DEFAULT_SIZE_WEIGHT) -> "SizeTarget":
        return cls("uniform", weight=weight)

    @classmethod
    def expression(cls, text: str, weight: float = DEFAULT_SIZE_WEIGHT) -> "SizeTarget":
        """The target of a NumPy expression in x, y (:func:`parse_size_expression`)."""
        return cls("expression", text=text, weight=weight)

    @classmethod
    def of_function(cls, function: Callable, weight: float = DEFAULT_SIZE_WEIGHT
                    ) -> "SizeTarget":
        """The target of a Python function ``h(x, y)`` of NumPy arrays."""
        return cls("callable", function=function, weight=weight)

    @classmethod
    def of_samples(cls, samples, weight: float = DEFAULT_SIZE_WEIGHT) -> "SizeTarget":
        """The target known at points: rows (x, y, h)."""
        return cls("samples", samples=samples, weight=weight)

    @property
    def is_uniform(self) -> bool:
        return self.kind == "uniform"

    def describe(self) -> str:
        """One line: what the target is."""
        if self.kind == "expression":
            return f"h = {self.text}"
        if self.kind == "samples":
            return f"the file's sizes ({len(self.samples)} samples)"
        return {"uniform": "uniform", "callable": "a Python function"}[self.kind]

    def __call__(self, x) -> np.ndarray:
        """h at the points ``x`` ((M, 2) or (M, 3), or (2, M)/(3, M) with M > 3), (M,).

        Raises:
            ValueError: h is not finite and positive at every point (one line, with the
                first bad point).
        """
        x = np.asarray(x, dtype=np.float64)
        if x.ndim != 2:
            raise ValueError(f"points must be a 2D array, got shape {x.shape}")
        if x.shape[1] not in (2, 3) and x.shape[0] in (2, 3):
            x = x.T
        px, py = x[:, 0], x[:, 1]
        if self.kind == "uniform":
            h = np.ones(len(x))
        elif self.kind == "samples":
            h = self._interpolator(px, py)
        else:
            h = np.broadcast_to(np.asarray(self.function(px, py), dtype=np.float64),
                                px.shape).copy()
        bad = ~(np.isfinite(h) & (h > 0))
        if np.any(bad):
            i = int(np.flatnonzero(bad)[0])
            raise ValueError(f"the size target ({self.describe()}) is {h[i]:g} at "
                             f"({px[i]:g}, {py[i]:g}): sizes must be finite and > 0")
        return h


class _SampleInterpolator:
    """log h interpolated linearly between samples (x, y, h) (the nearest sample outside
    their hull); called with x, y, returns h.

    The triangulation is Qhull's with joggled input (``QJ``): a file's samples lie along
    its curves, many collinear or cocircular, and Qhull's default merging of such facets
    took 76 CPU s on the 66 000 samples of a rotor sector (1.2 s joggled). Where the
    samples are degenerate the Delaunay triangulation is not unique, and neither is the
    linear interpolation between them; a linear log h is reproduced by any of them.
    """

    def __init__(self, samples: np.ndarray):
        from scipy.interpolate import LinearNDInterpolator, NearestNDInterpolator
        from scipy.spatial import Delaunay

        points, logs = samples[:, :2], np.log(samples[:, 2])
        self.nearest = NearestNDInterpolator(points, logs)
        self.linear = None
        if len(points) >= 3:
            try:
                self.linear = LinearNDInterpolator(Delaunay(points, qhull_options="QJ"), logs)
            except Exception:  # degenerate (all collinear) samples: scipy's Qhull refuses
                self.linear = None

    def __call__(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        query = np.column_stack([x, y])
        if self.linear is None:
            return np.exp(self.nearest(query))
        value = self.linear(query)
        outside = ~np.isfinite(value)
        if np.any(outside):
            value[outside] = self.nearest(query[outside])
        return np.exp(value)


def quad_count_factor(h: np.ndarray, areas: np.ndarray, quads: float) -> float:
    """The factor c such that the target c·h asks for about ``quads`` quads:
    N ≈ ∫ 1/(c h)² dx, so c = √(∫ h⁻² dx / N).

    Args:
        h: the target at the cells (e.g. at their centroids), (m,).
        areas: the cells' areas, (m,).
        quads: the number of quads asked for (> 0).
    """
    if not quads > 0:
        raise ValueError(f"the number of quads must be > 0, got {quads}")
    h, areas = np.asarray(h, dtype=np.float64), np.asarray(areas, dtype=np.float64)
    return float(np.sqrt(np.dot(areas, 1.0 / h**2) / quads))


def resolving_factor(h: np.ndarray, edges: np.ndarray, areas: np.ndarray, quads: float,
                     per_edge: float = TRIANGLES_PER_QUAD_EDGE) -> float:
    """The factor f ≤ 1 by which the triangles' sizes must shrink so that the quads of the
    target, c·h with c = :func:`quad_count_factor` (``quads`` of them), span at least
    ``per_edge`` triangle edges each, but on a share of :data:`_UNRESOLVED_SHARE` of the
    cells: f = min(1, q₅(c h / e) / per_edge), q₅ the 5th percentile over the cells.

    A parametrisation made on triangles as large as its quads cannot place their corners
    (the integer-grid map folds); the file's own sizes are the quads' sizes up to c, so a
    file graded towards a point gets about one triangle per quad edge there whatever N is.

    Args:
        h: the target at the cells' centroids, (m,).
        edges: the cells' mean edge lengths, (m,).
        areas: the cells' areas, (m,).
        quads: the number of quads asked for.
        per_edge: triangle edges per quad edge asked for (> 0).

    Returns:
        f in (0, 1]: 1 where the triangles resolve the quads already.
    """
    if not per_edge > 0:
        raise ValueError(f"per_edge must be > 0, got {per_edge}")
    h, edges = np.asarray(h, dtype=np.float64), np.asarray(edges, dtype=np.float64)
    c = quad_count_factor(h, areas, quads)
    ratio = c * h / edges
    return float(min(1.0, np.percentile(ratio, 100 * _UNRESOLVED_SHARE) / per_edge))


def file_size_samples() -> np.ndarray | None:
    """The sizes the current Gmsh model asks for, as Gmsh evaluates them, (k, 3) rows
    x, y, h; None where the model sets no sizes.

    Gmsh has no call that evaluates its size at given points; its mesh size callback
    (``gmsh.model.mesh.setSizeCallback``) is called at every point where the mesher asks
    for a size, with the size Gmsh computed there (point sizes, ``MeshSize{}``, size
    fields and the ``Background Field``, extended from the boundary as the options say).
    So this meshes the model in 2D once with a callback that records those values and
    returns them unchanged, then clears the mesh. The model must be loaded (rank 0).
    """
    import gmsh

    from ufl_frames.mesh import feature_size

    has_fields = len(gmsh.model.mesh.field.list()) > 0
    point_sizes = [s for s in gmsh.model.mesh.getSizes(gmsh.model.getEntities(0))
                   if 0 < s < 1e21]
    if not has_fields and not point_sizes:
        return None
    recorded = []

    def record(dim, tag, x, y, z, lc):
        recorded.append((x, y, lc))
        return lc

    # Gmsh integrates 1/size along every curve to place its points, asking the callback
    # at a precision of 1e-9 by default: 674 734 calls on the rotor sector of the
    # gallery, 66 192 at the local feature size's precision (the same sizes, fewer points).
    precision = gmsh.option.getNumber("Mesh.LcIntegrationPrecision")
    gmsh.option.setNumber("Mesh.LcIntegrationPrecision",
                          max(precision, feature_size.INTEGRATION_PRECISION))
    gmsh.model.mesh.setSizeCallback(record)
    try:
        gmsh.model.mesh.generate(2)
    finally:
        gmsh.model.mesh.removeSizeCallback()
        gmsh.model.mesh.clear()
        gmsh.option.setNumber("Mesh.LcIntegrationPrecision", precision)
    samples = np.asarray(recorded, dtype=np.float64).reshape(-1, 3)
    samples = samples[np.isfinite(samples).all(axis=1) & (samples[:, 2] > 0)
                      & (samples[:, 2] < 1e21)]
    return samples if len(samples) else None


def read_file_sizes(path: str, time_limit: float | None = None) -> np.ndarray | None:
    """:func:`file_size_samples` of the geometry file ``path``, opened in Gmsh for that
    alone: None where the file sets no sizes. Rank 0's work.

    Gmsh runs in a forked child process stopped after ``time_limit`` seconds (None: the
    loader's default, :func:`~ufl_frames.mesh.files.mesh_time_limit`; ``math.inf``: in
    this process, Gmsh initialised here if it is not), as the loader's meshing does: Gmsh's
    parser keeps a ``.geo``'s ``Function`` definitions for the life of the process
    (``gmsh.clear`` and ``gmsh.finalize`` do not forget them), so a parse here would make
    every later parse of the file, in this process or a child forked from it, a
    redefinition that crashes Gmsh."""
    from ufl_frames.gmsh_scratch import scratch_model

    def work():
        with scratch_model("ufl_frames_sizes") as gmsh:
            gmsh.open(str(path))
            return file_size_samples()

    if time_limit is None:
        from ufl_frames.mesh.files import mesh_time_limit

        time_limit = mesh_time_limit()
    if not math.isfinite(time_limit):
        return work()
    from ufl_frames.mesh.distribute import _in_child

    return _in_child(work, str(path), time_limit)
