r"""Pointwise algebra of 3D Odeco tensors, vectorised over vertices (note §2.1, n = 3).

A 3D frame is three orthogonal unit directions u_1, u_2, u_3 (the columns of a rotation
R) with lengths λ_1, λ_2, λ_3; its Odeco tensor is T = Σ λ_i u_i⊗⁴ and its coefficients
q ∈ R¹⁵ are those of T's polynomial in the spherical harmonics of degrees 0, 2 and 4
(:mod:`ufl_frames.frames3d.harmonics`: |q| is the L² norm of the polynomial on the
sphere). The frames form a variety of dimension 6 (3 rotations, 3 lengths), cut out by
27 quadratic equations g_m(q) = qᵀ A_m q (derived exactly by
``scripts/derive_odeco3d.py``; here in an orthonormal basis of their span).

Projection (the closest frame in |·|). The note's construction gives the start: the
Mandel matrix of T (6 × 6) has the Mandel vectors of u_i u_iᵀ as its leading
eigenvectors, eigenvalues λ_i. Reading the directions from D = Σ λ̃_i D_i is fragile near
isotropy (there the three leading eigenvectors are any orthonormal basis of their span:
``docs/note-checks.md``); but every matrix of that span is diagonal in the frame's basis,
so the rotation is found stably as the joint diagonaliser of the three D_i (Jacobi
rotations, Cardoso–Souloumiac's closed-form angle). Gauss–Newton in (rotation, lengths)
from there makes it the exact closest point: quadratic convergence, the residual
orthogonal to the variety's tangent space. A step is halved until the distance decreases,
except a small one (under 1e-6 rad), taken as it is: there the distance changes by less
than its rounding error, and the comparison would stop about √ε·|r| short. Far from the
variety (a residual of tens of per cent of |q|) the convergence is linear and slow, and
the iteration stops after its last step at a closer frame than the start, not always the
closest.

The same algorithm is compiled to C (:mod:`ufl_frames.frames3d.kernel`, one vertex at a
time, 3–5 times faster); the projections use it where cffi and a C compiler are there
(``compiled=None``) and this NumPy code, the reference, elsewhere or with
``compiled=False``.

The degenerate frames (a length zero, or lengths of both signs) are points of the same
variety; lengths are not forced positive here. No DOLFINx: NumPy arrays of shape (N, 15).
"""

import numpy as np

from ufl_frames.frames3d import harmonics, kernel
from ufl_frames.frames3d._variety_table import NUM_QUADRICS, QUADRICS

__all__ = ["NUM_COEFFICIENTS", "VARIETY_MATRICES", "aligned_frames", "frames_to_q", "project",
           "project_aligned", "q_to_frames", "tangent_basis", "variety_residual"]

NUM_COEFFICIENTS = harmonics.NUM_COEFFICIENTS

#: Gauss–Newton iterations of the projection and Jacobi sweeps of its start. Near the
#: variety the convergence is quadratic (3–5 steps to rounding); far from it (a residual
#: over a few per cent of |q|) it is linear and the iteration stops at this count, at a
#: frame closer than the start but not always the closest.
_GN_ITERATIONS = 8
_JACOBI_SWEEPS = 4
# A step below this leaves an error of order step² (quadratic convergence): the last one.
_STEP_TOL = 1e-8
#: A step this small is taken without comparing distances: the distance changes by less
#: than its rounding error there (|r|·ε), so the comparison would stop the iteration at
#: about √ε·|r| from the closest point; the Gauss–Newton step itself is accurate to ε.
_SMALL_STEP = 1e-6
#: Halvings of a Gauss-Newton step that does not lower the distance.
_HALVINGS = 4


def _variety_matrices() -> np.ndarray:
    """The 27 symmetric A_m (27, 15, 15) in q, orthonormal in the Frobenius product."""
    L = harmonics.FROM_Q / harmonics.WEIGHTS[:, None]  # distinct components t = L q
    B = np.zeros((NUM_QUADRICS, NUM_COEFFICIENTS, NUM_COEFFICIENTS))
    for (m, i, j), c in QUADRICS.items():
        B[m, i, j] += float(c) / 2
        B[m, j, i] += float(c) / 2
    A = np.einsum("ai,mab,bj->mij", L, B, L)
    flat = A.reshape(NUM_QUADRICS, -1)
    _, s, vt = np.linalg.svd(flat, full_matrices=False)
    if s[-1] < 1e-10 * s[0]:
        raise RuntimeError("the variety table's quadrics are dependent")
    return vt.reshape(NUM_QUADRICS, NUM_COEFFICIENTS, NUM_COEFFICIENTS)


#: Symmetric matrices A_m (27, 15, 15) of the variety equations g_m(q) = qᵀ A_m q,
#: orthonormal (Σ_ij A_m,ij A_n,ij = δ_mn).
VARIETY_MATRICES = _variety_matrices()


def _rows(q, name="q") -> np.ndarray:
    q = np.asarray(q)
    if np.iscomplexobj(q):
        raise ValueError(f"{name} must be real, got complex values")
    q = np.asarray(q, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != NUM_COEFFICIENTS:
        raise ValueError(f"{name} must have shape (N, {NUM_COEFFICIENTS}), got {q.shape}")
    if not np.all(np.isfinite(q)):
        raise ValueError(f"{name} has NaN or infinite entries")
    return q


def _rotations(R) -> np.ndarray:
    R = np.asarray(R, dtype=np.float64)
    if R.ndim != 3 or R.shape[1:] != (3, 3):
        raise ValueError(f"rotations must have shape (N, 3, 3), got {R.shape}")
    if not np.allclose(R.transpose(0, 2, 1) @ R, np.eye(3), atol=1e-10):
        raise ValueError("rotations must be orthogonal matrices")
    return R


# --- frames <-> coefficients --------------------------------------------------------


def frames_to_q(lengths, rotations) -> np.ndarray:
    """Coefficients (N, 15) of the frames Σ λ_i u_i⊗⁴.

    Args:
        lengths: λ (N, 3).
        rotations: R (N, 3, 3), the directions u_i its columns.

    Returns:
        q (N, 15).
    """
    lengths = np.asarray(lengths, dtype=np.float64)
    R = _rotations(rotations)
    if lengths.shape != (R.shape[0], 3):
        raise ValueError(f"lengths must have shape ({R.shape[0]}, 3), got {lengths.shape}")
    return np.einsum("ni,nik->nk", lengths, _branch_q(R))


def _branch_q(R) -> np.ndarray:
    """Coefficients (N, 3, 15) of u_i⊗⁴ for the columns u_i of R."""
    n = R.shape[0]
    u = R.transpose(0, 2, 1).reshape(-1, 3)
    return harmonics.q_of_powers(u).reshape(n, 3, NUM_COEFFICIENTS)


def variety_residual(q) -> np.ndarray:
    """g_m(q) = qᵀ A_m q (N, 27): zero exactly on frames."""
    q = _rows(q)
    return np.einsum("ni,mij,nj->nm", q, VARIETY_MATRICES, q)


def variety_normals(q) -> np.ndarray:
    """The gradients 2 A_m q (N, 27, 15) of the variety equations."""
    q = _rows(q)
    return 2.0 * np.einsum("mij,nj->nmi", VARIETY_MATRICES, q)


# --- the start: Mandel eigenvectors, joint diagonalisation ---------------------------


def _joint_diagonaliser(D: np.ndarray) -> np.ndarray:
    """Rotations V (N, 3, 3) that make the symmetric matrices D (N, K, 3, 3) as diagonal
    as possible together (Jacobi sweeps; the angle of each plane rotation in closed form:
    the leading eigenvector of Σ_k h_k h_kᵀ, h = (d_pp − d_qq, 2 d_pq))."""
    D = D.copy()
    n = D.shape[0]
    V = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
    for _ in range(_JACOBI_SWEEPS):
        for p, r in ((0, 1), (0, 2), (1, 2)):
            h1 = D[:, :, p, p] - D[:, :, r, r]
            h2 = 2.0 * D[:, :, p, r]
            a, b, d = (h1 * h1).sum(1), (h1 * h2).sum(1), (h2 * h2).sum(1)
            theta = 0.25 * np.arctan2(2.0 * b, a - d)
            c, s = np.cos(theta), np.sin(theta)
            J = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
            J[:, p, p] = c
            J[:, r, r] = c
            J[:, p, r] = -s
            J[:, r, p] = s
            D = J.transpose(0, 2, 1)[:, None] @ D @ J[:, None]
            V = V @ J
    det = np.linalg.det(V)
    V[:, :, 2] *= np.sign(det)[:, None]
    return V


def initial_rotations(q) -> np.ndarray:
    """The frames' rotations (N, 3, 3) read from the Mandel matrices' three leading
    eigenvectors by joint diagonalisation (see the module docstring)."""
    w, v = np.linalg.eigh(harmonics.mandel(q))
    top = v[:, :, -3:]  # (N, 6, 3)
    weights = np.abs(w[:, -3:])
    D = harmonics.symmetric_of_mandel(top.transpose(0, 2, 1)) * weights[:, :, None, None]
    return _joint_diagonaliser(D)


# --- Gauss-Newton in (rotation, lengths) ---------------------------------------------


def _rodrigues(w: np.ndarray) -> np.ndarray:
    """exp([w]×) (N, 3, 3)."""
    theta = np.linalg.norm(w, axis=1)
    K = np.zeros((w.shape[0], 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -w[:, 2], w[:, 1], -w[:, 0]
    K = K - K.transpose(0, 2, 1)
    small = theta < 1e-8
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6, np.sin(safe) / safe)
    b = np.where(small, 0.5 - theta**2 / 24, (1.0 - np.cos(safe)) / safe**2)
    return np.eye(3) + a[:, None, None] * K + b[:, None, None] * (K @ K)


def _rotation_columns(R, q_frame, axes) -> np.ndarray:
    """d q / d ω_a (N, 15, len(axes)) of the frames q_frame (N, 15) turned about their own
    axes u_a (the columns ``axes`` of R): L(u_a) q_frame, with the rotation generators
    L(w) = Σ_k w_k L_k on the coefficients."""
    L = harmonics.ROTATION_GENERATORS
    turned = np.einsum("kij,nj->nki", L, q_frame)  # (N, 3, 15): L_k q
    return np.einsum("nka,nki->nia", R[:, :, list(axes)], turned)


def _fit_lengths(q, B, isotropic: bool) -> np.ndarray:
    """The least-squares lengths (N, 3) of q in the branches B (N, 3, 15)."""
    if isotropic:
        s = B.sum(axis=1)
        lam = np.einsum("nk,nk->n", s, q) / np.einsum("nk,nk->n", s, s)
        return np.repeat(lam[:, None], 3, axis=1)
    G = np.einsum("nik,njk->nij", B, B)
    return np.linalg.solve(G, np.einsum("nik,nk->ni", B, q)[:, :, None])[:, :, 0]


def _residual2(q, R, isotropic):
    B = _branch_q(R)
    lam = _fit_lengths(q, B, isotropic)
    r = q - np.einsum("ni,nik->nk", lam, B)
    return np.einsum("nk,nk->n", r, r), B, lam, r


def _refine(q, R, axes=(0, 1, 2), isotropic=False):
    """Gauss–Newton on |q − Σ λ_i u_i⊗⁴|² over rotations about the frame's ``axes`` (the
    lengths eliminated: variable projection), from R, each step halved until the distance
    decreases. Returns (R, lengths)."""
    R = R.copy()
    f, B, lam, r = _residual2(q, R, isotropic)
    active = np.ones(q.shape[0], dtype=bool)
    for _ in range(_GN_ITERATIONS):
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        Ra, qa, Ba = R[idx], q[idx], B[idx]
        # the lengths' directions projected out (variable projection, Kaufman's step)
        J = _rotation_columns(Ra, qa - r[idx], axes)
        Bs = Ba.sum(axis=1)[:, None, :] if isotropic else Ba
        Jp = J - Bs.transpose(0, 2, 1) @ np.linalg.solve(Bs @ Bs.transpose(0, 2, 1), Bs @ J)
        H = Jp.transpose(0, 2, 1) @ Jp
        g = np.einsum("nka,nk->na", Jp, r[idx])
        scale = np.trace(H, axis1=1, axis2=2)[:, None, None] / len(axes)
        H = H + 1e-12 * (scale + 1e-300) * np.eye(len(axes))
        step = np.linalg.solve(H, g[:, :, None])[:, :, 0]
        taken = np.zeros(idx.size)  # the size of the step each row took
        rows, t = np.arange(idx.size), np.ones(idx.size)
        for _halving in range(_HALVINGS):
            w = np.zeros((rows.size, 3))
            w[:, list(axes)] = step[rows] * t[:, None]
            trial = Ra[rows] @ _rodrigues(w)
            f_new, B_new, lam_new, r_new = _residual2(qa[rows], trial, isotropic)
            better = (f_new <= f[idx[rows]] * (1 + 1e-15)) | (np.abs(w).max(axis=1)
                                                               <= _SMALL_STEP)
            at = idx[rows[better]]
            R[at], f[at], B[at], lam[at], r[at] = (trial[better], f_new[better], B_new[better],
                                                   lam_new[better], r_new[better])
            taken[rows[better]] = np.abs(w[better]).max(axis=1)
            rows, t = rows[~better], 0.5 * t[~better]
            if rows.size == 0:
                break
        # converged: the last step was small (its error is of its size squared), or no
        # step along the Gauss-Newton direction lowers the distance
        active[idx] = taken > _STEP_TOL
    return R, lam


# --- projections ---------------------------------------------------------------------


def _use_compiled(compiled: bool | None) -> bool:
    """Whether a projection runs the compiled kernel (:mod:`ufl_frames.frames3d.kernel`):
    ``None`` where it can be loaded, ``False`` never (the NumPy reference), ``True`` always
    (a RuntimeError where it cannot be loaded)."""
    if compiled is False:
        return False
    if kernel.load() is not None:
        return True
    if compiled:
        raise RuntimeError("the compiled 3D projection is unavailable (no cffi or no C compiler)")
    return False


def q_to_frames(q, isotropic: bool = False,
                compiled: bool | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Lengths (N, 3) and rotations (N, 3, 3) of the frames closest to q (isotropic ones,
    λ_1 = λ_2 = λ_3, with ``isotropic``); ``compiled`` as in :func:`project`."""
    q = _rows(q)
    if _use_compiled(compiled):
        return kernel.frames(q, isotropic=isotropic)
    R, lam = _refine(q, initial_rotations(q), isotropic=isotropic)
    return lam, R


def project(q, isotropic: bool = False, compiled: bool | None = None) -> np.ndarray:
    """The closest frames (N, 15) to q (isotropic ones with ``isotropic``).

    Args:
        q: coefficients (N, 15).
        isotropic: the closest frames with λ_1 = λ_2 = λ_3.
        compiled: run the compiled kernel (the same algorithm in C, one vertex at a time;
            :mod:`ufl_frames.frames3d.kernel`): None where it can be loaded, False never
            (NumPy), True always.

    Returns:
        The projected coefficients (N, 15).
    """
    lam, R = q_to_frames(q, isotropic=isotropic, compiled=compiled)
    return np.einsum("ni,nik->nk", lam, _branch_q(R))


def _aligning_rotations(R, normals):
    """R turned the least so that one of its axes lies along ``normals``, that axis made
    the first column (a proper rotation kept)."""
    n = normals / np.linalg.norm(normals, axis=1)[:, None]
    dots = np.einsum("nij,ni->nj", R, n)
    k = np.argmax(np.abs(dots), axis=1)
    rows = np.arange(R.shape[0])
    u = R[rows, :, k] * np.sign(dots[rows, k])[:, None]
    axis = np.cross(u, n)
    sin = np.linalg.norm(axis, axis=1)
    cos = np.einsum("ni,ni->n", u, n)
    angle = np.arctan2(sin, cos)
    w = axis * np.where(sin > 0, angle / np.where(sin > 0, sin, 1.0), 0.0)[:, None]
    turned = _rodrigues(w) @ R
    order = np.stack([k, (k + 1) % 3, (k + 2) % 3], axis=1)
    out = np.take_along_axis(turned, order[:, None, :], axis=2)
    out[:, :, 0] = n  # exactly (u was along ±n: the cyclic order keeps det = +1 ...)
    out[:, :, 2] = np.cross(out[:, :, 0], out[:, :, 1])  # ... up to the sign of column 0
    out[:, :, 1] = np.cross(out[:, :, 2], out[:, :, 0])
    return out


def aligned_frames(q, normals, isotropic: bool = False,
                   compiled: bool | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Lengths (N, 3) and rotations (N, 3, 3) of the closest frames to q with one direction
    (the rotation's first column) along ``normals`` (N, 3): the rotation about the normal
    and the lengths free (λ equal with ``isotropic``); ``compiled`` as in :func:`project`."""
    q = _rows(q)
    normals = np.asarray(normals, dtype=np.float64)
    if (normals.shape != (q.shape[0], 3) or not np.all(np.isfinite(normals))
            or np.any(np.linalg.norm(normals, axis=1) == 0)):
        raise ValueError(f"normals must be finite non-zero vectors of shape ({q.shape[0]}, 3)")
    if _use_compiled(compiled):
        return kernel.frames(q, normals, isotropic=isotropic)
    _, R = q_to_frames(q, isotropic=isotropic, compiled=False)
    R = _aligning_rotations(R, normals)
    R, lam = _refine(q, R, axes=(0,), isotropic=isotropic)
    return lam, R


def project_aligned(q, normals, isotropic: bool = False,
                    compiled: bool | None = None) -> np.ndarray:
    """The closest frames to q with one direction along ``normals`` (N, 3): the rotation
    about the normal and the lengths free (λ equal with ``isotropic``).

    Args:
        q: coefficients (N, 15).
        normals: a direction at each frame (N, 3), non-zero.
        isotropic: the lengths fitted with λ_1 = λ_2 = λ_3.
        compiled: as in :func:`project`.

    Returns:
        The projected coefficients (N, 15).
    """
    lam, R = aligned_frames(q, normals, isotropic=isotropic, compiled=compiled)
    return np.einsum("ni,nik->nk", lam, _branch_q(R))


def tangent_basis(q) -> np.ndarray:
    """Orthonormal bases (N, 15, 6) of the variety's tangent spaces at the frames closest
    to q: three rotations about the frame's axes, three lengths (fewer independent
    columns at degenerate frames, where QR leaves near-zero columns)."""
    lam, R = q_to_frames(q)
    B = _branch_q(R)
    J = np.concatenate([_rotation_columns(R, np.einsum("ni,nik->nk", lam, B), (0, 1, 2)),
                        B.transpose(0, 2, 1)], axis=2)
    Q, _ = np.linalg.qr(J)
    return Q
