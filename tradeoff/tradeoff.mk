# tradeoff/tradeoff.mk — the speed-accuracy sweep, included by the Makefile.
#
#   make tradeoff           full sweep: 128x128, reference 2 x 8192 spp MIS, path tracing
#                           2..2048 spp per estimator, radiosity patch size x iterations per
#                           solver, Whitted max depth / min weight, local light samples
#                           (about 20 minutes on 2 cores) -> out/tradeoff.csv, out/tradeoff.md,
#                           out/tradeoff-*.png/.svg
#   make tradeoff QUICK=1   the whole pipeline on a tiny budget (32x32; under a minute)
#                           -> out/quick/...
# Overrides (environment or make variables): SIZE, REF_SPP, PT_MAX_SPP, REPEATS, CAP, AA_SPP,
# OUT, REUSE_REF=1 (see tradeoff/tradeoff.py).

TRADEOFF_PACKAGES := gnuplot-nox

QUICK ?=
.PHONY: tradeoff
tradeoff: deps-tradeoff
	$(MAKE) --no-print-directory all
	QUICK=$(QUICK) BUILD=$(BUILD) $(PYTHON) tradeoff/tradeoff.py
	QUICK=$(QUICK) BUILD=$(BUILD) $(PYTHON) tradeoff/hierarchical.py  # radiosity: hierarchical against uniform
