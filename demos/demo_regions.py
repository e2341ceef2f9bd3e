# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: light
#       format_version: '1.5'
#       jupytext_version: 1.16.0
# ---

# # A quad mesh for a simulation: two materials, named boundaries
#
# What a Gmsh + DOLFINx user does with a mesher: draw the geometry with its physical
# groups, mesh it, read the mesh back with its tags, put a material on every region and
# the boundary conditions on named curves. Here the geometry is `demos/two_materials.geo`:
# a steel plate $[0, 2] \times [0, 1]$ with a round rubber inclusion of radius 0.3 in its
# middle, physical surfaces `steel` and `rubber`, physical curves `inlet` (the left side),
# `outlet` (the right side), `wall` (top and bottom) and `interface` (the circle).
#
# 1. **The quad mesh** (`ufl-frames mesh`, here called as a library:
#    `ufl_frames.app.run.RunConfig.for_mesh` and `run`): the integrable isotropic frame
#    field of the shape (its conformal scale), its seamless map, the quads, and their
#    boundary nodes moved onto the CAD curves; `quads.msh` is Gmsh MSH 4.1.
# 2. **Read back with DOLFINx**: `dolfinx.io.gmsh.read_from_msh` gives the quadrilateral
#    mesh, its cell tags (the surface groups) and facet tags (the curve groups), and the
#    groups' names.
# 3. **Steady heat conduction** with a conductivity $\kappa$ per material: find
#    $u \in H^1(\Omega)$ with $u = 1$ on the inlet, $u = 0$ on the outlet and
#
#    $$\int_\Omega \kappa \nabla u \cdot \nabla v \,\mathrm{d}x = 0$$
#
#    for all $v$ vanishing there (the walls are insulated: the natural condition
#    $\kappa \partial_n u = 0$). Discretised with $Q_1$ elements on the quads, $\kappa$
#    piecewise constant (DG0) by cell tag.
# 4. **The heat flow** $Q = \int_{\text{outlet}} -\kappa \partial_n u \,\mathrm{d}s$ gives the
#    plate's effective conductivity $\kappa_\text{eff} = Q L / (\Delta u\, H)$ ($L = 2$,
#    $H = 1$, $\Delta u = 1$), checked against the bounds every geometry obeys and set
#    beside the Maxwell Garnett estimate for a disc of area share $\varphi$ in a matrix,
#    $\kappa_\text{eff} \approx \kappa_m \frac{1 + \varphi\beta}{1 - \varphi\beta}$,
#    $\beta = \frac{\kappa_i - \kappa_m}{\kappa_i + \kappa_m}$ (a dilute, unbounded-matrix
#    estimate: the walls 0.2 from the disc make the true value lower).
#
# The quad stage does not carry regions yet: until it does, `quads.msh` holds one surface
# group `domain` and one curve group `boundary`, the interface is not made of quad edges,
# and this demo falls back on the geometry (a cell is rubber where its centre lies in the
# disc; the inlet and outlet are the sides $x = 0$ and $x = 2$). With the regions carried,
# the same script reads the file's names and tags.
#
# Run it with `python demo_regions.py` or `mpirun -n 2 python demo_regions.py`; output in
# `out_demo_regions/` (`mesh/` with the `mesh` command's files, `regions.png`,
# `temperature.png`). With `CI` set, the quads are coarser.

# +
import sys

from ufl_frames.bootstrap import init_petsc

init_petsc(sys.argv)

import os  # noqa: E402
from pathlib import Path  # noqa: E402

import dolfinx.fem.petsc  # noqa: E402
import dolfinx.io.gmsh  # noqa: E402
import numpy as np  # noqa: E402
import ufl  # noqa: E402
from dolfinx import fem, mesh  # noqa: E402
from mpi4py import MPI  # noqa: E402

from ufl_frames.app.run import RunConfig, run  # noqa: E402

comm = MPI.COMM_WORLD
CI = os.environ.get("CI", "").strip().lower() not in ("", "0", "false")
GEOMETRY = Path(__file__).resolve().parent / "two_materials.geo"
out = Path("out_demo_regions")
quad_size = 0.1 if CI else 0.04
KAPPA = {"steel": 45.0, "rubber": 0.15}  # W/(m K)
CENTRE, RADIUS, LENGTH, HEIGHT = np.array([1.0, 0.5]), 0.3, 2.0, 1.0
# -

# ## 1. The quad mesh
#
# `RunConfig.for_mesh` is what `ufl-frames mesh` runs; the summary says what came out.

summary = run(RunConfig.for_mesh(str(GEOMETRY), quad_size=quad_size, out=out / "mesh",
                                 force=True, quiet=True), comm=comm)
found = summary["quads"]
if comm.rank == 0:
    print(f"{found['quads']} quads, {found['irregular_vertices']} irregular vertices, "
          f"scaled Jacobian min {found['min_sj']:.3f} mean {found['mean_sj']:.3f}; "
          f"{found['cad']['moved']} boundary nodes moved onto the CAD curves "
          f"(up to {found['cad']['max_offset_before']:.1e} off before)")

# ## 2. Read back with DOLFINx
#
# The physical groups come back by name: `data.physical_groups[name]` is `(dim, tag)`.

data = dolfinx.io.gmsh.read_from_msh(out / "mesh" / "quads.msh", comm, 0, gdim=2)
domain, cell_tags, facet_tags = data.mesh, data.cell_tags, data.facet_tags
groups = {name: group.tag for name, group in data.physical_groups.items()}
regions = set(KAPPA) <= set(groups)
named_ends = {"inlet", "outlet"} <= set(groups)
tdim = domain.topology.dim
if comm.rank == 0:
    print(f"{domain.topology.cell_name()} mesh; physical groups: {sorted(groups)}; "
          f"materials {'by cell tag' if regions else 'by position (no region tags yet)'}, "
          f"inlet/outlet {'by facet tag' if named_ends else 'by position'}")

# ## 3. A conductivity per material, conditions on named curves
#
# $\kappa$ is a DG0 function: by the cell tags where the file's regions survived, else by
# the position of the cell's centre.

# +
Q = fem.functionspace(domain, ("DG", 0))
kappa = fem.Function(Q, name="kappa")
num_cells = domain.topology.index_map(tdim).size_local + domain.topology.index_map(tdim).num_ghosts
if regions:
    for name, value in KAPPA.items():
        kappa.x.array[cell_tags.find(groups[name])] = value
else:
    centres = mesh.compute_midpoints(domain, tdim, np.arange(num_cells, dtype=np.int32))
    inside = np.linalg.norm(centres[:, :2] - CENTRE, axis=1) < RADIUS
    kappa.x.array[:num_cells] = np.where(inside, KAPPA["rubber"], KAPPA["steel"])
kappa.x.scatter_forward()

V = fem.functionspace(domain, ("Lagrange", 1))
domain.topology.create_connectivity(tdim - 1, tdim)
if named_ends:
    ends = {name: facet_tags.find(groups[name]) for name in ("inlet", "outlet")}
else:
    ends = {"inlet": mesh.locate_entities_boundary(domain, tdim - 1,
                                                   lambda x: np.isclose(x[0], 0.0)),
            "outlet": mesh.locate_entities_boundary(domain, tdim - 1,
                                                    lambda x: np.isclose(x[0], LENGTH))}
bcs = [fem.dirichletbc(value, fem.locate_dofs_topological(V, tdim - 1, ends[name]), V)
       for name, value in (("inlet", 1.0), ("outlet", 0.0))]

u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
a = kappa * ufl.inner(ufl.grad(u), ufl.grad(v)) * ufl.dx
L = fem.Constant(domain, 0.0) * v * ufl.dx
problem = dolfinx.fem.petsc.LinearProblem(
    a, L, bcs=bcs, petsc_options_prefix="regions_",
    petsc_options={"ksp_type": "cg", "pc_type": "gamg", "ksp_rtol": 1e-10})
uh = problem.solve()
reason = problem.solver.getConvergedReason()
assert reason > 0, f"the conduction solve did not converge (KSP reason {reason})"
uh.name = "temperature"
# -

# ## 4. The heat flow and the effective conductivity
#
# The flow out of the outlet, from the discrete solution: the residual of the assembled
# form at the outlet's degrees of freedom is the consistent flux (exact conservation, where
# $\int \kappa \nabla u_h \cdot n$ would carry the $Q_1$ gradient's error).
#
# Two bounds hold whatever the inclusion's shape, for the discrete problem too: the linear
# $u = 1 - x/L$ lies in the $Q_1$ space, so the discrete energy, $\kappa_\text{eff} H/L$, is
# at most its energy, the arithmetic mean $\kappa_m (1 - \varphi_h) + \kappa_i \varphi_h$
# ($\varphi_h$ the rubber cells' area share); and a conforming solution's energy is at least
# the exact one, which is at least the harmonic mean's (Voigt and Reuss bounds).

# +
outlet_dofs = fem.locate_dofs_topological(V, tdim - 1, ends["outlet"])
indicator = fem.Function(V)
indicator.x.array[outlet_dofs] = 1.0
indicator.x.scatter_forward()


def integral(form):
    return comm.allreduce(fem.assemble_scalar(fem.form(form)), op=MPI.SUM)


flow = integral(kappa * ufl.inner(ufl.grad(uh), ufl.grad(indicator)) * ufl.dx)
area = integral(fem.Constant(domain, 1.0) * ufl.dx)
km, ki = KAPPA["steel"], KAPPA["rubber"]
phi_h = integral((km - kappa) / (km - ki) * ufl.dx) / area
voigt, reuss = km * (1 - phi_h) + ki * phi_h, 1 / ((1 - phi_h) / km + phi_h / ki)
phi = np.pi * RADIUS**2 / (LENGTH * HEIGHT)
beta = (ki - km) / (ki + km)
maxwell = km * (1 + phi * beta) / (1 - phi * beta)
effective = -flow * LENGTH / HEIGHT
if comm.rank == 0:
    print(f"area {area:.5f} (the plate's: {LENGTH * HEIGHT}); rubber share {phi_h:.4f} "
          f"(the disc's: {phi:.4f}); heat flow {-flow:.4f}")
    print(f"effective conductivity {effective:.3f}: between the bounds {reuss:.3f} and "
          f"{voigt:.3f}; Maxwell Garnett (dilute) {maxwell:.3f}, steel alone {km:g}")
assert abs(area - LENGTH * HEIGHT) < 1e-9
assert reuss < effective <= voigt * (1 + 1e-9)
# -

# ## 5. Pictures
#
# The quads coloured by material, and the temperature (its $Q_1$ values at the quads'
# corners, gathered on rank 0).

# +
cells = np.arange(domain.topology.index_map(tdim).size_local, dtype=np.int32)
dofs = V.dofmap.list[cells][:, [0, 1, 3, 2]]  # DOLFINx's tensor order -> counter-clockwise
corners = V.tabulate_dof_coordinates()[dofs][..., :2]
parts = comm.gather((corners, uh.x.array[dofs], kappa.x.array[cells]), root=0)
if comm.rank == 0:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection

    polygons = np.concatenate([p[0] for p in parts])
    values = np.concatenate([p[1] for p in parts])
    material = np.concatenate([p[2] for p in parts])
    circle = CENTRE + RADIUS * np.c_[np.cos(np.linspace(0, 2 * np.pi, 200)),
                                     np.sin(np.linspace(0, 2 * np.pi, 200))]
    for name in ("regions.png", "temperature.png"):
        fig, ax = plt.subplots(figsize=(8, 4.4))
        if name == "regions.png":
            drawn = PolyCollection(polygons, array=(material == KAPPA["rubber"]).astype(float),
                                   cmap="Pastel1", edgecolors="k", linewidths=0.3)
            ax.add_collection(drawn)
            title = f"{len(polygons)} quads: rubber (1) and steel (0)"
        else:  # every quad as two triangles, the Q1 values at their corners
            points = polygons.reshape(-1, 2)
            first = 4 * np.arange(len(polygons))[:, None]
            triangles = np.concatenate([first + [0, 1, 2], first + [0, 2, 3]])
            drawn = ax.tripcolor(points[:, 0], points[:, 1], triangles, values.ravel(),
                                 shading="gouraud", cmap="inferno")
            title = f"temperature: kappa_eff {effective:.2f} (steel alone {km:g})"
        fig.colorbar(drawn, ax=ax, shrink=0.8)
        ax.plot(circle[:, 0], circle[:, 1], "k--" if name == "regions.png" else "w--", lw=0.8)
        ax.set_xlim(-0.02, LENGTH + 0.02)
        ax.set_ylim(-0.02, HEIGHT + 0.02)
        ax.set_aspect("equal")
        ax.set_axis_off()
        ax.set_title(f"two materials, {title}", fontsize=10)
        fig.tight_layout()
        fig.savefig(out / name, dpi=150)
        plt.close(fig)
    print(f"wrote {out}/regions.png, {out}/temperature.png")
# -
