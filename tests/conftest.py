"""Shared fixtures of the test suite (serial and ``mpirun -n N python -m pytest -m "not serial"``).

Modelled on DOLFINx's ``python/test/conftest.py``:

* a watchdog: a test stuck for ``UFL_FRAMES_TEST_TIMEOUT`` seconds (600) dumps every
  thread's traceback and exits, so that ``mpirun`` ends instead of waiting forever, and
  under MPI a failure is named at once with its rank;
* under MPI, one base temporary folder per rank (pytest's numbered folders are raced on
  by ranks that start together);
* after every test, ``gc.collect()`` and a barrier on ``MPI.COMM_WORLD``, so that collective
  destructors (PETSc objects, DOLFINx meshes) run in step on all ranks;
* tests marked ``serial`` are skipped when ``MPI.COMM_WORLD`` has more than one rank;
* the global PETSc options database is restored after every test: ``solvers.solve`` and
  ``mbo.mbo_frame_field`` write their defaults into it, and an option left by one test
  (``tao_max_it``, say) would silently override another test's arguments.

``annulus_mesh`` (a fixture returning a function ``annulus_mesh(h, comm)``) builds the
annulus 0.5 <= r <= 1 with :func:`ufl_frames.mesh.annulus`, or with Gmsh directly when
that module is not available.

Nothing here needs DOLFINx, petsc4py or mpi4py to be importable: the pure NumPy tests
(``make test-pure``: odeco, bracket, aspect, the NumPy side of singularities) run in a
virtual environment without them. Each is imported where it is used; without mpi4py
there is one process and no barrier, without petsc4py there is no options database to
restore, and ``annulus_mesh`` skips the tests that ask for it when DOLFINx is missing.
"""

from __future__ import annotations

import faulthandler
import gc
import os
import sys
import threading
from typing import TYPE_CHECKING

# One BLAS thread per process, as in the Makefile (effective if NumPy is not loaded yet):
# threaded OpenBLAS makes small dot products ~1000x slower on a loaded machine.
for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import pytest  # noqa: E402

from ufl_frames.bootstrap import init_petsc  # noqa: E402  (pure Python)

if TYPE_CHECKING:  # annotations only
    import dolfinx
    from mpi4py import MPI

# Where petsc4py exists, initialise it now, before any test module imports mpi4py or
# DOLFINx (the order ufl_frames.bootstrap requires), with pytest's own command line
# (-q, -m "not serial", -k ...) kept away from PETSc. This imports petsc4py only, not
# PETSc and not DOLFINx; in an environment without petsc4py it does nothing.
try:
    init_petsc(sys.argv[:1])
    HAVE_PETSC = True
except ImportError:
    HAVE_PETSC = False

R_INNER = 0.5
R_OUTER = 1.0


def _mpi():
    """``mpi4py.MPI``, or None where mpi4py is not installed (one process, no MPI)."""
    try:
        from mpi4py import MPI
    except ImportError:
        return None
    return MPI


def _gmsh_annulus(h: float, comm: MPI.Comm) -> dolfinx.mesh.Mesh:
    """Fallback annulus: OCC disk minus disk, meshed on rank 0 of ``comm``, distributed."""
    import dolfinx.io.gmsh
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


def _annulus_mesh(h: float, comm: MPI.Comm | None = None) -> dolfinx.mesh.Mesh:
    """Triangle mesh of the annulus 0.5 <= r <= 1 with mesh size ``h``, distributed on ``comm``
    (default ``MPI.COMM_WORLD``)."""
    if comm is None:
        comm = _mpi().COMM_WORLD
    try:
        from ufl_frames.mesh import annulus as build
    except (ImportError, AttributeError):
        return _gmsh_annulus(h, comm)
    return build(comm, mesh_size=h, r_inner=R_INNER, r_outer=R_OUTER).mesh


@pytest.fixture(scope="session")
def annulus_mesh():
    """``annulus_mesh(h, comm=MPI.COMM_WORLD)`` -> mesh of the annulus 0.5 <= r <= 1."""
    pytest.importorskip("dolfinx")
    return _annulus_mesh


# A test that runs longer than this is stuck (the slowest takes under a minute): dump every
# thread's traceback and exit, which under mpirun ends all ranks. Without it, a test that
# fails on one rank between two collectives leaves the others waiting forever.
TEST_TIMEOUT_S = float(os.environ.get("UFL_FRAMES_TEST_TIMEOUT", "600"))


def _stuck(item, config):
    """The watchdog's end: pytest's capture off (so the lines reach the log), tracebacks, exit."""
    capture = config.pluginmanager.getplugin("capturemanager")
    if capture is not None:
        capture.suspend_global_capture(in_=True)
    sys.stderr.write(f"\n{item.nodeid}: stuck for {TEST_TIMEOUT_S:g} s; tracebacks:\n")
    sys.stderr.flush()
    faulthandler.dump_traceback(file=sys.stderr, all_threads=True)
    sys.stderr.flush()
    os._exit(1)


@pytest.hookimpl(wrapper=True)
def pytest_runtest_protocol(item, nextitem):
    """Exit with tracebacks if one test, with its fixtures' setup and teardown (module-scoped
    ones included), runs past ``TEST_TIMEOUT_S``."""
    timer = threading.Timer(TEST_TIMEOUT_S, _stuck, args=(item, item.config))
    timer.daemon = True
    timer.start()
    try:
        return (yield)
    finally:
        timer.cancel()


def pytest_runtest_logreport(report):
    """Under MPI, name a failure at once, with its rank: pytest's summary comes only at the
    end, which a rank stuck in a collective never reaches."""
    MPI = _mpi()
    if not report.failed or MPI is None or MPI.COMM_WORLD.size == 1:
        return
    text = str(report.longrepr).splitlines()
    detail = "\n".join(text[-15:])
    sys.__stderr__.write(f"\n[rank {MPI.COMM_WORLD.rank}] FAILED {report.nodeid} ({report.when})\n"
                         f"{detail}\n")
    sys.__stderr__.flush()


@pytest.fixture(autouse=True)
def _collective_cleanup():
    """gc.collect() and a barrier after each test (collective destructors in step)."""
    yield
    gc.collect()
    MPI = _mpi()
    if MPI is not None:
        MPI.COMM_WORLD.Barrier()


@pytest.fixture(autouse=True)
def _restore_petsc_options():
    """Put the global PETSc options database back as it was before the test."""
    if not HAVE_PETSC:
        yield
        return
    from ufl_frames.bootstrap import options_scope

    with options_scope():
        yield


@pytest.hookimpl(tryfirst=True)
def pytest_configure(config):
    """Under MPI, a base temporary folder per rank in one new folder of the run (unless
    ``--basetemp`` is given): pytest's numbered ``pytest-of-<user>/pytest-N`` folders are
    made and pruned by each process on its own, which two ranks starting together race on."""
    MPI = _mpi()
    if MPI is None or MPI.COMM_WORLD.size == 1 or config.option.basetemp:
        return
    import tempfile

    comm = MPI.COMM_WORLD
    run = tempfile.mkdtemp(prefix="ufl-frames-pytest-mpi-") if comm.rank == 0 else None
    config.option.basetemp = os.path.join(comm.bcast(run, root=0), f"rank{comm.rank}")
    config._ufl_frames_mpi_run = run


def pytest_sessionfinish(session, exitstatus):
    """Under MPI: whether every rank passed (for :func:`pytest_unconfigure`)."""
    MPI = _mpi()
    if MPI is None or not hasattr(session.config, "_ufl_frames_mpi_run"):
        return
    worst = MPI.COMM_WORLD.allreduce(int(exitstatus), op=MPI.MAX)
    session.config._ufl_frames_mpi_passed = worst == 0


def pytest_unconfigure(config):
    """Remove the per-rank temporary folders of a passing MPI run (kept when it fails):
    each rank its own, after pytest's own clean-up of it; then rank 0 the run's folder."""
    if not getattr(config, "_ufl_frames_mpi_passed", False):
        return
    import shutil

    MPI = _mpi()
    shutil.rmtree(config.option.basetemp, ignore_errors=True)
    MPI.COMM_WORLD.Barrier()
    if config._ufl_frames_mpi_run is not None:
        shutil.rmtree(config._ufl_frames_mpi_run, ignore_errors=True)


def pytest_collection_modifyitems(config, items):
    """Skip tests marked ``serial`` when running on more than one MPI rank."""
    MPI = _mpi()
    if MPI is None or MPI.COMM_WORLD.size == 1:
        return
    skip = pytest.mark.skip(reason="serial test: skipped under MPI")
    for item in items:
        if "serial" in item.keywords:
            item.add_marker(skip)
