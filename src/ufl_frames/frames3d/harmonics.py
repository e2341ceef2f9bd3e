r"""Fourth-order symmetric tensors in 3D as 15 spherical-harmonic coefficients.

A symmetric tensor T of order 4 in 3D has 15 independent components; its polynomial on
the unit sphere is :math:`p(x) = T_{ijkl} x_i x_j x_k x_l`, a homogeneous quartic that
decomposes into spherical harmonics of degrees 0, 2 and 4 (1 + 5 + 9 = 15 functions;
note §2.1, eq. 2). The coefficients ``q`` used throughout :mod:`ufl_frames.frames3d` are
those of p in the real spherical harmonics, orthonormal for :math:`\int_{S^2} f g\, dA`:

    q = (Y_0; Y_2^{-2..2}; Y_4^{-4..4}) coefficients,   |q|² = ∫_{S²} p² dA,

so the Euclidean norm of q is the L² norm of the tensor's polynomial, invariant under
rotations (as the 2D coefficients of :mod:`ufl_frames.frames2d.odeco`).

Every quartic is handled through its 15 monomial coefficients (:data:`MONOMIALS`); the
change of basis is exact up to rounding: :data:`FROM_Q` (monomial coefficients of the
harmonics, columns) and :data:`TO_Q` = :data:`FROM_Q`\ ᵀ G, with G the sphere integrals
of products of monomials, in closed form. Pure NumPy.
"""

from itertools import product
from math import factorial, gamma, sqrt

import numpy as np

__all__ = ["FROM_Q", "MONOMIALS", "NUM_COEFFICIENTS", "TO_Q", "DEGREES", "mandel",
           "power_coefficients", "q_of_powers", "tensor_components"]

#: Coefficients per 3D frame: spherical harmonics of degrees 0, 2, 4.
NUM_COEFFICIENTS = 15

#: Exponents (a, b, c), a + b + c = 4, of the quartic monomials x^a y^b z^c, in order.
MONOMIALS = tuple((a, b, 4 - a - b) for a in range(4, -1, -1) for b in range(4 - a, -1, -1))
_CUBICS = tuple((a, b, 3 - a - b) for a in range(3, -1, -1) for b in range(3 - a, -1, -1))

#: The harmonic degree of each coefficient of q.
DEGREES = np.array([0] + [2] * 5 + [4] * 9)


def _multinomial(e) -> int:
    return factorial(sum(e)) // (factorial(e[0]) * factorial(e[1]) * factorial(e[2]))


def _sphere_integral(e) -> float:
    """∫_{S²} x^a y^b z^c dA (closed form; zero unless every exponent is even)."""
    if any(k % 2 for k in e):
        return 0.0
    return 2.0 * gamma((e[0] + 1) / 2) * gamma((e[1] + 1) / 2) * gamma((e[2] + 1) / 2) / gamma(
        (sum(e) + 3) / 2)


def _poly(terms: dict) -> dict:
    return {k: v for k, v in terms.items() if v != 0}


def _mul(p: dict, r: dict) -> dict:
    out: dict = {}
    for (ea, ca), (eb, cb) in product(p.items(), r.items()):
        e = (ea[0] + eb[0], ea[1] + eb[1], ea[2] + eb[2])
        out[e] = out.get(e, 0) + ca * cb
    return _poly(out)


def _add(*ps) -> dict:
    out: dict = {}
    for p in ps:
        for e, c in p.items():
            out[e] = out.get(e, 0) + c
    return _poly(out)


def _scale(c, p: dict) -> dict:
    return {e: c * v for e, v in p.items()}


_X, _Y, _Z = {(1, 0, 0): 1}, {(0, 1, 0): 1}, {(0, 0, 1): 1}
_R2 = _add(_mul(_X, _X), _mul(_Y, _Y), _mul(_Z, _Z))


def _harmonic_quartics() -> list[dict]:
    """The 15 real spherical harmonics (unnormalised, Cartesian, made homogeneous of degree
    4 by powers of r² = 1 on the sphere), ordered by degree and then m = −l..l."""
    x, y, z, r2 = _X, _Y, _Z, _R2
    xx, yy, zz = _mul(x, x), _mul(y, y), _mul(z, z)
    deg2 = [_mul(x, y), _mul(y, z), _add(_scale(3, zz), _scale(-1, r2)), _mul(x, z),
            _add(xx, _scale(-1, yy))]
    s7 = _add(_scale(7, zz), _scale(-1, r2))  # 7z² − r²
    s73 = _add(_scale(7, zz), _scale(-3, r2))  # 7z² − 3r²
    deg4 = [
        _mul(_mul(x, y), _add(xx, _scale(-1, yy))),
        _mul(_mul(_add(_scale(3, xx), _scale(-1, yy)), y), z),
        _mul(_mul(x, y), s7),
        _mul(_mul(y, z), s73),
        _add(_scale(35, _mul(zz, zz)), _scale(-30, _mul(zz, r2)), _scale(3, _mul(r2, r2))),
        _mul(_mul(x, z), s73),
        _mul(_add(xx, _scale(-1, yy)), s7),
        _mul(_mul(_add(xx, _scale(-3, yy)), x), z),
        _add(_mul(xx, _add(xx, _scale(-3, yy))),
             _scale(-1, _mul(yy, _add(_scale(3, xx), _scale(-1, yy))))),
    ]
    return [_mul(r2, r2)] + [_mul(p, r2) for p in deg2] + deg4


def _vector(p: dict) -> np.ndarray:
    index = {e: i for i, e in enumerate(MONOMIALS)}
    v = np.zeros(len(MONOMIALS))
    for e, c in p.items():
        v[index[e]] = c
    return v


#: Sphere integrals of products of quartic monomials (15, 15).
GRAM = np.array([[_sphere_integral((a[0] + b[0], a[1] + b[1], a[2] + b[2])) for b in MONOMIALS]
                 for a in MONOMIALS])


def _basis() -> np.ndarray:
    columns = [_vector(p) for p in _harmonic_quartics()]
    return np.stack([c / sqrt(c @ GRAM @ c) for c in columns], axis=1)


#: Monomial coefficients (15, 15) of the harmonics: a quartic with coefficients q has
#: monomial coefficients ``FROM_Q @ q``.
FROM_Q = _basis()
#: Harmonic coefficients of a quartic from its monomial coefficients c: ``TO_Q @ c``.
TO_Q = FROM_Q.T @ GRAM

#: Multinomial weights of the monomials: p's coefficient of x^α is weight(α) · T_α.
WEIGHTS = np.array([_multinomial(e) for e in MONOMIALS], dtype=float)
_CUBIC_WEIGHTS = np.array([_multinomial(e) for e in _CUBICS], dtype=float)
_CUBIC_EXPONENTS = np.array(_CUBICS)
# (10, 3, 15): 1 where the cubic β times x_k is the quartic α
_RAISE = np.zeros((len(_CUBICS), 3, len(MONOMIALS)))
for _b, _beta in enumerate(_CUBICS):
    for _k in range(3):
        _alpha = list(_beta)
        _alpha[_k] += 1
        _RAISE[_b, _k, MONOMIALS.index(tuple(_alpha))] = 1.0
# (3 · 10, 15): x_k times the cubic β, in harmonic coefficients (rows k-major)
_RAISE_TO_Q = np.concatenate([_RAISE[:, k, :] @ TO_Q.T for k in range(3)])


def _rotation_generators() -> np.ndarray:
    """L_k (3, 15, 15): d/dθ of the coefficients of T rotated by θ about the axis e_k, at
    θ = 0 (the polynomial p(x) becomes p(R_θᵀ x), whose derivative is −∇p · (e_k × x))."""
    index = {e: i for i, e in enumerate(MONOMIALS)}
    out = np.zeros((3, len(MONOMIALS), len(MONOMIALS)))
    for k in range(3):
        e_k = np.eye(3)[k]
        D = np.zeros((len(MONOMIALS), len(MONOMIALS)))
        for col, alpha in enumerate(MONOMIALS):
            for j in range(3):  # ∂_j x^α · (e_k × x)_j, (e_k × x)_j = Σ_l ε_jkl... as a sum
                if alpha[j] == 0:
                    continue
                lowered = list(alpha)
                lowered[j] -= 1
                # (e_k × x)_j = Σ_m c_jm x_m with c = [e_k]×
                cross = np.cross(e_k, np.eye(3))  # row m: e_k × e_m
                for m_ in range(3):
                    c = cross[m_, j]
                    if c == 0:
                        continue
                    raised = list(lowered)
                    raised[m_] += 1
                    D[index[tuple(raised)], col] -= alpha[j] * c
        out[k] = TO_Q @ D @ FROM_Q
    return out


def _cubic_monomials(u: np.ndarray) -> np.ndarray:
    """The weighted cubic monomials (N, 10) of u: (u·x)³ = Σ_β weight(β) u^β x^β."""
    x, y, z = (np.ascontiguousarray(u[:, k]) for k in range(3))
    xx, yy, zz = x * x, y * y, z * z
    out = np.empty((u.shape[0], len(_CUBICS)))
    for column, monomial in enumerate((xx * x, xx * y, xx * z, x * yy, x * y * z, x * zz,
                                       yy * y, yy * z, y * zz, zz * z)):
        out[:, column] = monomial
    return out * _CUBIC_WEIGHTS


def power_coefficients(u: np.ndarray, v: np.ndarray | None = None) -> np.ndarray:
    """Monomial coefficients (N, 15) of the quartic (u·x)³ (v·x), or (u·x)⁴ without v.

    Args:
        u: vectors (N, 3).
        v: vectors (N, 3), or None (v = u).

    Returns:
        The coefficients, in the order of :data:`MONOMIALS`.
    """
    u = np.asarray(u, dtype=float)
    v = u if v is None else np.asarray(v, dtype=float)
    cubic = _cubic_monomials(u)
    return sum(v[:, k, None] * (cubic @ _RAISE[:, k, :]) for k in range(3))


def q_of_powers(u: np.ndarray, v: np.ndarray | None = None) -> np.ndarray:
    """Harmonic coefficients (N, 15) of (u·x)³ (v·x), or of (u·x)⁴ without v: the
    coefficients of the tensor u⊗⁴ (and, times 4, of its derivative as u moves along v)."""
    u = np.asarray(u, dtype=float)
    v = u if v is None else np.asarray(v, dtype=float)
    cubic = _cubic_monomials(u)
    features = (cubic[:, None, :] * v[:, :, None]).reshape(-1, 3 * len(_CUBICS))
    return features @ _RAISE_TO_Q


def tensor_components(q: np.ndarray) -> np.ndarray:
    """The full tensors T_ijkl (N, 3, 3, 3, 3) of the coefficients q (N, 15)."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    t = (q @ FROM_Q.T) / WEIGHTS  # distinct components
    T = np.empty((q.shape[0], 3, 3, 3, 3))
    for idx in product(range(3), repeat=4):
        e = (idx.count(0), idx.count(1), idx.count(2))
        T[(slice(None),) + idx] = t[:, MONOMIALS.index(e)]
    return T


#: Mandel order of the index pairs of a symmetric 3 × 3 matrix, and their weights.
MANDEL_PAIRS = ((0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1))
MANDEL_WEIGHTS = np.array([1.0, 1.0, 1.0, sqrt(2.0), sqrt(2.0), sqrt(2.0)])


def mandel(q: np.ndarray) -> np.ndarray:
    """The Mandel matrices (N, 6, 6) of the tensors q (N, 15): M_IJ = w_I w_J T_ijkl, so
    that u⊗⁴ becomes m mᵀ with m the unit Mandel vector of u uᵀ."""
    T = tensor_components(q)
    rows = np.array(MANDEL_PAIRS)
    M = T[:, rows[:, 0][:, None], rows[:, 1][:, None], rows[:, 0][None, :], rows[:, 1][None, :]]
    return M * np.outer(MANDEL_WEIGHTS, MANDEL_WEIGHTS)


def symmetric_of_mandel(m: np.ndarray) -> np.ndarray:
    """The symmetric matrices (..., 3, 3) of Mandel vectors m (..., 6)."""
    s = m / MANDEL_WEIGHTS
    out = np.empty(m.shape[:-1] + (3, 3))
    for k, (i, j) in enumerate(MANDEL_PAIRS):
        out[..., i, j] = out[..., j, i] = s[..., k]
    return out


#: The rotation generators on q: the coefficients of T turned by a small rotation w
#: (axis-angle) change by Σ_k w_k L_k q.
ROTATION_GENERATORS = _rotation_generators()
