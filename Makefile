# texsyn - plain Makefile (Redis style): one library of everything shared,
# thin mains on top, one test binary per concern; image I/O in a shared
# library of its own, loaded only by what reads or writes images.
#
#   make            build binaries into build/
#   make install    the binaries into PREFIX/bin (default /usr/local), the
#                   image library into PREFIX/lib/texsyn, the man pages into
#                   PREFIX/share/man/man1 (man texsyn-synth)
#   make doc        the command pages' options blocks from the programs' --help
#   make test       install missing packages, build, run every test
#   make test-valgrind  the unit tests under valgrind
#   make test-tsan  the cluster's integration tests on a ThreadSanitizer build (build-tsan/)
#   make test-faults    fault injection (TRIALS random trials, default 20), the load test,
#                       a coordinator killed half-way through level 0 of a 20 s job, and the
#                       rebalancing measurements (slow worker, slow link, load over Modbus);
#                       network partitions and half-open TCP in namespaces (root, nft)
#   make fuzz       run each libFuzzer target for FUZZ_SECONDS (default 30)
#   make bench      quick benchmarks (< 10 min), write bench/results/ and its RESULTS.md
#                   (with TEXSYN_EBSYNTH=PATH to the peer, also texsyn stylize against
#                   Ebsynth: bench/stylize.py); make bench-full: all of them, full size
#   make bench-netem  the cluster under added network latency (root: namespaces, netem or
#                   bench/delay_relay) and a fitted performance model; writes
#                   bench/results/netem.{json,md,png}
#   make test-hostile  SCHEDULES (2000) seeded schedules of a hostile worker over every engine;
#                   writes bench/results/hostile.{json,md}
#   make test-seal  SEAL_ROUNDS (125) rounds of the man-in-the-middle relay altering,
#                   dropping, replaying and reordering sealed frames (1,000 trials)
#   make soak       SOAK_MINUTES (default 10) of small jobs on 3 workers that are killed,
#                   stalled, partitioned and replaced, the coordinator killed and its spool's
#                   disk filled or made read-only (root); writes bench/results/soak.{json,txt}
#   make test-deploy  (root) deploy/: the Slurm batch script on a single-node Slurm,
#                   byte-identical to the embedded run; systemd-analyze verify of the
#                   units; the Kubernetes manifests against the API's fields and schema
#   make demo       install missing packages, run an embedded synthesis
#   make clean
#
# SAN=1 builds with AddressSanitizer + UBSan into build-asan/.

CC ?= cc
CXX ?= c++
OPT ?= -O2
ifeq ($(SAN),1)
BUILD ?= build-asan
SANFLAGS = -fsanitize=address,undefined -fno-omit-frame-pointer -fno-sanitize-recover=all
OPT = -O1 -g
# The worker's planted faults (worker/planted.h), which prove that the
# suite notices a daemon's sanitizer report, exist only in this build.
FAULT_HOOKS = -DTEXSYN_FAULT_HOOKS
else
BUILD ?= build
SANFLAGS =
FAULT_HOOKS =
endif
# TSAN=1 builds with ThreadSanitizer into build-tsan/ (make test-tsan), the
# image library too: its shim's C++ and the C it calls are instrumented,
# OpenImageIO itself is not (tests/tsan.supp).
ifeq ($(TSAN),1)
BUILD = build-tsan
SANFLAGS = -fsanitize=thread -fno-omit-frame-pointer
OPT = -O1 -g
# The SIMD L1 kernels are left uninstrumented: each vector load would be a
# range check (a 192x144 job took 38 s instead of 1.4). They only read the
# set, queries and masks that instrumented code wrote, and write their
# caller's stack; the best of a scan is written by l1.c, instrumented.
$(BUILD)/common/search/l1_x86.o: SANFLAGS =
endif

WARN = -Wall -Wextra -Werror -Wstrict-prototypes -Wno-missing-field-initializers
# Layers, each seeing only the folders below it (the compiler enforces the
# direction: a header from a higher layer is simply not found):
#   common <- common/search <- proto <- worker
#   common/search <- server/engines
#   proto + server/engines <- server/cli
#   proto <- server/pool <- server/jobs (+ server/engines) <- server/http <- server
# Engines know the search interface, never the daemon, the wire or the CLI.
# The CLI knows the wire and the engines (a job spec is an engine's), never
# the coordinator; the coordinator's folders are its pool of workers, its
# job queue and spool, its operations page, and at server/ itself the
# daemon (main.c, and smon.c, its Modbus monitor), which sees them all.
INC_common = -Icommon
INC_common/search = $(INC_common) -Icommon/search
INC_proto = $(INC_common/search) -Iproto
INC_worker = $(INC_proto) -Iworker
INC_server/engines = $(INC_common/search) -Iserver/engines
INC_server/cli = $(INC_proto) -Iserver/engines -Iserver/cli
INC_server/pool = $(INC_proto) -Iserver/pool
INC_server/jobs = $(INC_server/pool) -Iserver/engines -Iserver/jobs
INC_server/http = $(INC_server/jobs) -Iserver/http $(MHD_CFLAGS)
INC_server = $(INC_server/http) -Iserver
# Tests, fuzz targets and benchmarks may reach any layer.
INC_ALL = $(INC_server) -Iserver/cli -Iworker
INC_tests/unit = $(INC_ALL)
INC_tests/fuzz = $(INC_ALL)
INC_tests/preload = $(INC_common)
INC_bench = $(INC_ALL)
# The include paths of a source file: those of its folder.
inc = $(INC_$(patsubst %/,%,$(dir $(1))))

CFLAGS_ALL = -std=c11 -D_GNU_SOURCE $(WARN) $(OPT) -g $(SANFLAGS) $(FAULT_HOOKS) $(CFLAGS)
CXXFLAGS_ALL = -std=c++17 -Wall -Wextra -Werror $(OPT) -g $(SANFLAGS) -Icommon $(CXXFLAGS)
# The programs link neither OpenImageIO nor the C++ runtime: loading those
# cost every process 0.2 s at start, `texsyn status` included. They dlopen
# the image library (below) on their first image call.
LIBS = -lmodbus -lsodium -lpthread -lm -ldl $(LDLIBS)
LDFLAGS_ALL = $(SANFLAGS) $(LDFLAGS)
# libmicrohttpd for the operations page (server/http/http.c): only
# texsyn-server links it, the CLI and the worker start without it.
MHD_CFLAGS := $(shell pkg-config --cflags libmicrohttpd 2>/dev/null)
MHD_LIBS := $(or $(shell pkg-config --libs libmicrohttpd 2>/dev/null),-lmicrohttpd)

# Mains: everything else in these folders goes into the library.
MAINS = server/cli/main.c server/main.c worker/main.c
LIB_DIRS = common common/search proto worker server server/engines server/pool server/jobs server/http \
           server/cli
LIB_C = $(filter-out $(MAINS),$(foreach d,$(LIB_DIRS),$(wildcard $(d)/*.c)))
LIB_OBJ = $(LIB_C:%.c=$(BUILD)/%.o)
LIB = $(BUILD)/libtexsyn.a

# Image I/O as a shared library (common/image_lib.h): the OpenImageIO shim
# and the C it calls, compiled once more as position-independent code into
# BUILD/pic/ with the programs' own flags (sanitizers too), every symbol
# hidden but the shim's table. The programs find it next to themselves.
IMAGE_SRC = common/image_oiio.cpp common/image_check.c common/tiff_tags.c common/image.c \
            common/error.c
IMAGE_OBJ = $(patsubst %.c,%.o,$(IMAGE_SRC:%.cpp=%.o))
IMAGE_LIB = $(BUILD)/libtexsyn-image.so
IMAGE_LIBS = -lOpenImageIO -lOpenImageIO_Util
PIC = -fPIC -fvisibility=hidden

# Optical flow as a shared library of its own (common/flow_lib.h), built
# like the image library: OpenCV's DIS flow behind a C table, loaded by
# common/flow_load.c on the first flow, so the programs link neither OpenCV
# nor the C++ runtime.
FLOW_SRC = common/flow_cv.cpp common/error.c
FLOW_OBJ = $(patsubst %.c,%.o,$(FLOW_SRC:%.cpp=%.o))
FLOW_LIB = $(BUILD)/libtexsyn-flow.so
FLOW_CFLAGS = -I/usr/include/opencv4
FLOW_LIBS = -lopencv_video -lopencv_core

# GIS rasters and vectors (common/gis.h, gis_lib.h) as a shared library
# of its own, built like the others: GDAL's C API behind a table, loaded
# by common/gis_load.c on the first GIS call. Its C sits in common/gis/,
# a folder the static library does not take, and only it sees GDAL's headers.
GIS_SRC = $(wildcard common/gis/*.c) common/error.c
GIS_OBJ = $(GIS_SRC:%.c=%.o)
GIS_LIB = $(BUILD)/libtexsyn-gis.so
GDAL_CFLAGS := $(or $(shell pkg-config --cflags gdal 2>/dev/null),-I/usr/include/gdal)
GDAL_LIBS := $(or $(shell pkg-config --libs gdal 2>/dev/null),-lgdal)
INC_common/gis = $(INC_common) -Icommon/gis $(GDAL_CFLAGS)

BINS = $(BUILD)/texsyn $(BUILD)/texsyn-server $(BUILD)/texsyn-worker
UNIT_SRC = $(wildcard tests/unit/test_*.c)
UNIT_BINS = $(UNIT_SRC:tests/unit/%.c=$(BUILD)/tests/%)
# The libFuzzer targets' inputs replayed by a plain main() (tests/fuzz).
FUZZ_TARGETS = frame msg jobspec image checkpoint modbus spool catalogue gis_rules
REPLAY_BINS = $(FUZZ_TARGETS:%=$(BUILD)/tests/replay_%)
BENCH_SRC = $(wildcard bench/*.c)
BENCH_BINS = $(BENCH_SRC:bench/%.c=$(BUILD)/bench/%)

.PHONY: all install deps test test-unit test-integration test-faults test-valgrind fuzz fuzz-build bench demo clean
# Shims preloaded into texsyn-server by fault tests: a poll() that fails on
# demand, a rename() that kills the process (tests/preload/).
PRELOADS = $(BUILD)/tests/libfail_poll.so $(BUILD)/tests/libkill_at_rename.so
# ... and one that numbers the spool's writes, killing or failing one.
PRELOADS += $(BUILD)/tests/libspool_fault.so
all: $(BINS) $(IMAGE_LIB) $(FLOW_LIB) $(GIS_LIB) $(UNIT_BINS) $(BENCH_BINS) $(REPLAY_BINS) $(PRELOADS)

$(BUILD)/%.o: %.c
	@mkdir -p $(dir $@)
	$(CC) $(CFLAGS_ALL) $(call inc,$<) -MMD -MP -c $< -o $@

$(BUILD)/pic/%.o: %.c
	@mkdir -p $(dir $@)
	$(CC) $(CFLAGS_ALL) $(PIC) $(call inc,$<) -MMD -MP -c $< -o $@

$(BUILD)/pic/%.o: %.cpp
	@mkdir -p $(dir $@)
	$(CXX) $(CXXFLAGS_ALL) $(PIC) -MMD -MP -c $< -o $@

$(LIB): $(LIB_OBJ)
	@rm -f $@
	ar rcs $@ $^

# -z defs: a symbol the library lacks fails this link, not a dlopen later.
$(IMAGE_LIB): $(IMAGE_OBJ:%=$(BUILD)/pic/%)
	$(CXX) -shared $(LDFLAGS_ALL) -Wl,-z,defs -o $@ $^ $(IMAGE_LIBS)

$(BUILD)/pic/common/flow_cv.o: CXXFLAGS_ALL += $(FLOW_CFLAGS)
$(FLOW_LIB): $(FLOW_OBJ:%=$(BUILD)/pic/%)
	$(CXX) -shared $(LDFLAGS_ALL) -Wl,-z,defs -o $@ $^ $(FLOW_LIBS)

$(GIS_LIB): $(GIS_OBJ:%=$(BUILD)/pic/%)
	$(CC) -shared $(LDFLAGS_ALL) -Wl,-z,defs -o $@ $^ $(GDAL_LIBS) -lpthread -lm

$(BUILD)/texsyn: $(BUILD)/server/cli/main.o $(LIB)
	$(CC) $(LDFLAGS_ALL) -o $@ $^ $(LIBS)

$(BUILD)/texsyn-server: $(BUILD)/server/main.o $(LIB)
	$(CC) $(LDFLAGS_ALL) -o $@ $^ $(LIBS) $(MHD_LIBS)

$(BUILD)/texsyn-worker: $(BUILD)/worker/main.o $(LIB)
	$(CC) $(LDFLAGS_ALL) -o $@ $^ $(LIBS)

# Test binaries live in BUILD/tests/, not next to the image library: the
# runners point TEXSYN_IMAGE_LIB at it.
$(BUILD)/tests/%: $(BUILD)/tests/unit/%.o $(LIB)
	@mkdir -p $(dir $@)
	$(CC) $(LDFLAGS_ALL) -o $@ $^ $(LIBS) -lcmocka

# test_gis makes its fixtures and checks its outputs with GDAL itself (an
# independent reader), while what it tests goes through libtexsyn-gis.so.
$(BUILD)/tests/unit/test_gis.o: CFLAGS_ALL += $(GDAL_CFLAGS)
$(BUILD)/tests/test_gis: LIBS += $(GDAL_LIBS)

$(BUILD)/tests/replay_%: $(BUILD)/tests/fuzz/fuzz_%.o $(BUILD)/tests/fuzz/replay.o $(LIB)
	@mkdir -p $(dir $@)
	$(CC) $(LDFLAGS_ALL) -o $@ $^ $(LIBS)

# Without sanitizers: preloaded ahead of an ASan runtime, it would stop it.
$(BUILD)/tests/lib%.so: tests/preload/%.c
	@mkdir -p $(dir $@)
	$(CC) -std=c11 -D_GNU_SOURCE $(WARN) -O2 -fPIC -shared -o $@ $< -ldl

$(BUILD)/bench/%: $(BUILD)/bench/%.o $(LIB) | $(BUILD)/bench/$(notdir $(IMAGE_LIB)) \
                                               $(BUILD)/bench/$(notdir $(GIS_LIB))
	@mkdir -p $(dir $@)
	$(CC) $(LDFLAGS_ALL) -o $@ $^ $(LIBS)

# Benchmark programs that write images (bench/mkscene) find the image
# library next to themselves, as the programs do.
$(BUILD)/bench/$(notdir $(IMAGE_LIB)): $(IMAGE_LIB)
	@mkdir -p $(dir $@)
	ln -sf ../$(notdir $(IMAGE_LIB)) $@

$(BUILD)/bench/$(notdir $(GIS_LIB)): $(GIS_LIB)
	@mkdir -p $(dir $@)
	ln -sf ../$(notdir $(GIS_LIB)) $@

# The library goes to ../lib/texsyn from the programs' directory, where
# they look for it (common/image_load.c); DESTDIR for staged installs.
PREFIX ?= /usr/local
install: $(BINS) $(IMAGE_LIB) $(FLOW_LIB) $(GIS_LIB) install-man
	install -d $(DESTDIR)$(PREFIX)/bin $(DESTDIR)$(PREFIX)/lib/texsyn
	install -m 755 $(BINS) $(DESTDIR)$(PREFIX)/bin/
	install -m 644 $(IMAGE_LIB) $(FLOW_LIB) $(GIS_LIB) $(DESTDIR)$(PREFIX)/lib/texsyn/

# The command pages (doc/texsyn*.md): `make doc` fills their options blocks
# with what the programs' --help prints (doc/gen.py; test_manual.py fails on
# a stale one). Each page is also a man page (doc/md2man.py), with a stub
# for each further name it has (texsyn-watch: texsyn-jobs), installed into
# PREFIX/share/man/man1.
DOC_PAGES = $(wildcard doc/texsyn*.md)
MAN_DIR = $(BUILD)/man
.PHONY: doc install-man
doc: $(BINS)
	/usr/bin/python3 doc/gen.py --build $(BUILD)

$(MAN_DIR)/.stamp: $(DOC_PAGES) doc/md2man.py
	rm -rf $(MAN_DIR)
	/usr/bin/python3 doc/md2man.py --out $(MAN_DIR) $(DOC_PAGES)
	touch $@

install-man: $(MAN_DIR)/.stamp
	install -d $(DESTDIR)$(PREFIX)/share/man/man1
	install -m 644 $(MAN_DIR)/*.1 $(DESTDIR)$(PREFIX)/share/man/man1/

deps:
	@bash deploy/install-deps.sh

# The whole suite: unit tests (each test in its own process), integration
# tests driving the real binaries, then the unit tests again under ASan+UBSan;
# the fuzz seeds and regressions replayed on both builds; each libFuzzer
# target for 7 s (as long as the unit stages it runs beside).
test: deps
	$(MAKE) -j2 all
	$(MAKE) -j2 SAN=1 all
	$(MAKE) -j2 fuzz-build
	bash tests/run-all.sh

test-unit: all
	bash tests/run-unit.sh $(BUILD)

test-integration: all
	bash tests/run-integration.sh $(BUILD)

# The fault-injection suite with TRIALS random worker faults (`make test`
# runs 6), then 50 jobs from 5 clients with a worker killed, then the
# coordinator killed half-way through level 0 of a job of 20 s or more
# (it prints the step resumed at and the work redone). A failing trial
# names its seed: replay it with TEXSYN_FAULT_SEED=S.
TRIALS ?= 20
test-faults: all
	TEXSYN_DATA=$$(bash tests/test-data.sh) && export TEXSYN_DATA && \
	TEXSYN_BUILD=$(abspath $(BUILD)) TEXSYN_FAULT_TRIALS=$(TRIALS) TEXSYN_LONG_TESTS=1 /usr/bin/python3 -m pytest -q \
	  -p no:cacheprovider --durations=5 tests/integration/test_faults.py tests/integration/test_load.py \
	  tests/integration/test_resume.py && \
	TEXSYN_BUILD=$(abspath $(BUILD)) TEXSYN_LONG_TESTS=1 /usr/bin/python3 -m pytest -q -p no:cacheprovider \
	  --durations=5 -m long tests/integration/test_cluster.py tests/integration/test_modbus.py \
	  tests/integration/test_crashpoints.py \
	  tests/integration/test_disk_faults.py tests/integration/test_partitions.py
	TEXSYN_DATA=$$(bash tests/test-data.sh) TEXSYN_BUILD=$(abspath $(BUILD)) TEXSYN_LONG_TESTS=1 /usr/bin/python3 -m pytest \
	  -q -p no:cacheprovider --durations=5 -m long tests/integration/test_hostile.py tests/integration/test_phases.py

# The man-in-the-middle relay of tests/integration/test_seal.py for
# SEAL_ROUNDS rounds of 8 sealed-frame alterations (default 125: 1,000
# trials, about 70 minutes on 2 cores; `make test` runs one round).
SEAL_ROUNDS ?= 125
.PHONY: test-seal
test-seal: all
	TEXSYN_DATA=$$(bash tests/test-data.sh) TEXSYN_BUILD=$(abspath $(BUILD)) TEXSYN_SEAL_ROUNDS=$(SEAL_ROUNDS) \
	  /usr/bin/python3 -m pytest -q -p no:cacheprovider --durations=5 tests/integration/test_seal.py

# Seeded random schedules of a hostile worker (issue 25) over every engine:
# SCHEDULES (default 2000, about 35 minutes on 2 cores), the seed printed and
# new per run, SEED=S to replay one; writes bench/results/hostile.{json,md}.
# tests/hostile_run.py says what a schedule is and what it checks.
SCHEDULES ?= 2000
.PHONY: test-hostile
test-hostile: $(BINS) $(IMAGE_LIB) $(BUILD)/bench/mkscene
	TEXSYN_DATA=$$(bash tests/test-data.sh) /usr/bin/python3 tests/hostile_run.py --build $(BUILD) \
	  --schedules $(SCHEDULES) $(if $(SEED),--seed $(SEED))

# The cluster's integration tests (tests/run-tsan.sh says which) on the
# ThreadSanitizer build: a data race in a daemon or the client fails its
# test (not in `test`: about 7 minutes on 2 busy cores, build included).
.PHONY: test-tsan tsan-build
test-tsan: deps
	$(MAKE) -j2 TSAN=1 tsan-build
	bash tests/run-tsan.sh build-tsan

# What test-tsan runs, with TSAN=1: the programs, the image and GIS
# libraries, the preloaded shims, and the scene maker its aerial tests use.
tsan-build: $(BINS) $(IMAGE_LIB) $(GIS_LIB) $(PRELOADS) $(BUILD)/bench/mkscene

# Every unit test under valgrind memcheck (about 4 minutes; not in `test`).
test-valgrind: deps all
	bash tests/run-valgrind.sh $(BUILD)

# libFuzzer targets (clang, clang++ for the OpenImageIO shim) in
# build-fuzz/: each runs FUZZ_SECONDS on build-fuzz/corpus-<target>, seeded
# from tests/fuzz/seeds/<target> and tests/fuzz/regress/<target>; findings
# go to build-fuzz/artifacts/. `make test` runs each for 7 s.
FUZZ_SECONDS ?= 30
FUZZ_SAN = -g -O1 -fno-omit-frame-pointer -fsanitize=address,undefined -fno-sanitize-recover=undefined
FUZZ_CC = clang -std=c11 -D_GNU_SOURCE $(WARN) $(FUZZ_SAN) -fsanitize=fuzzer-no-link
FUZZ_CXX = clang++ -std=c++17 -Wall -Wextra -Werror $(FUZZ_SAN) -fsanitize=fuzzer-no-link -Icommon
# The fuzz targets link the library built with the fuzzer's flags; each
# pulls in only the objects it reaches. The image library is built with
# them too and loaded by fuzz_image from next to it, as the programs load
# theirs: coverage guides the fuzzer through the shim, and what is fuzzed
# is the dlopen path that ships.
FUZZ_LIB = build-fuzz/libtexsyn.a
FUZZ_LIB_OBJ = $(LIB_C:%.c=build-fuzz/%.o)
FUZZ_IMAGE_LIB = build-fuzz/libtexsyn-image.so

build-fuzz/%.o: %.c
	@mkdir -p $(dir $@)
	$(FUZZ_CC) $(call inc,$<) -MMD -MP -c $< -o $@

build-fuzz/pic/%.o: %.c
	@mkdir -p $(dir $@)
	$(FUZZ_CC) $(PIC) $(call inc,$<) -MMD -MP -c $< -o $@

build-fuzz/pic/%.o: %.cpp
	@mkdir -p $(dir $@)
	$(FUZZ_CXX) $(PIC) -MMD -MP -c $< -o $@

.PRECIOUS: build-fuzz/%.o
$(FUZZ_LIB): $(FUZZ_LIB_OBJ)
	@rm -f $@
	ar rcs $@ $^

# No -z defs here: clang leaves the sanitizer runtimes to the executable.
$(FUZZ_IMAGE_LIB): $(IMAGE_OBJ:%=build-fuzz/pic/%)
	clang++ $(FUZZ_SAN) -shared -o $@ $^ $(IMAGE_LIBS)

# Linked by clang++: the image library's UBSan checks need the runtime's
# C++ parts, which only clang++ puts into the executable.
build-fuzz/fuzz_%: build-fuzz/tests/fuzz/fuzz_%.o $(FUZZ_LIB)
	clang++ $(FUZZ_SAN) -fsanitize=fuzzer -o $@ $^ $(LIBS)

fuzz-build: $(FUZZ_TARGETS:%=build-fuzz/fuzz_%) $(FUZZ_IMAGE_LIB)

fuzz: deps fuzz-build
	bash tests/run-fuzz.sh fuzz $(FUZZ_SECONDS)

bench: deps all
	bash bench/run.sh $(BUILD) --quick

.PHONY: bench-full
bench-full: deps all
	bash bench/run.sh $(BUILD) --full

# Cluster efficiency under 0-1000 us of added round-trip time between the
# coordinator and its workers, in network namespaces (not in `make test`:
# a few minutes, needs root); bench/netem.py says how. NETEM_ARGS=--quick
# for a smaller job.
.PHONY: bench-netem
bench-netem: $(BINS) $(IMAGE_LIB) $(BUILD)/bench/delay_relay
	bash deploy/install-deps.sh --bench
	/usr/bin/python3 bench/netem.py --build $(BUILD) --out bench/results $(NETEM_ARGS)

# Soak (not in `make test`; root: network namespaces, nft, a tmpfs spool):
# 4 clients submit small jobs for SOAK_MINUTES to a coordinator whose 3
# workers are SIGKILLed, SIGSTOPped, cut off (partitions, half-open links)
# and replaced at random, while the coordinator itself is SIGKILLed and
# restarted on its spool and that spool's disk is filled or made read-only.
# Every accepted job must be done once with the embedded run's bytes or fail
# with a reason under a disk fault; the daemons' fds, RSS and the spool must
# stay within the bounds bench/soak.py states. It ends and reports by
# SOAK_MINUTES + 5 minutes whatever hangs. Writes bench/results/soak.json
# and soak.txt.
SOAK_MINUTES ?= 10
.PHONY: soak
soak: $(BINS) $(IMAGE_LIB)
	@bash deploy/install-deps.sh
	/usr/bin/python3 bench/soak.py --build $(BUILD) --minutes $(SOAK_MINUTES)

# Not in `make test`: it installs Slurm and starts its daemons (as root),
# and takes under a minute here. tests/deploy/run.sh says what each check does.
.PHONY: test-deploy
test-deploy: deps $(BINS) $(IMAGE_LIB)
	bash tests/deploy/run.sh $(BUILD)

demo: deps all
	bash deploy/demo.sh $(BUILD)

clean:
	rm -rf build build-asan build-fuzz
	rm -rf build-tsan

-include $(shell find $(BUILD) build-fuzz -name '*.d' 2>/dev/null)
