r"""A compiled element kernel of the Gauss–Newton matrix of H, damped in the H¹ metric.

The Newton model assembles ∫ J[δq]·J[w] dx + λ (∫ ∇δq:∇w dx + ∫ δq·w dx / A) at every
Newton step (:class:`ufl_frames.solvers.hessian.GaussNewtonModel`), J the linearised Lie
bracket of eq. (10),

.. math::  J[\delta q]_i = C_{ijkl}\,(\delta q_l\,\partial_k q_j + q_l\,\partial_k \delta q_j).

On P1 frame fields ∇q is constant on a triangle and q linear, so J is linear there and the
integrand quadratic: the three edge midpoints integrate it exactly. FFCx expands the UFL
form of :func:`ufl_frames.fem.energy.gauss_newton_form` into one weight per pair of
(component, derivative) of the test and the trial function, about 10⁴ flops a triangle;
written in J, the same matrix costs about 2·10³ (2 × 15 entries of J per point, then
Jᵀ J). This module writes that kernel in C from the bracket table
(:data:`~ufl_frames.frames2d.bracket.BRACKET_ENTRIES`), compiles it with cffi as FFCx
does its own kernels (once, cached beside FFCx's), and gives DOLFINx a form made of it:
the same matrix as the UFL form (tested to round-off), assembled by DOLFINx into PETSc.
"""

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

__all__ = ["gauss_newton_kernel_source", "damped_gauss_newton_form"]

_NAME = "ufl_frames_damped_gauss_newton"
_SIGNATURE = (f"void {_NAME}(double* restrict A, const double* restrict w, "
              "const double* restrict c, const double* restrict coordinate_dofs, "
              "const int* restrict entity_local_index, "
              "const uint8_t* restrict quadrature_permutation, void* custom_data)")


def _bracket_lines() -> tuple[list[str], list[str]]:
    """C statements of the two coefficient arrays of J, from the bracket's entries:
    a[i][l] = Σ C_ijkl ∂_k q_j (multiplies δq_l) and b[i][j][k] = Σ C_ijkl q_l (multiplies
    ∂_k δq_j), q and ∇q at the point."""
    a_terms, b_terms = {}, {}
    for (i, j, k, l), value in sorted(BRACKET_ENTRIES.items()):
        a_terms.setdefault((i, l), []).append(f"{float(value)!r} * gq[{j}][{k}]")
        b_terms.setdefault((i, j, k), []).append(f"{float(value)!r} * qp[{l}]")
    a_lines = [f"  a[{i}][{l}] = {' + '.join(t)};" for (i, l), t in sorted(a_terms.items())]
    b_lines = [f"    b[{i}][{j}][{k}] = {' + '.join(t)};" for (i, j, k), t in
               sorted(b_terms.items())]
    return a_lines, b_lines


def gauss_newton_kernel_source() -> str:
    """The C source of the element kernel (DOLFINx's ``tabulate_tensor`` signature).

    Per triangle: ``w`` the 3 × 5 Odeco coefficients of q at its vertices (vertex-major),
    ``c`` = (λ, 1/A), ``coordinate_dofs`` its 3 vertices (x, y, z). ``A`` (15 × 15,
    row-major, zeroed by DOLFINx) receives Σ_points (area/3) J[φ_r]·J[φ_s] +
    λ (K_rs + M_rs/A) δ_components.
    """
    a_lines, b_lines = _bracket_lines()
    return "\n".join([
        "#include <math.h>",
        "#include <stdint.h>",
        _SIGNATURE,
        "{",
        "  const double *x = coordinate_dofs;",
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
        "  for (int p = 0; p < 3; ++p)",
        "  {",
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
        "    for (int r = 0; r < 15; ++r)",
        "    {",
        "      const double j0 = weight * J[0][r], j1 = weight * J[1][r];",
        "      for (int s = 0; s < 15; ++s)",
        "        A[15 * r + s] += j0 * J[0][s] + j1 * J[1][s];",
        "    }",
        "  }",
        "  /* λ (K + M / A) on each of the 5 components */",
        "  const double lambda = c[0], inverse_area = c[1];",
        "  for (int v = 0; v < 3; ++v)",
        "    for (int u = 0; u < 3; ++u)",
        "    {",
        "      const double stiffness = area * (dphi[v][0] * dphi[u][0]",
        "                                       + dphi[v][1] * dphi[u][1]);",
        "      const double mass = area / 12.0 * (v == u ? 2.0 : 1.0);",
        "      const double value = lambda * (stiffness + inverse_area * mass);",
        "      for (int m = 0; m < 5; ++m)",
        "        A[15 * (5 * v + m) + 5 * u + m] += value;",
        "    }",
        "}",
        "",
    ])


def _compiled(comm):
    """The compiled kernel module (collective): built by rank 0 into the JIT cache the
    first time (named by a hash of the source), then loaded on every rank."""
    source = gauss_newton_kernel_source()
    digest = hashlib.sha256((source + sys.version).encode()).hexdigest()[:16]
    name = f"_{_NAME}_{digest}"
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
        raise RuntimeError(f"could not compile the Gauss-Newton kernel: {error}")
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _build(name: str, source: str, cache: Path, path: Path) -> None:
    """Compile ``source`` with cffi in a temporary folder and move the library to ``path``
    (a rename: a reader never sees half a file)."""
    import cffi

    cache.mkdir(parents=True, exist_ok=True)
    ffi = cffi.FFI()
    ffi.cdef(_SIGNATURE.replace("restrict ", "") + ";")
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
    check_frame_function(q)
    V = q.function_space
    mesh = V.mesh
    module = _compiled(mesh.comm)
    pointer = int(module.ffi.cast("uintptr_t", module.ffi.addressof(module.lib, _NAME)))
    cells = np.arange(mesh.topology.index_map(mesh.topology.dim).size_local, dtype=np.int32)
    # (position in the flattened list of integrals, kernel, cells, active coefficients)
    integrals = {fem.IntegralType.cell: [(0, pointer, cells, np.array([0], dtype=np.int8))]}
    form = fem.form_cpp_class(PETSc.ScalarType)(
        [V._cpp_object, V._cpp_object], integrals, [q._cpp_object],
        [damping._cpp_object, inverse_area._cpp_object], False, [], mesh._cpp_object)
    compiled = fem.Form(form)
    compiled._kernel_module = module  # keeps the library loaded as long as the form lives
    return compiled
