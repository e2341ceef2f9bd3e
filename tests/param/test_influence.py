"""SeamlessSystem.influence (the fold repair's ranking) in bounded memory.

Truth: the dense formula Σ_rows |(N⁻¹ T_rowsᵀ)ᵀ Fᵀ G⁻¹| with N⁻¹ applied to the whole
identity (small mesh); the blocked back-substitutions, from either side, must give it to
rounding, with fewer and with more functionals than rows, and with blocks smaller than
either.
"""

import numpy as np
import pytest
import scipy.sparse as sp
from planar_meshes import annulus, annulus_field

from ufl_frames.param import cut, seamless


@pytest.mark.parametrize("functionals", [5, 60])
def test_influence_is_the_dense_formula(functionals, monkeypatch):
    x, cells = annulus(4, 24)
    system = seamless.SeamlessSystem(cut.cut_mesh(x, cells, annulus_field(x)), 3.0)
    free = system.T.shape[1]
    rng = np.random.default_rng(1)
    F = sp.random(functionals, free, density=0.05, random_state=rng, format="csr")
    F = F + sp.eye(functionals, free, format="csr")  # full row rank
    N_inv = system.lu.solve(np.eye(free))
    G = F @ N_inv @ F.T
    triangles = np.arange(0, system.mesh.cells.shape[0], 24)  # 6 rows each: 48
    rows = (2 * system.mesh.corners[triangles].reshape(-1, 1) + np.arange(2)).ravel()
    Z = N_inv @ system.T[rows].T.toarray()
    expected = np.abs(np.linalg.solve(G, F @ Z).T).sum(axis=0)
    assert (rows.size > functionals) == (functionals == 5)  # both branches
    monkeypatch.setattr(seamless, "INFLUENCE_BLOCK", 16)
    found = system.influence(F, G, triangles)
    np.testing.assert_allclose(found, expected, rtol=1e-8, atol=1e-12 * expected.max())
