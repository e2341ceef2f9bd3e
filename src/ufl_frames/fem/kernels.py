r"""Compiled element kernels of the Newton model's matrices, damped in the H¹ metric.

The Newton model assembles, at every Newton step
(:class:`ufl_frames.solvers.hessian.GaussNewtonModel`), either the Gauss–Newton matrix
∫ J[δq]·J[w] dx or the full Hessian of H, ∫ J[δq]·J[w] + r·D²r[δq, w] dx, plus the damping
λ (∫ ∇δq:∇w dx + ∫ δq·w dx / A). Here r = [u, v] is the Lie bracket of eq. (10) and J its
linearisation,

.. math::  J[\delta q]_i = C_{ijkl}\,(\delta q_l\,\partial_k q_j + q_l\,\partial_k \delta q_j),

.. math::  D^2 r_i[\delta q, w] = C_{ijkl}\,(\delta q_l\,\partial_k w_j
           + w_l\,\partial_k \delta q_j).

On P1 frame fields ∇q is constant on a cell and q linear, so J and r are linear there
and the integrands quadratic: a rule of degree 2 (on a triangle the three edge midpoints)
integrates them exactly. FFCx expands the UFL forms
(:func:`ufl_frames.fem.energy.gauss_newton_form`, the second derivative of
:func:`~ufl_frames.fem.energy.integrability_energy_form`) into one weight per pair of
(component, derivative) of the test and the trial function; written in J, the same matrix
costs several times fewer flops (2 × 15 entries of J per point on a triangle, then Jᵀ J).
This module writes both kernels in C, compiles them with cffi as FFCx does its own (once,
cached beside FFCx's), and gives DOLFINx forms made of them: the same matrices as the UFL
forms (tested to round-off).

The C code is generated from a frame algebra (:mod:`ufl_frames.frames2d.algebra`, the 2D
:data:`~ufl_frames.frames2d.algebra.ALGEBRA` unless one is given): its bracket table, its
number of coefficients a vertex, its dimension and its cell's vertex count are the
template's parameters, and the cell's gradients and quadrature rule come from this
module's table of cells (the triangle's). A 3D algebra (15 coefficients on tetrahedra)
needs its table and a tetrahedron entry there.
"""

import functools
import hashlib
import importlib.machinery
import importlib.util
import os
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

from ufl_frames.bootstrap import init_petsc

init_petsc()

import dolfinx  # noqa: E402
import dolfinx.fem as fem  # noqa: E402
import numpy as np  # noqa: E402
from petsc4py import PETSc  # noqa: E402

from ufl_frames.fem.energy import check_frame_function  # noqa: E402
from ufl_frames.frames2d.algebra import ALGEBRA  # noqa: E402

__all__ = ["model_kernel_source", "damped_gauss_newton_form", "damped_hessian_form",
           "reduced_model_form", "model_action_form", "size_model_form", "SizeKernel",
           "SIZE_GAUSS_NEWTON", "SIZE_EXACT", "SIZE_MODIFIED"]

#: The size misfit's matrix in the kernels (:class:`SizeKernel` ``mode``): its Gauss–Newton
#: form, its second derivative, or the second derivative made positive semidefinite per
#: quadrature point (:func:`size_model_form`).
SIZE_GAUSS_NEWTON, SIZE_EXACT, SIZE_MODIFIED = 0, 1, 2

_NAMES = {False: "ufl_frames_damped_gauss_newton", True: "ufl_frames_damped_hessian"}
_ARGUMENTS = ("(double* restrict A, const double* restrict w, const double* restrict c, "
              "const double* restrict coordinate_dofs, const int* restrict entity_local_index, "
              "const uint8_t* restrict quadrature_permutation, void* custom_data)")


@dataclass(frozen=True)
class SizeKernel:
    """What the kernels need of the size target's term w H_s M (2D frames,
    :class:`ufl_frames.fem.problem.SizeTerm`): log h (a scalar P1 function), the factor
    w H_s, 1/A and the mode (:data:`SIZE_GAUSS_NEWTON`, :data:`SIZE_EXACT`,
    :data:`SIZE_MODIFIED`), and the factor C of the smoothing term C S
    (:func:`ufl_frames.fem.energy.size_smoothing_form`; 0: none), each Constant read at
    every assembly."""

    log_h: fem.Function
    coefficient: fem.Constant
    inverse_area: fem.Constant
    mode: fem.Constant
    smoothing: fem.Constant | None = None

    def constants(self) -> list:
        """w H_s, 1/A, the mode and C (a zero Constant where ``smoothing`` is None)."""
        smoothing = self.smoothing
        if smoothing is None:
            smoothing = fem.Constant(self.log_h.function_space.mesh, PETSc.ScalarType(0.0))
        return [self.coefficient, self.inverse_area, self.mode, smoothing]


@dataclass(frozen=True)
class _CellRule:
    """What the kernels need of a cell besides its sizes: C statements that compute, from
    the vertices' coordinates ``x`` (3 a vertex), the hat functions' gradients
    ``dphi[vertices][dim]`` and the cell's measure ``area``; and a quadrature rule exact
    for quadratics, ``phi[points][vertices]`` (the hat functions at the points) and
    ``weight`` (one for all points)."""

    gradients: tuple[str, ...]
    rule: tuple[str, ...]
    points: int


#: The cells the kernels are written for, by the algebra's ``cell`` (a tetrahedron: the
#: inverse of its 3 × 3 Jacobian and a 4-point rule of degree 2).
_CELLS = {
    "triangle": _CellRule(
        gradients=(
            "  const double e1x = x[3] - x[0], e1y = x[4] - x[1];",
            "  const double e2x = x[6] - x[0], e2y = x[7] - x[1];",
            "  const double det = e1x * e2y - e1y * e2x, area = 0.5 * fabs(det);",
            "  double dphi[3][2];",
            "  dphi[1][0] = e2y / det; dphi[1][1] = -e2x / det;",
            "  dphi[2][0] = -e1y / det; dphi[2][1] = e1x / det;",
            "  dphi[0][0] = -dphi[1][0] - dphi[2][0]; dphi[0][1] = -dphi[1][1] - dphi[2][1];",
        ),
        rule=(
            "  /* the edge midpoints: the rule of degree 2 with weights area / 3 */",
            "  static const double phi[3][3] = "
            "{{0.5, 0.5, 0.0}, {0.0, 0.5, 0.5}, {0.5, 0.0, 0.5}};",
            "  const double weight = area / 3.0;",
        ),
        points=3,
    ),
}


@dataclass(frozen=True)
class _Sizes:
    """The sizes the C code is written for, from a frame algebra: ``n`` coefficients a
    vertex, ``nv`` vertices a cell, ``d`` the dimension, ``nr`` components of the bracket,
    ``nd`` = nv n unknowns a cell, ``ncs`` the column counts of the reduced kernels (the
    largest first) and the cell's rule."""

    n: int
    nv: int
    d: int
    nr: int
    ncs: tuple[int, ...]
    cell: _CellRule

    @property
    def nd(self) -> int:
        return self.nv * self.n

    @classmethod
    def of(cls, algebra) -> "_Sizes":
        full = algebra.tangent_columns
        return cls(n=algebra.count, nv=algebra.cell_vertices, d=algebra.dim,
                   nr=algebra.bracket_components,
                   ncs=(full, full - len(algebra.anisotropy_columns)),
                   cell=_CELLS[algebra.cell])


def _reduced_names(algebra) -> dict:
    """The reduced kernels' names by (exact, columns of the basis)."""
    return {(exact, nc): f"{_NAMES[exact]}_reduced{nc}"
            for exact in (False, True) for nc in sorted(_Sizes.of(algebra).ncs)}


#: The same matrices' products with a field (linear forms).
_ACTION_NAMES = {exact: f"{_NAMES[exact]}_action" for exact in (False, True)}
#: The size misfit's matrix alone (:func:`size_model_form`).
_SIZE_NAME = "ufl_frames_size_model"
#: The kernels with the size misfit's matrix added (suffix of the reduced and action names).
_SIZED = "_sized"


def _has_size(algebra) -> bool:
    """Whether the size misfit's kernels are written for ``algebra``: 2D frames (σ and β
    read q0, q1, q2 of the 2D Odeco coefficients, :func:`energy.log_size`)."""
    return algebra.dim == 2 and algebra.count == 5 and algebra.cell == "triangle"


def _all_names(algebra) -> tuple[str, ...]:
    names = (*_NAMES.values(), *_reduced_names(algebra).values(), *_ACTION_NAMES.values())
    if not _has_size(algebra):
        return names
    sized = (*_reduced_names(algebra).values(), *_ACTION_NAMES.values())
    return (*names, _SIZE_NAME, *(name + _SIZED for name in sized))


def _bracket_lines(algebra, z: _Sizes) -> tuple[list[str], list[str], list[str]]:
    """C statements from the bracket's entries C_ijkl: J's two coefficient arrays
    a[i][l] = Σ C_ijkl ∂_k q_j (multiplies δq_l) and b[i][j][k] = Σ C_ijkl q_l (multiplies
    ∂_k δq_j), q and ∇q at the point; and the residual's second derivative paired with
    the residual, r_i C_ijkl (δq_l ∂_k w_j + w_l ∂_k δq_j), into the element matrix."""
    a_terms, b_terms, second = {}, {}, []
    n, nv, nd = z.n, z.nv, z.nd
    for (i, j, k, l), value in sorted(algebra.bracket_entries):
        a_terms.setdefault((i, l), []).append(f"{float(value)!r} * gq[{j}][{k}]")
        b_terms.setdefault((i, j, k), []).append(f"{float(value)!r} * qp[{l}]")
        second.append(
            f"      {{ const double s = weight * r[{i}] * {float(value)!r};"
            f" for (int v = 0; v < {nv}; ++v) for (int u = 0; u < {nv}; ++u) {{"
            f" A[{nd} * ({n} * v + {j}) + {n} * u + {l}] += s * phi[p][u] * dphi[v][{k}];"
            f" A[{nd} * ({n} * v + {l}) + {n} * u + {j}] += s * phi[p][v] * dphi[u][{k}]; }} }}")
    a_lines = [f"  a[{i}][{l}] = {' + '.join(t)};" for (i, l), t in sorted(a_terms.items())]
    b_lines = [f"    b[{i}][{j}][{k}] = {' + '.join(t)};" for (i, j, k), t in
               sorted(b_terms.items())]
    return a_lines, b_lines, second


def _continued(first: str, indent: str, terms: list[str], per_line: int, end: str = ";"):
    """``first`` followed by the ``terms`` joined by " + ", ``per_line`` a line, the later
    lines starting with ``indent`` + "+ "."""
    chunks = [terms[i : i + per_line] for i in range(0, len(terms), per_line)]
    lines = [first + " + ".join(chunks[0])]
    lines += [f"{indent}+ " + " + ".join(chunk) for chunk in chunks[1:]]
    lines[-1] += end
    return lines


def _geometry_lines(z: _Sizes, a_lines: list[str]) -> list[str]:
    """C statements: the cell's gradients of the hat functions dphi, its measure area, ∇q
    (gq), J's first coefficient array a and the quadrature rule (phi, weight)."""
    n, d = z.n, z.d
    return [
        *z.cell.gradients,
        f"  double gq[{n}][{d}];",
        f"  for (int j = 0; j < {n}; ++j)",
        f"    for (int k = 0; k < {d}; ++k)",
        "      gq[j][k] = " + " + ".join(
            "w[j] * dphi[0][k]" if v == 0 else f"w[{n * v} + j] * dphi[{v}][k]"
            for v in range(z.nv)) + ";",
        f"  double a[{z.nr}][{n}] = {{{{0}}}};",
        *a_lines,
        *z.cell.rule,
    ]


def _point_lines(z: _Sizes, b_lines: list[str]) -> list[str]:
    """C statements at quadrature point p: q there (qp), J's second coefficient array b
    and J (nr × nd: the bracket's linearisation at the nd basis functions)."""
    n, d, nr = z.n, z.d, z.nr
    return [
        f"    double qp[{n}];",
        f"    for (int l = 0; l < {n}; ++l)",
        "      qp[l] = " + " + ".join(
            "phi[p][0] * w[l]" if v == 0 else f"phi[p][{v}] * w[{n * v} + l]"
            for v in range(z.nv)) + ";",
        f"    double b[{nr}][{n}][{d}] = {{{{{{0}}}}}};",
        *b_lines,
        f"    double J[{nr}][{z.nd}];",
        f"    for (int i = 0; i < {nr}; ++i)",
        f"      for (int v = 0; v < {z.nv}; ++v)",
        f"        for (int m = 0; m < {n}; ++m)",
        *_continued(f"          J[i][{n} * v + m] = phi[p][v] * a[i][m] + ",
                    " " * 28, [f"b[i][m][{k}] * dphi[v][{k}]" for k in range(d)], 1),
    ]


def _damping_lines(z: _Sizes) -> list[str]:
    """C statements: λ (K + M/A) of the vertices v, u of the cell, into ``value`` (the P1
    mass matrix: |K| (1 + δ_vu) / ((d + 1)(d + 2)))."""
    return [
        *_continued("      const double stiffness = area * (", " " * 39,
                    [f"dphi[v][{k}] * dphi[u][{k}]" for k in range(z.d)], 1, end=");"),
        f"      const double mass = area / {(z.d + 1) * (z.d + 2)}.0 * (v == u ? 2.0 : 1.0);",
        "      const double value = lambda * (stiffness + inverse_area * mass);",
    ]


def _outer_lines(z: _Sizes, target: str, rows: str, columns: str, count: str,
                 stride: str) -> list[str]:
    """C statements: target[stride r + s] += weight Σ_i rows[i][r] rows[i][s]."""
    return [
        f"    for (int r = 0; r < {count}; ++r)",
        "    {",
        "      const double " + ", ".join(f"j{i} = weight * {rows}[{i}][r]"
                                          for i in range(z.nr)) + ";",
        f"      for (int s = 0; s < {count}; ++s)",
        f"        {target}[{stride} * r + s] += "
        + " + ".join(f"j{i} * {columns}[{i}][s]" for i in range(z.nr)) + ";",
        "    }",
    ]


def _model_lines(z: _Sizes, a_lines, b_lines, second) -> list[str]:
    """C function ``model``: the damped (Gauss–Newton or exact) nd × nd element matrix."""
    n, nv, nd = z.n, z.nv, z.nd
    return [
        "static inline void model(double* restrict A, const double* restrict w,",
        "                         const double* restrict c, const double* restrict x,",
        "                         const int exact)",
        "{",
        *_geometry_lines(z, a_lines),
        f"  for (int p = 0; p < {z.cell.points}; ++p)",
        "  {",
        *_point_lines(z, b_lines),
        *_outer_lines(z, "A", "J", "J", str(nd), str(nd)),
        "    if (exact)",
        "    {",
        f"      double r[{z.nr}];",
        f"      for (int i = 0; i < {z.nr}; ++i)",
        *_continued("        r[i] = ", " " * 15, [f"a[i][{m}] * qp[{m}]" for m in range(n)], 4),
        *second,
        "    }",
        "  }",
        f"  /* λ (K + M / A) on each of the {n} components */",
        "  const double lambda = c[0], inverse_area = c[1];",
        f"  for (int v = 0; v < {nv}; ++v)",
        f"    for (int u = 0; u < {nv}; ++u)",
        "    {",
        *_damping_lines(z),
        f"      for (int m = 0; m < {n}; ++m)",
        f"        A[{nd} * ({n} * v + m) + {n} * u + m] += value;",
        "    }",
        "}",
    ]


def _reduced_gauss_newton_lines(z: _Sizes, a_lines, b_lines) -> list[str]:
    """C function ``reduced_gauss_newton``: Σ (J T)ᵀ (J T) + λ (K + M/A) T_vᵀ T_u."""
    n, nv, nd = z.n, z.nv, z.nd
    return [
        "/* Gauss–Newton in tangent coordinates: Σ (J T)ᵀ (J T) + λ (K + M/A) T_vᵀ T_u, with",
        f"   T_v ({n} × nc, row-major) the tangent basis of vertex v, after q in w */",
        "static inline void reduced_gauss_newton(double* restrict R, const double* restrict w,",
        "                                        const double* restrict c,",
        "                                        const double* restrict x, const int nc)",
        "{",
        f"  const double* restrict T = w + {nd};",
        f"  const int m = {nv} * nc;",
        *_geometry_lines(z, a_lines),
        f"  for (int p = 0; p < {z.cell.points}; ++p)",
        "  {",
        *_point_lines(z, b_lines),
        f"    double JT[{z.nr}][{nv * max(z.ncs)}];",
        f"    for (int i = 0; i < {z.nr}; ++i)",
        f"      for (int v = 0; v < {nv}; ++v)",
        "        for (int k = 0; k < nc; ++k)",
        "        {",
        "          double s = 0.0;",
        f"          for (int n = 0; n < {n}; ++n)",
        f"            s += J[i][{n} * v + n] * T[{n} * nc * v + nc * n + k];",
        "          JT[i][nc * v + k] = s;",
        "        }",
        *_outer_lines(z, "R", "JT", "JT", "m", "m"),
        "  }",
        "  const double lambda = c[0], inverse_area = c[1];",
        f"  for (int v = 0; v < {nv}; ++v)",
        f"    for (int u = 0; u < {nv}; ++u)",
        "    {",
        *_damping_lines(z),
        "      for (int k = 0; k < nc; ++k)",
        "        for (int l = 0; l < nc; ++l)",
        "        {",
        "          double s = 0.0;",
        f"          for (int n = 0; n < {n}; ++n)",
        f"            s += T[{n} * nc * v + nc * n + k] * T[{n} * nc * u + nc * n + l];",
        "          R[m * (nc * v + k) + nc * u + l] += value * s;",
        "        }",
        "    }",
        "}",
    ]


def _reduced_hessian_and_action_lines(z: _Sizes, size: bool) -> list[str]:
    """C functions ``reduced_hessian`` (Tᵀ A T from the nd × nd matrix), ``project``
    (R += Tᵀ A T) and ``action`` (A d); with ``sized`` (an argument of the C functions,
    where ``size``: the size misfit's kernel is in the source) the size misfit's matrix
    (``size_model``, its log h at ``logh``, c[2] = w H_s, c[3] = 1/A, c[4] = the mode) is
    added to A first."""
    n, nv, nd = z.n, z.nv, z.nd

    def sized_line(logh: str) -> list[str]:
        if not size:
            return []
        return [f"  if (sized) size_model(A, w, {logh}, c[2], c[3], (int)c[4], c[5], x);"]

    return [
        "static inline void project(double* restrict R, const double* restrict A,",
        "                           const double* restrict w, const int nc);",
        f"/* the full Hessian in tangent coordinates: Tᵀ A T from the {nd} × {nd} matrix */",
        "static inline void reduced_hessian(double* restrict R, const double* restrict w,",
        "                                   const double* restrict c,",
        "                                   const double* restrict x, const int nc,",
        "                                   const int sized)",
        "{",
        f"  double A[{nd * nd}] = {{0}};",
        "  model(A, w, c, x, 1);",
        *sized_line(f"w + {nd} + {nd} * nc"),
        "  project(R, A, w, nc);",
        "}",
        "/* R += Tᵀ A T, T the tangent basis after q in w */",
        "static inline void project(double* restrict R, const double* restrict A,",
        "                           const double* restrict w, const int nc)",
        "{",
        f"  const double* restrict T = w + {nd};",
        f"  const int m = {nv} * nc;",
        f"  double AT[{nd} * {nv * max(z.ncs)}];  /* A T: {nd} × {nv} nc */",
        f"  for (int r = 0; r < {nd}; ++r)",
        f"    for (int u = 0; u < {nv}; ++u)",
        "      for (int l = 0; l < nc; ++l)",
        "      {",
        "        double s = 0.0;",
        f"        for (int n = 0; n < {n}; ++n)",
        f"          s += A[{nd} * r + {n} * u + n] * T[{n} * nc * u + nc * n + l];",
        "        AT[m * r + nc * u + l] = s;",
        "      }",
        f"  for (int v = 0; v < {nv}; ++v)",
        "    for (int k = 0; k < nc; ++k)",
        "      for (int j = 0; j < m; ++j)",
        "      {",
        "        double s = 0.0;",
        f"        for (int n = 0; n < {n}; ++n)",
        f"          s += T[{n} * nc * v + nc * n + k] * AT[m * ({n} * v + n) + j];",
        "        R[m * (nc * v + k) + j] += s;",
        "      }",
        "}",
        "/* the model's product with a field d (after q in w): b = A d */",
        "static inline void action(double* restrict b, const double* restrict w,",
        "                          const double* restrict c, const double* restrict x,",
        "                          const int exact, const int sized)",
        "{",
        f"  double A[{nd * nd}] = {{0}};",
        "  model(A, w, c, x, exact);",
        *sized_line(f"w + {2 * nd}"),
        f"  for (int r = 0; r < {nd}; ++r)",
        f"    for (int s = 0; s < {nd}; ++s)",
        f"      b[r] += A[{nd} * r + s] * w[{nd} + s];",
        "}",
    ]


def _size_lines(z: _Sizes) -> list[str]:
    """C functions of the size misfit's matrix (2D frames only, :func:`size_model_form`):
    ``eigen3`` (a 3 × 3 symmetric eigendecomposition by cyclic Jacobi rotations) and
    ``size_model``, which adds w H_s times the element matrix of M's Gauss–Newton form
    (mode 0), its second derivative (mode 1) or the positive semidefinite modification of
    the second derivative (mode 2) to A (nd × nd)."""
    n, nv, nd = z.n, z.nv, z.nd
    sum_per_q0 = 8.0 / (3.0 * float(np.sqrt(2.0)))
    third, sixth = repr(2.0 / 3.0), repr(1.0 / 6.0)
    return [
        "/* a (3 × 3, symmetric) = v diag(lam) vᵀ, v's columns the eigenvectors; a is",
        "   overwritten. Cyclic Jacobi rotations until the off-diagonal part is round-off. */",
        "static void eigen3(double a[3][3], double lam[3], double v[3][3])",
        "{",
        "  for (int i = 0; i < 3; ++i)",
        "    for (int j = 0; j < 3; ++j)",
        "      v[i][j] = (i == j) ? 1.0 : 0.0;",
        "  for (int sweep = 0; sweep < 60; ++sweep)",
        "  {",
        "    const double off = a[0][1] * a[0][1] + a[0][2] * a[0][2] + a[1][2] * a[1][2];",
        "    const double diagonal = a[0][0] * a[0][0] + a[1][1] * a[1][1] + a[2][2] * a[2][2];",
        "    if (off <= 1e-34 * diagonal || off == 0.0)",
        "      break;",
        "    for (int p = 0; p < 2; ++p)",
        "      for (int q = p + 1; q < 3; ++q)",
        "      {",
        "        if (a[p][q] == 0.0)",
        "          continue;",
        "        const double theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);",
        "        const double t = fabs(theta) > 1e150 ? 0.5 / theta",
        "          : (theta >= 0.0 ? 1.0 : -1.0) / (fabs(theta) + sqrt(theta * theta + 1.0));",
        "        const double c = 1.0 / sqrt(t * t + 1.0), s = t * c;",
        "        for (int k = 0; k < 3; ++k)",
        "        {",
        "          const double kp = a[k][p], kq = a[k][q];",
        "          a[k][p] = c * kp - s * kq; a[k][q] = s * kp + c * kq;",
        "        }",
        "        for (int k = 0; k < 3; ++k)",
        "        {",
        "          const double pk = a[p][k], qk = a[q][k];",
        "          a[p][k] = c * pk - s * qk; a[q][k] = s * pk + c * qk;",
        "        }",
        "        for (int k = 0; k < 3; ++k)",
        "        {",
        "          const double kp = v[k][p], kq = v[k][q];",
        "          v[k][p] = c * kp - s * kq; v[k][q] = s * kp + c * kq;",
        "        }",
        "      }",
        "  }",
        "  for (int i = 0; i < 3; ++i)",
        "    lam[i] = a[i][i];",
        "}",
        "/* f(a) = v diag(f(lam)) vᵀ of a symmetric 3 × 3 a: |a| (positive = 0) or a₊ (1) */",
        "static void spectral3(const double a[3][3], double out[3][3], const int positive)",
        "{",
        "  double b[3][3], lam[3], v[3][3];",
        "  for (int i = 0; i < 3; ++i)",
        "    for (int j = 0; j < 3; ++j)",
        "      b[i][j] = a[i][j];",
        "  eigen3(b, lam, v);",
        "  for (int i = 0; i < 3; ++i)",
        "    lam[i] = positive ? (lam[i] > 0.0 ? lam[i] : 0.0) : fabs(lam[i]);",
        "  for (int i = 0; i < 3; ++i)",
        "    for (int j = 0; j < 3; ++j)",
        "      out[i][j] = lam[0] * v[i][0] * v[j][0] + lam[1] * v[i][1] * v[j][1]",
        "                  + lam[2] * v[i][2] * v[j][2];",
        "}",
        "/* weight × the element matrix of M = ½ ∫ |∇(σ(q) − log h)|² + ½ (1/A) ∫ |β(q)|², added",
        "   to A: σ = ½ log P, P = l1 l2 = s²/4 − q1² − q2², s = c0 q0; β = (2/c0)(q1, q2)/q0.",
        "   mode 0: Gauss–Newton; 1: the second derivative; 2: its positive semidefinite",
        "   modification (the residual's curvature clipped per quadrature point).",
        "   And smoothing × the element matrix of S = ½ ∫ |∇q|²/h², h = exp(mean log h). */",
        "static inline void size_model(double* restrict A, const double* restrict w,",
        "                              const double* restrict logh, const double weight,",
        "                              const double inverse_area, const int mode,",
        "                              const double smoothing, const double* restrict x)",
        "{",
        *z.cell.gradients,
        "  if (smoothing != 0.0)",
        "  {",
        "    const double ws = smoothing * area * exp(-2.0 * ("
        + " + ".join(f"logh[{v}]" for v in range(nv)) + f") / {nv}.0);",
        f"    for (int v = 0; v < {nv}; ++v)",
        f"      for (int u = 0; u < {nv}; ++u)",
        "      {",
        "        const double k = ws * (" + " + ".join(
            f"dphi[v][{d}] * dphi[u][{d}]" for d in range(z.d)) + ");",
        f"        for (int m = 0; m < {n}; ++m)",
        f"          A[{nd} * ({n} * v + m) + {n} * u + m] += k;",
        "      }",
        "  }",
        "  double gq[3][2], gl[2];",
        "  for (int k = 0; k < 2; ++k)",
        "  {",
        "    gl[k] = " + " + ".join(f"logh[{v}] * dphi[{v}][k]" for v in range(nv)) + ";",
        "    for (int m = 0; m < 3; ++m)",
        "      gq[m][k] = " + " + ".join(f"w[{n * v} + m] * dphi[{v}][k]" for v in range(nv))
        + ";",
        "  }",
        "  /* FFCx's rule of degree 2 (basix): weights area / 3 */",
        f"  static const double phi[3][3] = {{{{{third}, {sixth}, {sixth}}}, "
        f"{{{sixth}, {sixth}, {third}}}, {{{sixth}, {third}, {sixth}}}}};",
        "  const double wp = weight * area / 3.0;",
        f"  const double c0 = {sum_per_q0!r}, kb = 2.0 / c0;",
        "  const double ddp[3] = {0.5 * c0 * c0, -2.0, -2.0};",
        "  for (int p = 0; p < 3; ++p)",
        "  {",
        "    double qp[3];",
        "    for (int m = 0; m < 3; ++m)",
        "      qp[m] = " + " + ".join(f"phi[p][{v}] * w[{n * v} + m]" for v in range(nv))
        + ";",
        "    const double P = 0.25 * c0 * c0 * qp[0] * qp[0] - qp[1] * qp[1] - qp[2] * qp[2];",
        "    const double dp[3] = {0.5 * c0 * c0 * qp[0], -2.0 * qp[1], -2.0 * qp[2]};",
        "    double s1[3], S[3][3], e[2], B[2][3];",
        "    for (int m = 0; m < 3; ++m)",
        "    {",
        "      s1[m] = 0.5 * dp[m] / P;",
        "      for (int l = 0; l < 3; ++l)",
        "        S[m][l] = 0.5 * ((m == l ? ddp[m] : 0.0) / P - dp[m] * dp[l] / (P * P));",
        "    }",
        "    for (int k = 0; k < 2; ++k)",
        "    {",
        "      e[k] = s1[0] * gq[0][k] + s1[1] * gq[1][k] + s1[2] * gq[2][k] - gl[k];",
        "      for (int l = 0; l < 3; ++l)",
        "        B[k][l] = S[0][l] * gq[0][k] + S[1][l] * gq[1][k] + S[2][l] * gq[2][k];",
        "    }",
        "    const double q0 = qp[0];",
        "    const double beta[2] = {kb * qp[1] / q0, kb * qp[2] / q0};",
        "    const double db[2][3] = {{-kb * qp[1] / (q0 * q0), kb / q0, 0.0},",
        "                             {-kb * qp[2] / (q0 * q0), 0.0, kb / q0}};",
        "    /* the values' block: (1/A) Dβᵀ Dβ, and with the curvature e·∂²∇σ + (1/A) β·∂²β */",
        "    double G[3][3], R[3][3] = {{0}};",
        "    for (int m = 0; m < 3; ++m)",
        "      for (int l = 0; l < 3; ++l)",
        "        G[m][l] = inverse_area * (db[0][m] * db[0][l] + db[1][m] * db[1][l]);",
        "    double X[3][3] = {{0}}, egrad[3] = {0}, length = 0.0;",
        "    const double cross = mode == 2 ? 0.5 : 1.0;",
        "    if (mode)",
        "    {",
        "      const double P2 = P * P, P3 = P2 * P;",
        "      double eg[3];",
        "      for (int m = 0; m < 3; ++m)",
        "        eg[m] = e[0] * gq[m][0] + e[1] * gq[m][1];",
        "      for (int a = 0; a < 3; ++a)",
        "        for (int b = 0; b < 3; ++b)",
        "          for (int m = 0; m < 3; ++m)",
        "          {",
        "            const double t = 0.5 * (-((m == a ? ddp[m] : 0.0) * dp[b]",
        "                                      + (m == b ? ddp[m] : 0.0) * dp[a]",
        "                                      + (a == b ? ddp[a] : 0.0) * dp[m]) / P2",
        "                                    + 2.0 * dp[m] * dp[a] * dp[b] / P3);",
        "            R[a][b] += t * eg[m];",
        "          }",
        "      const double d00 = 2.0 * kb / (q0 * q0 * q0), d0 = -kb / (q0 * q0);",
        "      R[0][0] += inverse_area * (beta[0] * d00 * qp[1] + beta[1] * d00 * qp[2]);",
        "      R[0][1] += inverse_area * beta[0] * d0; R[1][0] += inverse_area * beta[0] * d0;",
        "      R[0][2] += inverse_area * beta[1] * d0; R[2][0] += inverse_area * beta[1] * d0;",
        "      length = sqrt(e[0] * e[0] + e[1] * e[1]);",
        "      if (mode == 2)",
        "      {",
        "        /* [[R, X], [X, 0]] in (δq, ê·∇δq), X = |e| S, becomes its positive part",
        "           [[R₊ + ½|X|, ½X], [½X, ½|X|]] (that of [[0, X], [X, 0]] is",
        "           ½[[|X|, X], [X, |X|]]): positive semidefinite, not below the exact */",
        "        double Rp[3][3], absS[3][3];",
        "        spectral3(R, Rp, 1);",
        "        spectral3(S, absS, 0);",
        "        for (int a = 0; a < 3; ++a)",
        "          for (int b = 0; b < 3; ++b)",
        "          {",
        "            X[a][b] = 0.5 * length * absS[a][b];",
        "            R[a][b] = Rp[a][b] + X[a][b];",
        "          }",
        "      }",
        "    }",
        f"    for (int v = 0; v < {nv}; ++v)",
        "    {",
        "      const double ev = e[0] * dphi[v][0] + e[1] * dphi[v][1];",
        "      egrad[v] = length > 0.0 ? ev / length : 0.0;",
        "    }",
        f"    for (int v = 0; v < {nv}; ++v)",
        "      for (int a = 0; a < 3; ++a)",
        "      {",
        "        const double da0 = phi[p][v] * B[0][a] + s1[a] * dphi[v][0];",
        "        const double da1 = phi[p][v] * B[1][a] + s1[a] * dphi[v][1];",
        "        const double ev = e[0] * dphi[v][0] + e[1] * dphi[v][1];",
        f"        for (int u = 0; u < {nv}; ++u)",
        "          for (int b = 0; b < 3; ++b)",
        "          {",
        "            const double db0 = phi[p][u] * B[0][b] + s1[b] * dphi[u][0];",
        "            const double db1 = phi[p][u] * B[1][b] + s1[b] * dphi[u][1];",
        "            double value = da0 * db0 + da1 * db1",
        "                           + phi[p][v] * phi[p][u] * (G[a][b] + R[a][b]);",
        "            if (mode)",
        "            {",
        "              const double eu = e[0] * dphi[u][0] + e[1] * dphi[u][1];",
        "              value += cross * S[a][b] * (phi[p][v] * eu + phi[p][u] * ev)",
        "                       + X[a][b] * egrad[v] * egrad[u];",
        "            }",
        f"            A[{nd} * ({n} * v + a) + {n} * u + b] += wp * value;",
        "          }",
        "      }",
        "  }",
        "}",
    ]


@functools.cache
def model_kernel_source(algebra=ALGEBRA) -> str:
    """The C source of the element kernels (DOLFINx's ``tabulate_tensor`` signature) of a
    frame ``algebra``: ``ufl_frames_damped_gauss_newton`` and ``ufl_frames_damped_hessian``,
    the same in reduced coordinates (``…_reduced2``, ``…_reduced3`` in 2D: the column
    counts of isotropic and general frames) and their products with a field
    (``…_action``).

    Written for the algebra's sizes: n coefficients a vertex (``count``, 5 in 2D), nv
    vertices a cell (``cell_vertices``, 3), the dimension d (``dim``, 2), the bracket's
    components and table; the cell's gradients and quadrature rule come from the cell
    table of this module (the triangle's). In 2D, per triangle: ``w`` the 3 × 5 Odeco
    coefficients of q at its vertices (vertex-major), ``c`` = (λ, 1/A),
    ``coordinate_dofs`` its 3 vertices (x, y, z). ``A`` (15 × 15, row-major, zeroed by
    DOLFINx) receives Σ_points (area/3) J[φ_s]·J[φ_r] (+ r · D²r[φ_s, φ_r] for the
    Hessian, r = [u, v] at the point) + λ (K_rs + M_rs/A) δ_components. The reduced
    kernels read after q in ``w`` the 5 × c blocks T_v of a tangent basis and write
    Tᵀ A T (3c × 3c); Gauss–Newton's from J T (2 × 3c a point) directly. The action
    kernels read a field d after q and write A d (15 values).
    """
    z = _Sizes.of(algebra)
    a_lines, b_lines, second = _bracket_lines(algebra, z)
    size = _has_size(algebra)
    return "\n".join([
        "#include <math.h>",
        "#include <stdint.h>",
        *_model_lines(z, a_lines, b_lines, second),
        *(_size_lines(z) if size else []),
        *(_sized_kernel_lines(z, algebra) if size else []),
        *[line for exact, name in _NAMES.items() for line in (
            f"void {name}{_ARGUMENTS}",
            "{",
            f"  model(A, w, c, coordinate_dofs, {int(exact)});",
            "}")],
        *_reduced_gauss_newton_lines(z, a_lines, b_lines),
        *_reduced_hessian_and_action_lines(z, size),
        *[line for (exact, nc), name in _reduced_names(algebra).items() for line in (
            f"void {name}{_ARGUMENTS}",
            "{",
            f"  {_reduced_call(exact, nc, False)}",
            "}")],
        *[line for exact, name in _ACTION_NAMES.items() for line in (
            f"void {name}{_ARGUMENTS}",
            "{",
            f"  action(A, w, c, coordinate_dofs, {int(exact)}, 0);",
            "}")],
        *(_sized_entry_lines(z, algebra) if size else []),
        "",
    ])


def _reduced_call(exact: bool, nc: int, sized: bool) -> str:
    """The C call of a reduced kernel's body (R in ``A``)."""
    if exact:
        return f"reduced_hessian(A, w, c, coordinate_dofs, {nc}, {int(sized)});"
    call = f"reduced_gauss_newton(A, w, c, coordinate_dofs, {nc});"
    if sized:
        call += f" reduced_size(A, w, c, coordinate_dofs, {nc});"
    return call


def _sized_kernel_lines(z: _Sizes, algebra) -> list[str]:
    """C: ``size_entry`` (the size misfit's matrix alone: w = q, log h; c = w H_s, 1/A,
    mode) and ``reduced_size`` (R += Tᵀ A_M T, the misfit's matrix in tangent
    coordinates, for the reduced Gauss–Newton kernel, which forms J T directly)."""
    nd = z.nd
    return [
        f"void {_SIZE_NAME}{_ARGUMENTS}",
        "{",
        f"  size_model(A, w, w + {nd}, c[0], c[1], (int)c[2], c[3], coordinate_dofs);",
        "}",
        "static inline void project(double* restrict R, const double* restrict A,",
        "                           const double* restrict w, const int nc);",
        "static inline void reduced_size(double* restrict R, const double* restrict w,",
        "                                const double* restrict c,",
        "                                const double* restrict x, const int nc)",
        "{",
        f"  double A[{nd * nd}] = {{0}};",
        f"  size_model(A, w, w + {nd} + {nd} * nc, c[2], c[3], (int)c[4], c[5], x);",
        "  project(R, A, w, nc);",
        "}",
    ]


def _sized_entry_lines(z: _Sizes, algebra) -> list[str]:
    """C: the entry points of the reduced and action kernels with the size misfit."""
    lines = []
    for (exact, nc), name in _reduced_names(algebra).items():
        lines += [f"void {name}{_SIZED}{_ARGUMENTS}", "{",
                  f"  {_reduced_call(exact, nc, True)}", "}"]
    for exact, name in _ACTION_NAMES.items():
        lines += [f"void {name}{_SIZED}{_ARGUMENTS}", "{",
                  f"  action(A, w, c, coordinate_dofs, {int(exact)}, 1);", "}"]
    return lines


#: The kernel modules this process has loaded, by name (every rank loads in the same
#: order, so a hit here is a hit on every rank and no collective call is skipped alone).
_LOADED = {}


def _compiled(comm, algebra=ALGEBRA):
    """The compiled kernel module of a frame ``algebra`` (collective on its first call):
    built by rank 0 into the JIT cache the first time (named by a hash of the source),
    loaded on every rank."""
    source = model_kernel_source(algebra)
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
            _build(name, source, cache, path, _all_names(algebra))
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


def _build(name: str, source: str, cache: Path, path: Path, functions) -> None:
    """Compile ``source`` (which defines ``functions``) with cffi in a temporary folder and
    move the library to ``path`` (a rename: a reader never sees half a file)."""
    import cffi

    cache.mkdir(parents=True, exist_ok=True)
    ffi = cffi.FFI()
    ffi.cdef("\n".join(f"void {function}{_ARGUMENTS.replace('restrict ', '')};"
                        for function in functions))
    ffi.set_source(name, source, extra_compile_args=["-O2", "-std=c99"])
    with tempfile.TemporaryDirectory(dir=cache) as build:
        built = Path(ffi.compile(tmpdir=build, verbose=False))
        os.replace(built, path)


def damped_gauss_newton_form(q: fem.Function, damping: fem.Constant,
                             inverse_area: fem.Constant, algebra=ALGEBRA) -> fem.Form:
    """The DOLFINx form of ∫ J[δq]·J[w] + λ (∇δq:∇w + δq·w/A) dx with the compiled kernel:
    the matrix of ``energy.gauss_newton_form(q) + λ sobolev_form``, over the cells this
    rank owns.

    Args:
        q: The frame field.
        damping: λ, read at every assembly.
        inverse_area: 1/A, read at every assembly.
        algebra: The frame algebra of ``q``.

    Returns:
        The compiled form (collective: compiles once).
    """
    return _damped_form(q, damping, inverse_area, False, algebra)


def damped_hessian_form(q: fem.Function, damping: fem.Constant,
                        inverse_area: fem.Constant, algebra=ALGEBRA) -> fem.Form:
    """The same with the full Hessian of H, ∫ J[δq]·J[w] + r·D²r[δq, w] dx (r = [u, v],
    D²r_i[δq, w] = C_ijkl (δq_l ∂_k w_j + w_l ∂_k δq_j)): the matrix of the UFL second
    derivative of :func:`energy.integrability_energy_form` plus the damping.

    Args:
        q: The frame field.
        damping: λ, read at every assembly.
        inverse_area: 1/A, read at every assembly.
        algebra: The frame algebra of ``q``.

    Returns:
        The compiled form (collective: compiles once).
    """
    return _damped_form(q, damping, inverse_area, True, algebra)


def reduced_model_form(q: fem.Function, basis: fem.Function, space: fem.FunctionSpace,
                       damping: fem.Constant, inverse_area: fem.Constant,
                       exact: bool = False, algebra=ALGEBRA,
                       size: SizeKernel | None = None) -> fem.Form:
    """The model's matrix of :func:`damped_gauss_newton_form` (``exact``:
    :func:`damped_hessian_form`) in tangent coordinates, Tᵀ A T, assembled directly: no
    nN × nN matrix and no product Pᵀ A P (the reduced matrix of
    :class:`~ufl_frames.solvers.hessian.GaussNewtonModel`).

    Both spaces must number the vertices as ``q``'s space does, so that the reduced
    unknown (v, k) pairs with column k of T_v.

    Args:
        q: The frame field.
        basis: A P1 function with n·c components a vertex, the n × c matrix T_v row-major
            (n the algebra's ``count``; in 2D c = 3 tangent directions of non-isotropic
            frames, 2 isotropic; a zero column where a direction is absent gives a zero
            row and column).
        space: The P1 space of c components the matrix acts on.
        damping: λ, read at every assembly.
        inverse_area: 1/A, read at every assembly.
        exact: The full Hessian instead of Gauss–Newton.
        algebra: The frame algebra of ``q``.
        size: The size target's term, whose matrix (:func:`size_model_form`, in its
            ``mode``) is added to the model's before the projection: one matrix for
            J = H + w H_s M (None: H's alone).

    Returns:
        The compiled form (collective: compiles once).
    """
    check_frame_function(q, algebra=algebra)
    V = q.function_space
    n = algebra.count
    names = _reduced_names(algebra)
    counts = sorted(nc for _, nc in names)
    columns = basis.function_space.dofmap.index_map_bs // n
    if (columns not in counts or basis.function_space.dofmap.index_map_bs != n * columns
            or space.dofmap.index_map_bs != columns):
        allowed = " or ".join(str(nc) for nc in dict.fromkeys(counts))
        raise ValueError(f"a tangent basis of {allowed} columns and a space of as many "
                         f"components, not {basis.function_space.dofmap.index_map_bs} "
                         f"and {space.dofmap.index_map_bs}")
    for other in (basis.function_space, space):
        _check_same_vertices(V, other)
    coefficients, constants = _with_size([q, basis], [damping, inverse_area], size, algebra)
    suffix = "" if size is None else _SIZED
    return _compiled_form(names[(exact, columns)] + suffix, [space, space], coefficients,
                          constants, algebra)


def model_action_form(q: fem.Function, direction: fem.Function, damping: fem.Constant,
                      inverse_area: fem.Constant, exact: bool = False,
                      algebra=ALGEBRA, size: SizeKernel | None = None) -> fem.Form:
    """The vector A d of the matrix A of :func:`damped_gauss_newton_form` (``exact``:
    :func:`damped_hessian_form`) and a P1 field ``direction`` d of ``q``'s space, without
    A (a linear form, the element matrix applied in the kernel).

    Args:
        q: The frame field.
        direction: d, a P1 function of as many components as ``q``, numbering the
            vertices as ``q``'s space does.
        damping: λ, read at every assembly.
        inverse_area: 1/A, read at every assembly.
        exact: The full Hessian instead of Gauss–Newton.
        algebra: The frame algebra of ``q``.
        size: The size target's term, whose matrix is added (as in
            :func:`reduced_model_form`).

    Returns:
        The compiled linear form on ``q``'s space (collective: compiles once).

    Raises:
        ValueError: ``direction`` numbers the vertices otherwise or has another number
            of components.
    """
    check_frame_function(q, algebra=algebra)
    _check_same_vertices(q.function_space, direction.function_space)
    if direction.function_space.dofmap.index_map_bs != q.function_space.dofmap.index_map_bs:
        raise ValueError(f"the direction must have the frame field's {algebra.count} "
                         f"components")
    coefficients, constants = _with_size([q, direction], [damping, inverse_area], size,
                                         algebra)
    suffix = "" if size is None else _SIZED
    return _compiled_form(_ACTION_NAMES[exact] + suffix, [q.function_space], coefficients,
                          constants, algebra)


def size_model_form(q: fem.Function, size: SizeKernel) -> fem.Form:
    r"""The matrix of w H_s M (M the size misfit, :func:`energy.size_misfit_form`) with the
    compiled kernel, in ``size.mode``:

    * :data:`SIZE_GAUSS_NEWTON`: w H_s times :func:`energy.size_gauss_newton_form`'s,
      ∫ ∇Dσ[δq]·∇Dσ[w] + (1/A) Dβ[δq]·Dβ[w] dx;
    * :data:`SIZE_EXACT`: w H_s times :func:`energy.size_hessian_form`'s (M's second
      derivative), which adds the terms with the residuals e = ∇(σ − log h) and β;
    * :data:`SIZE_MODIFIED`: the second derivative made positive semidefinite per
      quadrature point. There M's integrand is a function of the jet (a, G) = (q, ∇q) of
      (q0, q1, q2) (9 numbers); its Hessian is the Gauss–Newton part (positive
      semidefinite) plus the residual's part, which in (δa, α = ê·δG) is
      [[R, |e| S], [|e| S, 0]] (S = ∂²σ/∂q², R = e·∂³σ ∇q + (1/A) β·∂²β): indefinite
      wherever e ≠ 0 and S is not zero. It is replaced by its positive part taken in two
      pieces, [[R₊ + ½|X|, ½X], [½X, ½|X|]] with X = |e| S (R₊ R's positive part;
      ½[[|X|, X], [X, |X|]] is the positive part of [[0, X], [X, 0]]): positive
      semidefinite, and not below the exact one (their difference is R₋ and the negative
      part of the cross term): the Gauss–Newton part and every direction of positive
      curvature are kept, the negative curvature is turned positive.

    Same quadrature as the UFL forms (degree :data:`energy.SIZE_QUADRATURE_DEGREE`, basix'
    three points), so the first two agree with them to round-off.

    Args:
        q: The 2D frame field.
        size: log h, w H_s, 1/A and the mode.

    Returns:
        The compiled bilinear form on q's space (collective: compiles once).
    """
    check_frame_function(q, algebra=ALGEBRA)
    V = q.function_space
    return _compiled_form(_SIZE_NAME, [V, V], [q, size.log_h],
                          size.constants(), ALGEBRA)


def _with_size(coefficients: list, constants: list, size: SizeKernel | None, algebra):
    """The kernels' coefficients and constants with the size term's appended (log h; w H_s,
    1/A, mode, the smoothing's C)."""
    if size is None:
        return coefficients, constants
    if not _has_size(algebra):
        raise ValueError("the size misfit's kernels are written for 2D frames only")
    _check_same_vertices(coefficients[0].function_space, size.log_h.function_space)
    return ([*coefficients, size.log_h],
            [*constants, *size.constants()])


def _check_same_vertices(V: fem.FunctionSpace, W: fem.FunctionSpace) -> None:
    """Raise ValueError unless the P1 spaces V and W number the mesh's vertices alike."""
    a, b = V.dofmap.index_map, W.dofmap.index_map
    if (V.mesh is not W.mesh or a.size_local != b.size_local or a.num_ghosts != b.num_ghosts
            or not np.array_equal(V.dofmap.list, W.dofmap.list)):
        raise ValueError("the spaces do not number the mesh's vertices alike")


def _damped_form(q, damping, inverse_area, exact: bool, algebra) -> fem.Form:
    check_frame_function(q, algebra=algebra)
    V = q.function_space
    return _compiled_form(_NAMES[exact], [V, V], [q], [damping, inverse_area], algebra)


def _compiled_form(name: str, spaces, coefficients, constants, algebra) -> fem.Form:
    """A DOLFINx form over the owned cells whose kernel is the compiled function ``name``
    of ``algebra``'s kernels (collective: compiles once)."""
    mesh = coefficients[0].function_space.mesh
    module = _compiled(mesh.comm, algebra)
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
