# Everything runs from .venv/ at the repository root (created by `make install`).
# Override the interpreter with `make PYTHON=/path/to/python3.12 install`.
PYTHON ?= $(shell for p in python3.12 python3.13 $$HOME/.pyenv/versions/3.12*/bin/python3.12 /usr/bin/python3.12; do \
             $$p -c 'import sys; assert sys.version_info >= (3, 12)' >/dev/null 2>&1 && { echo $$p; break; }; done)
VENV    := .venv
PY      := $(VENV)/bin/python
MPIRUN  := $(VENV)/bin/mpirun
NP      ?= 2
STAMP   := $(VENV)/.installed
# The pure NumPy tests run in a second venv without DOLFINx, PETSc, MPI or Gmsh, so that
# the pointwise maths (odeco, bracket, singularities' NumPy side) stays importable alone.
VENV_PURE  := .venv-pure
PY_PURE    := $(VENV_PURE)/bin/python
STAMP_PURE := $(VENV_PURE)/.installed
# The pure layer is selected by folder: the tests of the packages that need no DOLFINx.
PURE_TESTS := tests/frames2d tests/frames3d tests/param tests/quads tests/benchmarks
# One BLAS thread per process: the suite runs two MPI ranks on small dense problems.
export OMP_NUM_THREADS ?= 1
export OPENBLAS_NUM_THREADS ?= 1

.PHONY: install demo test test-pure test-serial test-mpi bench lint clean

install: $(STAMP)

$(STAMP): pyproject.toml
	@test -n "$(PYTHON)" || { echo "error: no Python >= 3.12 found; pass PYTHON=/path/to/python3.12" >&2; exit 1; }
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[dolfinx,test,dev]"
	@touch $(STAMP)

$(STAMP_PURE): pyproject.toml
	@test -n "$(PYTHON)" || { echo "error: no Python >= 3.12 found; pass PYTHON=/path/to/python3.12" >&2; exit 1; }
	$(PYTHON) -m venv $(VENV_PURE)
	$(PY_PURE) -m pip install --quiet --upgrade pip
	$(PY_PURE) -m pip install --quiet "numpy>=1.26" "scipy>=1.11" "sympy>=1.12" "hypothesis>=6.100" "pytest>=8"
	$(PY_PURE) -m pip install --quiet --no-deps -e .
	@touch $(STAMP_PURE)

# The main job: integrable frame field on the built-in 'piano' geometry, and a quad mesh
# of a shipped two-material geometry with named groups.
demo: $(STAMP)
	$(MPIRUN) -n $(NP) $(VENV)/bin/ufl-frames solve piano --out out_piano --force
	$(MPIRUN) -n $(NP) $(VENV)/bin/ufl-frames mesh demos/two_materials.geo --out out_regions --force

# The whole suite: the pure NumPy tests without DOLFINx, then serially and under MPI.
test: test-pure test-serial test-mpi

# Refuses to run if .venv-pure has any of the FEniCS/MPI stack (the test would prove
# nothing). find_spec, not import: a bare `import dolfinx` fails even where the
# dolfinx-solver-real wheel is installed (it needs `import dolfinx_solver` first).
PURE_ABSENT := dolfinx dolfinx_solver petsc4py mpi4py gmsh ufl
test-pure: $(STAMP_PURE)
	@$(PY_PURE) -c 'import importlib.util as u, sys; found = [m for m in sys.argv[1:] if u.find_spec(m)]; \
	  sys.exit("error: installed in $(VENV_PURE): " + " ".join(found) if found else 0)' $(PURE_ABSENT)
	$(PY_PURE) -m pytest -q -p no:cacheprovider $(PURE_TESTS)

test-serial: $(STAMP)
	$(PY) -m pytest -q

test-mpi: $(STAMP)
	$(MPIRUN) -n $(NP) $(PY) -m pytest -q -m "not serial"

bench: $(STAMP)
	$(PY) benchmarks/projection.py

lint: $(STAMP)
	$(VENV)/bin/ruff check src tests demos benchmarks

clean:
	rm -rf $(VENV) $(VENV_PURE) out_* .pytest_cache
