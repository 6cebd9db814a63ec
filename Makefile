# Haptic Hand: `make demo` and `make test` set up everything they need on a fresh Debian
# machine (Debian packages, a pinned venv, the native build), then run.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
BUILD := build/native
LIB := $(BUILD)/libhaptic_hand.so
NATIVE_SOURCES := $(shell find native -name '*.cpp' -o -name '*.h' -o -name CMakeLists.txt)
OUT := out

.PHONY: all deps venv native test test-native test-python test-sanitize test-tsan demo bench clean addon docs
all: native

deps: $(BUILD)/.deps
$(BUILD)/.deps: scripts/install_system_deps.sh
	bash scripts/install_system_deps.sh
	mkdir -p $(BUILD) && touch $@

venv: $(VENV)/.installed
$(VENV)/.installed: requirements.txt pyproject.toml | $(BUILD)/.deps
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -r requirements.txt
	$(PY) -m pip install -q --no-deps -e .
	touch $@

native: $(LIB)
$(LIB): $(NATIVE_SOURCES) | $(BUILD)/.deps
	cmake -S native -B $(BUILD) -DCMAKE_BUILD_TYPE=Release > /dev/null
	cmake --build $(BUILD) -j2

test-native: native
	cd $(BUILD) && ctest --output-on-failure

# The native tests again under AddressSanitizer and UndefinedBehaviorSanitizer, two at a time
# (none depends on running alone: the haptic loop's rate check allows 20x). Built at -O1
# (native/CMakeLists.txt): the tests take ~1 minute there on the 2-core CI machine, against 10
# at -O0, for ~1.5 minutes more of building.
test-sanitize: | $(BUILD)/.deps
	cmake -S native -B build/asan -DCMAKE_BUILD_TYPE=Debug -DHH_SANITIZE=address,undefined > /dev/null
	cmake --build build/asan -j2
	cd build/asan && ctest --output-on-failure -j2

# The threaded parts (haptic loop, live sessions, the OpenHaptics stand-in, the world step on two
# threads, the factor's parts side by side) under ThreadSanitizer.
test-tsan: | $(BUILD)/.deps
	cmake -S native -B build/tsan -DCMAKE_BUILD_TYPE=Debug -DHH_SANITIZE=thread > /dev/null
	cmake --build build/tsan -j2 --target test_haptics test_world_threads test_block_ldlt hd_standin
	cd build/tsan && TSAN_OPTIONS="halt_on_error=1 second_deadlock_stack=1" ctest --output-on-failure -R "haptics|world_threads"
	cd build/tsan && TSAN_OPTIONS="halt_on_error=1" CHECK_ONLY=side_by_side ./test_block_ldlt

test-python: native venv
	$(PY) -m pytest -q tests

test: test-native test-python

demo: native venv
	$(PY) -m haptic_hand demo --out $(OUT)/demo
	$(PY) blender_scenes/demo.py --out $(OUT)/demo

# The Blender extension zip (out/haptic_hand-<version>.zip, about 43 MB with its wheels;
# `$(PY) scripts/build_addon.py --no-wheels` makes a small one without them).
addon: native venv
	$(PY) scripts/build_addon.py --out $(OUT)

# The parameter table of docs/scene_format.md, written from the library's table (a test fails
# until it matches).
docs: native venv
	$(PY) scripts/param_docs.py

bench: native venv
	$(PY) bench/bench_step.py
	$(PY) bench/bench_visual.py

clean:
	rm -rf build $(OUT)
