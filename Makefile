# drench build. `make` builds build/libdrench.a and bin/{precompute,bake,mesh,render};
# `make test` installs what is missing, builds and runs every test; `make bench` runs benchmarks.
SHELL := /bin/bash
CC      ?= gcc
CXX     ?= g++
HDF5_INC := /usr/include/hdf5/serial
HDF5_LIB := /usr/lib/x86_64-linux-gnu/hdf5/serial
CPPFLAGS := -Isrc -I$(HDF5_INC) -D_POSIX_C_SOURCE=200809L -D_DEFAULT_SOURCE
CFLAGS   ?= -O2 -g
CFLAGS   += -std=c11 -Wall -Wextra -Werror -ffp-contract=off -fopenmp -MMD -MP
CXXFLAGS ?= -O2 -g
CXXFLAGS += -std=c++17 -Wall -Wextra -ffp-contract=off -fopenmp -MMD -MP -Wno-deprecated-declarations
LDLIBS   := -L$(HDF5_LIB) -lopenvdb -ltbb -lImath-3_1 -lassimp -lhdf5 -ljansson -lxxhash \
            -lcholmod -lsuitesparseconfig -lopenblas -lpng -lstdc++ -lgomp -lm -lpthread

DEB_PACKAGES := build-essential pkg-config libopenvdb-dev libboost-dev libtbb-dev libassimp-dev \
    libhdf5-dev hdf5-tools libsuitesparse-dev libopenblas-dev libpng-dev libjansson-dev \
    libcmocka-dev libxxhash-dev libopenvdb-tools gnuplot-nox
# Only `make test` needs these: the farm test brings up a one-node Slurm (tests/pipeline/test_farm.sh).
TEST_PACKAGES := slurmctld slurmd slurm-client munge

LIB_C   := $(sort $(wildcard src/*/*.c))
LIB_CXX := $(sort $(wildcard src/*/*.cpp))
LIB_OBJ := $(LIB_C:%.c=build/%.o) $(LIB_CXX:%.cpp=build/%.o)
LIB     := build/libdrench.a
STAGES  := precompute bake mesh render
BINS    := $(STAGES:%=bin/%)
TEST_C  := $(sort $(wildcard tests/unit/test_*.c tests/validation/test_*.c tests/stress/test_*.c))
TEST_BIN := $(TEST_C:%.c=build/%)
BENCH_C := $(sort $(wildcard tests/bench/bench_*.c))
BENCH_BIN := $(BENCH_C:%.c=build/%)
BENCH_SH := $(sort $(wildcard tests/bench/bench_*.sh))

.PHONY: all deps test-deps test bench clean readme
all: $(BINS)

deps: PACKAGES = $(DEB_PACKAGES)
test-deps: PACKAGES = $(DEB_PACKAGES) $(TEST_PACKAGES)
deps test-deps:
	@missing=""; for p in $(PACKAGES); do \
	  dpkg-query -W -f='$${Status}' $$p 2>/dev/null | grep -q "install ok installed" || missing="$$missing $$p"; \
	done; \
	if [ -n "$$missing" ]; then \
	  echo "make deps: installing$$missing"; \
	  if [ "$$(id -u)" != 0 ]; then SUDO=sudo; else SUDO=; fi; \
	  $$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq --no-install-recommends $$missing >/dev/null \
	    || { echo "make deps: apt-get failed; install these Debian packages:$$missing" >&2; exit 1; }; \
	fi

build/%.o: %.c
	@mkdir -p $(@D)
	$(CC) $(CPPFLAGS) $(CFLAGS) -c $< -o $@

# The particle-grid loops vectorise at -O3: P2G of 1M particles 0.19-0.28 s at -O2 against 0.13 s, measured
# back to back (tests/bench/bench_transfer). No reassociation without -ffast-math: the same results as -O2.
build/src/transfer/%.o build/src/mpm/%.o: CFLAGS += -O3

# The OpenVDB shim is one heavy translation unit: built once, never with -Werror on library headers.
build/%.o: %.cpp
	@mkdir -p $(@D)
	$(CXX) $(CPPFLAGS) $(CXXFLAGS) -c $< -o $@

$(LIB): $(LIB_OBJ)
	@mkdir -p $(@D)
	rm -f $@ && ar rcs $@ $^

# Objects are kept, not treated as intermediate files to delete after linking.
.SECONDARY:

# A stage links its own folder's objects (main.c and any stage-only code) with the library.
.SECONDEXPANSION:
stage_objs = $(patsubst %.c,build/%.o,$(wildcard $(1)/*.c))
bin/%: $$(call stage_objs,$$*) $(LIB)
	@mkdir -p $(@D)
	$(CC) $(CFLAGS) $(filter %.o,$^) $(LIB) $(LDLIBS) -o $@

build/tests/%: tests/%.c $(LIB)
	@mkdir -p $(@D)
	$(CC) $(CPPFLAGS) $(CFLAGS) $< $(LIB) $(LDLIBS) -lcmocka -o $@

# Helpers of the pipeline tests: objcheck (OBJ surfaces), pngstat (image regions).
TEST_HELPERS := build/tests/objcheck build/tests/pngstat
$(TEST_HELPERS): build/tests/%: tests/pipeline/%.c $(LIB)
	@mkdir -p $(@D)
	$(CC) $(CPPFLAGS) $(CFLAGS) $< $(LIB) $(LDLIBS) -o $@

# The build before the tests and benchmarks uses every core (the tests then set their own threads).
test: test-deps
	@$(MAKE) --no-print-directory -j$$(nproc) all $(TEST_BIN) $(TEST_HELPERS)
	@bash tests/run_tests.sh $(TEST_BIN)

bench: deps
	@$(MAKE) --no-print-directory -j$$(nproc) all $(BENCH_BIN)
	@bash tests/bench/run_bench.sh $(BENCH_BIN) $(BENCH_SH)

# Refreshes the README's component reference from the scene tables (headings moved under README's own).
readme: bin/bake
	@bin/bake --list-components --markdown | tail -n +2 | sed 's/^#### /###### /; s/^### /##### /; s/^## /#### /' > build/reference.md
	@awk 'BEGIN{skip=0} /<!-- BEGIN COMPONENT REFERENCE -->/{print; while ((getline l < "build/reference.md") > 0) print l; skip=1; next} \
	     /<!-- END COMPONENT REFERENCE -->/{skip=0} !skip{print}' README.md > README.md.tmp && mv README.md.tmp README.md

clean:
	rm -rf build bin

-include $(shell find build -name '*.d' 2>/dev/null)
