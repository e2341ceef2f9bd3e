"""Shared fixtures of the test suite (serial and ``mpirun -n N python -m pytest -m "not serial"``).

Modelled on DOLFINx's ``python/test/conftest.py``:

* after every test, ``gc.collect()`` and a barrier on ``MPI.COMM_WORLD``, so that collective
  destructors (PETSc objects, DOLFINx meshes) run in step on all ranks;
* tests marked ``serial`` are skipped when ``MPI.COMM_WORLD`` has more than one rank;
* the global PETSc options database is restored after every test: ``solver.solve`` and
  ``mbo.mbo_frame_field`` write their defaults into it, and an option left by one test
  (``tao_max_it``, say) would silently override another test's arguments.

``annulus_mesh`` (a fixture returning a function ``annulus_mesh(h, comm)``) builds the
annulus 0.5 <= r <= 1 with :func:`ufl_frames.geometry.annulus`, or with Gmsh directly when
that module is not available.
"""

import gc
import os
import sys

# One BLAS thread per process, as in the Makefile (effective if NumPy is not loaded yet):
# threaded OpenBLAS makes small dot products ~1000x slower on a loaded machine.
for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

from ufl_frames.bootstrap import init_petsc

# pytest's own command line (-q, -m "not serial", -k ...) is not for PETSc.
init_petsc(sys.argv[:1])

import dolfinx  # noqa: E402
import dolfinx.io.gmsh  # noqa: E402
import pytest  # noqa: E402
from mpi4py import MPI  # noqa: E402
from petsc4py import PETSc  # noqa: E402

R_INNER = 0.5
R_OUTER = 1.0


def _gmsh_annulus(h: float, comm: MPI.Comm) -> dolfinx.mesh.Mesh:
    """Fallback annulus: OCC disk minus disk, meshed on rank 0 of ``comm``, distributed."""
    import gmsh

    owns = not gmsh.isInitialized()
    if comm.rank == 0:
        if owns:
            gmsh.initialize(argv=[], readConfigFiles=False)
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("annulus")
        occ = gmsh.model.occ
        outer = occ.addDisk(0.0, 0.0, 0.0, R_OUTER, R_OUTER)
        inner = occ.addDisk(0.0, 0.0, 0.0, R_INNER, R_INNER)
        occ.cut([(2, outer)], [(2, inner)])
        occ.synchronize()
        surfaces = [tag for _, tag in gmsh.model.getEntities(2)]
        gmsh.model.addPhysicalGroup(2, surfaces, tag=1)
        gmsh.option.setNumber("Mesh.MeshSizeMax", h)
        gmsh.model.mesh.generate(2)
    try:
        model = gmsh.model if comm.rank == 0 else None
        data = dolfinx.io.gmsh.model_to_mesh(model, comm, 0, gdim=2)
    finally:
        if comm.rank == 0:
            gmsh.model.remove()
            if owns:
                gmsh.finalize()
    return data.mesh


def _annulus_mesh(h: float, comm: MPI.Comm = MPI.COMM_WORLD) -> dolfinx.mesh.Mesh:
    """Triangle mesh of the annulus 0.5 <= r <= 1 with mesh size ``h``, distributed on ``comm``."""
    try:
        from ufl_frames import geometry

        build = geometry.annulus
    except (ImportError, AttributeError):
        return _gmsh_annulus(h, comm)
    return build(comm, mesh_size=h, r_inner=R_INNER, r_outer=R_OUTER).mesh


@pytest.fixture(scope="session")
def annulus_mesh():
    """``annulus_mesh(h, comm=MPI.COMM_WORLD)`` -> mesh of the annulus 0.5 <= r <= 1."""
    return _annulus_mesh


@pytest.fixture(autouse=True)
def _collective_cleanup():
    """gc.collect() and a barrier after each test (collective destructors in step)."""
    yield
    gc.collect()
    MPI.COMM_WORLD.Barrier()


@pytest.fixture(autouse=True)
def _restore_petsc_options():
    """Put the global PETSc options database back as it was before the test."""
    opts = PETSc.Options()
    before = opts.getAll()
    yield
    after = opts.getAll()
    for name in after.keys() - before.keys():
        opts.delValue(name)
    for name, value in before.items():
        if after.get(name) != value:
            opts.setValue(name, value)


def pytest_collection_modifyitems(config, items):
    """Skip tests marked ``serial`` when running on more than one MPI rank."""
    if MPI.COMM_WORLD.size == 1:
        return
    skip = pytest.mark.skip(reason="serial test: skipped under MPI")
    for item in items:
        if "serial" in item.keywords:
            item.add_marker(skip)
