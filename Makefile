# Two commands on a fresh machine:  make demo   and   make test
# Both create .venv if needed and install everything the project needs into it.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp
VIEWER := src/sc_fem/io/_viewer/viewer.js
OUT    ?= out

.PHONY: demo test venv viewer bench notebooks docs clean

$(STAMP): pyproject.toml Makefile .ci/install-cholmod.sh .ci/install-browser.sh
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e ".[test]"
	@# optional fast sparse Cholesky (CHOLMOD); sc_fem falls back to scipy when it is absent
	-bash .ci/install-cholmod.sh $(PY)
	@# headless Chromium for the web viewer's browser test (Debian packages; skipped where impossible)
	-bash .ci/install-browser.sh
	touch $(STAMP)

# the web viewer's JavaScript (three.js from the npm registry, bundled by esbuild)
$(VIEWER): src/sc_fem/io/_viewer/main.js .ci/build-viewer.sh
	-bash .ci/build-viewer.sh

viewer: $(VIEWER)

venv: $(STAMP)

demo: $(STAMP) $(VIEWER)
	$(VENV)/bin/sc-fem demo -o $(OUT)

test: $(STAMP) $(VIEWER)
	$(PY) -m pytest -q -p no:cacheprovider tests $(wildcard notebooks/*.ipynb) $(if $(wildcard notebooks/*.ipynb),--nbmake,)

bench: $(STAMP)
	for f in benchmarks/[a-z]*.py; do $(PY) $$f $(BENCH_ARGS) || exit 1; done

# the documentation site (Sphinx; sources in docs/, notebooks shown with their stored outputs)
DOCS_STAMP := $(VENV)/.docs-stamp
$(DOCS_STAMP): $(STAMP)
	$(PY) -m pip install -q -e ".[docs]"
	touch $(DOCS_STAMP)

docs: $(DOCS_STAMP)
	$(VENV)/bin/sphinx-build -E -W --keep-going -q -b html docs build/docs
	@echo "docs: build/docs/index.html"

notebooks: $(STAMP)
	$(PY) notebooks/execute.py           # re-execute and store the outputs (plots) in place

clean:
	rm -rf $(VENV) $(OUT) benchmarks/out build src/*.egg-info $(VIEWER)
