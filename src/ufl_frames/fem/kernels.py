r"""Compiled element kernels of the Newton model's matrices, damped in the H¹ metric.

The Newton model assembles, at every Newton step
(:class:`ufl_frames.solvers.hessian.GaussNewtonModel`), either the Gauss–Newton matrix
∫ J[δq]·J[w] dx or the full Hessian of H, ∫ J[δq]·J[w] + r·D²r[δq, w] dx, plus the damping
λ (∫ ∇δq:∇w dx + ∫ δq·w dx / A). Here r = [u, v] is the Lie bracket of eq. (10) and J its
linearisation,

.. math::  J[\delta q]_i = C_{ijkl}\,(\delta q_l\,\partial_k q_j + q_l\,\partial_k \delta q_j),

.. math::  D^2 r_i[\delta q, w] = C_{ijkl}\,(\delta q_l\,\partial_k w_j
           + w_l\,\partial_k \delta q_j).

On P1 frame fields ∇q is constant on a triangle and q linear, so J and r are linear there
and the integrands quadratic: the three edge midpoints integrate them exactly. FFCx
expands the UFL forms (:func:`ufl_frames.fem.energy.gauss_newton_form`, the second
derivative of :func:`~ufl_frames.fem.energy.integrability_energy_form`) into one weight
per pair of (component, derivative) of the test and the trial function, about 10⁴ flops a
triangle; written in J, the same matrix costs about 2·10³ (2 × 15 entries of J per point,
then Jᵀ J). This module writes both kernels in C from the bracket table
(:data:`~ufl_frames.frames2d.bracket.BRACKET_ENTRIES`), compiles them with cffi as FFCx
does its own (once, cached beside FFCx's), and gives DOLFINx forms made of them: the
same matrices as the UFL forms (tested to round-off), assembled by DOLFINx into PETSc
in 0.21 / 0.30 s instead of 0.46 / 0.48 s at 10⁵ triangles (Gauss–Newton / exact).
"""

import functools
import hashlib
import importlib.machinery
import importlib.util
import os
import sys
import tempfile
from pathlib import Path

from ufl_frames.bootstrap import init_petsc

init_petsc()

import dolfinx  # noqa: E402
import dolfinx.fem as fem  # noqa: E402
import numpy as np  # noqa: E402
from petsc4py import PETSc  # noqa: E402

from ufl_frames.fem.energy import check_frame_function  # noqa: E402
from ufl_frames.frames2d.bracket import BRACKET_ENTRIES  # noqa: E402

__all__ = ["model_kernel_source", "damped_gauss_newton_form", "damped_hessian_form",
           "reduced_model_form", "model_action_form"]

_NAMES = {False: "ufl_frames_damped_gauss_newton", True: "ufl_frames_damped_hessian"}
#: The same in reduced tangent coordinates, by (exact, columns of the basis).
_REDUCED_NAMES = {(exact, nc): f"{_NAMES[exact]}_reduced{nc}"
                  for exact in (False, True) for nc in (2, 3)}
#: The same matrices' products with a field (linear forms).
_ACTION_NAMES = {exact: f"{_NAMES[exact]}_action" for exact in (False, True)}
_ALL_NAMES = (*_NAMES.values(), *_REDUCED_NAMES.values(), *_ACTION_NAMES.values())
_ARGUMENTS = ("(double* restrict A, const double* restrict w, const double* restrict c, "
              "const double* restrict coordinate_dofs, const int* restrict entity_local_index, "
              "const uint8_t* restrict quadrature_permutation, void* custom_data)")


def _bracket_lines() -> tuple[list[str], list[str], list[str]]:
    """C statements from the bracket's entries C_ijkl: J's two coefficient arrays
    a[i][l] = Σ C_ijkl ∂_k q_j (multiplies δq_l) and b[i][j][k] = Σ C_ijkl q_l (multiplies
    ∂_k δq_j), q and ∇q at the point; and the residual's second derivative paired with
    the residual, r_i C_ijkl (δq_l ∂_k w_j + w_l ∂_k δq_j), into the element matrix."""
    a_terms, b_terms, second = {}, {}, []
    for (i, j, k, l), value in sorted(BRACKET_ENTRIES.items()):
        a_terms.setdefault((i, l), []).append(f"{float(value)!r} * gq[{j}][{k}]")
        b_terms.setdefault((i, j, k), []).append(f"{float(value)!r} * qp[{l}]")
        second.append(
            f"      {{ const double s = weight * r[{i}] * {float(value)!r};"
            f" for (int v = 0; v < 3; ++v) for (int u = 0; u < 3; ++u) {{"
            f" A[15 * (5 * v + {j}) + 5 * u + {l}] += s * phi[p][u] * dphi[v][{k}];"
            f" A[15 * (5 * v + {l}) + 5 * u + {j}] += s * phi[p][v] * dphi[u][{k}]; }} }}")
    a_lines = [f"  a[{i}][{l}] = {' + '.join(t)};" for (i, l), t in sorted(a_terms.items())]
    b_lines = [f"    b[{i}][{j}][{k}] = {' + '.join(t)};" for (i, j, k), t in
               sorted(b_terms.items())]
    return a_lines, b_lines, second


def _geometry_lines(a_lines: list[str]) -> list[str]:
    """C statements: the triangle's gradients of the hat functions dphi, area, ∇q (gq),
    J's first coefficient array a and the quadrature rule (phi, weight)."""
    return [
        "  const double e1x = x[3] - x[0], e1y = x[4] - x[1];",
        "  const double e2x = x[6] - x[0], e2y = x[7] - x[1];",
        "  const double det = e1x * e2y - e1y * e2x, area = 0.5 * fabs(det);",
        "  double dphi[3][2];",
        "  dphi[1][0] = e2y / det; dphi[1][1] = -e2x / det;",
        "  dphi[2][0] = -e1y / det; dphi[2][1] = e1x / det;",
        "  dphi[0][0] = -dphi[1][0] - dphi[2][0]; dphi[0][1] = -dphi[1][1] - dphi[2][1];",
        "  double gq[5][2];",
        "  for (int j = 0; j < 5; ++j)",
        "    for (int k = 0; k < 2; ++k)",
        "      gq[j][k] = w[j] * dphi[0][k] + w[5 + j] * dphi[1][k] + w[10 + j] * dphi[2][k];",
        "  double a[2][5] = {{0}};",
        *a_lines,
        "  /* the edge midpoints: the rule of degree 2 with weights area / 3 */",
        "  static const double phi[3][3] = {{0.5, 0.5, 0.0}, {0.0, 0.5, 0.5}, {0.5, 0.0, 0.5}};",
        "  const double weight = area / 3.0;",
    ]


def _point_lines(b_lines: list[str]) -> list[str]:
    """C statements at quadrature point p: q there (qp), J's second coefficient array b
    and J (2 × 15: the bracket's linearisation at the 15 basis functions)."""
    return [
        "    double qp[5];",
        "    for (int l = 0; l < 5; ++l)",
        "      qp[l] = phi[p][0] * w[l] + phi[p][1] * w[5 + l] + phi[p][2] * w[10 + l];",
        "    double b[2][5][2] = {{{0}}};",
        *b_lines,
        "    double J[2][15];",
        "    for (int i = 0; i < 2; ++i)",
        "      for (int v = 0; v < 3; ++v)",
        "        for (int m = 0; m < 5; ++m)",
        "          J[i][5 * v + m] = phi[p][v] * a[i][m] + b[i][m][0] * dphi[v][0]",
        "                            + b[i][m][1] * dphi[v][1];",
    ]


#: C statements: λ (K + M/A) of the vertices v, u of the triangle, into ``value``.
_DAMPING_LINES = [
    "      const double stiffness = area * (dphi[v][0] * dphi[u][0]",
    "                                       + dphi[v][1] * dphi[u][1]);",
    "      const double mass = area / 12.0 * (v == u ? 2.0 : 1.0);",
    "      const double value = lambda * (stiffness + inverse_area * mass);",
]


@functools.cache
def model_kernel_source() -> str:
    """The C source of the element kernels (DOLFINx's ``tabulate_tensor`` signature):
    ``ufl_frames_damped_gauss_newton`` and ``ufl_frames_damped_hessian``, the same in
    reduced coordinates (``…_reduced2``, ``…_reduced3``) and their products with a field
    (``…_action``).

    Per triangle: ``w`` the 3 × 5 Odeco coefficients of q at its vertices (vertex-major),
    ``c`` = (λ, 1/A), ``coordinate_dofs`` its 3 vertices (x, y, z). ``A`` (15 × 15,
    row-major, zeroed by DOLFINx) receives Σ_points (area/3) J[φ_s]·J[φ_r] (+ r · D²r[φ_s,
    φ_r] for the Hessian, r = [u, v] at the point) + λ (K_rs + M_rs/A) δ_components.
    The reduced kernels read after q in ``w`` the 5 × c blocks T_v of a tangent basis
    and write Tᵀ A T (3c × 3c); Gauss–Newton's from J T (2 × 3c a point) directly, about
    a third of the flops of the 15 × 15 matrix and its product. The action kernels read
    a field d after q and write A d (15 values).
    """
    a_lines, b_lines, second = _bracket_lines()
    return "\n".join([
        "#include <math.h>",
        "#include <stdint.h>",
        "static inline void model(double* restrict A, const double* restrict w,",
        "                         const double* restrict c, const double* restrict x,",
        "                         const int exact)",
        "{",
        *_geometry_lines(a_lines),
        "  for (int p = 0; p < 3; ++p)",
        "  {",
        *_point_lines(b_lines),
        "    for (int r = 0; r < 15; ++r)",
        "    {",
        "      const double j0 = weight * J[0][r], j1 = weight * J[1][r];",
        "      for (int s = 0; s < 15; ++s)",
        "        A[15 * r + s] += j0 * J[0][s] + j1 * J[1][s];",
        "    }",
        "    if (exact)",
        "    {",
        "      double r[2];",
        "      for (int i = 0; i < 2; ++i)",
        "        r[i] = a[i][0] * qp[0] + a[i][1] * qp[1] + a[i][2] * qp[2] + a[i][3] * qp[3]",
        "               + a[i][4] * qp[4];",
        *second,
        "    }",
        "  }",
        "  /* λ (K + M / A) on each of the 5 components */",
        "  const double lambda = c[0], inverse_area = c[1];",
        "  for (int v = 0; v < 3; ++v)",
        "    for (int u = 0; u < 3; ++u)",
        "    {",
        *_DAMPING_LINES,
        "      for (int m = 0; m < 5; ++m)",
        "        A[15 * (5 * v + m) + 5 * u + m] += value;",
        "    }",
        "}",
        *[line for exact, name in _NAMES.items() for line in (
            f"void {name}{_ARGUMENTS}",
            "{",
            f"  model(A, w, c, coordinate_dofs, {int(exact)});",
            "}")],
        "/* Gauss–Newton in tangent coordinates: Σ (J T)ᵀ (J T) + λ (K + M/A) T_vᵀ T_u, with",
        "   T_v (5 × nc, row-major) the tangent basis of vertex v, after q in w */",
        "static inline void reduced_gauss_newton(double* restrict R, const double* restrict w,",
        "                                        const double* restrict c,",
        "                                        const double* restrict x, const int nc)",
        "{",
        "  const double* restrict T = w + 15;",
        "  const int m = 3 * nc;",
        *_geometry_lines(a_lines),
        "  for (int p = 0; p < 3; ++p)",
        "  {",
        *_point_lines(b_lines),
        "    double JT[2][9];",
        "    for (int i = 0; i < 2; ++i)",
        "      for (int v = 0; v < 3; ++v)",
        "        for (int k = 0; k < nc; ++k)",
        "        {",
        "          double s = 0.0;",
        "          for (int n = 0; n < 5; ++n)",
        "            s += J[i][5 * v + n] * T[5 * nc * v + nc * n + k];",
        "          JT[i][nc * v + k] = s;",
        "        }",
        "    for (int r = 0; r < m; ++r)",
        "    {",
        "      const double j0 = weight * JT[0][r], j1 = weight * JT[1][r];",
        "      for (int s = 0; s < m; ++s)",
        "        R[m * r + s] += j0 * JT[0][s] + j1 * JT[1][s];",
        "    }",
        "  }",
        "  const double lambda = c[0], inverse_area = c[1];",
        "  for (int v = 0; v < 3; ++v)",
        "    for (int u = 0; u < 3; ++u)",
        "    {",
        *_DAMPING_LINES,
        "      for (int k = 0; k < nc; ++k)",
        "        for (int l = 0; l < nc; ++l)",
        "        {",
        "          double s = 0.0;",
        "          for (int n = 0; n < 5; ++n)",
        "            s += T[5 * nc * v + nc * n + k] * T[5 * nc * u + nc * n + l];",
        "          R[m * (nc * v + k) + nc * u + l] += value * s;",
        "        }",
        "    }",
        "}",
        "/* the full Hessian in tangent coordinates: Tᵀ A T from the 15 × 15 matrix */",
        "static inline void reduced_hessian(double* restrict R, const double* restrict w,",
        "                                   const double* restrict c,",
        "                                   const double* restrict x, const int nc)",
        "{",
        "  double A[225] = {0};",
        "  model(A, w, c, x, 1);",
        "  const double* restrict T = w + 15;",
        "  const int m = 3 * nc;",
        "  double AT[15 * 9];  /* A T: 15 × 3 nc */",
        "  for (int r = 0; r < 15; ++r)",
        "    for (int u = 0; u < 3; ++u)",
        "      for (int l = 0; l < nc; ++l)",
        "      {",
        "        double s = 0.0;",
        "        for (int n = 0; n < 5; ++n)",
        "          s += A[15 * r + 5 * u + n] * T[5 * nc * u + nc * n + l];",
        "        AT[m * r + nc * u + l] = s;",
        "      }",
        "  for (int v = 0; v < 3; ++v)",
        "    for (int k = 0; k < nc; ++k)",
        "      for (int j = 0; j < m; ++j)",
        "      {",
        "        double s = 0.0;",
        "        for (int n = 0; n < 5; ++n)",
        "          s += T[5 * nc * v + nc * n + k] * AT[m * (5 * v + n) + j];",
        "        R[m * (nc * v + k) + j] += s;",
        "      }",
        "}",
        "/* the model's product with a field d (after q in w): b = A d */",
        "static inline void action(double* restrict b, const double* restrict w,",
        "                          const double* restrict c, const double* restrict x,",
        "                          const int exact)",
        "{",
        "  double A[225] = {0};",
        "  model(A, w, c, x, exact);",
        "  for (int r = 0; r < 15; ++r)",
        "    for (int s = 0; s < 15; ++s)",
        "      b[r] += A[15 * r + s] * w[15 + s];",
        "}",
        *[line for (exact, nc), name in _REDUCED_NAMES.items() for line in (
            f"void {name}{_ARGUMENTS}",
            "{",
            f"  reduced_{'hessian' if exact else 'gauss_newton'}(A, w, c, coordinate_dofs, "
            f"{nc});",
            "}")],
        *[line for exact, name in _ACTION_NAMES.items() for line in (
            f"void {name}{_ARGUMENTS}",
            "{",
            f"  action(A, w, c, coordinate_dofs, {int(exact)});",
            "}")],
        "",
    ])


#: The kernel modules this process has loaded, by name (every rank loads in the same
#: order, so a hit here is a hit on every rank and no collective call is skipped alone).
_LOADED = {}


def _compiled(comm):
    """The compiled kernel module (collective on its first call): built by rank 0 into
    the JIT cache the first time (named by a hash of the source), loaded on every rank."""
    source = model_kernel_source()
    digest = hashlib.sha256((source + sys.version).encode()).hexdigest()[:16]
    name = f"_ufl_frames_model_kernels_{digest}"
    if name in _LOADED:
        return _LOADED[name]
    cache = Path(dolfinx.jit.get_options()["cache_dir"]).expanduser() / "ufl_frames"
    suffix = importlib.machinery.EXTENSION_SUFFIXES[0]
    path = cache / f"{name}{suffix}"
    error = None
    if comm.rank == 0 and not path.is_file():
        try:
            _build(name, source, cache, path)
        except Exception as exc:  # every rank raises below, not rank 0 alone
            error = f"{type(exc).__name__}: {exc}"
    error = comm.bcast(error, root=0)
    if error is not None:
        raise RuntimeError(f"could not compile the Newton model's kernels: {error}")
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    _LOADED[name] = module
    return module


def _build(name: str, source: str, cache: Path, path: Path) -> None:
    """Compile ``source`` with cffi in a temporary folder and move the library to ``path``
    (a rename: a reader never sees half a file)."""
    import cffi

    cache.mkdir(parents=True, exist_ok=True)
    ffi = cffi.FFI()
    ffi.cdef("\n".join(f"void {function}{_ARGUMENTS.replace('restrict ', '')};"
                        for function in _ALL_NAMES))
    ffi.set_source(name, source, extra_compile_args=["-O2", "-std=c99"])
    with tempfile.TemporaryDirectory(dir=cache) as build:
        built = Path(ffi.compile(tmpdir=build, verbose=False))
        os.replace(built, path)


def damped_gauss_newton_form(q: fem.Function, damping: fem.Constant,
                             inverse_area: fem.Constant) -> fem.Form:
    """The DOLFINx form of ∫ J[δq]·J[w] + λ (∇δq:∇w + δq·w/A) dx with the compiled kernel:
    the matrix of ``energy.gauss_newton_form(q) + λ sobolev_form`` (λ = ``damping``, 1/A =
    ``inverse_area``, both read at every assembly), over the cells this rank owns
    (collective: compiles once)."""
    return _damped_form(q, damping, inverse_area, exact=False)


def damped_hessian_form(q: fem.Function, damping: fem.Constant,
                        inverse_area: fem.Constant) -> fem.Form:
    """The same with the full Hessian of H, ∫ J[δq]·J[w] + r·D²r[δq, w] dx (r = [u, v],
    D²r_i[δq, w] = C_ijkl (δq_l ∂_k w_j + w_l ∂_k δq_j)): the matrix of the UFL second
    derivative of :func:`energy.integrability_energy_form` plus the damping."""
    return _damped_form(q, damping, inverse_area, exact=True)


def reduced_model_form(q: fem.Function, basis: fem.Function, space: fem.FunctionSpace,
                       damping: fem.Constant, inverse_area: fem.Constant,
                       exact: bool = False) -> fem.Form:
    """The model's matrix of :func:`damped_gauss_newton_form` (``exact``:
    :func:`damped_hessian_form`) in tangent coordinates, Tᵀ A T, assembled directly: no
    5N × 5N matrix and no product Pᵀ A P (the reduced matrix of
    :class:`~ufl_frames.solvers.hessian.GaussNewtonModel`).

    ``basis`` is a P1 function with 5·c components a vertex, the 5 × c matrix T_v row-major
    (c = 3 tangent directions of non-isotropic frames, 2 isotropic; a zero column where a
    direction is absent gives a zero row and column); ``space`` the P1 space of c
    components the matrix acts on. Both must number the vertices as ``q``'s space does,
    so that the reduced unknown (v, k) pairs with column k of T_v.
    """
    check_frame_function(q)
    V = q.function_space
    columns = basis.function_space.dofmap.index_map_bs // 5
    if (columns not in (2, 3) or basis.function_space.dofmap.index_map_bs != 5 * columns
            or space.dofmap.index_map_bs != columns):
        raise ValueError(f"a tangent basis of 2 or 3 columns and a space of as many "
                         f"components, not {basis.function_space.dofmap.index_map_bs} "
                         f"and {space.dofmap.index_map_bs}")
    for other in (basis.function_space, space):
        _check_same_vertices(V, other)
    return _compiled_form(_REDUCED_NAMES[(exact, columns)], [space, space], [q, basis],
                          [damping, inverse_area])


def model_action_form(q: fem.Function, direction: fem.Function, damping: fem.Constant,
                      inverse_area: fem.Constant, exact: bool = False) -> fem.Form:
    """The vector A d of the matrix A of :func:`damped_gauss_newton_form` (``exact``:
    :func:`damped_hessian_form`) and a P1 field ``direction`` d of ``q``'s space, without
    A (a linear form, the element matrix applied in the kernel)."""
    check_frame_function(q)
    _check_same_vertices(q.function_space, direction.function_space)
    if direction.function_space.dofmap.index_map_bs != q.function_space.dofmap.index_map_bs:
        raise ValueError("the direction must have the frame field's 5 components")
    return _compiled_form(_ACTION_NAMES[exact], [q.function_space], [q, direction],
                          [damping, inverse_area])


def _check_same_vertices(V: fem.FunctionSpace, W: fem.FunctionSpace) -> None:
    """Raise ValueError unless the P1 spaces V and W number the mesh's vertices alike."""
    a, b = V.dofmap.index_map, W.dofmap.index_map
    if (V.mesh is not W.mesh or a.size_local != b.size_local or a.num_ghosts != b.num_ghosts
            or not np.array_equal(V.dofmap.list, W.dofmap.list)):
        raise ValueError("the spaces do not number the mesh's vertices alike")


def _damped_form(q, damping, inverse_area, exact: bool) -> fem.Form:
    check_frame_function(q)
    V = q.function_space
    return _compiled_form(_NAMES[exact], [V, V], [q], [damping, inverse_area])


def _compiled_form(name: str, spaces, coefficients, constants) -> fem.Form:
    """A DOLFINx form over the owned cells whose kernel is the compiled function ``name``
    (collective: compiles once)."""
    mesh = coefficients[0].function_space.mesh
    module = _compiled(mesh.comm)
    kernel = module.ffi.addressof(module.lib, name)
    pointer = int(module.ffi.cast("uintptr_t", kernel))
    cells = np.arange(mesh.topology.index_map(mesh.topology.dim).size_local, dtype=np.int32)
    # (position in the flattened list of integrals, kernel, cells, active coefficients)
    active = np.arange(len(coefficients), dtype=np.int8)
    integrals = {fem.IntegralType.cell: [(0, pointer, cells, active)]}
    form = fem.form_cpp_class(PETSc.ScalarType)(
        [V._cpp_object for V in spaces], integrals, [f._cpp_object for f in coefficients],
        [c._cpp_object for c in constants], False, [], mesh._cpp_object)
    compiled = fem.Form(form)
    compiled._kernel_module = module  # keeps the library loaded as long as the form lives
    return compiled
