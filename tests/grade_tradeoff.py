"""Grading of the speed-accuracy sweep (tradeoff/tradeoff.py).

The first test runs the whole pipeline in QUICK mode (what `make tradeoff
QUICK=1` runs, minus `make all`, which `make test` has done) with this build's
executables into the scratch directory; the others grade its CSV.  The numbers
come from the chapters' own --stats; the noise of each point comes from the
column mse_se, the standard error of the MSE from the spread of the per-pixel
squared errors (pixels have independent random streams).

How the tolerances are derived (a quick run: 32x32 pixels, spp 2, 8, ..., 512):
- An MSE is a mean over 1024 independent pixels, but a handful of them (the
  light's edges, radiance 17 next to 0) dominate it, so its relative standard
  error is large (0.1 to 0.6).  Comparisons are therefore made on log MSE,
  whose standard error is SE(MSE)/MSE (delta method), and a difference counts
  when it exceeds 4 standard errors (one-sided false alarm 3e-5 per check).
- Path tracing's slope: weighted least squares of log RMSE on log spp with
  those errors gives the slope's standard error SE (0.02 to 0.06 in quick
  runs).  Accepted: |slope + 0.5| <= 4 SE, and never wider than 0.2 (the
  interval [-0.7, -0.3]) so the check keeps its teeth: N^-1/4 or N^-1 fail.
  A full run (128x128, 16x the pixels, SE about 4x smaller) would use 0.1,
  [-0.6, -0.4].  Fitted only where the reference's own MSE is at most 10% of
  the point's, after subtracting it (measured MSE = true MSE + reference MSE).
- Radiosity is deterministic (one common seed, no Monte Carlo in its image
  beyond the identical pixel jitter), so its comparisons need no noise margin.
- Times are never compared where the work ratio is small: tests do not depend
  on the machine's speed (benchmarks measure speed); the only time check is 1 spp-equivalent
  against 256 times the samples.  So chapter 6's targets (ratios at equal time) are
  measured and reported by the full run (out/tradeoff.md, targets.json), not tested here.
- Chapter 6 (light tracing, BDPT, VCM over passes 2 .. 128): on four scenes; its error
  falls from 2 passes to the last by 4 standard errors of log MSE (expected: log 64 = 4.2
  for an unbiased method; measured 3.0 to 4.5 with standard errors 0.3 to 0.5) on cornell
  and gap, where the quick run resolves it.  Not on cornell-spheres (light tracing misses
  what the camera sees in the mirror and through the glass, a floor; BDPT's caustics
  through the glass are rare large samples: standard errors above 1) nor on sds at 32x32
  (one pixel of the mirror ball, a rare eye path that hits the 13 mm light, weighted
  against merging with only 1,024 light paths a pass, dominates even the reference's
  error: its own RMSE 0.15 against 0.001 on cornell).
- Chapter 7 (PSSMLT and MMLT over mutations per pixel, 4 .. 64): at least 3 points on
  every scene, each over at least 2 independent seeds with a finite standard error over
  them (its error is correlated across pixels; a fall of the error is not tested: two
  seeds give no standard error to test it with).
- A reference from chapter 6 (BDPT on gap) against chapter 4: path tracing's longest
  run has the reference's image mean within 4 standard errors, sqrt(MSE / pixels) (path
  tracing's pixels have independent errors; it is unbiased, so a biased reference fails).
"""
import csv
import json
import math
import os
import subprocess

import lib

GRADES_NOTHING = True  # no grading, no handout: may run beside the RUN_ALONE tests (tests/run.py)

PYTHON = "/usr/bin/python3"
SCRIPT = os.path.join(lib.ROOT, "tradeoff", "tradeoff.py")
# The quick run's scenes: tradeoff.py's SCENES less NOT_QUICK (smallpt runs only in a full run or when SCENES names it).
SCENES = ["cornell", "cornell-spheres", "gap", "sds"]
FULL_SCENES = ["cornell", "cornell-spheres"]  # every chapter; on gap and sds only chapters 4 (MIS), 5 and 6
BIDIR = ["light", "bdpt", "vcm"]
METROPOLIS = ["pssmlt", "mmlt"]  # chapter 7: every point over independent seeds (tradeoff.py's MLT_METHODS)
ESTIMATORS = ["hemisphere", "cosine", "light", "mis"]
REQUIRED_COLUMNS = ["scene", "method", "setting", "spp", "patches", "time_s", "rmse", "relmse", "ssim"]
SLOPE_HALF_WIDTH_QUICK = 0.2
Z = 4.0

_runs = {}  # build -> (out dir, rows, references): the pipeline runs once per build
RUN_IN_SEQUENCE = True  # (tests/run.py) in one worker, so that they share _runs: else each worker ran the pipeline


def _pipeline(ctx):
    if ctx.build in _runs:
        return _runs[ctx.build]
    out = ctx.path("tradeoff-out")
    env = dict(os.environ, QUICK="1", BUILD=ctx.build, OUT=out)
    if "asan" in ctx.build:
        # Not run by the tests (each returns early on the sanitizer build: the
        # pipeline is Python around renders that every chapter's own tests run
        # under the sanitizers); by hand, the sanitizer build (ASan + -O1, ~5x
        # slower) takes a reference of 2 x 2048 spp instead of 2 x 4096 and a
        # longer cap.
        env.update(REF_SPP="2048", CAP="20")
    result = subprocess.run([PYTHON, SCRIPT], cwd=lib.ROOT, env=env, capture_output=True, text=True,
                            timeout=900, stdin=subprocess.DEVNULL)
    assert result.returncode == 0, f"tradeoff.py exited {result.returncode}:\n{result.stderr[-3000:]}"
    with open(os.path.join(out, "tradeoff.csv")) as f:
        rows = list(csv.DictReader(f))
    with open(os.path.join(out, "tradeoff", "references.json")) as f:
        refs = json.load(f)["references"]
    for r in rows:
        for k in ("spp", "patches", "time_s", "cpu_s", "rmse", "relmse", "ssim", "mse_se", "ref_mse", "patch_size",
                  "pixels", "mean", "seeds"):
            r[k] = float(r[k]) if r.get(k) not in ("", None) else None
    _runs[ctx.build] = (out, rows, refs)
    return _runs[ctx.build]


def _curve(rows, scene, curve):
    return [r for r in rows if r["scene"] == scene and r["curve"] == curve and r["status"] == "ok"]


def _log_mse_and_sigma(r):
    mse = r["rmse"] ** 2
    return math.log(mse), r["mse_se"] / mse


def test_tradeoff_1_pipeline_outputs(ctx):
    # The pipeline is Python around renders that every chapter's own tests run under the sanitizers.
    if lib.sanitizer_build(ctx):
        return
    out, rows, refs = _pipeline(ctx)
    with open(os.path.join(out, "tradeoff.csv")) as f:
        header = f.readline().strip().split(",")
    missing = [c for c in REQUIRED_COLUMNS if c not in header]
    assert not missing, f"tradeoff.csv lacks columns {missing}"
    for scene in SCENES:
        methods = {r["method"] for r in rows if r["scene"] == scene and r["status"] == "ok"}
        expected = {"pathtrace", "photonmap", "bidirectional", "metropolis"}
        if scene in FULL_SCENES:
            expected |= {"radiosity", "whitted", "local"}
        assert methods >= expected, f"{scene}: methods {methods}, expected {expected}"
        for e in ESTIMATORS if scene in FULL_SCENES else ["mis"]:
            assert len(_curve(rows, scene, f"pt-{e}")) >= 3, f"{scene}: fewer than 3 points for {e}"
        for m in BIDIR:
            assert len(_curve(rows, scene, f"bd-{m}")) >= 3, f"{scene}: fewer than 3 points for chapter 6's {m}"
        for m in METROPOLIS:
            points = _curve(rows, scene, f"mlt-{m}")
            assert len(points) >= 3, f"{scene}: fewer than 3 points for chapter 7's {m}"
            for r in points:  # correlated error: the RMSE over independent seeds, its standard error over them
                assert r["seeds"] >= 2 and r["mse_se"] is not None and math.isfinite(r["mse_se"]), \
                    f"{scene} mlt-{m} {r['setting']}: seeds {r['seeds']}, mse_se {r['mse_se']}"
        for r in rows:
            if r["scene"] == scene and r["status"] == "ok":
                for k in ("time_s", "cpu_s", "rmse", "relmse", "ssim"):
                    assert r[k] is not None and math.isfinite(r[k]), f"{scene} {r['curve']} {r['setting']}: {k}"
                assert r["time_s"] > 0 and r["rmse"] > 0
        ref = refs[scene]
        assert ref["nonfinite_samples"] == 0
        assert 0 < ref["rmse"] == ref["rmse_halves"] / 2
        plots = [f"tradeoff-bidirectional-{scene}"] + \
            ([f"tradeoff-{scene}", f"tradeoff-radiosity-{scene}"] if scene in FULL_SCENES else [])
        for name in (p + ".png" for p in plots):
            with open(os.path.join(out, name), "rb") as f:
                assert f.read(8) == b"\x89PNG\r\n\x1a\n", f"{name} is not a PNG"
        for name in (p + ".svg" for p in plots):
            with open(os.path.join(out, name)) as f:
                text = f.read()
            assert "<svg" in text and "</svg>" in text, f"{name} is not an SVG"
    with open(os.path.join(out, "tradeoff.md")) as f:
        md = f.read()
    for scene in SCENES:
        assert f"## {scene}.scene" in md
        assert f"### {scene}.scene" in md, f"tradeoff.md: no equal-time section of chapters 4, 5, 6 for {scene}"
    assert "fastest is" in md or "no method gets there" in md
    with open(os.path.join(out, "tradeoff", "targets.json")) as f:
        targets = json.load(f)
    assert set(targets) == set(SCENES), f"targets.json: scenes {sorted(targets)}"
    assert targets["gap"]["time_s"]["bdpt_over_pt"], "targets.json: no BDPT / path tracing ratio on gap"


def test_tradeoff_2_error_falls_along_each_sweep(ctx):
    if lib.sanitizer_build(ctx):  # as test 1
        return
    _, rows, _ = _pipeline(ctx)
    for scene in FULL_SCENES:
        # Path tracing: spp grows 4x per point; 2 spp against the last point.
        for e in ESTIMATORS:
            pts = sorted(_curve(rows, scene, f"pt-{e}"), key=lambda r: r["spp"])
            a, b = pts[0], pts[-1]
            (la, sa), (lb, sb) = _log_mse_and_sigma(a), _log_mse_and_sigma(b)
            assert la - lb > Z * math.hypot(sa, sb), \
                f"{scene} {e}: log MSE {la:.3f} at {a['spp']:.0f} spp, {lb:.3f} at {b['spp']:.0f} spp " \
                f"(need a fall of {Z} x {math.hypot(sa, sb):.3f})"
            if b["spp"] >= 64 * a["spp"]:
                assert b["time_s"] > a["time_s"], f"{scene} {e}: {b['spp']:.0f} spp no slower than {a['spp']:.0f}"
        # Radiosity, the finest patch size with an iteration sweep: Jacobi and
        # Gauss-Seidel error falls from K=1 and then stops (the floor).  Both
        # deterministic: no noise margin.  The floor: the iterate's remaining
        # change after K steps is at most rho^K / (1 - rho) of the indirect
        # light, and relative to the first step's rho^(K-1) -- for the white
        # walls' rho = 0.725 and K = 16, 0.6 %: we allow 10 %.
        for solver in ("jacobi", "gauss-seidel"):
            pts = _curve(rows, scene, f"radiosity-{solver}-iter")
            assert pts, f"{scene}: no {solver} iteration sweep"
            finest = min(r["patch_size"] for r in pts)
            sweep = sorted([r for r in pts if r["patch_size"] == finest], key=lambda r: int(r["setting"].split("K=")[1]))
            conv = [r for r in _curve(rows, scene, f"radiosity-{solver}") if r["patch_size"] == finest]
            assert conv, f"{scene}: no converged {solver} run at S={finest}"
            first, last, floor = sweep[0]["rmse"], sweep[-1]["rmse"], conv[0]["rmse"]
            assert first > last, f"{scene} {solver} S={finest}: rmse {first} at K=1, {last} at the end"
            if scene == "cornell":  # rho = 0.725; the mirror ball (0.95) of the other scene converges slower
                assert abs(last - floor) <= 0.1 * (first - floor), \
                    f"{scene} {solver} S={finest}: no floor (K=1 {first}, last K {last}, converged {floor})"
        # Local illumination: more light samples only remove light-sampling
        # noise, under the (large) bias of the missing indirect light; the
        # expected fall is below a quick run's resolution, so the check is that
        # the error does not rise significantly.
        pts = sorted(_curve(rows, scene, "local"), key=lambda r: int(r["setting"].split("=")[1]))
        (la, sa), (lb, sb) = _log_mse_and_sigma(pts[0]), _log_mse_and_sigma(pts[-1])
        assert lb - la <= Z * math.hypot(sa, sb), f"{scene} local: error rises with light samples ({la} -> {lb})"


def test_tradeoff_5_bidirectional_error_falls(ctx):
    """Chapter 6's passes: 2 passes against the last (64 times the passes), on cornell and gap (module
    docstring: where the quick run resolves the fall)."""
    if lib.sanitizer_build(ctx):
        return
    _, rows, _ = _pipeline(ctx)
    failures = []
    for scene in ("cornell", "gap"):
        for m in BIDIR:
            pts = sorted(_curve(rows, scene, f"bd-{m}"), key=lambda r: r["spp"])
            a, b = pts[0], pts[-1]
            (la, sa), (lb, sb) = _log_mse_and_sigma(a), _log_mse_and_sigma(b)
            if not la - lb > Z * math.hypot(sa, sb):
                failures.append(f"{scene} {m}: log MSE {la:.3f} at {a['spp']:.0f} passes, {lb:.3f} at "
                                f"{b['spp']:.0f} (need a fall of {Z} x {math.hypot(sa, sb):.3f})")
    assert not failures, "; ".join(failures)


def test_tradeoff_6_bidirectional_reference_agrees_with_pathtrace(ctx):
    """gap.scene's reference is chapter 6's BDPT: path tracing's longest run (unbiased, independent pixels) has
    its image mean within 4 standard errors sqrt(MSE / pixels)."""
    if lib.sanitizer_build(ctx):
        return
    _, rows, refs = _pipeline(ctx)
    r = max(_curve(rows, "gap", "pt-mis"), key=lambda r: r["spp"])
    se = math.sqrt(r["rmse"] ** 2 / r["pixels"])
    z = (r["mean"] - refs["gap"]["mean"]) / se
    assert abs(z) <= Z, f"gap: path tracing at {r['spp']:.0f} spp, image mean {r['mean']:.5g}; the BDPT reference's " \
                        f"{refs['gap']['mean']:.5g}: {z:+.1f} standard errors ({se:.3g})"


def _slope(rows, scene, estimator):
    """Weighted least squares of log RMSE (reference MSE removed) on log spp."""
    pts = []
    for r in _curve(rows, scene, f"pt-{estimator}"):
        mse = r["rmse"] ** 2
        if r["spp"] < 2 or r["ref_mse"] > 0.1 * mse:
            continue
        corrected = mse - r["ref_mse"]
        pts.append((math.log(r["spp"]), 0.5 * math.log(corrected), r["mse_se"] / (2 * corrected)))
    assert len(pts) >= 3, f"{scene} {estimator}: only {len(pts)} points where the reference's error is negligible"
    w = [1 / s ** 2 for _, _, s in pts]
    xm = sum(wi * x for wi, (x, _, _) in zip(w, pts)) / sum(w)
    ym = sum(wi * y for wi, (_, y, _) in zip(w, pts)) / sum(w)
    sxx = sum(wi * (x - xm) ** 2 for wi, (x, _, _) in zip(w, pts))
    sxy = sum(wi * (x - xm) * (y - ym) for wi, (x, y, _) in zip(w, pts))
    return sxy / sxx, math.sqrt(1 / sxx)


def test_tradeoff_3_pathtrace_slope_is_minus_one_half(ctx):
    if lib.sanitizer_build(ctx):  # as test 1
        return
    _, rows, _ = _pipeline(ctx)
    failures = []
    for scene in FULL_SCENES:
        for e in ESTIMATORS:
            slope, se = _slope(rows, scene, e)
            half = min(SLOPE_HALF_WIDTH_QUICK, Z * se)
            if abs(slope + 0.5) > half:
                failures.append(f"{scene} {e}: slope {slope:.3f} +- {se:.3f}, accepted [{-0.5 - half:.3f}, "
                                f"{-0.5 + half:.3f}]")
    assert not failures, "; ".join(failures)


def test_tradeoff_4_biased_methods_floor_on_spheres(ctx):
    """On cornell-spheres the caustics under the glass ball and the light
    reflected by the mirror onto the walls are paths only Monte Carlo
    samples: the best error of radiosity, Whitted and local stays above path
    tracing's best by more than the noise."""
    if lib.sanitizer_build(ctx):  # as test 1
        return
    _, rows, _ = _pipeline(ctx)
    scene = "cornell-spheres"
    pt = min(_curve(rows, scene, "pt-mis"), key=lambda r: r["rmse"])
    for method in ("radiosity", "whitted", "local"):
        pts = [r for r in rows if r["scene"] == scene and r["method"] == method and r["status"] == "ok"]
        best = min(pts, key=lambda r: r["rmse"])
        (lb, sb), (lp, sp) = _log_mse_and_sigma(best), _log_mse_and_sigma(pt)
        assert lb - lp > Z * math.hypot(sb, sp), \
            f"{method}'s best rmse {best['rmse']:.4g} ({best['setting']}) is not above path tracing's {pt['rmse']:.4g}"
