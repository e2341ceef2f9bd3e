# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: light
#       format_version: '1.5'
#       jupytext_version: 1.16.0
# ---

# # Integrable frame fields on the annulus
#
# This demo computes integrable 2D frame fields on the annulus
# $\Omega = \{0.5 \le |x| \le 1\}$, where the integrable fields are known in closed
# form, and checks the computed fields against them. It follows the research note
# *A tensor formulation for integrable frame fields* (cited below as "the note")
# and reproduces its Fig. 1 (final frames coloured by length) and Fig. 2 (energies
# against the iteration) for the annulus. It shows how to
#
# - represent a frame field by the coefficients $q$ of Odeco tensors in P1,
# - build a smooth boundary-aligned initial field with an MBO scheme,
# - minimise the integrability energy $H(q)$ over frame fields with PETSc TAO,
#   isotropic (both branches of equal length) and non-isotropic,
# - check the converged reason of TAO, and compare the default Riemannian
#   Gauss–Newton method with the note's projected gradient method.
#
# Run it with `python demo_annulus.py` or `mpirun -n 2 python demo_annulus.py`;
# PETSc options on the command line act on the two main solves, e.g.
# `-tao_monitor` or `-tao_type lmvm`, and with the prefix `pg_` on the projected
# gradient run (`-pg_tao_max_it 500`). Everything is written to `out_demo_annulus/`
# in the current directory. With the environment variable `CI` set, the mesh is
# coarse and the iterations few (a smoke test).
#
# ## Frames as Odeco tensors
#
# A frame at a point is a pair of orthogonal branches $u = l_1 \hat u$,
# $v = l_2 \hat v$, with $\hat u = (\cos t, \sin t)$, $\hat v = (-\sin t, \cos t)$ and
# lengths $l_1, l_2 > 0$. The frame is the same object after relabelling
# ($u \to v \to -u$) or flipping a branch, so $(l_1, l_2, t)$ are not good unknowns.
# The fourth-order tensor (note eq. 1)
#
# $$
# T = l_1\, \hat u^{\otimes 4} + l_2\, \hat v^{\otimes 4}
# $$
#
# is invariant under these symmetries. Its polynomial on the unit circle
# $x = (\cos\varphi, \sin\varphi)$ is, with $s = l_1 + l_2$ and $d = l_1 - l_2$,
#
# $$
# p_T(\varphi) = T_{ijkl}\, x_i x_j x_k x_l
#   = \tfrac{3s}{8} + \tfrac{d}{2} \cos 2(\varphi - t) + \tfrac{s}{8} \cos 4(\varphi - t),
# $$
#
# and its coefficients in the circular harmonics
# $Y = (1/\sqrt2, \cos 2\varphi, \sin 2\varphi, \cos 4\varphi, \sin 4\varphi)$ (note eq. 2)
# are the five numbers
#
# $$
# q = \left(\tfrac{3\sqrt2}{8} s,\ \tfrac d2 \cos 2t,\ \tfrac d2 \sin 2t,\
#           \tfrac s8 \cos 4t,\ \tfrac s8 \sin 4t\right).
# $$
#
# Not every $q \in \mathbb R^5$ is a frame: frames form the Odeco variety
# $\mathcal F$, three quadratic equations $q^\top A_m q = 0$ (note eq. 3). With
# $a = q_0/\sqrt2$, $B = q_1 + i q_2$, $C = q_3 + i q_4$ they read $a^2 = 9|C|^2$ and
# $aB = 3\bar B C$. The direction is read from $\arg C = 4t$, the lengths from $a$ and
# $|B|$; isotropic frames ($l_1 = l_2$, crosses) are those with $B = 0$.
#
# ## Integrability
#
# A frame field is integrable — locally the gradient of a parametrisation, the
# property quad meshing needs — when its branches commute: the Lie bracket
# $[u, v] = \nabla_u v - \nabla_v u$ vanishes. The note's key result (eq. 10) is that
# the bracket is a bilinear function of $q$ and $\nabla q$ alone,
#
# $$
# [u, v]_i = C_{ijkl}\, q_l\, \frac{\partial q_j}{\partial x_k},
# $$
#
# with a constant tensor $C$ (derived symbolically; `ufl_frames.frames2d.bracket`). The
# integrability energy (note eq. 11) is
#
# $$
# H(q) = \frac12 \int_\Omega |[u, v]|^2 \, \mathrm dx ,
# $$
#
# and we seek a frame field with $H = 0$, aligned with the boundary normal on
# $\partial\Omega$. The Dirichlet energy $E(q) = \frac12 \int_\Omega |\nabla q|^2\,\mathrm dx$
# measures its smoothness.
#
# ## Discretisation
#
# $q_h = \sum_v q_v \varphi_v$ with $\varphi_v$ the P1 hat functions of a triangle mesh
# and $q_v \in \mathbb R^5$ at the vertices (note §3). On each triangle $q_h$ is linear
# and $\nabla q_h$ constant, so $[u, v]$ is linear and the integrand of $H$ a quadratic:
# the UFL form `energy.integrability_energy_form(q)` is integrated exactly. The
# discrete problem is
#
# $$
# \min_{q_h \in \mathcal M_h} H(q_h), \qquad
# \mathcal M_h = \Big\{ q_v \in \mathcal F\ \forall v,\ \ \hat u(q_v) \parallel n
#   \text{ on } \partial\Omega,\ \ \textstyle\sum_v m_v |q_v|^2 = \text{const} \Big\},
# $$
#
# with $m_v$ the lumped mass of vertex $v$ (and $d = 0$ at every vertex in the
# isotropic case). The fixed norm stops the trivial minimiser $q = 0$ ($H$ is quartic
# in $q$). The note minimises by projected gradient steps: (1) $\Delta q = -\nabla H$,
# (2) projection of $\Delta q$ on the tangent space of $\mathcal F$, (3) update, (4)
# projection back onto $\mathcal F$ (orientation fixed on the boundary), (5) uniform
# rescaling. That is a Riemannian gradient descent on $\mathcal M_h$; TAO runs it
# with `-tao_type bncg`. The default here, `-tao_type nls`, is a Riemannian
# Gauss–Newton method: with $J$ the linearisation of $q \mapsto [u, v]$ (from
# `ufl.derivative`), $P$ the tangent projector of $\mathcal M_h$ and $K$, $M$ the P1
# stiffness and mass matrices, each step solves
#
# $$
# P \big(J^\top J + \lambda (K + M)\big) P\, \delta q = -P\, \nabla H(q_h),
# \qquad q_h \leftarrow R(q_h + \alpha\, \delta q),
# $$
#
# where $R$ is steps (4)–(5), $\alpha$ comes from a line search, and the $H^1$ damping
# $\lambda$ shrinks with the gradient (`ufl_frames.solvers.GaussNewtonModel`). For
# isotropic frames the default replaces $J^\top J$ by the exact Riemannian Hessian:
# $\nabla^2 H$ (a second `ufl.derivative`) plus the curvature of the constraints — the
# second fundamental form of the Odeco variety paired with the normal part of
# $\nabla H$, and $-4H/\rho^2$ from the fixed norm $\rho$ — which makes it Newton's
# method on $\mathcal M_h$. For non-isotropic frames $\nabla^2 H$ is indefinite far
# from a minimum: the default there starts with $J^\top J$ and switches to the exact
# Hessian once $|g| \le 10^{-3} |g_0|$, where Gauss–Newton would converge only linearly
# (`-frames_hessian hybrid|exact|gauss_newton` to choose).
#
# ## The annulus and its integrable fields
#
# In polar coordinates take $u = g(r)\, e_r$ and $v = f(r)\, e_\theta$. Since
# $e_\theta = r^{-1} \partial_\theta$,
#
# $$
# [u, v] = g\, \partial_r\!\Big(\frac f r\Big) \partial_\theta
#        = g\, \Big(f' - \frac f r\Big) e_\theta ,
# $$
#
# which vanishes if and only if $f = c\, r$, for any radial profile $g$. The integrable
# axisymmetric fields are therefore
#
# $$
# (u, v) = (g(r)\, e_r,\ c\, r\, e_\theta) \quad \text{(non-isotropic)}, \qquad
# (u, v) = (c\, r\, e_r,\ c\, r\, e_\theta) \quad \text{(isotropic, the log-polar map)}.
# $$
#
# (The note's eq. 12 swaps the roles of the two branches: the *tangential* length is
# the one forced to grow linearly with $r$.) The demo checks that the computed
# isotropic lengths, and the computed tangential lengths of the non-isotropic field,
# are proportional to $r$.
#
# ## Implementation
#
# PETSc must read the command line before DOLFINx is imported, so the first
# statements are:

# +
import sys

from ufl_frames.bootstrap import init_petsc

init_petsc(sys.argv)

import os  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from mpi4py import MPI  # noqa: E402

from ufl_frames import output, solvers  # noqa: E402
from ufl_frames.fem import energy  # noqa: E402
from ufl_frames.fem.constraints import frame_constraints  # noqa: E402
from ufl_frames.fem.manifold import FrameManifold  # noqa: E402
from ufl_frames.frames2d import odeco, singularities  # noqa: E402
from ufl_frames.mesh import build  # noqa: E402
from ufl_frames.solvers import mbo  # noqa: E402

comm = MPI.COMM_WORLD
CI = os.environ.get("CI", "").strip().lower() not in ("", "0", "false")
out = Path("out_demo_annulus")
if comm.rank == 0:
    out.mkdir(parents=True, exist_ok=True)
comm.Barrier()


def say(*args):
    """print on rank 0 only."""
    if comm.rank == 0:
        print(*args, flush=True)


# -

# The parameters: mesh size and iteration limits, much smaller when `CI` is set.
# `-tao_max_it` on the command line wins over `max_it`.

mesh_size = 0.12 if CI else 0.05
max_it = 6 if CI else 200
pg_max_it = 10 if CI else 200  # projected gradient iterations (fixed count)

# ### Mesh and initial field
#
# `ufl_frames.mesh.build` meshes the annulus with Gmsh (on rank 0) and distributes it; it
# returns a `Domain` (the mesh, its boundary curves and corners, the Euler
# characteristic). The frame field lives in $[P_1]^5$.

mesh = build(comm, "annulus", mesh_size).mesh
V = energy.frame_space(mesh)
num_vertices = mesh.topology.index_map(0).size_global
say(f"annulus: {num_vertices} vertices, "
    f"{mesh.topology.index_map(2).size_global} triangles, {comm.size} process(es)")

# The initial field is the MBO field (note §3, "Initial condition"): diffusion of
# the five coefficients with the boundary frames fixed, alternating with
# projection onto unit crosses, for decreasing diffusion times. On the annulus it
# is the cross field aligned with $e_r$ everywhere, with unit lengths — smooth, but
# not integrable ($f = 1$ is not $c\,r$).

q0 = mbo.mbo_frame_field(
    V, monitor=lambda level, tau, change: say(
        f"  MBO level {level}: sqrt(tau) = {np.sqrt(tau):.3g}, max change {change:.2e}")
)
found = singularities.locate_singularities(q0)
say(f"MBO field: H = {energy.integrability_energy(q0):.4e}, "
    f"E = {energy.dirichlet_energy(q0):.4e}, singularities: {output.describe_singularities(found)}")
output.plot_frames(out / "frames_initial.png", q0, title="Annulus: MBO initial field",
               singularities=found)

# ### The exact isotropic solution on this mesh
#
# For reference, the interpolant of the exact isotropic field $(r e_r, r e_\theta)$,
# rescaled to the norm the solver keeps, has a small but nonzero discrete energy:
# the P1 discretisation error, which falls as $O(h^2)$. A computed field cannot be
# expected to do much better.

# +
q_exact = energy.interpolate_frames(
    V, lambda x: (np.hypot(x[0], x[1]), np.hypot(x[0], x[1]), np.arctan2(x[1], x[0]))
)
cone = FrameManifold(frame_constraints(V, isotropic=True))
on_sphere = FrameManifold(cone.constraints, radius2=cone.norm2(q0.x.array.reshape(-1, 5)))
q_exact.x.array[:] = on_sphere.normalise(q_exact.x.array.reshape(-1, 5)).ravel()
H_exact = energy.integrability_energy(q_exact)
say(f"interpolated exact isotropic field: H = {H_exact:.4e}")


# -

# ### Solving
#
# `solvers.frame_problem` compiles the forms, finds the constraints (boundary
# vertices, and the vertices of singular triangles, of which the annulus has none)
# and retracts $q$ onto $\mathcal M_h$; `solvers.solve` runs TAO and leaves the result
# in `problem.q`. TAO does not raise when it fails: the converged reason is checked
# explicitly. A run cut short by the iteration limit in CI mode is accepted.


def check_converged(result, what):
    reason = result.converged_reason
    say(f"{what}: {reason} after {result.iterations} iterations "
        f"({result.wall_time_s:.2f} s), H {result.H_initial:.4e} -> {result.H_final:.4e}")
    if reason.startswith("CONVERGED"):
        return
    if reason == "DIVERGED_MAXITS" and CI:
        say(f"  (iteration limit reached: expected with CI={os.environ['CI']})")
        return
    raise RuntimeError(f"{what}: TAO did not converge ({reason})")


def make_monitor(times, every=5):
    """Monitor printing every ``every``-th iteration and recording its time in ``times``."""
    start = time.perf_counter()

    def monitor(entry):
        times.append(time.perf_counter() - start)
        if entry["it"] % every == 0:
            say(f"  it {entry['it']:3d}  H {entry['H']:.4e}  E {entry['E']:.4e}  "
                f"|grad H| {entry['gnorm']:.2e}")

    return monitor


# The isotropic solve starts from a copy of the MBO field:

q_iso = q0.copy()
problem_iso = solvers.frame_problem(q_iso, isotropic=True)
times_iso = []
result_iso = solvers.solve(problem_iso, max_it=max_it, monitor=make_monitor(times_iso))
check_converged(result_iso, "isotropic")

# and the non-isotropic one from another copy:

q_aniso = q0.copy()
problem_aniso = solvers.frame_problem(q_aniso, isotropic=False)
times_aniso = []
result_aniso = solvers.solve(problem_aniso, max_it=max_it,
                            monitor=make_monitor(times_aniso))
check_converged(result_aniso, "non-isotropic")

# ### Check against the analytic solution
#
# At every vertex we read the frame from $q_v$ (`odeco.branch_vectors`), sort its
# branches into the radial and the tangential one, measure how far the cross is
# turned away from $e_r$, and fit the lengths linearly in $r$: $l \approx a r + b$.
# Proportional to $r$ means $R^2 \approx 1$ and an intercept $b$ small against the
# lengths. The vertices of all processes are gathered.

# +
def frame_data(q):
    """(r, radial length, tangential length, turn from e_r in degrees) at all vertices."""
    owned = q.function_space.dofmap.index_map.size_local
    x = q.function_space.tabulate_dof_coordinates()[:owned, :2]
    rows = q.x.array.reshape(-1, 5)[:owned]
    u, v = odeco.branch_vectors(rows)
    _, t = odeco.q_to_frames(rows)
    r = np.linalg.norm(x, axis=1)
    e_r = x / r[:, None]
    u_radial = np.abs(np.einsum("ni,ni->n", u, e_r)) >= np.abs(np.einsum("ni,ni->n", v, e_r))
    lu, lv = np.linalg.norm(u, axis=1), np.linalg.norm(v, axis=1)
    radial, tangential = np.where(u_radial, lu, lv), np.where(u_radial, lv, lu)
    turn4 = 4 * (t - np.arctan2(x[:, 1], x[:, 0]))  # a cross repeats every 90 degrees
    turn = np.degrees(np.arctan2(np.sin(turn4), np.cos(turn4)) / 4)
    data = np.stack([r, radial, tangential, turn], axis=1)
    return np.concatenate(comm.allgather(data)).T


def linear_fit(r, length):
    """Slope a, intercept b and R² of the least-squares fit length ≈ a r + b."""
    a, b = np.polyfit(r, length, 1)
    residual = length - (a * r + b)
    r2 = 1.0 - residual @ residual / np.sum((length - length.mean()) ** 2)
    return a, b, r2


r, radial_iso, tangential_iso, turn_iso = frame_data(problem_iso.q)
a_iso, b_iso, r2_iso = linear_fit(r, 0.5 * (radial_iso + tangential_iso))
r, radial_aniso, tangential_aniso, turn_aniso = frame_data(problem_aniso.q)
a_tan, b_tan, r2_tan = linear_fit(r, tangential_aniso)
say(f"isotropic:     l   = {a_iso:.4f} r {b_iso:+.4f}   R^2 = {r2_iso:.6f}, "
    f"b / l(1) = {b_iso / (a_iso + b_iso):+.2e}; "
    f"turn from e_r: max {np.abs(turn_iso).max():.2f} deg")
say(f"non-isotropic: l_t = {a_tan:.4f} r {b_tan:+.4f}   R^2 = {r2_tan:.6f}, "
    f"b / l_t(1) = {b_tan / (a_tan + b_tan):+.2e}; "
    f"turn from e_r: max {np.abs(turn_aniso).max():.2f} deg, "
    f"rms {np.sqrt(np.mean(turn_aniso**2)):.2f} deg")
say(f"non-isotropic: radial length in [{radial_aniso.min():.3f}, {radial_aniso.max():.3f}]")
# -

# The isotropic field is the log-polar one: aligned with $e_r$ and $l \propto r$ to
# plotting accuracy. The non-isotropic field is integrable to the same accuracy
# (its $H$ is even lower) but only close to the axisymmetric family: the crosses
# turn by up to about a degree away from $e_r$, and $l_\theta$ scatters by a few
# per cent around $c\,r$. Two reasons, which this demo does not separate. The
# axisymmetric fields are not the only integrable ones: any orthogonal coordinate
# net $(U, V)$ in which both circles are lines $U =$ const gives commuting fields
# $(\partial_U, \partial_V)$ aligned with the boundary, whose directions need not be
# radial inside, and with free lengths the solver has that whole family to choose
# from. And at this level $H$ is comparable with the discretisation error (the
# interpolated exact field above), so the discrete energy does not tell these
# fields apart from fields a discretisation error away. The checks below are
# therefore strict for the isotropic field and loose for the non-isotropic one, and
# enforced in the full run only (a CI run stops after a few iterations).

if not CI:
    if not (r2_iso > 0.999 and abs(b_iso) < 0.02 * (a_iso + b_iso)):
        raise RuntimeError("isotropic annulus: the lengths are not proportional to r")
    if not (r2_tan > 0.95 and abs(b_tan) < 0.05 * (a_tan + b_tan)):
        raise RuntimeError("non-isotropic annulus: l_theta is not proportional to r")

# ### The note's projected gradient method
#
# The same non-isotropic problem, from the MBO field, with the note's method: TAO's
# `bncg` with the plain gradient direction (`-pg_tao_bncg_type gd`) and an Armijo
# line search — set as defaults by `solvers.solve` for `bncg`. The options prefix
# `pg_` keeps it apart from the command-line options of the main solves. It runs a
# fixed number of iterations, so its converged reason is normally
# `DIVERGED_MAXITS`; any other failure is an error.

q_pg = q0.copy()
problem_pg = solvers.frame_problem(q_pg, isotropic=False)
times_pg = []
result_pg = solvers.solve(problem_pg, max_it=pg_max_it, options_prefix="pg_",
                         defaults={"tao_type": "bncg"}, monitor=make_monitor(times_pg, 50))
say(f"projected gradient: {result_pg.converged_reason} after {result_pg.iterations} "
    f"iterations ({result_pg.wall_time_s:.2f} s): H = {result_pg.H_final:.4e}")
say(f"Gauss-Newton:       {result_aniso.converged_reason} after {result_aniso.iterations} "
    f"iterations ({result_aniso.wall_time_s:.2f} s): H = {result_aniso.H_final:.4e}")
if not (result_pg.converged_reason.startswith("CONVERGED")
        or result_pg.converged_reason == "DIVERGED_MAXITS"):
    raise RuntimeError(f"projected gradient failed: {result_pg.converged_reason}")

# ### Figures
#
# Fig. 1 of the note: the final frames, each branch drawn in proportion to its
# length and coloured by it. Fig. 2: $H$ and $E$ against the iteration.

# +
for name, problem, result, label in (
    ("isotropic", problem_iso, result_iso, "isotropic"),
    ("nonisotropic", problem_aniso, result_aniso, "non-isotropic"),
):
    output.plot_frames(out / f"frames_{name}.png", problem.q,
                   title=f"Annulus, {label}: final frames (H = {result.H_final:.3g})",
                   singularities=singularities.locate_singularities(problem.q))
    output.plot_convergence(out / f"convergence_{name}.png", result.history,
                        title=f"Annulus, {label}: Gauss-Newton, "
                        f"{result.iterations} iterations", comm=comm)
    output.write_field(out, problem.q, stem=f"frames_{name}")


# -

# Two more figures: the lengths against $r$ with the fits (the analytic check),
# and $H$ against wall time for Gauss–Newton and the projected gradient.

# +
def plot_checks():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(10, 3.8), layout="constrained")
    rr = np.linspace(0.5, 1.0, 2)
    ax0.plot(r, 0.5 * (radial_iso + tangential_iso), ".", ms=3, color="#2ca02c",
             label="isotropic $l$")
    ax0.plot(rr, a_iso * rr + b_iso, "-", color="#2ca02c", lw=1,
             label=f"fit, $R^2$ = {r2_iso:.4f}")
    ax0.plot(r, tangential_aniso, ".", ms=3, color="#1f77b4",
             label="non-isotropic $l_\\theta$")
    ax0.plot(rr, a_tan * rr + b_tan, "-", color="#1f77b4", lw=1,
             label=f"fit, $R^2$ = {r2_tan:.4f}")
    ax0.plot(r, radial_aniso, ".", ms=3, color="#ff7f0e",
             label="non-isotropic $l_r$ (free)")
    ax0.set_xlabel("$r$")
    ax0.set_ylabel("branch length")
    ax0.set_title("lengths at the vertices: $l_\\theta \\propto r$")
    ax0.legend(fontsize=8)
    ax0.grid(alpha=0.3)
    for result, times, label in ((result_aniso, times_aniso, "Gauss-Newton (nls)"),
                                 (result_pg, times_pg, "projected gradient (bncg, gd)")):
        ax1.semilogy(times, [e["H"] for e in result.history], lw=1.5,
                     label=f"{label}: {result.iterations} it")
    ax1.axhline(H_exact, color="0.4", ls="--", lw=1,
                label="exact isotropic field, interpolated")
    ax1.set_xlabel("wall time [s] (rank 0)")
    ax1.set_ylabel("$H(q)$")
    ax1.set_title("non-isotropic annulus: two methods")
    ax1.legend(fontsize=8)
    ax1.grid(alpha=0.3, which="both")
    fig.savefig(out / "checks.png", dpi=150)
    plt.close(fig)


if comm.rank == 0:
    plot_checks()
comm.Barrier()
# -

# The summary of the run, for scripts:

output.write_summary(out / "summary.json", {
    "mesh_size": mesh_size, "num_vertices": num_vertices, "processes": comm.size, "ci": CI,
    "H_exact_isotropic_interpolant": H_exact,
    "isotropic": {"reason": result_iso.converged_reason, "iterations": result_iso.iterations,
                  "H": result_iso.H_final, "E": result_iso.E_final,
                  "fit": {"a": a_iso, "b": b_iso, "R2": r2_iso}},
    "nonisotropic": {"reason": result_aniso.converged_reason,
                     "iterations": result_aniso.iterations, "H": result_aniso.H_final,
                     "E": result_aniso.E_final,
                     "fit_tangential": {"a": a_tan, "b": b_tan, "R2": r2_tan}},
    "projected_gradient": {"reason": result_pg.converged_reason,
                           "iterations": result_pg.iterations, "H": result_pg.H_final,
                           "wall_time_s": result_pg.wall_time_s},
}, comm=comm)
say(f"wrote {out}/")
