# zeroshot_calib_ros: one-command development environment.
#
#   make test    # create .venv (ROS 2 Jazzy from PyPI wheels + colcon),
#                # colcon-build this package into build/ install/, run pytest
#   make run     # start the installed node with config/hero9_w1.yaml
#   make echo    # print the CameraInfo it publishes (in another terminal)
#
# No system ROS installation and no sourcing of setup files are needed: the
# recipes set PYTHONPATH / AMENT_PREFIX_PATH for the install tree themselves.

# Every path is anchored at the directory of this Makefile, so that
# `make -C <clone> test` and `make -f <clone>/Makefile test` both work.
TOP := $(patsubst %/,%,$(dir $(abspath $(lastword $(MAKEFILE_LIST)))))

PKG       := zeroshot_calib_ros
PYTHON    ?= python3
VENV      := $(TOP)/.venv
VPY       := $(VENV)/bin/python
PREFIX    := $(TOP)/install/$(PKG)
VSTAMP    := $(VENV)/.stamp
# Ubuntu 24.04's numpy / SciPy / OpenCV 4 (what ROS 2 Jazzy users have), for the ROS-free tests
LIBS_VENV := $(TOP)/.venv-jazzy-libs
LSTAMP    := $(LIBS_VENV)/.stamp
BSTAMP    := $(TOP)/build/.make-build.stamp
PYTEST_ARGS ?=
PARAMS    ?= $(TOP)/config/hero9_w1.yaml
ARGS      ?=
TOPIC     ?= /camera_info
ECHO_ARGS ?=

# --- environment of every ROS process started from here ------------------
# (each only if the caller has not set it already)
ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST
RMW_IMPLEMENTATION ?= rmw_fastrtps_cpp
ROS_DOMAIN_ID ?= 42
# Fast DDS 2.14 (Jazzy) reads FASTRTPS_DEFAULT_PROFILES_FILE; Fast DDS 3.x
# reads FASTDDS_DEFAULT_PROFILES_FILE.
FASTDDS_DEFAULT_PROFILES_FILE ?= $(TOP)/config/fastdds_shm.xml
FASTRTPS_DEFAULT_PROFILES_FILE ?= $(FASTDDS_DEFAULT_PROFILES_FILE)
export ROS_AUTOMATIC_DISCOVERY_RANGE RMW_IMPLEMENTATION ROS_DOMAIN_ID
export FASTDDS_DEFAULT_PROFILES_FILE FASTRTPS_DEFAULT_PROFILES_FILE

# The install tree, usable without sourcing install/setup.sh. Recursive (=)
# so that the venv's Python version is read only when a recipe runs, i.e.
# after .venv exists.
PY_VER = $(shell $(VPY) -c 'import sys; print("%d.%d" % sys.version_info[:2])')
ROS_ENV = PYTHONPATH="$(PREFIX)/lib/python$(PY_VER)/site-packages$${PYTHONPATH:+:$$PYTHONPATH}" \
	AMENT_PREFIX_PATH="$(PREFIX):$(VENV)$${AMENT_PREFIX_PATH:+:$$AMENT_PREFIX_PATH}"

SOURCES := $(addprefix $(TOP)/,setup.py setup.cfg package.xml) \
	$(shell cd $(TOP) && find zeroshot_calib_ros config launch resource -type f \
		! -name '*.pyc' ! -path '*/__pycache__/*' 2>/dev/null | sed 's|^|$(TOP)/|')

.PHONY: all venv build test test-ros test-jazzy-libs run echo clean distclean mutation
all: build

venv: $(VSTAMP)

$(VSTAMP): $(TOP)/requirements.txt
	test -x $(VPY) || $(PYTHON) -m venv $(VENV)
	touch $(VENV)/COLCON_IGNORE
	$(VPY) -m pip install -q -r $(TOP)/requirements.txt
	touch $@

$(LSTAMP): $(TOP)/requirements-jazzy-libs.txt
	test -x $(LIBS_VENV)/bin/python || $(PYTHON) -m venv $(LIBS_VENV)
	touch $(LIBS_VENV)/COLCON_IGNORE
	$(LIBS_VENV)/bin/python -m pip install -q -r $(TOP)/requirements-jazzy-libs.txt
	touch $@

build: $(BSTAMP)

# --paths: colcon looks at this one package only and never crawls into
# .venv (whose site-packages ship package.xml files), build/, install/ or log/.
# Quiet output (colcon-core's handlers only); the package's build log is shown
# if the build fails. PYTHONDONTWRITEBYTECODE (set on these machines) would make setuptools skip
# byte-compiling the install tree, and every start of the node would compile its modules again
# (0.05-0.1 s before the first CameraInfo); a user's colcon build compiles them, so this one does too.
$(BSTAMP): $(VSTAMP) $(SOURCES)
	cd $(TOP) && . $(VENV)/bin/activate && env -u PYTHONDONTWRITEBYTECODE colcon --log-base log build \
		--paths . --build-base build --install-base install \
		--event-handlers console_start_end+ console_direct- \
	|| { cat $(TOP)/log/latest_build/$(PKG)/stdout_stderr.log 2>/dev/null; exit 1; }
	touch $@

# Five pytest processes at the same time, sharing the cores: the ROS tests (conftest.NEEDS_ROS:
# nodes in real processes, mostly waiting for them) with the newest libraries; the ROS-free tests
# with the same libraries and the install tree, and the ROS-free tests on Jazzy's libraries (Ubuntu
# 24.04's numpy / SciPy / OpenCV 4), each as two halves of their modules (ZEROSHOT_SHARD: a run of
# one process uses one core, and the longest such chain would decide the wall time). The ROS-free
# runs are CPU-bound and run at SCHED_IDLE (TEST_BACKGROUND), so that the ROS tests' processes
# (whose waits have timeouts) get a core whenever they need one; the nodes' refinement workers,
# SCHED_IDLE themselves, share the cores with those runs as equals (a nice value would starve
# them). Wall time ~ the CPU time of all of them over the cores. The ROS-free runs' output is kept
# in log/test-ros-free-[12].log and log/test-jazzy-libs-[12].log and printed after the ROS run's;
# the status fails if any run failed (pytest's status 5, no test selected, only when every run of
# that environment had none, as one run of all of them would have said).
# The test processes load numpy before the front ends could ask for one BLAS thread (cli/__init__.py),
# so they are given it as the command and the node run: five processes on two cores with OpenBLAS's
# own threads waiting beside them made the ROS-free run on Jazzy's libraries ~1.7x the CPU time
# (a board fit 5x; benchmarks/results/blas_threads.md).
# The fuzz tests' generated cases are split between the two ROS-free runs (test/fuzz_settings.py:
# each draws its half from a seed of its own): the two runs fuzz different cases, not the same twice.
TEST_BACKGROUND ?= chrt --idle 0
TEST_BLAS = OPENBLAS_NUM_THREADS=1
LIBS_RUN = $(TEST_BLAS) ZEROSHOT_ROS_FREE_ONLY=1 ZEROSHOT_SHARD=$(1)/2 ZEROSHOT_FUZZ_PART=2/2 $(TEST_BACKGROUND) $(LIBS_VENV)/bin/python -m pytest -q \
	-p no:cacheprovider test $(PYTEST_ARGS) > log/test-jazzy-libs-$(1).log 2>&1; echo $$? > log/test-jazzy-libs-$(1).rc
FREE_RUN = $(TEST_BLAS) ZEROSHOT_ROS_FREE_ONLY=1 ZEROSHOT_SHARD=$(1)/2 ZEROSHOT_FUZZ_PART=1/2 $(ROS_ENV) $(TEST_BACKGROUND) $(VPY) -m pytest -q \
	-p no:cacheprovider --durations=5 test $(PYTEST_ARGS) > log/test-ros-free-$(1).log 2>&1; echo $$? > log/test-ros-free-$(1).rc
test: $(BSTAMP) $(LSTAMP)
	@mkdir -p $(TOP)/log
	@cd $(TOP) && { $(call LIBS_RUN,1); } & \
	cd $(TOP) && { $(call LIBS_RUN,2); } & \
	cd $(TOP) && { $(call FREE_RUN,1); } & \
	cd $(TOP) && { $(call FREE_RUN,2); } & \
	cd $(TOP) && $(TEST_BLAS) ZEROSHOT_ROS_ONLY=1 $(ROS_ENV) $(VPY) -m pytest -q --durations=10 test $(PYTEST_ARGS); ros=$$?; wait; \
	echo '--- ROS-free tests, same libraries (log/test-ros-free-1.log, -2.log) ---'; \
	cat log/test-ros-free-1.log log/test-ros-free-2.log; \
	echo '--- ROS-free tests on Ubuntu 24.04 libraries (log/test-jazzy-libs-1.log, -2.log) ---'; \
	cat log/test-jazzy-libs-1.log log/test-jazzy-libs-2.log; \
	venv="$$ros $$(cat log/test-ros-free-1.rc) $$(cat log/test-ros-free-2.rc)"; \
	libs="$$(cat log/test-jazzy-libs-1.rc) $$(cat log/test-jazzy-libs-2.rc)"; \
	for run in "$$venv" "$$libs"; do \
		case " $$run " in *' 0 '*) run=$$(echo $$run | sed 's/\b5\b/0/g');; esac; \
		for rc in $$run; do test $$rc -eq 0 || exit 1; done; \
	done

test-ros: $(BSTAMP)
	cd $(TOP) && $(TEST_BLAS) $(ROS_ENV) $(VPY) -m pytest -q test $(PYTEST_ARGS)

test-jazzy-libs: $(LSTAMP)
	cd $(TOP) && $(TEST_BLAS) ZEROSHOT_ROS_FREE_ONLY=1 $(LIBS_VENV)/bin/python -m pytest -q test $(PYTEST_ARGS)

# `make run PARAMS=config/c922.yaml ARGS='-p hfov:=118 -r __ns:=/front'`: what
# `ros2 run zeroshot_calib_ros node --ros-args --params-file PARAMS ARGS` does with a system ROS.
run: $(BSTAMP)
	cd $(TOP) && $(ROS_ENV) $(PREFIX)/lib/$(PKG)/node --ros-args --params-file $(PARAMS) $(ARGS)

# `make echo [TOPIC=/front/camera_info] [ECHO_ARGS='--count 3 --timeout 20']`: the CameraInfo a
# running node (make run, in another terminal) publishes, printed as `ros2 topic echo` prints it,
# with rclpy from .venv and the DDS environment above (no system ROS needed).
echo: $(BSTAMP)
	@cd $(TOP) && $(ROS_ENV) $(VPY) -m $(PKG).ros.echo $(TOPIC) $(ECHO_ARGS)

# `make mutation MUTATION_ARGS='--only ID[,ID] --out FILE'`: the curated deliberate bugs of
# test/mutation/mutants.py, each applied alone to a copy of the repository and its tests run there
# (test/mutation/run.py; slow: not part of `make test`).
mutation: $(BSTAMP)
	cd $(TOP) && $(ROS_ENV) $(VPY) test/mutation/run.py $(MUTATION_ARGS)

clean:
	rm -rf $(TOP)/build $(TOP)/install $(TOP)/log $(TOP)/.pytest_cache \
		$(TOP)/.hypothesis $(TOP)/$(PKG).egg-info
	find $(TOP)/$(PKG) $(TOP)/test -name __pycache__ -type d -prune \
		-exec rm -rf {} + 2>/dev/null || true

distclean: clean
	rm -rf $(VENV) $(LIBS_VENV)
