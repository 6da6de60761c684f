# Two commands on a fresh machine:  make demo   and   make test
# Both create .venv if needed and install everything the project needs into it.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp
OUT    ?= out

.PHONY: demo test venv bench notebooks clean

$(STAMP): pyproject.toml Makefile
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e ".[test]"
	@# optional fast sparse Cholesky (CHOLMOD); sc_fem falls back to scipy when it is absent
	-bash .ci/install-cholmod.sh $(PY)
	touch $(STAMP)

venv: $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/sc-fem demo -o $(OUT)

test: $(STAMP)
	$(PY) -m pytest -q -p no:cacheprovider tests $(wildcard notebooks/*.ipynb) $(if $(wildcard notebooks/*.ipynb),--nbmake,)

bench: $(STAMP)
	for f in benchmarks/[a-z]*.py; do $(PY) $$f $(BENCH_ARGS) || exit 1; done

notebooks: $(STAMP)
	$(PY) notebooks/execute.py           # re-execute and store the outputs (plots) in place

clean:
	rm -rf $(VENV) $(OUT) benchmarks/out build src/*.egg-info
