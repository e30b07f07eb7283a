# wfisim — one static library per layer, one program, Check tests.
#   make            build bin/wfisim
#   make MPI=1      also bin/wfisim-mpi: `survey run` on many processes (Open MPI's mpicc)
#   make demo       run the main job on the built-in default scene
#   make test       build and run every test (SAN=1: under ASan+UBSan)
#   make bench      benchmarks -> docs/BENCHMARKS.md
#   make fuzz       libFuzzer harnesses (fuzz/), FUZZ_SECONDS each -> docs/FUZZ.md
PKGS    := cfitsio fftw3 zlib libdeflate yaml-0.1
CC      ?= cc
PKG_CONFIG   ?= pkg-config
INSTALL_DEPS ?= scripts/install-deps.sh
SAN     ?= 0
FUZZ    ?= 0
FUZZ_CC ?= clang
ifeq ($(FUZZ),1)
# The fuzz build (make fuzz): clang's libFuzzer needs clang's coverage hooks in the code.
CC      := $(FUZZ_CC)
OPT     := -O1
endif
# -O2's vectoriser with -O3's cost model: loops of unknown length and possible aliasing get
# vector versions too (5% fewer instructions over GalSim's scene). ISO C mode contracts no
# multiply-add and nothing is reassociated, so the bits are those of plain -O2.
# -fno-math-errno -fno-trapping-math change no value either (no code reads errno after libm
# or the FPU's flags): without them a comparison or sqrt under a condition, or nearbyint,
# keeps a loop scalar (the moments ramp's selects and the ADC's rounding: 10% of its time).
OPT     ?= -O2 -fvect-cost-model=dynamic -fno-math-errno -fno-trapping-math
CFLAGS  := -std=c11 -D_DEFAULT_SOURCE -Wall -Wextra -Werror -Wshadow \
           -Wstrict-prototypes -Wmissing-prototypes -g $(OPT) -I. \
           $(shell $(PKG_CONFIG) --cflags $(PKGS) 2>/dev/null)
LDLIBS  := $(shell $(PKG_CONFIG) --libs $(PKGS) 2>/dev/null) -lsep -lpthread -lm
TEST_LDLIBS := $(shell $(PKG_CONFIG) --libs check 2>/dev/null)

# The README's commands (demo, test, bench) install the packages first and only then build,
# in a second make that reads this file again: flags resolved while it was first read, on a
# machine without the packages, would be empty. Any other build needs the packages already.
ENTRY   := demo test bench deps clean
BUILDING := $(filter-out $(ENTRY),$(or $(MAKECMDGOALS),all))
ifneq ($(BUILDING),)
ifneq ($(shell $(PKG_CONFIG) --exists $(PKGS) check 2>/dev/null && echo yes),yes)
$(error missing build packages ($(PKGS) check): run `make deps` (scripts/install-deps.sh) first)
endif
endif

ifeq ($(SAN),1)
BUILD   := build/san
CFLAGS  += -fsanitize=address,undefined -fno-omit-frame-pointer -fno-sanitize-recover=all
LDFLAGS += -fsanitize=address,undefined
else ifeq ($(FUZZ),1)
BUILD   := build/fuzz
CFLAGS  += -fsanitize=fuzzer-no-link,address,undefined -fno-omit-frame-pointer \
           -fno-sanitize-recover=all
LDFLAGS += -fsanitize=address,undefined
else
BUILD   := build/rel
endif

# The compiler and flags a build directory was made with: when they change (OPT=..., another
# CC), everything in it is rebuilt rather than mixed with objects made with the old ones.
FLAGS   := $(BUILD)/flags
FLAGS_NOW := $(strip $(CC) $(CFLAGS) $(LDFLAGS))
ifneq ($(BUILDING),)
ifneq ($(FLAGS_NOW),$(strip $(shell cat $(FLAGS) 2>/dev/null)))
$(shell mkdir -p $(BUILD) && printf '%s\n' '$(FLAGS_NOW)' > $(FLAGS))
endif
endif

LAYERS  := hal firmware $(patsubst %/,%,$(sort $(dir $(wildcard sim/*/*.c)))) analysis tools
HEADERS := $(wildcard */*.h */*/*.h)
LIBSRC  := $(filter-out tools/main.c tools/survey_mpi.c,$(foreach d,$(LAYERS),$(wildcard $(d)/*.c)))
LIBOBJ  := $(LIBSRC:%.c=$(BUILD)/%.o)
LIB     := $(BUILD)/libwfisim.a
TESTSRC := $(wildcard tests/test_*.c)
TESTBIN := $(TESTSRC:tests/%.c=$(BUILD)/tests/%)
TESTUTIL:= $(BUILD)/tests/testutil.o
PROG    := bin/wfisim
ifeq ($(SAN),1)
PROG    := $(BUILD)/wfisim
endif
# The MPI program: main.c and tools/survey_mpi.c compiled by mpicc with WF_MPI, linked with
# the same library, so the plain program and the library never need MPI's headers. Built by
# MPI=1, and for the tests whenever mpicc is there (the test is skipped without it).
MPI     ?= 0
MPICC   ?= mpicc
MPIPROG := $(patsubst %/wfisim,%/wfisim-mpi,$(PROG))
HAVE_MPICC := $(shell command -v $(MPICC) 2>/dev/null)

.PHONY: all demo test tests bench clean deps run-demo run-test run-bench fuzz fuzz-smoke \
        fuzz-targets
.SECONDARY: $(TESTUTIL) $(BUILD)/fuzz/common.o
all: $(PROG) $(if $(filter 1,$(MPI)),$(MPIPROG))

# '+': runs under `make -n` too, so a dry run shows the build the installed packages give.
deps:
	+@$(INSTALL_DEPS)

$(BUILD)/%.o: %.c $(HEADERS) $(FLAGS)
	@mkdir -p $(dir $@)
	$(CC) $(CFLAGS) -c $< -o $@

# The version a product records (tools/digest.h) carries a digest of the program's sources:
# any change to the code that makes products changes it. Rewritten only when it changes.
SRCDIGEST_IN := $(sort $(foreach d,$(LAYERS),$(wildcard $(d)/*.c $(d)/*.h)))
SRCDIGEST := $(BUILD)/gen/srcdigest.h
$(SRCDIGEST): $(SRCDIGEST_IN)
	@mkdir -p $(dir $@)
	@printf '#define WF_SOURCE_DIGEST "%s"\n' "$$(cat $(SRCDIGEST_IN) | sha256sum | cut -c1-16)" > $@.tmp
	@cmp -s $@.tmp $@ && rm -f $@.tmp || mv $@.tmp $@
$(BUILD)/tools/digest.o: $(SRCDIGEST)
$(BUILD)/tools/digest.o: CFLAGS += -include $(SRCDIGEST)

$(LIB): $(LIBOBJ)
	@mkdir -p $(dir $@)
	ar rcs $@ $^

$(PROG): $(BUILD)/tools/main.o $(LIB) $(FLAGS)
	@mkdir -p $(dir $@)
	$(CC) $(LDFLAGS) -o $@ $(BUILD)/tools/main.o $(LIB) $(LDLIBS)

$(BUILD)/tests/%: tests/%.c $(TESTUTIL) $(LIB) $(HEADERS) $(FLAGS)
	@mkdir -p $(dir $@)
	$(CC) $(CFLAGS) $(LDFLAGS) -o $@ $< $(TESTUTIL) $(LIB) $(TEST_LDLIBS) $(LDLIBS)

$(BUILD)/mpi/%.o: tools/%.c $(HEADERS) $(FLAGS)
	@mkdir -p $(dir $@)
	$(MPICC) $(CFLAGS) -DWF_MPI -c $< -o $@

$(MPIPROG): $(BUILD)/mpi/main.o $(BUILD)/mpi/survey_mpi.o $(LIB) $(FLAGS)
	@mkdir -p $(dir $@)
	$(MPICC) $(LDFLAGS) -o $@ $(BUILD)/mpi/main.o $(BUILD)/mpi/survey_mpi.o $(LIB) $(LDLIBS)

tests: $(TESTBIN) $(PROG) $(if $(HAVE_MPICC),$(MPIPROG))

demo test bench: deps
	+@$(MAKE) --no-print-directory run-$@

run-demo: $(PROG)
	$(PROG) demo --out out/demo --threads $$(nproc)

run-test: tests
	@WFISIM_BIN=$(abspath $(PROG)) $(if $(HAVE_MPICC),WFISIM_MPI_BIN=$(abspath $(MPIPROG))) tests/run-all.sh $(TESTBIN)

run-bench: $(PROG)
	bench/run.sh

clean:
	rm -rf build bin

$(BUILD)/bench/%: bench/%.c $(LIB) $(HEADERS) $(FLAGS)
	@mkdir -p $(dir $@)
	$(CC) $(CFLAGS) $(LDFLAGS) -o $@ $< $(LIB) $(LDLIBS)

# Fuzzing (fuzz/README.md): one libFuzzer harness per outside input. GCC-only code (vector
# extensions clang lacks, no parser in it) is built by gcc without instrumentation.
FUZZ_SECONDS ?= 60
FUZZ_JOBS    ?= 1
FUZZ_GCC     := hal/noise_batch.c firmware/detector.c sim/draw/profile_kernels.c
FUZZBIN := $(patsubst fuzz/%.c,$(BUILD)/bin/%,$(wildcard fuzz/fuzz_*.c))
ifeq ($(FUZZ),1)
$(FUZZ_GCC:%.c=$(BUILD)/%.o): $(BUILD)/%.o: %.c $(HEADERS) $(FLAGS)
	@mkdir -p $(dir $@)
	gcc $(filter-out -fsanitize=% -fno-sanitize-recover=% $(OPT),$(CFLAGS)) -O2 -c $< -o $@
endif

$(BUILD)/bin/fuzz_%: fuzz/fuzz_%.c $(BUILD)/fuzz/common.o $(LIB) $(HEADERS) $(FLAGS)
	@mkdir -p $(dir $@)
	$(CC) $(CFLAGS) $(LDFLAGS) -fsanitize=fuzzer -o $@ $< $(BUILD)/fuzz/common.o $(LIB) $(LDLIBS)

fuzz-targets: $(FUZZBIN)

fuzz fuzz-smoke:
	@printf 'int LLVMFuzzerTestOneInput(const unsigned char *d, unsigned long n) { (void)d; (void)n; return 0; }\n' | \
	    $(FUZZ_CC) -fsanitize=fuzzer,address,undefined -x c - -o /dev/null 2>/dev/null || \
	    $(INSTALL_DEPS) clang libclang-rt-dev
	+@$(MAKE) --no-print-directory FUZZ=1 fuzz-targets
	@FUZZ_CC=$(FUZZ_CC) FUZZ_SECONDS=$(FUZZ_SECONDS) FUZZ_JOBS=$(FUZZ_JOBS) fuzz/run.sh $(if $(filter fuzz-smoke,$@),--smoke) \
	    $(patsubst fuzz/%.c,build/fuzz/bin/%,$(wildcard fuzz/fuzz_*.c))

# The reduced reproduction of the paper's analysis (docs/ANALYSIS.md, "make paper"): survey,
# coadds, differences, detection, efficiencies, hosts -> out/paper/summary.json and plots.
# AREA=RA,DEC,R (deg) sets the circle; PAPER_ARGS passes further options to scripts/paper.sh.
AREA       ?=
PAPER_ARGS ?=
.PHONY: paper
paper: $(PROG)
	WFISIM=$(PROG) scripts/paper.sh $(if $(AREA),--area $(AREA)) $(PAPER_ARGS)
