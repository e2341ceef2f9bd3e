r"""The discrete energies of :mod:`ufl_frames.fem.energy` against independent truth.

Exact values come from hand calculations with explicit frames, never from the package:

* unit isotropic frames at angle t: u = û, v = v̂ and [u, v] = −(û·∇t) û − (v̂·∇t) v̂
  (note-checks §3, l1 = l2 = 1), so |[u, v]| = |∇t|. For t = φ + k r on the annulus
  0.5 ≤ r ≤ 1: |∇t|² = 1/r² + k², H = ½ ∫∫ (1/r² + k²) r dr dφ = π ln 2 + 3π k²/8.
* u = e_r, v = f(r) e_θ: [u, v] = (f' − f/r) e_θ (note-checks §4); f = r² gives [u, v] = r e_θ
  and H = ½ ∫∫ r³ dr dφ = π (1 − 1/16)/4 = 15π/64.
* integrable fields (H = 0): (g(r) e_r, c r e_θ), (c r e_r, c r e_θ), and the coordinate
  fields a(U) ∂_U, b(V) ∂_V of a conformal map z = F(w), w = U + iV (parabolic: F = w²/2,
  elliptic: F = cosh w). ∂_U = F'(w) and ∂_V = i F'(w) as complex numbers, so the frame
  has angle t = arg F'(w) (v̂ is û turned by +90°: positively oriented) and lengths
  a(U)|F'(w)|, b(V)|F'(w)|. [a ∂_U, b ∂_V] = a ∂_U b ∂_V − b ∂_V a ∂_U = 0 because
  ∂_U, ∂_V commute and a, b depend on their own coordinate only. A finite-difference
  test below checks this derivation on the Cartesian vector fields.

The discrete H is assembled from P1-interpolated q, so it converges at O(h²) to these
values (the quadrature of the degree-2 integrand is exact, the polygonal annulus has an
O(h²) area error). Rates are printed (``pytest -s``).
"""

import math

import dolfinx
import dolfinx.fem as fem
import numpy as np
import pytest
import ufl
from mpi4py import MPI

from ufl_frames.fem import energy
from ufl_frames.frames2d import odeco
from ufl_frames.frames2d.bracket import BRACKET_TENSOR

# --- frame fields f(x) -> (l1, l2, t), x of shape (3, M) --------------------------


def _polar(x):
    return np.hypot(x[0], x[1]), np.arctan2(x[1], x[0])


def isotropic_spiral(k):
    """Unit isotropic frames at angle φ + k r (|[u, v]| = |∇t|)."""

    def f(x):
        r, phi = _polar(x)
        return 1.0, 1.0, phi + k * r

    return f


def radial_unit_tangential_square(x):
    """u = e_r, v = r² e_θ: [u, v] = r e_θ."""
    r, phi = _polar(x)
    return 1.0, r**2, phi


def annulus_integrable_isotropic(x, c=0.8):
    """(c r e_r, c r e_θ): the log-polar map, H = 0."""
    r, phi = _polar(x)
    return c * r, c * r, phi


def annulus_integrable(x, c=0.8):
    """(g(r) e_r, c r e_θ) with g = 1 + r² (radial branch free), H = 0."""
    r, phi = _polar(x)
    return 1.0 + r**2, c * r, phi


def conformal_coordinate_frames(F_inv, dF, a, b):
    """Frames (a(U) ∂_U, b(V) ∂_V) of the coordinates w = U + iV = F⁻¹(z)."""

    def f(x):
        w = F_inv(x[0] + 1j * x[1])
        d = dF(w)
        return a(w.real) * np.abs(d), b(w.imag) * np.abs(d), np.angle(d)

    return f


PARABOLIC = conformal_coordinate_frames(
    lambda z: np.sqrt(2 * z), lambda w: w, lambda U: 1 + 0.5 * U**2, lambda V: 2 + np.sin(V)
)
ELLIPTIC = conformal_coordinate_frames(
    np.arccosh, np.sinh, lambda U: np.exp(U / 2), lambda V: 1.5 + np.cos(V)
)
#: Rectangle [0.5, 1.5] x [0.25, 1.25]: away from the branch cuts of √(2z) and arccosh z.
RECTANGLE = [[0.5, 0.25], [1.5, 1.25]]

ANNULUS_SIZES = (0.1, 0.05, 0.025)
RECTANGLE_CELLS = (8, 16, 32)


# --- helpers ----------------------------------------------------------------------


def rectangle_mesh(n, comm=MPI.COMM_WORLD):
    return dolfinx.mesh.create_rectangle(comm, RECTANGLE, [n, n], dolfinx.mesh.CellType.triangle)


def num_cells(mesh):
    return mesh.topology.index_map(mesh.topology.dim).size_global


def observed_rates(sizes, errors):
    """log(e_i / e_{i+1}) / log(h_i / h_{i+1}) for consecutive refinements."""
    return [
        math.log(errors[i] / errors[i + 1]) / math.log(sizes[i] / sizes[i + 1])
        for i in range(len(errors) - 1)
    ]


def h_effective(mesh):
    """√(1/cells): proportional to the mean edge length on quasi-uniform meshes."""
    return 1.0 / math.sqrt(num_cells(mesh))


def energy_study(meshes, f, exact=0.0):
    """(h, |H_h − exact|) on each mesh for the interpolated frames ``f``."""
    hs, errors = [], []
    for mesh in meshes:
        q = energy.interpolate_frames(energy.frame_space(mesh), f)
        hs.append(h_effective(mesh))
        errors.append(abs(energy.integrability_energy(q) - exact))
    return hs, errors


def report(label, hs, errors):
    rates = observed_rates(hs, errors)
    if MPI.COMM_WORLD.rank == 0:
        print(f"\n{label}: |H_h - H| = {['%.3e' % e for e in errors]}, rates {np.round(rates, 3)}")
    return rates


def random_direction(V, rng):
    """Random Function in V (owned entries random, ghosts updated)."""
    d = fem.Function(V)
    n = V.dofmap.index_map.size_local * V.dofmap.index_map_bs
    d.x.array[:n] = rng.standard_normal(n)
    d.x.scatter_forward()
    return d


def owned_dot(a, b, V):
    n = V.dofmap.index_map.size_local * V.dofmap.index_map_bs
    return V.mesh.comm.allreduce(float(np.dot(a[:n], b[:n])), op=MPI.SUM)


# --- (a) exact values -------------------------------------------------------------


@pytest.fixture(scope="module")
def annulus_meshes(annulus_mesh):
    return [annulus_mesh(h, MPI.COMM_WORLD) for h in ANNULUS_SIZES]


@pytest.mark.parametrize("k", [0.0, 0.7])
def test_isotropic_spiral_converges_to_exact_energy(annulus_meshes, k):
    exact = math.pi * math.log(2) + 3 * math.pi * k**2 / 8
    hs, errors = energy_study(annulus_meshes, isotropic_spiral(k), exact)
    rates = report(f"spiral t = phi + {k} r, H = {exact:.6f}", hs, errors)
    assert errors[-1] < 0.01 * exact
    assert min(rates) >= 1.8


def test_length_gradients_converge_to_exact_energy(annulus_meshes):
    exact = 15 * math.pi / 64
    hs, errors = energy_study(annulus_meshes, radial_unit_tangential_square, exact)
    rates = report(f"(e_r, r^2 e_theta), H = {exact:.6f}", hs, errors)
    assert errors[-1] < 0.01 * exact
    assert min(rates) >= 1.8


# --- (b) integrable fields: H_h -> 0 ----------------------------------------------


def _fd_bracket(f, x, eps=1e-5):
    """[u, v] = (u·∇)v − (v·∇)u of the Cartesian vector fields of ``f``, by central differences."""

    def fields(x):
        l1, l2, t = f(x)
        u = np.array([l1 * np.cos(t), l1 * np.sin(t)])
        v = np.array([-l2 * np.sin(t), l2 * np.cos(t)])
        return u, v

    u, v = fields(x)
    jac_u, jac_v = np.zeros((2, 2, x.shape[1])), np.zeros((2, 2, x.shape[1]))
    for k in range(2):
        e = np.zeros_like(x)
        e[k] = eps
        (up, vp), (um, vm) = fields(x + e), fields(x - e)
        jac_u[:, k], jac_v[:, k] = (up - um) / (2 * eps), (vp - vm) / (2 * eps)
    bracket = np.einsum("ikn,kn->in", jac_v, u) - np.einsum("ikn,kn->in", jac_u, v)
    return bracket, np.linalg.norm(u, axis=0) * np.linalg.norm(v, axis=0)


@pytest.mark.serial
@pytest.mark.parametrize(
    "f, lo, hi",
    [
        (annulus_integrable, (-1, -1), (1, 1)),
        (annulus_integrable_isotropic, (-1, -1), (1, 1)),
        (PARABOLIC, RECTANGLE[0], RECTANGLE[1]),
        (ELLIPTIC, RECTANGLE[0], RECTANGLE[1]),
    ],
)
def test_test_fields_are_integrable(f, lo, hi):
    """Check of the hand derivations: the Cartesian bracket of each test field vanishes."""
    rng = np.random.default_rng(0)
    n = 200
    x = np.vstack([rng.uniform(lo[0], hi[0], n), rng.uniform(lo[1], hi[1], n), np.zeros(n)])
    x = x[:, np.hypot(x[0], x[1]) > 0.4]
    bracket, scale = _fd_bracket(f, x)
    assert np.max(np.linalg.norm(bracket, axis=0) / scale) < 1e-7
    # ... and a non-integrable field is seen as such by the same check.
    bracket, scale = _fd_bracket(radial_unit_tangential_square, x)
    assert np.max(np.linalg.norm(bracket, axis=0) / scale) > 0.1


@pytest.mark.parametrize(
    "name, f",
    [
        ("(g e_r, c r e_theta)", annulus_integrable),
        ("(c r e_r, c r e_theta)", annulus_integrable_isotropic),
    ],
)
def test_annulus_integrable_fields_energy_vanishes(annulus_meshes, name, f):
    hs, energies = energy_study(annulus_meshes, f)
    rates = report(f"annulus {name}, H = 0", hs, energies)
    assert energies[-1] < 1e-3
    assert min(rates) >= 1.8


@pytest.mark.parametrize("name, f", [("parabolic", PARABOLIC), ("elliptic", ELLIPTIC)])
def test_coordinate_frames_energy_vanishes(name, f):
    meshes = [rectangle_mesh(n) for n in RECTANGLE_CELLS]
    hs, energies = energy_study(meshes, f)
    rates = report(f"{name} coordinate frames on a rectangle, H = 0", hs, energies)
    assert energies[-1] < 0.01
    assert min(rates) >= 1.8


# --- (c) gradients against finite differences -------------------------------------


@pytest.mark.parametrize("which", ["H", "E"])
def test_gradient_matches_finite_differences(annulus_meshes, which):
    mesh = annulus_meshes[0]
    V = energy.frame_space(mesh)
    rng = np.random.default_rng(1 + MPI.COMM_WORLD.rank)
    # A generic field: integrable frames, off the variety by a random perturbation.
    q = energy.interpolate_frames(V, annulus_integrable)
    q.x.array[:] += 0.1 * random_direction(V, rng).x.array
    form = {"H": energy.integrability_energy_form, "E": energy.dirichlet_energy_form}[which](q)
    value = fem.form(form)
    b = fem.assemble_vector(fem.form(energy.gradient_form(form, q)))
    b.scatter_reverse(dolfinx.la.InsertMode.add)

    q0 = q.x.array.copy()
    eps = 1e-5
    for _ in range(3):
        d = random_direction(V, rng)
        q.x.array[:] = q0 + eps * d.x.array
        plus = energy.assemble_energy(value)
        q.x.array[:] = q0 - eps * d.x.array
        minus = energy.assemble_energy(value)
        q.x.array[:] = q0
        fd = (plus - minus) / (2 * eps)
        exact = owned_dot(b.array, d.x.array, V)
        rel = abs(fd - exact) / abs(exact)
        if MPI.COMM_WORLD.rank == 0:
            print(f"\n{which}: d{which}[d] = {exact:.10e}, FD {fd:.10e}, relative error {rel:.1e}")
        assert rel < 1e-6


# --- (d) the choice of C ----------------------------------------------------------


def bracket_with_null_term(q, alpha):
    """[u, v] of eq. (10) with C + ΔC, ΔC_ijkl = Σ_mk α_imk (A_m)_jl (note-checks §3 null space).

    ΔC contributes Σ α_imk q^T A_m ∂_k q to component i: zero where q is on the variety
    (at the vertices), not inside the P1 elements. ``alpha`` is a Constant of shape (2, 3, 2).
    """
    grad_q = ufl.grad(q)
    extra = []
    for i in range(2):
        terms = []
        for m in range(3):
            A = ufl.as_matrix(odeco.VARIETY_MATRICES[m].tolist())
            for k in range(2):
                terms.append(alpha[i, m, k] * ufl.dot(q, ufl.dot(A, grad_q[:, k])))
        extra.append(sum(terms[1:], terms[0]))
    return energy.lie_bracket(q) + ufl.as_vector(extra)


def null_element(alpha):
    return np.einsum("imk,mjl->ijkl", alpha, odeco.VARIETY_MATRICES)


def test_minimum_norm_bracket_is_orthogonal_to_the_null_space():
    """BRACKET_TENSOR has no component along the 12 null-space directions (minimum norm)."""
    for index in np.ndindex(2, 3, 2):
        alpha = np.zeros((2, 3, 2))
        alpha[index] = 1.0
        D = null_element(alpha)
        assert abs(np.sum(BRACKET_TENSOR * D)) < 1e-12 * np.linalg.norm(D)


def random_null_alphas(count, seed=7):
    """``count`` random coefficient arrays α (2, 3, 2) with ‖ΔC‖_F = ‖C‖_F / 2."""
    rng = np.random.default_rng(seed)
    scale = 0.5 * np.linalg.norm(BRACKET_TENSOR)
    alphas = [rng.standard_normal((2, 3, 2)) for _ in range(count)]
    return [a * scale / np.linalg.norm(null_element(a)) for a in alphas]


def energy_with_null_term(q):
    """(compiled H with C + ΔC(α), the Constant α) for the frame Function q."""
    alpha = fem.Constant(q.function_space.mesh, np.zeros((2, 3, 2)))
    bracket = bracket_with_null_term(q, alpha)
    return fem.form(0.5 * ufl.inner(bracket, bracket) * ufl.dx), alpha


ANNULUS_INTEGRABLE = [
    ("(g e_r, c r e_theta)", annulus_integrable),
    ("(c r e_r, c r e_theta)", annulus_integrable_isotropic),
]


@pytest.mark.parametrize("name, f", ANNULUS_INTEGRABLE)
def test_every_bracket_tensor_agrees_in_the_limit(annulus_meshes, name, f):
    """note-checks §3: C + ΔC, ΔC in the null space, gives another H_h with the same limit H = 0."""
    (alpha_value,) = random_null_alphas(1)
    hs, energies = [], []
    for mesh in annulus_meshes:
        q = energy.interpolate_frames(energy.frame_space(mesh), f)
        H, alpha = energy_with_null_term(q)
        assert energy.assemble_energy(H) == pytest.approx(energy.integrability_energy(q), rel=1e-12)
        alpha.value[:] = alpha_value
        hs.append(h_effective(mesh))
        energies.append(energy.assemble_energy(H))
    rates = report(f"annulus {name} with C + null element, H = 0", hs, energies)
    assert min(rates) >= 1.8


@pytest.mark.parametrize("name, f", ANNULUS_INTEGRABLE)
def test_minimum_norm_bracket_gives_smaller_residual(annulus_meshes, name, f):
    """note-checks §3: a typical null-space element added to the minimum-norm C raises the residual.

    Null-space elements ΔC of Frobenius norm ‖C‖/2 in random directions (fixed seed) on the
    integrable annulus field at h = 0.05; prints the residuals. Measured: the minimum-norm
    residual is below the median of the perturbed ones, but not below all of them
    ((g e_r, c r e_θ): 2.06e-3 against 5.74e-3, 4.59e-3, 3.47e-3, 1.35e-3), and a null
    element fitted to these fields lowers it 1.6–7x: minimum norm is canonical, not optimal.
    """
    mesh = annulus_meshes[ANNULUS_SIZES.index(0.05)]
    q = energy.interpolate_frames(energy.frame_space(mesh), f)
    H, alpha = energy_with_null_term(q)
    H_min = energy.assemble_energy(H)
    perturbed = []
    for value in random_null_alphas(4):
        alpha.value[:] = value
        perturbed.append(energy.assemble_energy(H))
    if MPI.COMM_WORLD.rank == 0:
        print(
            f"\n{name}, h = 0.05: residual H with minimum-norm C {H_min:.3e}; "
            f"with C + null element (|dC| = |C|/2): {['%.3e' % p for p in perturbed]}"
        )
    assert np.median(perturbed) > H_min


# --- (e) input checks -------------------------------------------------------------


def test_frame_space_rejects_non_planar_meshes():
    comm = MPI.COMM_WORLD
    with pytest.raises(ValueError):
        energy.frame_space(dolfinx.mesh.create_unit_cube(comm, 1, 1, 1))
    with pytest.raises(ValueError):
        energy.frame_space(dolfinx.mesh.create_unit_interval(comm, 4))
    V = energy.frame_space(dolfinx.mesh.create_unit_square(comm, 2, 2))
    assert V.dofmap.index_map_bs == 5


def test_forms_refuse_what_is_not_a_p1_frame_field():
    """Tetrahedra, quadrilaterals, P2 geometry, or a q that is not P1 with 5 components:
    one clear ValueError (before: tets gave a number, a DG0 or P1x3 q an IndexError)."""
    import dolfinx.fem as fem
    import dolfinx.mesh

    comm = MPI.COMM_WORLD
    tets = dolfinx.mesh.create_unit_cube(comm, 2, 2, 2)
    with pytest.raises(ValueError, match="planar 2D"):
        energy.frame_space(tets)
    with pytest.raises(ValueError, match="planar 2D"):
        energy.integrability_energy(fem.Function(fem.functionspace(tets, ("Lagrange", 1, (5,)))))
    quads = dolfinx.mesh.create_unit_square(comm, 2, 2, dolfinx.mesh.CellType.quadrilateral)
    with pytest.raises(ValueError, match="triangles"):
        energy.frame_space(quads)
    square = dolfinx.mesh.create_unit_square(comm, 2, 2)
    for element in (("DG", 0, (5,)), ("Lagrange", 1, (3,)), ("Lagrange", 1)):
        q = fem.Function(fem.functionspace(square, element))
        with pytest.raises(ValueError, match="continuous P1 function with 5 components"):
            energy.integrability_energy(q)
    with pytest.raises(ValueError, match="dolfinx Function"):
        energy.lie_bracket(np.zeros(5))
