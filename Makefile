# The two commands of the README: `make demo` and `make test`. Both create .venv if missing.
# `make demo` installs relcal alone (no extra); `make test` adds the development extras.
VENV := .venv
PY := $(VENV)/bin/python
CORE := $(VENV)/.installed-core
DEV := $(VENV)/.installed-dev
LINTED := src tests bench docs examples

.PHONY: demo test docs lint bench clean chromium postgresql mujoco-gl

$(CORE): pyproject.toml
	test -x $(PY) || python3 -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e .
	touch $(CORE)

$(DEV): $(CORE) pyproject.toml
	$(PY) -m pip install -q -e '.[dev]'
	touch $(DEV)

demo: $(CORE)
	$(VENV)/bin/relcal simulate --robot a465
	@echo
	@echo "Next: a real calibration, on the data beside this checkout (../shared/data):"
	@echo "  $(VENV)/bin/relcal import rct-positioner ../shared/data/rct_positioner/positioner_kinematic_measurements.yaml --out positioner"
	@echo "  $(VENV)/bin/relcal calibrate positioner --report positioner.html"
	@echo "More: README.md, and the tutorials in docs/tutorials/ (make docs builds the site)."

# The documentation site, warnings as errors; open docs/_build/html/index.html.
docs: $(DEV)
	OPENBLAS_NUM_THREADS=1 $(PY) -m sphinx -W --keep-going -q -b html docs docs/_build/html

# The browser of tests/test_report_browser.py: Debian's chromium package (apt-get, as root).
chromium:
	@command -v chromium >/dev/null || { \
	  test "$$(id -u)" = 0 || { echo "make chromium: install Debian's chromium package (needs root)"; exit 1; }; \
	  export DEBIAN_FRONTEND=noninteractive; \
	  apt-get update -qq && apt-get install -y -qq chromium fonts-dejavu-core >/dev/null; }

# The server of tests/test_registry_postgresql.py: Debian's postgresql package (apt-get, as root).
# The tests start a throw-away cluster of their own (initdb + pg_ctl); no system service is used.
postgresql:
	@ls /usr/lib/postgresql/*/bin/initdb >/dev/null 2>&1 || command -v initdb >/dev/null || { \
	  test "$$(id -u)" = 0 || { echo "make postgresql: install Debian's postgresql package (needs root)"; exit 1; }; \
	  export DEBIAN_FRONTEND=noninteractive; \
	  apt-get update -qq && apt-get install -y -qq postgresql >/dev/null; }

# Offscreen OpenGL for the virtual cell's MuJoCo renderer (tests/test_capture_*.py): EGL with
# Mesa's software rasteriser, from Debian (apt-get, as root). MUJOCO_GL=egl is the default.
mujoco-gl:
	@ldconfig -p | grep -q 'libEGL_mesa.so' && ls /usr/lib/*/dri/swrast_dri.so >/dev/null 2>&1 || { \
	  test "$$(id -u)" = 0 || { echo "make mujoco-gl: install Debian's libegl1 libegl-mesa0 libgl1-mesa-dri (needs root)"; exit 1; }; \
	  export DEBIAN_FRONTEND=noninteractive; \
	  apt-get update -qq && apt-get install -y -qq libegl1 libegl-mesa0 libgl1-mesa-dri libgles2 >/dev/null; }

# One BLAS thread: relcal's matrices are small, and threads only add overhead (see relcal.cli);
# two test processes instead (pytest-xdist), one per core of the CI machine.
# The suite includes the documentation: tests/test_docs_site.py builds the site (warnings as
# errors) and opens it in Chromium; tests/test_docs_commands.py runs the commands of the pages.
test: $(DEV) chromium postgresql mujoco-gl
	$(VENV)/bin/ruff check $(LINTED)
	$(VENV)/bin/ruff format --check $(LINTED)
	OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 $(PY) -m pytest -n 2 --dist worksteal

bench: $(DEV)
	$(PY) -m pip install -q -e '.[dev,bench]'
	$(PY) bench/run.py

clean:
	rm -rf $(VENV) docs/_build docs/gallery docs/reference/api.rst docs/reference/generated
