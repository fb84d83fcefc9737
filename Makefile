# The two commands of the README: `make demo` and `make test`. Both create .venv if missing.
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: demo test lint bench clean chromium postgresql mujoco-gl

$(STAMP): pyproject.toml
	test -x $(PY) || python3 -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[dev]'
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/relcal simulate --robot a465

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

# One BLAS thread: relcal's matrices are small, and threads only add overhead (see relcal.cli).
test: $(STAMP) chromium postgresql mujoco-gl
	$(VENV)/bin/ruff check src tests bench
	$(VENV)/bin/ruff format --check src tests bench
	OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 $(PY) -m pytest

bench: $(STAMP)
	$(PY) -m pip install -q -e '.[dev,bench]'
	$(PY) bench/run.py

clean:
	rm -rf $(VENV)
