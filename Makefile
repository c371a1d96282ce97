# The teaching renderer.  Targets:
#   make            all chapters into build/
#   make demo       render the Cornell box with every chapter and show the results
#   make test       unit tests + grading tests, plain and under ASan/UBSan
#   make bench      throughput and timing (a benchmark, not a test)
#   make fuzz       libFuzzer on the scene parser (FUZZ_SECONDS=60)
#   make tradeoff   error against time for every method (QUICK=1: under a minute)
#   make slides     lecture decks (HTML + PDF) into out/slides/
#   make handout    a student tree with the solutions stubbed (OUT=DIR; see kit/README.md)
#   make grade      grade a student's tree or a class (SUBMISSION=DIR | SUBMISSIONS=...)
#   make format     rewrite the C sources in the style of .clang-format (make test checks it)
#   make deps       install the Debian packages the project needs
#   make clean
# Options: NATIVE=1 adds -march=native; CC=clang builds with clang;
#          SANITIZE=1 builds with AddressSanitizer + UndefinedBehaviorSanitizer.

CC      ?= cc
BUILD   ?= build
PYTHON  := /usr/bin/python3

# -ffp-contract=off: a * b + c rounds twice on every compiler and machine (clang would fuse it where FMA exists),
# so the BVH's two-wide sphere tests and the scalar ones they must equal to the bit do the same arithmetic.
CFLAGS_BASE := -std=c17 -ffp-contract=off -g -Wall -Wextra -Wpedantic -fopenmp -D_POSIX_C_SOURCE=200809L -MMD -MP
ifeq ($(SANITIZE),1)
  CFLAGS_OPT := -O1 -fno-omit-frame-pointer -fsanitize=address,undefined -fno-sanitize-recover=undefined
  LDFLAGS_SAN := -fsanitize=address,undefined
else
  # Link-time optimisation: the chapters call common/'s and earlier chapters' small functions (vec3 helpers
  # excepted, which are inline) across files; -flto inlines them (chapter 6's BDPT ~12 % faster a pass).
  CFLAGS_OPT := -O3 -flto=auto
endif
ifeq ($(NATIVE),1)
  CFLAGS_OPT += -march=native
endif
CFLAGS  += $(CFLAGS_BASE) $(CFLAGS_OPT)
LDLIBS  += -lpng -lm
LDFLAGS += -fopenmp $(LDFLAGS_SAN)

COMMON_SRC := $(wildcard common/*.c)
COMMON_OBJ := $(COMMON_SRC:%.c=$(BUILD)/%.o)
CHAPTER_PROGRAMS := $(patsubst chapters/%.c,$(BUILD)/%,$(wildcard chapters/*.c))
TESTS      := $(patsubst tests/%.c,$(BUILD)/tests/%,$(wildcard tests/test_*.c))

.PHONY: all tests demo test test-plain bench deps print-deps fuzz format clean
.DEFAULT_GOAL := all
.SECONDARY:

all: $(CHAPTER_PROGRAMS) $(BUILD)/bench/bench_rays
tests: $(TESTS)

$(BUILD)/common/%.o: common/%.c
	@mkdir -p $(dir $@)
	$(CC) $(CFLAGS) -c $< -o $@

$(BUILD)/%: chapters/%.c $(COMMON_OBJ)
	@mkdir -p $(dir $@)
	$(CC) $(CFLAGS) -Icommon $< $(filter %.o,$^) -o $@ $(LDFLAGS) $(LDLIBS)

# A chapter that builds on an earlier one links that chapter's object with
# its main renamed (by -Dmain: objcopy cannot rename a symbol in an -flto
# object), so neither includes the other and each answer is written
# once: chapter 2 shades with chapter 1's local model (chapters/local_model.h),
# chapter 03c computes form factors as chapter 3 (chapters/radiosity_model.h),
# chapter 5 scatters and samples lights as chapter 4 (chapters/pathtrace_model.h), chapter 7 draws its
# paths as chapter 6 (chapters/bidir_model.h).
$(BUILD)/chapters/%_model.o: chapters/%.c
	@mkdir -p $(dir $@)
	$(CC) $(CFLAGS) -Dmain=chapter_$*_main -Icommon -MF $(@:.o=.d) -MT $@ -c $< -o $@
$(BUILD)/02_whitted: $(BUILD)/chapters/01_local_model.o
$(BUILD)/03c_hierarchical: $(BUILD)/chapters/03_radiosity_model.o
$(BUILD)/05_photonmap: $(BUILD)/chapters/04_pathtrace_model.o
$(BUILD)/06_bidirectional: $(BUILD)/chapters/04_pathtrace_model.o $(BUILD)/chapters/05_photonmap_model.o
$(BUILD)/07_metropolis: $(BUILD)/chapters/04_pathtrace_model.o $(BUILD)/chapters/05_photonmap_model.o \
                        $(BUILD)/chapters/06_bidirectional_model.o

$(BUILD)/bench/%: bench/%.c $(COMMON_OBJ)
	@mkdir -p $(dir $@)
	$(CC) $(CFLAGS) -Icommon $< $(COMMON_OBJ) -o $@ $(LDFLAGS) $(LDLIBS)

$(BUILD)/tests/%: tests/%.c $(COMMON_OBJ)
	@mkdir -p $(dir $@)
	$(CC) $(CFLAGS) -Icommon $< $(COMMON_OBJ) -o $@ $(LDFLAGS) $(LDLIBS)

# --- set-up ---------------------------------------------------------------
# Debian 12 packages, by what needs them; each target installs only its own
# groups (`make demo` no browser, no valgrind), .ci/run and `make deps` all.
BUILD_PACKAGES := build-essential libpng-dev python3
# The viewer's (VIEWER_PACKAGES), the slides' and the sweep's are set by the
# files that own those rules:
-include viewer/viewer.mk
-include slides/slides.mk
-include tradeoff/tradeoff.mk
# make test: valgrind (tests/grade_extremes.py), Xvfb and xdotool (the viewer's
# window tests), clang and its OpenMP (make fuzz, CC=clang), clang-format (the
# style check), and what the slide and sweep tests need.
# make grade: bubblewrap (the sandbox around a submission's code) and GNU parallel (a class).
GRADE_PACKAGES := bubblewrap parallel
TEST_PACKAGES := valgrind clang libomp-dev clang-format xvfb xauth xdotool $(GRADE_PACKAGES)
DEBIAN_PACKAGES := $(sort $(BUILD_PACKAGES) $(VIEWER_PACKAGES) $(SLIDES_PACKAGES) $(TRADEOFF_PACKAGES) \
                          $(TEST_PACKAGES))
print-deps:
	@echo $(DEBIAN_PACKAGES)

# $(call install_packages,LIST[,APT OPTIONS]): nothing when all are installed; apt-get as
# root; otherwise print the command to run.
define install_packages
	@dpkg -s $(1) >/dev/null 2>&1 && exit 0; \
	if [ "$$(id -u)" = 0 ]; then \
	  apt-get update && DEBIAN_FRONTEND=noninteractive apt-get install -y $(2) $(1); \
	else \
	  echo "missing packages; run:  sudo apt-get install -y $(2) $(1)"; exit 1; \
	fi
endef
.PHONY: deps deps-demo deps-slides deps-tradeoff deps-grade
deps:
	$(call install_packages,$(DEBIAN_PACKAGES))
# The demo's packages without their recommendations (Vulkan drivers, image codecs, GnuPG, manual pages: 147
# packages, not 223): on a fresh Debian 12 they installed in 35 s, not 57, of `make demo`'s minute.
deps-demo:
	$(call install_packages,$(BUILD_PACKAGES) $(VIEWER_PACKAGES),--no-install-recommends)
deps-slides:
	$(call install_packages,$(BUILD_PACKAGES) $(VIEWER_PACKAGES) $(SLIDES_PACKAGES))
deps-tradeoff:
	$(call install_packages,$(BUILD_PACKAGES) $(VIEWER_PACKAGES) $(TRADEOFF_PACKAGES))
deps-grade:
	$(call install_packages,$(BUILD_PACKAGES) $(GRADE_PACKAGES))

# --- the two commands -------------------------------------------------------
# Renders the Cornell box with every chapter into out/demo/, then opens the
# viewer side by side (or, with no display, writes out/demo/cornell-side-by-side.png).
# It builds only what it runs (the chapters and the viewer), as many jobs as CPUs, in a tree of its own
# without link-time optimisation: LTO re-optimises common/ at each of the eight links, which made the build
# (33 s on 2 cores) longer than the renders; without it the build takes about 0.6 of that, and the renders,
# which have fixed time budgets, lose about a tenth of their samples.
DEMO_BUILD := $(BUILD)/demo
demo: deps-demo
	$(MAKE) --no-print-directory -j$(CPUS) BUILD=$(DEMO_BUILD) CFLAGS_OPT=-O3 \
	    $(patsubst $(BUILD)/%,$(DEMO_BUILD)/%,$(CHAPTER_PROGRAMS)) $(DEMO_BUILD)/viewer
	viewer/demo.sh $(DEMO_BUILD)

# Both trees build as many jobs at a time as there are CPUs; the tests run one more (tests/run.py -j).
CPUS := $(shell nproc 2>/dev/null || echo 2)
test: deps
	$(MAKE) --no-print-directory -j$(CPUS) all tests
	$(MAKE) --no-print-directory -j$(CPUS) all tests BUILD=build/asan SANITIZE=1
	$(PYTHON) tests/run.py build build/asan

test-plain: all tests
	$(PYTHON) tests/run.py build

# The class-scale tests (tests/cluster_*.py): a class graded over ssh on hosts in network namespaces, on a
# single-machine Slurm, and the Gradescope layout; too long for `make test`, so .ci/run runs them after it.
# CLUSTER_PACKAGES is what they need beyond grading's packages (the cluster test files add theirs here).
CLUSTER_PACKAGES := iproute2 debootstrap docker.io python3-yaml git openssh-server openssh-client patch slurm-wlm munge
.PHONY: test-cluster deps-cluster
deps-cluster:
	$(call install_packages,$(BUILD_PACKAGES) $(GRADE_PACKAGES) $(CLUSTER_PACKAGES))
test-cluster: deps-cluster
	$(MAKE) --no-print-directory -j$(CPUS) all
	$(PYTHON) tests/run.py --cluster build

# The Embree comparison (bench/bench_embree.c, bench/bench_00b_embree.py) needs Debian's libembree-dev,
# a dependency of the bench alone: without it `make bench` says so and benches the rest.  npm fetches the
# scanned meshes (bench/meshes.py), gnuplot plots.  `make deps-bench` installs them (as root).
BENCH_PACKAGES := libembree-dev npm gnuplot-nox
EMBREE_HEADER := /usr/include/embree3/rtcore.h
$(BUILD)/bench/bench_embree: LDLIBS += -lembree3
$(BUILD)/bench/bench_tree_counts: LDLIBS += -lembree3
.PHONY: deps-bench
deps-bench:
	$(call install_packages,$(BUILD_PACKAGES) $(VIEWER_PACKAGES) $(BENCH_PACKAGES))

bench: deps-demo
	$(MAKE) --no-print-directory all
	@if [ -f $(EMBREE_HEADER) ]; then \
	  $(MAKE) --no-print-directory $(BUILD)/bench/bench_embree $(BUILD)/bench/bench_tree_counts; \
	else echo "bench: Embree is missing ($(EMBREE_HEADER); make deps-bench installs libembree-dev):" \
	  "the comparison with Embree is skipped, the rest is benched"; \
	  rm -f $(BUILD)/bench/bench_embree $(BUILD)/bench/bench_tree_counts; fi
	$(PYTHON) bench/bench.py build

# libFuzzer on the scene parser (clang), time-boxed; crashing inputs land in
# tests/fuzz/findings/ (commit them: make test replays them through every chapter).
FUZZ_SECONDS ?= 60
fuzz: deps
	@mkdir -p build/fuzz/corpus tests/fuzz/findings
	clang -std=c17 -g -O1 -fsanitize=fuzzer,address,undefined -D_POSIX_C_SOURCE=200809L -Icommon \
	  tests/fuzz/fuzz_scene.c common/scene.c common/scene_parse.c common/bvh.c -lm -o build/fuzz/fuzz_scene
	cp -n scenes/*.scene tests/bad/*.scene build/fuzz/corpus/ 2>/dev/null || true
	cd tests/bad && ../../build/fuzz/fuzz_scene -max_total_time=$(FUZZ_SECONDS) -max_len=4096 \
	  -artifact_prefix=../fuzz/findings/ ../../build/fuzz/corpus

# Rewrite every C file in the project's style (.clang-format); make test checks it.
format:
	clang-format -i --style=file $$(/usr/bin/python3 -c 'import sys; sys.path.insert(0, "tests"); \
	  import grade_style; print(" ".join(grade_style.c_files()))')

# --- instructor kit (kit/) ----------------------------------------------------
# make handout OUT=DIR [CHAPTERS="03_radiosity ..."]   a student tree, marked functions stubbed
# make grade [SUBMISSION=DIR] [REPORT=DIR] [CHAPTERS=...] [SEED=N] [UNSAFE=1]   grade one tree (default: this one)
# make grade SUBMISSIONS="dir1 dir2 ..."|@list.txt [REPORT=DIR] [JOBS=N] [SSHLOGINFILE=FILE]   a class
.PHONY: handout grade
handout:
	@test -n "$$OUT" || { echo "make handout: OUT=DIR is required" >&2; exit 2; }
	$(PYTHON) kit/handout.py "$$OUT" $$CHAPTERS
# SUBMISSION, SUBMISSIONS, REPORT, CHAPTERS, SEED, JOBS, SSHLOGINFILE and UNSAFE reach the kit
# through the environment (make exports its command line's variables), never through the shell:
# a name with spaces, quotes or ';' is data (kit/make_grade.py).
grade:
	$(PYTHON) kit/make_grade.py

# make autograder [OUT=FILE] [CHAPTERS="01_local ..."] [UNSAFE=1]   a Gradescope autograder archive
# (default out/autograder.zip; kit/README.md).  OUT, CHAPTERS and UNSAFE reach the script through
# the environment, never through the shell, as for make grade.
.PHONY: autograder
autograder:
	$(PYTHON) kit/autograder/make_archive.py --packages "$(BUILD_PACKAGES)"

clean:
	rm -rf build out

-include $(shell find $(BUILD) -name '*.d' 2>/dev/null)
