# Everything runs from .venv/ at the repository root (created by `make install`).
# Override the interpreter with `make PYTHON=/path/to/python3.12 install`.
PYTHON ?= $(shell for p in python3.12 python3.13 $$HOME/.pyenv/versions/3.12*/bin/python3.12 /usr/bin/python3.12; do \
             $$p -c 'import sys; assert sys.version_info >= (3, 12)' >/dev/null 2>&1 && { echo $$p; break; }; done)
VENV    := .venv
PY      := $(VENV)/bin/python
MPIRUN  := $(VENV)/bin/mpirun
NP      ?= 2
STAMP   := $(VENV)/.installed
# One BLAS thread per process: the suite runs two MPI ranks on small dense problems.
export OMP_NUM_THREADS ?= 1
export OPENBLAS_NUM_THREADS ?= 1

.PHONY: install demo test test-serial test-mpi bench lint clean

install: $(STAMP)

$(STAMP): pyproject.toml
	@test -n "$(PYTHON)" || { echo "error: no Python >= 3.12 found; pass PYTHON=/path/to/python3.12" >&2; exit 1; }
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[dolfinx,test,dev]"
	@touch $(STAMP)

# The main job: integrable frame field on the built-in 'piano' geometry.
demo: $(STAMP)
	$(MPIRUN) -n $(NP) $(VENV)/bin/ufl-frames solve piano --out out_piano --force

# The whole suite, serially and then under MPI.
test: test-serial test-mpi

test-serial: $(STAMP)
	$(PY) -m pytest -q

test-mpi: $(STAMP)
	$(MPIRUN) -n $(NP) $(PY) -m pytest -q -m "not serial"

bench: $(STAMP)
	$(PY) benchmarks/projection.py

lint: $(STAMP)
	$(VENV)/bin/ruff check src tests demos benchmarks

clean:
	rm -rf $(VENV) out_* .pytest_cache
