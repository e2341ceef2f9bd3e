r"""The 3D Odeco projection of :mod:`ufl_frames.frames3d.odeco` compiled to C, one vertex
at a time.

The same algorithm as the NumPy code (which stays the reference and the fallback): the
Mandel matrix's three leading eigenpairs (cyclic Jacobi on the 6 × 6 matrix instead of
LAPACK), their joint diagonaliser (the same Jacobi sweeps and closed-form angles), then
Gauss–Newton in (rotation, lengths) with the lengths eliminated, the same step halvings and
the same stopping rule; optionally one axis turned onto a normal and Gauss–Newton about it
(``project_aligned``). Each vertex runs its own loop, so it stops when it has converged, and
nothing is allocated per step.

The C source is generated from the tables of :mod:`ufl_frames.frames3d.harmonics` (the
harmonic coefficients of u⊗⁴, the Mandel form, the rotation generators: their non-zero
entries written out as constants) and compiled with cffi into a cache folder, named by a
hash of the source: ``$UFL_FRAMES_CACHE``, else ``$XDG_CACHE_HOME/ufl_frames``, else
``~/.cache/ufl_frames``. The first process to need it builds it under a file lock (MPI ranks
included: the others wait, then load the library the first one built); a library is moved
into place by a rename, so no reader sees half a file. Without cffi (the pure NumPy install)
:func:`load` returns None and :mod:`~ufl_frames.frames3d.odeco` uses NumPy; a failed build
says why once (a warning) and falls back too. No DOLFINx, no MPI.
"""

import functools
import hashlib
import importlib.machinery
import importlib.util
import os
import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np

from ufl_frames.frames3d import harmonics

__all__ = ["cache_folder", "frames", "load", "source"]

_NAME = "ufl_frames_project3d"
_SIGNATURE = ("void {name}(long n, const double *q, const double *normals, int isotropic, "
              "double *lengths, double *rotations)")
#: Table entries below this (relative to the table's largest) are rounding noise of the
#: exact zeros of the Mandel and spherical-harmonic algebra, and left out of the C code.
_NOISE = 1e-13


def _dot_lines(target: str, matrix: np.ndarray, vector: str, indent: str = "  ") -> list[str]:
    """C statements ``target[i] = Σ_j matrix[i, j] * vector[j]`` over the non-zero entries."""
    lines = []
    cut = _NOISE * np.abs(matrix).max()
    for i, row in enumerate(matrix):
        terms = [f"{float(c)!r} * {vector}[{j}]" for j, c in enumerate(row) if abs(c) > cut]
        lines.append(f"{indent}{target}[{i}] = {' + '.join(terms) if terms else '0.0'};")
    return lines


def _power_lines() -> list[str]:
    """C body of ``power(u, out)``: the harmonic coefficients of (u·x)⁴, TO_Q (weights u^α)."""
    factors = {(a, b, c): " * ".join(["u[0]"] * a + ["u[1]"] * b + ["u[2]"] * c)
               for a, b, c in harmonics.MONOMIALS}
    lines = [f"  const double m[{len(harmonics.MONOMIALS)}] = {{"]
    lines += [f"    {factors[e]}," for e in harmonics.MONOMIALS]
    lines.append("  };")
    return lines + _dot_lines("out", harmonics.TO_Q * harmonics.WEIGHTS[None, :], "m")


def _mandel_lines() -> list[str]:
    """C body of ``mandel(q, M)``: the 6 × 6 Mandel matrix, M_IJ = w_I w_J T_ijkl."""
    lines = [f"  double t[{len(harmonics.MONOMIALS)}];"]
    lines += _dot_lines("t", harmonics.FROM_Q / harmonics.WEIGHTS[:, None], "q")
    pairs, w = harmonics.MANDEL_PAIRS, harmonics.MANDEL_WEIGHTS
    for I, (i, j) in enumerate(pairs):
        for J, (k, l) in enumerate(pairs):
            idx = (i, j, k, l)
            e = (idx.count(0), idx.count(1), idx.count(2))
            t = harmonics.MONOMIALS.index(e)
            lines.append(f"  M[{I}][{J}] = {float(w[I] * w[J])!r} * t[{t}];")
    return lines


def _generator_lines() -> list[str]:
    """C body of ``turn(qf, out)``: out[k] = L_k qf, the rotation generators on q."""
    lines = []
    for k, L in enumerate(harmonics.ROTATION_GENERATORS):
        lines += _dot_lines(f"out[{k}]", L, "qf")
    return lines


_BODY = r"""
#define NQ 15

static void solve3(const double A[3][3], const double b[3], double x[3])
{
  /* Gaussian elimination with partial pivoting on a copy */
  double M[3][4];
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) M[i][j] = A[i][j];
    M[i][3] = b[i];
  }
  for (int c = 0; c < 3; ++c) {
    int p = c;
    for (int r = c + 1; r < 3; ++r)
      if (fabs(M[r][c]) > fabs(M[p][c])) p = r;
    if (p != c)
      for (int j = 0; j < 4; ++j) { double s = M[c][j]; M[c][j] = M[p][j]; M[p][j] = s; }
    for (int r = c + 1; r < 3; ++r) {
      const double f = M[r][c] / M[c][c];
      for (int j = c; j < 4; ++j) M[r][j] -= f * M[c][j];
    }
  }
  for (int i = 2; i >= 0; --i) {
    double s = M[i][3];
    for (int j = i + 1; j < 3; ++j) s -= M[i][j] * x[j];
    x[i] = s / M[i][i];
  }
}

/* Eigenvalues w and eigenvectors (columns of V) of the symmetric 6 x 6 A (destroyed):
   cyclic Jacobi until the off-diagonal part is at rounding level. */
static void eigh6(double A[6][6], double w[6], double V[6][6])
{
  for (int i = 0; i < 6; ++i)
    for (int j = 0; j < 6; ++j) V[i][j] = (i == j);
  for (int sweep = 0; sweep < 30; ++sweep) {
    double off = 0.0, diag = 0.0;
    for (int i = 0; i < 6; ++i) {
      diag += A[i][i] * A[i][i];
      for (int j = i + 1; j < 6; ++j) off += A[i][j] * A[i][j];
    }
    if (off <= 1e-36 * diag || off == 0.0) break;
    for (int p = 0; p < 5; ++p)
      for (int r = p + 1; r < 6; ++r) {
        const double apr = A[p][r];
        if (apr == 0.0) continue;
        const double theta = (A[r][r] - A[p][p]) / (2.0 * apr);
        const double t = fabs(theta) > 1e150 ? 0.5 / theta
                         : (theta >= 0 ? 1.0 : -1.0) / (fabs(theta) + sqrt(theta * theta + 1.0));
        const double c = 1.0 / sqrt(t * t + 1.0), s = t * c;
        const double app = A[p][p], arr = A[r][r];
        for (int k = 0; k < 6; ++k) {  /* A <- J^T A J, J the rotation in the (p, r) plane */
          if (k == p || k == r) continue;
          const double akp = A[k][p], akr = A[k][r];
          A[k][p] = A[p][k] = c * akp - s * akr;
          A[k][r] = A[r][k] = s * akp + c * akr;
        }
        A[p][p] = c * c * app - 2.0 * c * s * apr + s * s * arr;
        A[r][r] = s * s * app + 2.0 * c * s * apr + c * c * arr;
        A[p][r] = A[r][p] = 0.0;
        for (int k = 0; k < 6; ++k) {
          const double vkp = V[k][p], vkr = V[k][r];
          V[k][p] = c * vkp - s * vkr;
          V[k][r] = s * vkp + c * vkr;
        }
      }
  }
  for (int i = 0; i < 6; ++i) w[i] = A[i][i];
}

/* The Mandel start: the rotation R (row-major, the frame's directions its columns) that
   jointly diagonalises the three leading Mandel eigenvectors' matrices. */
static void start(const double q[NQ], double R[9])
{
  static const int pi[6] = {0, 1, 2, 1, 0, 0}, pj[6] = {0, 1, 2, 2, 2, 1};
  static const double mw[6] = {1.0, 1.0, 1.0, 1.4142135623730951, 1.4142135623730951,
                               1.4142135623730951};
  double M[6][6], w[6], E[6][6];
  mandel(q, M);
  eigh6(M, w, E);
  int order[6] = {0, 1, 2, 3, 4, 5};
  for (int i = 1; i < 6; ++i)  /* ascending, as LAPACK's */
    for (int j = i; j > 0 && w[order[j]] < w[order[j - 1]]; --j) {
      int s = order[j]; order[j] = order[j - 1]; order[j - 1] = s;
    }
  double D[3][3][3];
  for (int k = 0; k < 3; ++k) {
    const int e = order[3 + k];
    const double weight = fabs(w[e]);
    for (int m = 0; m < 6; ++m)
      D[k][pi[m]][pj[m]] = D[k][pj[m]][pi[m]] = weight * E[m][e] / mw[m];
  }
  double V[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  static const int planes[3][2] = {{0, 1}, {0, 2}, {1, 2}};
  for (int sweep = 0; sweep < JACOBI_SWEEPS; ++sweep)
    for (int pl = 0; pl < 3; ++pl) {
      const int p = planes[pl][0], r = planes[pl][1];
      double a = 0.0, b = 0.0, d = 0.0;
      for (int k = 0; k < 3; ++k) {
        const double h1 = D[k][p][p] - D[k][r][r], h2 = 2.0 * D[k][p][r];
        a += h1 * h1; b += h1 * h2; d += h2 * h2;
      }
      /* c = cos θ, s = sin θ of θ = atan2(2b, a - d) / 4, by half angles without
         cancellation (2θ in (-π/2, π/2], θ in (-π/4, π/4]) */
      const double x = a - d, y = 2.0 * b, rho = hypot(x, y);
      double c2 = 1.0, s2 = 0.0;
      if (rho > 0.0) {
        if (x >= 0.0) {
          c2 = sqrt((rho + x) / (2.0 * rho));
          s2 = y / (2.0 * rho * c2);
        } else {
          s2 = copysign(sqrt((rho - x) / (2.0 * rho)), y);
          c2 = y / (2.0 * rho * s2);
        }
      }
      const double c = sqrt(0.5 * (1.0 + c2)), s = s2 / (2.0 * c);
      for (int k = 0; k < 3; ++k) {
        for (int i = 0; i < 3; ++i) {  /* D J: columns p, r */
          const double dp = D[k][i][p], dr = D[k][i][r];
          D[k][i][p] = c * dp + s * dr;
          D[k][i][r] = -s * dp + c * dr;
        }
        for (int j = 0; j < 3; ++j) {  /* J^T (D J): rows p, r */
          const double dp = D[k][p][j], dr = D[k][r][j];
          D[k][p][j] = c * dp + s * dr;
          D[k][r][j] = -s * dp + c * dr;
        }
      }
      for (int i = 0; i < 3; ++i) {
        const double vp = V[i][p], vr = V[i][r];
        V[i][p] = c * vp + s * vr;
        V[i][r] = -s * vp + c * vr;
      }
    }
  const double det = V[0][0] * (V[1][1] * V[2][2] - V[1][2] * V[2][1])
                   - V[0][1] * (V[1][0] * V[2][2] - V[1][2] * V[2][0])
                   + V[0][2] * (V[1][0] * V[2][1] - V[1][1] * V[2][0]);
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) R[3 * i + j] = (j == 2 && det < 0) ? -V[i][j] : V[i][j];
}

/* The branches B (the columns' u^4), the least-squares lengths and the residual
   r = q - sum lam_i B_i; returns |r|^2. */
static double residual(const double q[NQ], const double R[9], int isotropic, double B[3][NQ],
                       double lam[3], double r[NQ])
{
  for (int a = 0; a < 3; ++a) {
    const double u[3] = {R[a], R[3 + a], R[6 + a]};
    power(u, B[a]);
  }
  if (isotropic) {
    double sq = 0.0, ss = 0.0;
    for (int k = 0; k < NQ; ++k) {
      const double s = B[0][k] + B[1][k] + B[2][k];
      sq += s * q[k]; ss += s * s;
    }
    lam[0] = lam[1] = lam[2] = sq / ss;
  } else {
    double G[3][3], c[3];
    for (int a = 0; a < 3; ++a) {
      c[a] = 0.0;
      for (int k = 0; k < NQ; ++k) c[a] += B[a][k] * q[k];
      for (int b = a; b < 3; ++b) {
        double g = 0.0;
        for (int k = 0; k < NQ; ++k) g += B[a][k] * B[b][k];
        G[a][b] = G[b][a] = g;
      }
    }
    solve3(G, c, lam);
  }
  double f = 0.0;
  for (int k = 0; k < NQ; ++k) {
    r[k] = q[k] - lam[0] * B[0][k] - lam[1] * B[1][k] - lam[2] * B[2][k];
    f += r[k] * r[k];
  }
  return f;
}

/* exp([w]x) */
static void rodrigues(const double w[3], double E[3][3])
{
  const double theta = sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]);
  double a, b;
  if (theta < 1e-8) {
    a = 1.0 - theta * theta / 6.0;
    b = 0.5 - theta * theta / 24.0;
  } else {
    a = sin(theta) / theta;
    b = (1.0 - cos(theta)) / (theta * theta);
  }
  const double K[3][3] = {{0.0, -w[2], w[1]}, {w[2], 0.0, -w[0]}, {-w[1], w[0], 0.0}};
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) {
      double kk = 0.0;
      for (int l = 0; l < 3; ++l) kk += K[i][l] * K[l][j];
      E[i][j] = (i == j) + a * K[i][j] + b * kk;
    }
}

static void times(const double R[9], const double E[3][3], double out[9])
{
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j)
      out[3 * i + j] = R[3 * i] * E[0][j] + R[3 * i + 1] * E[1][j] + R[3 * i + 2] * E[2][j];
}

/* Gauss-Newton on |q - sum lam_i u_i^4|^2 over the rotations about the frame's first
   `axes` axes (3 or 1), the lengths eliminated (variable projection); R updated. */
static void refine(const double q[NQ], double R[9], int axes, int isotropic, double lam[3])
{
  double B[3][NQ], r[NQ];
  double f = residual(q, R, isotropic, B, lam, r);
  for (int it = 0; it < GN_ITERATIONS; ++it) {
    double qf[NQ], turned[3][NQ], J[NQ][3];
    for (int k = 0; k < NQ; ++k) qf[k] = q[k] - r[k];
    turn(qf, turned);
    for (int k = 0; k < NQ; ++k)
      for (int a = 0; a < axes; ++a)
        J[k][a] = R[a] * turned[0][k] + R[3 + a] * turned[1][k] + R[6 + a] * turned[2][k];
    /* project out the lengths' directions: Jp = J - Bs^T (Bs Bs^T)^-1 Bs J */
    if (isotropic) {
      double s[NQ], ss = 0.0;
      for (int k = 0; k < NQ; ++k) { s[k] = B[0][k] + B[1][k] + B[2][k]; ss += s[k] * s[k]; }
      for (int a = 0; a < axes; ++a) {
        double sj = 0.0;
        for (int k = 0; k < NQ; ++k) sj += s[k] * J[k][a];
        const double x = sj / ss;
        for (int k = 0; k < NQ; ++k) J[k][a] -= s[k] * x;
      }
    } else {
      double G[3][3];
      for (int a = 0; a < 3; ++a)
        for (int b = a; b < 3; ++b) {
          double g = 0.0;
          for (int k = 0; k < NQ; ++k) g += B[a][k] * B[b][k];
          G[a][b] = G[b][a] = g;
        }
      double X[3][3];
      for (int a = 0; a < axes; ++a) {
        double bj[3], x[3];
        for (int b = 0; b < 3; ++b) {
          bj[b] = 0.0;
          for (int k = 0; k < NQ; ++k) bj[b] += B[b][k] * J[k][a];
        }
        solve3(G, bj, x);
        for (int b = 0; b < 3; ++b) X[b][a] = x[b];
      }
      for (int k = 0; k < NQ; ++k)
        for (int a = 0; a < axes; ++a)
          J[k][a] -= B[0][k] * X[0][a] + B[1][k] * X[1][a] + B[2][k] * X[2][a];
    }
    double H[3][3] = {{0}}, g[3] = {0}, step[3] = {0};
    for (int a = 0; a < axes; ++a) {
      for (int k = 0; k < NQ; ++k) g[a] += J[k][a] * r[k];
      for (int b = a; b < axes; ++b) {
        double h = 0.0;
        for (int k = 0; k < NQ; ++k) h += J[k][a] * J[k][b];
        H[a][b] = H[b][a] = h;
      }
    }
    double scale = 0.0;
    for (int a = 0; a < axes; ++a) scale += H[a][a];
    scale /= axes;
    for (int a = 0; a < axes; ++a) H[a][a] += 1e-12 * (scale + 1e-300);
    if (axes == 3) solve3(H, g, step);
    else step[0] = g[0] / H[0][0];
    double taken = 0.0, t = 1.0;
    for (int h = 0; h < HALVINGS; ++h, t *= 0.5) {
      double w[3] = {0.0, 0.0, 0.0}, E[3][3], trial[9], Bt[3][NQ], lt[3], rt[NQ];
      for (int a = 0; a < axes; ++a) w[a] = step[a] * t;
      rodrigues(w, E);
      times(R, E, trial);
      const double fn = residual(q, trial, isotropic, Bt, lt, rt);
      const double wmax = fmax(fabs(w[0]), fmax(fabs(w[1]), fabs(w[2])));
      if (fn <= f * (1 + 1e-15) || wmax <= SMALL_STEP) {
        memcpy(R, trial, sizeof(trial));
        memcpy(B, Bt, sizeof(Bt));
        memcpy(r, rt, sizeof(rt));
        lam[0] = lt[0]; lam[1] = lt[1]; lam[2] = lt[2];
        f = fn;
        taken = wmax;
        break;
      }
    }
    if (!(taken > STEP_TOL)) break;
  }
}

/* R turned the least so that one of its axes lies along the normal, that axis made the
   first column (a proper rotation kept). */
static void align(double R[9], const double normal[3])
{
  const double len = sqrt(normal[0] * normal[0] + normal[1] * normal[1] + normal[2] * normal[2]);
  const double n[3] = {normal[0] / len, normal[1] / len, normal[2] / len};
  double dots[3];
  int k = 0;
  for (int j = 0; j < 3; ++j) {
    dots[j] = R[j] * n[0] + R[3 + j] * n[1] + R[6 + j] * n[2];
    if (fabs(dots[j]) > fabs(dots[k])) k = j;
  }
  const double sg = dots[k] > 0 ? 1.0 : (dots[k] < 0 ? -1.0 : 0.0);
  const double u[3] = {R[k] * sg, R[3 + k] * sg, R[6 + k] * sg};
  const double axis[3] = {u[1] * n[2] - u[2] * n[1], u[2] * n[0] - u[0] * n[2],
                          u[0] * n[1] - u[1] * n[0]};
  const double sn = sqrt(axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2]);
  const double cs = u[0] * n[0] + u[1] * n[1] + u[2] * n[2];
  const double factor = sn > 0 ? atan2(sn, cs) / sn : 0.0;
  const double w[3] = {axis[0] * factor, axis[1] * factor, axis[2] * factor};
  double E[3][3], turned[9];
  rodrigues(w, E);
  for (int i = 0; i < 3; ++i)  /* E R */
    for (int j = 0; j < 3; ++j)
      turned[3 * i + j] = E[i][0] * R[j] + E[i][1] * R[3 + j] + E[i][2] * R[6 + j];
  double c0[3], c1[3], c2[3];
  for (int i = 0; i < 3; ++i) {
    c0[i] = n[i];
    c1[i] = turned[3 * i + (k + 1) % 3];
  }
  c2[0] = c0[1] * c1[2] - c0[2] * c1[1];
  c2[1] = c0[2] * c1[0] - c0[0] * c1[2];
  c2[2] = c0[0] * c1[1] - c0[1] * c1[0];
  c1[0] = c2[1] * c0[2] - c2[2] * c0[1];
  c1[1] = c2[2] * c0[0] - c2[0] * c0[2];
  c1[2] = c2[0] * c0[1] - c2[1] * c0[0];
  for (int i = 0; i < 3; ++i) {
    R[3 * i] = c0[i];
    R[3 * i + 1] = c1[i];
    R[3 * i + 2] = c2[i];
  }
}

SIGNATURE
{
  for (long v = 0; v < n; ++v) {
    const double *qv = q + NQ * v;
    double *R = rotations + 9 * v, *lam = lengths + 3 * v;
    start(qv, R);
    refine(qv, R, 3, isotropic, lam);
    if (normals) {
      align(R, normals + 3 * v);
      refine(qv, R, 1, isotropic, lam);
    }
  }
}
"""


@functools.cache
def source() -> str:
    """The C source of the projection kernel (its parameters those of
    :mod:`ufl_frames.frames3d.odeco`)."""
    from ufl_frames.frames3d import odeco

    def function(head, body):
        return [head, "{", *body, "}", ""]

    lines = [
        "#include <math.h>",
        "#include <string.h>",
        "",
        f"#define GN_ITERATIONS {odeco._GN_ITERATIONS}",
        f"#define JACOBI_SWEEPS {odeco._JACOBI_SWEEPS}",
        f"#define HALVINGS {odeco._HALVINGS}",
        f"#define STEP_TOL {odeco._STEP_TOL!r}",
        f"#define SMALL_STEP {odeco._SMALL_STEP!r}",
        "",
        *function("static void power(const double u[3], double out[15])", _power_lines()),
        *function("static void mandel(const double q[15], double M[6][6])", _mandel_lines()),
        *function("static void turn(const double qf[15], double out[3][15])",
                  _generator_lines()),
    ]
    body = _BODY.replace("SIGNATURE", _SIGNATURE.format(name=_NAME))
    return "\n".join(lines) + body


def cache_folder() -> Path:
    """Where the compiled library lives: ``$UFL_FRAMES_CACHE``, else
    ``$XDG_CACHE_HOME/ufl_frames``, else ``~/.cache/ufl_frames``."""
    if os.environ.get("UFL_FRAMES_CACHE"):
        return Path(os.environ["UFL_FRAMES_CACHE"]).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base).expanduser() / "ufl_frames"


@functools.cache
def load():
    """The compiled module (its ``lib`` and ``ffi``), built the first time; None where cffi
    is not installed or the build fails (then a warning says why, once)."""
    try:
        import cffi  # noqa: F401
    except ImportError:
        return None
    code = source()
    digest = hashlib.sha256((code + sys.version).encode()).hexdigest()[:16]
    name = f"_ufl_frames_project3d_{digest}"
    folder = cache_folder()
    path = folder / f"{name}{importlib.machinery.EXTENSION_SUFFIXES[0]}"
    try:
        if not path.is_file():
            _build_locked(name, code, folder, path)
        spec = importlib.util.spec_from_file_location(name, path)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    except Exception as exc:  # a missing compiler, an unwritable cache: NumPy instead
        warnings.warn(f"ufl_frames: the compiled 3D projection is unavailable "
                      f"({type(exc).__name__}: {exc}); using NumPy", RuntimeWarning, stacklevel=2)
        return None
    return module


def _build_locked(name: str, code: str, folder: Path, path: Path) -> None:
    """Build the library under a lock file in ``folder``, unless another process built it
    while this one waited."""
    import fcntl

    import cffi

    folder.mkdir(parents=True, exist_ok=True)
    with open(folder / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            if path.is_file():
                return
            ffi = cffi.FFI()
            ffi.cdef(_SIGNATURE.format(name=_NAME) + ";")
            ffi.set_source(name, code, extra_compile_args=["-O2", "-std=c99"])
            with tempfile.TemporaryDirectory(dir=folder) as build:
                built = Path(ffi.compile(tmpdir=build, verbose=False))
                os.replace(built, path)
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


def frames(q: np.ndarray, normals: np.ndarray | None = None,
           isotropic: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Lengths (N, 3) and rotations (N, 3, 3) of the closest frames to q, compiled: the
    NumPy ``odeco.q_to_frames`` (with ``normals``: then one axis along each normal and the
    rotation about it refined, as ``odeco.project_aligned``).

    Args:
        q: checked coefficients (N, 15), float64.
        normals: non-zero vectors (N, 3), or None.
        isotropic: the lengths fitted equal.

    Returns:
        (lengths, rotations); raises RuntimeError where the kernel cannot be loaded.
    """
    module = load()
    if module is None:
        raise RuntimeError("the compiled 3D projection is unavailable (no cffi or no C compiler)")
    q = np.ascontiguousarray(q, dtype=np.float64)
    n = q.shape[0]
    lengths = np.empty((n, 3))
    rotations = np.empty((n, 3, 3))
    ffi, lib = module.ffi, module.lib
    if normals is None:
        c_normals = ffi.NULL
    else:
        normals = np.ascontiguousarray(normals, dtype=np.float64)
        c_normals = ffi.from_buffer("double[]", normals)
    getattr(lib, _NAME)(n, ffi.from_buffer("double[]", q), c_normals, int(bool(isotropic)),
                        ffi.from_buffer("double[]", lengths),
                        ffi.from_buffer("double[]", rotations))
    return lengths, rotations
