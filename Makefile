# robot_ai: every target does its own set-up (Debian packages, .venv/, a private catkin workspace).
#   make demo   build, then run the headless demo (roslaunch robot_ai demo.launch)
#   make test   build, then unit tests (pytest) and rostest tests side by side, one summary, non-zero on any failure
#   make check  the edit loop: a lint (flake8) and the unit tests, no roscore
#   make build  Debian packages + .venv + .catkin_ws (catkin_make); a second run with nothing changed is quick
#   make bench  the benchmarks in bench/, figures beside the reference's, kept in output/bench.txt
#   make ray    the optional fleet engine (Ray) in the venv; make test and make bench install it
#   make clean  remove .venv, .catkin_ws and outputs
SHELL := /bin/bash
.SHELLFLAGS := -e -o pipefail -c  # not -u: ROS's setup.bash reads unset variables
.DEFAULT_GOAL := build

ROOT := $(abspath $(dir $(lastword $(MAKEFILE_LIST))))
VENV := $(ROOT)/.venv
WS := $(ROOT)/.catkin_ws
OUT := $(ROOT)/output
SYS_PYTHON := /usr/bin/python3

APT_PACKAGES := ros-core-dev catkin catkin-lint ros-message-generation rosbash rospack-tools \
	python3-rospy python3-roslaunch python3-rostest librostest-dev python3-tf python3-tf2-ros \
	python3-sensor-msgs python3-geometry-msgs libgeometry-msgs-dev python3-std-msgs python3-std-srvs python3-visualization-msgs libstd-msgs-dev \
	python3-trajectory-msgs python3-interactive-markers \
	python3-actionlib python3-actionlib-msgs ros-actionlib-msgs libactionlib-msgs-dev \
	ros-robot-state-publisher joint-state-publisher joint-state-publisher-gui rviz \
	tf-tools tf2-tools liburdfdom-tools xvfb x11-utils xdotool iproute2 nftables imagemagick python3-venv python3-numpy \
	bubblewrap util-linux

# Everything a target runs sees the venv first on PATH (ROS nodes start with `#!/usr/bin/env python3`), the
# workspace sourced, and caches kept inside the repository.
export PIP_CACHE_DIR := $(VENV)/.pip-cache
export MPLCONFIGDIR := $(VENV)/.mplconfig
export PYTHONDONTWRITEBYTECODE := 1
# ROS 1 has no authentication: ROS_HOSTNAME=localhost makes the master and every node bind to loopback only.
RUN := source $(WS)/devel/setup.bash && export PATH="$(VENV)/bin:$$PATH" ROS_HOSTNAME=localhost \
	ROS_MASTER_URI=http://localhost:11311 &&

.PHONY: build test check demo bench clean apt venv ray

# Tests at a time in make test: each rostest has a master of its own; most of their time is waiting for ROS, not CPU.
TEST_JOBS ?= 4

apt:
	@missing=$$(for p in $(APT_PACKAGES); do \
	    dpkg-query -W -f='$${Status}\n' $$p 2>/dev/null | grep -q '^install ok installed' || echo $$p; done); \
	if [ -n "$$missing" ]; then \
	  cmd="apt-get update && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends $$(echo $$missing)"; \
	  if [ "$$(id -u)" != 0 ]; then echo "Missing Debian packages. Run as root:"; echo "  $$cmd"; exit 1; fi; \
	  echo "Installing Debian packages: $$missing"; \
	  bash -c "$$cmd"; \
	fi

$(VENV)/.requirements.stamp: requirements.txt | apt
	test -x $(VENV)/bin/python || $(SYS_PYTHON) -m venv --system-site-packages $(VENV)
	$(VENV)/bin/python -m pip install --disable-pip-version-check -q -r requirements.txt
	touch $@

# robot_ai's pure modules importable from the venv with nothing sourced (`.venv/bin/python -m robot_ai.cartpole`);
# a sourced workspace's PYTHONPATH comes first, and its robot_ai adds the generated messages to the same package.
# and urdf_parser_py's URDF.from_parameter_server() with ROS 1's meaning, for course nodes (robot_ai.urdf_compat).
$(VENV)/.pth.stamp: $(VENV)/.requirements.stamp src/robot_ai/urdf_compat.py
	echo "$(ROOT)/src" > "$$($(VENV)/bin/python -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')/robot_ai_src.pth"
	$(VENV)/bin/python -m robot_ai.urdf_compat --install
	touch $@

venv: apt $(VENV)/.requirements.stamp $(VENV)/.pth.stamp

# Ray, the optional fleet engine: the tests and benchmarks of a class on a cluster need it; make demo does not
$(VENV)/.ray.stamp: requirements-ray.txt $(VENV)/.requirements.stamp
	$(VENV)/bin/python -m pip install --disable-pip-version-check -q -r requirements-ray.txt
	touch $@

ray: $(VENV)/.ray.stamp

build: venv
	@# The package in the workspace is a folder of links to the repository's entries, not a link to the root:
	@# that would put .catkin_ws inside the package, and rosrun/roslaunch would find every executable twice.
	[ ! -L $(WS)/src/robot_ai ] || rm $(WS)/src/robot_ai
	mkdir -p $(WS)/src/robot_ai
	find $(WS)/src/robot_ai -maxdepth 1 -type l ! -exec test -e {} \; -delete
	for f in $(ROOT)/*; do case "$${f##*/}" in output) ;; *) ln -sfn "$$f" $(WS)/src/robot_ai/ ;; esac; done
	cd $(WS) && PATH="$(VENV)/bin:$$PATH" catkin_make -DPYTHON_EXECUTABLE=$(VENV)/bin/python \
	  -DCATKIN_ENABLE_TESTING=ON -DCMAKE_BUILD_TYPE=Release > $(WS)/build.log 2>&1 \
	  || { tail -n 40 $(WS)/build.log; echo "catkin_make failed; full log: $(WS)/build.log"; exit 1; }
	@echo "built: source $(WS)/devel/setup.bash (with $(VENV)/bin first on PATH)"

test: build ray
	rm -rf $(WS)/build/test_results $(WS)/build/test_logs
	$(RUN) python $(ROOT)/test/run_tests.py --build $(WS)/build --jobs $(TEST_JOBS)
	$(RUN) python $(ROOT)/test/summarize.py $(WS)/build/test_results/robot_ai

# flake8: pyflakes' errors (unused imports, undefined names) and lines of at most 120 columns (setup.cfg)
check: build
	$(RUN) python -m flake8 $(ROOT)/src $(ROOT)/test $(ROOT)/bench $(ROOT)/examples
	$(RUN) cd $(ROOT) && python -m pytest -q -p no:cacheprovider -n 2 test/unit

# A master of its own on a free port, like the tests: never one that already runs on 11311 (its robot_description).
# launch_guard: whatever ends roslaunch (a SIGKILL too), the processes it started end with it and tee sees the end.
demo: build
	mkdir -p $(OUT)
	@# unbuffered: into tee's pipe Python would hold the demo's lines back in 8 KB blocks
	port=$$($(SYS_PYTHON) -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'); \
	$(RUN) export ROS_MASTER_URI=http://localhost:$$port PYTHONUNBUFFERED=1 && \
	  python -m robot_ai.launch_guard roslaunch -p $$port robot_ai demo.launch output_dir:=$(OUT) 2>&1 | tee $(OUT)/demo.log
	@# roslaunch exits 0 when its required client ends, whatever the client's status: the verdict decides
	@grep -q '^verdict: OK' $(OUT)/demo.log

# The last recorded figures (docs/benchmarks.md) first, then today's; the scripts' stderr (ROS's own log lines, warnings) goes to a log file
# so that the tables hold only figures.
bench: build ray
	mkdir -p $(OUT)
	@{ python3 $(ROOT)/bench/last_figures.py; \
	  echo "load average at start: $$(cut -d' ' -f1-3 /proc/loadavg)"; \
	  for b in fk_load search_speed q_learning_speed cartpole_loop ros_env_speed reach_speed reach_ars ros_reach_speed ros_manipulation_speed reach_safety reach_planner policy_latency manipulation pick_place class_on_ray; do \
	    $(RUN) python $(ROOT)/bench/$$b.py 2>>$(OUT)/bench-stderr.log \
	      || { echo "bench/$$b.py failed; its stderr: $(OUT)/bench-stderr.log"; tail -n 20 $(OUT)/bench-stderr.log; exit 1; }; \
	  done; \
	  echo "load average at end: $$(cut -d' ' -f1-3 /proc/loadavg)   (ROS log lines and warnings: $(OUT)/bench-stderr.log)"; \
	} | tee $(OUT)/bench.txt
	@echo "this run's figures: $(OUT)/bench.txt (copy them to docs/benchmarks.md's 'Figures of' block)"

clean:
	rm -rf $(WS) $(VENV) $(OUT)
