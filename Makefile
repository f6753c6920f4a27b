# Quick start:  make demo   (installs what is missing, runs the patina demo)
#               make test   (C++ runtime tests with sanitizers, then pytest)
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
SCENES ?= examples/scenes
DEMO_OUT ?= out/patina-bunny
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
APT_PACKAGES := g++ cmake ninja-build pkg-config python3-dev python3-venv \
	libembree-dev libopenmesh-dev libglm-dev libtbb-dev libnanoflann-dev libgtest-dev zlib1g-dev \
	libcgal-dev libgmp-dev libmpfr-dev libboost-dev chromium $(if $(shell command -v npm),,npm)
# chromium: the headless browser the viewer test drives (Playwright, never its own browser download);
# npm (unless a Node.js install already brings it): three.js and the glTF validator, see web/
# ray: the optional extra (.[ray]); installed here so its tests run in CI
# usd-core (< 26.8 keeps UsdUtils.ComplianceChecker; gammac export --format usd) and xatlas (the chart atlas)
PY_PACKAGES := scikit-build-core nanobind lark llvmlite numpy pillow pytest hypothesis pygltflib ray coverage playwright \
	'usd-core>=24.8,<26.8' 'xatlas==0.0.11' openexr pypng
# Blender 4.5 LTS as a module, the real client the export tests import into (tests/clients.py): it
# needs Python 3.11 and numpy < 2, so it has a venv of its own rather than pinning the project's numpy
BLENDER_VENV := .venv-blender
WEB_MODULES := web/node_modules/.installed
SOURCES := $(shell find compiler language runtime stdlib -type f -not -path '*/__pycache__/*' 2>/dev/null) \
	CMakeLists.txt pyproject.toml

.PHONY: blender-extension all demo stain moss-dirt leak-stain hydrant gallery erosion test deps install runtime-tests pytest bench clean fuzz coverage

all: install

deps:
	@missing=$$(for p in $(APT_PACKAGES); do dpkg -s $$p >/dev/null 2>&1 || echo $$p; done); \
	if [ -n "$$missing" ]; then \
	  echo "== installing system packages:" $$missing; \
	  $(SUDO) apt-get update -qq && \
	  DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq --no-install-recommends $$missing; \
	fi

$(PY): | deps
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip

$(VENV)/.deps: $(PY) Makefile
	$(PY) -m pip install -q $(PY_PACKAGES)
	touch $@

# The package (compiler + C++ runtime) is rebuilt when any source changes;
# scikit-build-core keeps its build folder (build/) so rebuilds are incremental.
# three.js (vendored into the package by CMake) and gltf-validator, pinned by web/package-lock.json
$(WEB_MODULES): web/package.json web/package-lock.json | deps
	cd web && npm ci --no-audit --no-fund --loglevel=error
	touch $@

$(VENV)/.installed: $(VENV)/.deps $(WEB_MODULES) $(SOURCES)
	$(PY) -m pip install -q --no-build-isolation .
	touch $@

install: deps $(VENV)/.installed

SPOT_OUT ?= out/patina-spot

demo: install
	$(VENV)/bin/gammac run examples/patina.gamma --scene $(SCENES)/stanford-bunny.obj \
	  --surfels 100000 --iterations 10 --out $(DEMO_OUT)
	$(VENV)/bin/gammac run examples/patina-spot.gamma --scene examples/scenes/spot.obj \
	  --surfels 100000 --iterations 10 --view 0.7,0.35,-1 --out $(SPOT_OUT)
	@echo
	@echo "Patina on the Stanford bunny (false colour), one picture per iteration:"
	@echo "  $(abspath $(DEMO_OUT))/renders/iter_0001.png ... iter_0010.png"
	@echo "Patina on Spot, its texture blended toward verdigris (the paper's Fig. 7):"
	@echo "  $(abspath $(SPOT_OUT))/renders/strip.png, sequence.gif, iter_0001.png ... iter_0010.png"
	@echo "Maps (PLY point clouds) and figures: maps/ and summary.json in the same folders"

# The paper's Fig. 8: rain, a rusty chain and a cement staircase (30 iterations).
stain: install
	$(PY) examples/scenes/make_staircase.py examples/scenes/staircase.obj
	$(VENV)/bin/gammac run examples/stain-bleeding.gamma --scene examples/scenes/staircase.obj \
	  --assign chain=Iron --assign '*=Cement' --show rust --view 1,0.7,0.9 \
	  --iterations 30 --out out/stain-bleeding
	@echo "Rust bleeding from the chain onto the steps: $(abspath out/stain-bleeding)/renders/"

# The paper's Fig. 11: wind-driven sand wears a sandstone arch (30 iterations);
# the shape follows the stone removed and deposited, re-tiled every iteration.
erosion: install
	$(PY) examples/scenes/make_arch.py examples/scenes/arch.obj
	$(VENV)/bin/gammac run examples/erosion.gamma --scene examples/scenes/arch.obj \
	  --assign ground=Ground --assign arch=Sandstone --view -1,0.45,0.9 \
	  --surfels 60000 --iterations 30 --out out/erosion
	@echo "Erosion of the arch: $(abspath out/erosion)/renders/ (stone laid bare pales, sand drifts at the foot),"
	@echo "  meshes/iter_0001.ply ... iter_0030.ply (the deformed mesh), summary.json (geometry, mass books)"

# The paper's other results (examples/gallery.py holds scenes, options and
# cameras): Fig. 9 moss suppressing dirt splatter, Fig. 10 a stain from a
# leak (spot source), Fig. 1 rust, dust and moss around a hydrant.
moss-dirt leak-stain hydrant: install
	$(PY) examples/gallery.py run $@

# Small pictures of every example and recipe for the README (docs/gallery/).
gallery: install
	$(PY) examples/gallery.py pictures

# Runtime unit tests, built separately with AddressSanitizer + UBSan.
runtime-tests: install
	cmake -S . -B build-tests -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo \
	  -DGAMMA_BUILD_TESTS=ON -DGAMMA_SANITIZE=ON -DPython_EXECUTABLE=$(abspath $(PY)) \
	  -Dnanobind_DIR=$$($(PY) -m nanobind --cmake_dir) > /dev/null
	cmake --build build-tests --target runtime_tests
	./build-tests/runtime_tests

$(BLENDER_VENV)/.installed: | deps
	$(PYTHON) -m venv $(BLENDER_VENV)
	$(BLENDER_VENV)/bin/python -m pip install -q --upgrade pip
	$(BLENDER_VENV)/bin/python -m pip install -q 'bpy==4.5.*'
	touch $@

# The Blender extension: dist/gamma-blender-VERSION.zip (install it in Blender from
# Edit > Preferences > Get Extensions > Install from Disk); it runs the gammac that
# `make install` puts in .venv/bin (or any on PATH, set in the add-on's preferences).
BLENDER_EXTENSION_SOURCES := $(wildcard blender/gamma_blender/*.py blender/gamma_blender/*.toml) \
	blender/build_extension.py CMakeLists.txt

blender-extension: $(BLENDER_EXTENSION_SOURCES)
	$(PYTHON) blender/build_extension.py --out dist

pytest: install $(BLENDER_VENV)/.installed
	$(PY) -m pytest -q tests

test: runtime-tests pytest

# Line coverage of the command line and the run driver, measured (coverage.py)
# over the whole Python suite, subprocesses included; fails under CLI_COVERAGE %
# (set just below the figure measured, 90 %, recorded in tests/README.md).  Not
# part of `make test`: it is a second pass of the whole suite with every
# `gammac` subprocess traced (34 min on the shared 2-core machine, against
# ~18 min for the plain suite in CI), which CI's 30 minutes cannot hold.
CLI_COVERAGE ?= 88
COVERAGE_TESTS ?= tests
coverage: install
	echo "import coverage; coverage.process_startup()" > \
	  "$$($(PY) -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')/gamma-coverage.pth"
	rm -rf .coverage-data && mkdir -p .coverage-data
	COVERAGE_PROCESS_START=$(abspath .coveragerc) COVERAGE_FILE=$(abspath .coverage-data)/coverage \
	  $(PY) -m coverage run --rcfile=.coveragerc -m pytest -q $(COVERAGE_TESTS)
	$(PY) -m coverage combine --rcfile=.coveragerc -q
	$(PY) -m coverage report --rcfile=.coveragerc --include='*/gamma/cli.py,*/gamma/driver/*'
	$(PY) -m coverage report --rcfile=.coveragerc --include='*/gamma/cli.py' --fail-under=$(CLI_COVERAGE)

# Fuzzing for longer than `make test` does: the compiler (grammar-aware
# mutants and random bytes) and the mesh readers, FUZZ_SECONDS each.  Inputs
# that break something are saved to tests/fuzz_regressions/ and
# tests/mesh_regressions/; checked in, they are regression tests.
FUZZ_SECONDS ?= 300
fuzz: install
	cd tests && ../$(PY) fuzz_gamma.py --seconds $(FUZZ_SECONDS)
	cd tests && ../$(PY) fuzz_meshes.py --seconds $(FUZZ_SECONDS)

bench: install
	$(PY) bench/bench_tracer.py
	$(PY) bench/bench_endtoend.py
	$(PY) bench/bench_stain.py
	$(PY) bench/bench_compile.py
	$(PY) bench/bench_render.py
	$(PY) bench/bench_scaling.py
	$(PY) bench/bench_erosion.py
	$(PY) bench/bench_ray.py

clean:
	rm -rf build build-tests out dist $(VENV) $(BLENDER_VENV)
