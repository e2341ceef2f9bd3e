# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: light
#       format_version: '1.5'
#       jupytext_version: 1.16.0
# ---

# # From a frame field to a quad mesh
#
# The integer iso-lines of a parametrisation $(U, V)$ outline quads, but only if the map is
# an *integer-grid map*: the grid $\mathbb{Z}^2$ must look the same from both sides of every
# cut and fit the boundary. This demo takes the piano's optimised fields, isotropic and
# non-isotropic, to quad meshes (`ufl_frames.pipeline.stages.quadrangulate`):
#
# 1. **The T-mesh of the seamless map** (`ufl_frames.quads.layout`). From every singular
#    vertex and concave corner, straight lines of the map (separatrices) are traced, in
#    exact fixed-point arithmetic across the cuts, each until it meets the boundary or an
#    earlier line (the motorcycle graph). The lines and the boundary cut the domain into
#    patches that are rectangles in the map.
# 2. **Integer lengths and quads** (`ufl_frames.quads.patches`). Every arc of the T-mesh
#    gets an integer length, opposite sides of every patch the same total, as close to the
#    map's lengths as possible (a small integer program); a grid of that many quads fills
#    every patch, mapped back through the map. No rounding can fold the map here: this is
#    valid by construction. Where the layout cannot be made (the map folds on a trace), the
#    older path is taken: greedy rounding of the seams, boundary curves and singular
#    vertices to integers (`ufl_frames.param.quantise`) and the integer iso-lines traced
#    into quads (`ufl_frames.quads.extract`). A singular vertex of the field becomes a quad
#    vertex with 3 or 5 edges; every other interior vertex has 4.
# 3. **The worst quads improved** (`ufl_frames.quads.improve`): the interior vertices of
#    quads with a scaled Jacobian under 0.8 are moved to raise the worst one around them.
#
# Run it with `python demo_quads.py` or `mpirun -n 2 python demo_quads.py`; output in
# `out_demo_quads/` (`quads_*.png`, `quads_*.msh` for Gmsh, `quads_*.vtu` for ParaView).
# With `CI` set, meshes are coarse and the solves short.

# +
import sys

from ufl_frames.bootstrap import init_petsc

init_petsc(sys.argv)

import os  # noqa: E402
from pathlib import Path  # noqa: E402

from mpi4py import MPI  # noqa: E402

from ufl_frames.mesh import piano  # noqa: E402
from ufl_frames.pipeline import FrameField  # noqa: E402
from ufl_frames.pipeline.files import write_quads  # noqa: E402
from ufl_frames.pipeline.stages import quadrangulate  # noqa: E402

comm = MPI.COMM_WORLD
CI = os.environ.get("CI", "").strip().lower() not in ("", "0", "false")
h = 0.1 if CI else 0.05
quad_size = 0.1 if CI else 0.05
out = Path("out_demo_quads")
if comm.rank == 0:
    out.mkdir(exist_ok=True)
comm.Barrier()


def say(text):
    if comm.rank == 0:
        print(text, flush=True)


def report(name, found):
    say(f"{name}: {found['quads']} quads, {found['vertices']} vertices, "
        f"{found['irregular_vertices']} irregular (interior valences "
        f"{dict(sorted(found['interior_valence'].items()))}), scaled Jacobian min "
        f"{found['min_sj']:.3f} mean {found['mean_sj']:.3f}, edge ratio "
        f"{found['edge_length_ratio']['mean']:.2f} mean, mean edge "
        f"{found['mean_edge_length']:.4f} (asked {found['quad_size']:.4f}), "
        f"valid: {found['valid']}")
    if found["quantisation"] == "layout":
        say(f"  misfit of the seamless map {found['misfit_seamless']:.4f}; quantised on its "
            f"T-mesh: {found['patches']} patches, {found['arcs']} arcs "
            f"({found['collapsed_arcs']} collapsed)")
    else:
        say(f"  misfit of the map: seamless {found['misfit_seamless']:.4f}, after rounding "
            f"{found['misfit_quantised']:.4f} ({found['rounded']} quantities rounded; "
            f"the layout failed: {found['fallback_reason']})")


# -

# ## The two optimised fields
#
# Each starts from the smooth MBO cross field and is optimised by TAO's Newton method on
# the integrability energy $H$. The non-isotropic field lets the two branches have
# different lengths (up to the aspect bound 4), the isotropic one does not.

# +
fields = {}
for isotropic in (False, True):
    kind = "isotropic" if isotropic else "non-isotropic"
    field = FrameField.initial(piano(comm, h), isotropic=isotropic)
    result = field.solve(max_it=30 if CI else 500)
    say(f"{kind}: {result.converged_reason} after {result.iterations} iterations, "
        f"H {result.H_final:.4e}; singularities "
        + ", ".join(f"{s['index']:+g} at ({s['x']:.2f}, {s['y']:.2f})"
                    for s in field.singularities))
    fields[kind] = field
# -

# A third field needs no TAO solve: the *conformal* field keeps the MBO field's directions
# t and takes the lengths e^{−φ} that make it integrable, ∇φ = R∇t, one Poisson solve
# (`FrameField.conformal`, `ufl_frames.fem.conformal`). Its lengths go to 0 at the +1/4
# singularity and grow without bound at the −1/4 one, like r^{±1/4}: cones that the P1
# energy H cannot follow, which is why TAO's isotropic minimum of H stops short of this.

# +
fields["conformal"] = FrameField.initial(piano(comm, h), isotropic=True).conformal()
# -

# ## Quad meshes
#
# The same quad size for all three. The singularities of the field, +1/4 on the left and −1/4
# on the right, should be the only irregular vertices: one of valence 3, one of valence 5.

# +
for kind, field in fields.items():
    quads = quadrangulate(field, quad_size)
    report(f"piano, {kind}", quads.quality)
    write_quads(out, quads, f"piano, {kind} field", comm, stem=f"quads_piano_{kind}")
# -

# `quads_piano_non-isotropic.png`, `quads_piano_isotropic.png` and
# `quads_piano_conformal.png` show the three meshes, coloured by scaled Jacobian, the
# valence-3 vertex marked blue and the valence-5 one red. All have exactly the field's two
# irregular vertices. They differ in shape, not in structure: the non-isotropic field's
# quads follow its two lengths, stretched up to the aspect bound (long thin quads towards
# the curved top left and the notch on the right); the isotropic fields' quads are close
# to squares, the conformal field's closest (mean edge ratio 1.04 against 1.11 at h = 0.05)
# and its map needs the least correction (misfit 0.038 against 0.076 and 0.072). For
# meshing, where near-square quads are asked for, take the conformal field
# (`ufl-frames solve ... --conformal --quads`); the non-isotropic one suits meshes meant to
# be anisotropic.

# ## And the MBO field?
#
# The starting point of both solves is smooth and boundary aligned but not integrable. Its
# map, too, can be rounded to an integer grid: the least squares spread its curl over the
# domain, and the same two steps give quads.

# +
mbo = FrameField.initial(piano(comm, h), isotropic=False)
try:
    quads = quadrangulate(mbo, quad_size)
    report("piano, MBO field", quads.quality)
    write_quads(out, quads, "piano, MBO field", comm, stem="quads_piano_mbo")
except ValueError as e:  # no valid integer-grid map: said in one line
    say(f"piano, MBO field: {e}")
# -

# Measured at h = 0.05 when this demo was written: the four meshes have the same structure
# (763, 763, 760 and 773 quads, exactly two irregular vertices each); the map's misfit after
# rounding is 0.074 (non-isotropic), 0.077 (isotropic), 0.045 (conformal) and 0.087 (MBO).
# The optimisation of the worst quads' vertices lifts the worst scaled Jacobian to 0.85,
# 0.86, 0.85 and 0.81. So on the piano at this size even the smooth cross field makes a
# good mesh; what integrability buys is a map that needs less correction, and with the
# conformal field squarer quads. `benchmarks/quads.py` measures these meshes against Gmsh's
# quad meshers on the piano and ten more shapes.
