# tradeoff/tradeoff.mk — the speed-accuracy sweep, included by the Makefile.
#
#   make tradeoff           full sweep: 128x128, reference 2 x 8192 spp MIS, path tracing
#                           2..2048 spp per estimator, radiosity patch size x iterations per
#                           solver, Whitted max depth / min weight, local light samples, photon
#                           mapping over passes; chapter 6 (light tracing, BDPT, VCM over passes)
#                           beside chapter 4's MIS and chapter 5 on cornell, cornell-spheres,
#                           gap, sds and smallpt (their references: chapter 6's BDPT on gap, VCM on
#                           sds, 2 x 512 passes; chapter 4's cosine estimator on smallpt), and the
#                           SDS caustic seen in the mirror
#                           (tradeoff/sds_convergence.py, about 12 CPU minutes; SDS_CONVERGENCE=0
#                           skips it) (about 42 CPU minutes in all,
#                           and smallpt about 12 more: 4x its 64x64 run, not measured at 128x128)
#                           -> out/tradeoff.csv, out/tradeoff.md, out/tradeoff-*.png/.svg
#                           Chapter 7 (PSSMLT and MMLT over mutations per pixel, each point the RMSE
#                           over independent seeds) on the same plots as chapter 6, and
#                           tradeoff/metropolis_blotches.py: BDPT beside MMLT at 1 s and 16 s
#                           -> out/metropolis-blotches.png (docs/metropolis-blotches.png; 70 s)
#   make tradeoff QUICK=1   the whole pipeline on a tiny budget (32x32; 2 min 20 s at load 4;
#                           without smallpt unless SCENES names it) -> out/quick/...
# Overrides (environment or make variables): SIZE, REF_SPP, REF_PASSES, PT_MAX_SPP, REPEATS, CAP,
# AA_SPP, OUT, REUSE_REF=1, SCENES=a,b, BIDIR_ONLY=1, REPORT_ONLY=1 (see tradeoff/tradeoff.py).

TRADEOFF_PACKAGES := gnuplot-nox

# Then radiosity, hierarchical against uniform, on the sweep's Cornell box reference (not when a partial
# run, SCENES without cornell, BIDIR_ONLY or REPORT_ONLY, has none).
QUICK ?=
.PHONY: tradeoff
tradeoff: deps-tradeoff
	$(MAKE) --no-print-directory all
	QUICK=$(QUICK) BUILD=$(BUILD) $(PYTHON) tradeoff/tradeoff.py
	case "$${REPORT_ONLY:-}" in "" | 0) QUICK=$(QUICK) BUILD=$(BUILD) $(PYTHON) tradeoff/metropolis_blotches.py ;; esac
	case ",$${SCENES:-cornell},$${BIDIR_ONLY:-}$${REPORT_ONLY:-}" in *,cornell, | *,cornell,*,) \
	  QUICK=$(QUICK) BUILD=$(BUILD) $(PYTHON) tradeoff/hierarchical.py ;; esac
