#!/usr/bin/python3
"""The price of accuracy: error against time for every chapter.

    make tradeoff            # full sweep, 128x128, about 20 minutes on 2 cores
    make tradeoff QUICK=1    # the whole pipeline on a tiny budget (32x32, < 1 minute)

Environment: QUICK=1, BUILD=build (whose executables to run), OUT=out (where
the results go; QUICK defaults to out/quick so a quick run never overwrites a
full one), SIZE=N (image N x N), REF_SPP=N (samples per pixel of *each* of
the two reference halves), PT_MAX_SPP=N, REPEATS=N, CAP=SECONDS (a run slower
than this is stopped and reported as over budget), REUSE_REF=1 (keep a
reference rendered earlier with the same build, size and samples).

Every number comes from the chapters' own --stats:
  time_s   = prepare_s + render_s (the radiosity solve and the pixel loop; not
             scene loading, probes, reading the reference or writing files),
             the median over the repeats of the identical render
  rmse, relmse, ssim, psnr = the chapter's "metrics" against the reference
The reference is a long MIS path trace rendered as two independent halves
(different --seed values); the second half is rendered with --ref first-half.pfm,
so the chapter itself reports RMSE(a - b), and the reference's own error is
RMSE((a + b)/2 - truth) ~= RMSE(a - b) / 2 (independent, unbiased halves).

The one number computed here from the images rather than read from stats is
each point's standard error of the MSE (column mse_se): pixels have
independent random streams, so the per-pixel squared errors are independent
and SE(MSE) = sd(per-pixel squared error) / sqrt(pixels).  It gives the
path-tracing slope its uncertainty and lets the tests tell a real fall of
the error from noise.

Photon mapping (chapter 5, when build/05_photonmap exists) is swept over its
progressive passes beside the path tracer.  On cornell-spheres every point also
gets caustic_rmse: the RMSE over the caustic region (tradeoff/caustic_region.py:
the pixels that see the floor within 80 mm of the glass ball's focus), with the
reference's own MSE there, MSE(a - b) / 4 over the region, subtracted.

Outputs (OUT/): tradeoff.csv, tradeoff.md, tradeoff-<scene>.png/.svg (error
against time, log-log), tradeoff-caustic-cornell-spheres.png/.svg (the caustic
region's error against time: path tracing and photon mapping), tradeoff-radiosity-<scene>.png/.svg (error against
iterations per patch size: the discretisation floor), tradeoff/ (the
renders, their stats and the plot data).
"""
import array
import csv
import json
import math
import os
import shutil
import statistics
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from caustic_region import caustic_region  # noqa: E402

sys.path.insert(0, os.path.join(os.path.dirname(HERE), "tests"))
import pfm  # noqa: E402  (tests/pfm.py: the one PFM reader of the Python tools)

CAUSTIC_SCENE = "cornell-spheres"

SCENES = ["cornell", "cornell-spheres"]
ESTIMATORS = ["hemisphere", "cosine", "light", "mis"]
SOLVERS = ["jacobi", "gauss-seidel", "shooting", "direct"]
# Whitted's soft shadows: points per emitter per pixel sample (its default is
# 16; with aa_spp pixel samples, 4 already gives hundreds per pixel).
WHITTED_LIGHT_SAMPLES = 4
COMMON_SEED = 424242

CSV_COLUMNS = ["scene", "method", "variant", "curve", "setting", "spp", "patches", "iterations", "light_samples",
               "max_depth", "min_weight", "patch_size", "seed", "time_s", "time_min_s", "repeats", "prepare_s",
               "render_s", "rmse", "relmse", "ssim", "psnr", "mse_se", "ref_mse", "caustic_rmse", "status"]


def env_int(name, default):
    v = os.environ.get(name, "")
    return int(v) if v.strip() else default


def env_float(name, default):
    v = os.environ.get(name, "")
    return float(v) if v.strip() else default


def config():
    quick = os.environ.get("QUICK", "") not in ("", "0")
    if quick:
        # Shooting and direct only at the coarsest patch size: they are the
        # slow solvers, and the quick run only checks the pipeline.
        c = dict(quick=True, pm_passes=[2, 8], pm_photons=5000, size=32, ref_spp=4096, pt_max_spp=512, repeats=1, cap=5.0, aa_spp=16,
                 patch_sizes=[200, 100], slow_solver_sizes=1, iters=[1, 2, 4, 8, 16], shoot_iters=[1, 2],
                 depths=[0, 1, 2, 4], min_weights=[0.3, 0.03], light_samples=[1, 4, 16, 64])
    else:
        c = dict(quick=False, pm_passes=[2, 8, 32, 128, 512], pm_photons=50000, size=128, ref_spp=8192, pt_max_spp=2048, repeats=3, cap=20.0, aa_spp=64,
                 patch_sizes=[200, 141, 100, 71, 50, 35, 25], slow_solver_sizes=7, iters=[1, 2, 3, 4, 6, 8, 12, 16, 24, 32],
                 shoot_iters=[1, 2, 3, 4, 6, 8], depths=[0, 1, 2, 3, 4, 6, 10],
                 min_weights=[0.5, 0.2, 0.1, 0.05, 0.02, 0.01], light_samples=[1, 2, 4, 8, 16, 32, 64])
    c["size"] = env_int("SIZE", c["size"])
    c["ref_spp"] = env_int("REF_SPP", c["ref_spp"])
    c["pt_max_spp"] = env_int("PT_MAX_SPP", c["pt_max_spp"])
    c["repeats"] = env_int("REPEATS", c["repeats"])
    c["cap"] = env_float("CAP", c["cap"])
    # Samples per pixel of the methods whose sweep is not over spp (local,
    # Whitted, radiosity): the reference averages radiance over each pixel's
    # area, and one sample through the pixel centre would add an aliasing error
    # (at the light's edges, radiance 17 next to 0) far above these methods'
    # own floors.  A square count: the driver stratifies it.
    c["aa_spp"] = env_int("AA_SPP", c["aa_spp"])
    # spp = 2 x 4^k: never a square, so the driver jitters every sample
    # uniformly over the pixel (independent samples: the N^-1/2 setting of the
    # lecture).  A square count would be stratified: the light's edge pixels
    # (radiance 17 next to 0), which dominate the RMSE, would then converge
    # like N^-3/4 and steepen the slope; 1 spp looks through the pixel centre
    # (a different estimator of the pixel's integral).
    c["pt_spp"] = [2 * 4 ** k for k in range(0, 20) if 2 * 4 ** k <= c["pt_max_spp"]]
    c["build"] = os.environ.get("BUILD", "build") or "build"
    c["out"] = os.environ.get("OUT", "") or ("out/quick" if quick else "out")
    c["reuse_ref"] = os.environ.get("REUSE_REF", "") not in ("", "0")
    return c


# --- images ------------------------------------------------------------------------

def read_pfm(path):
    """(width, height, array('f') of RGB, bottom row first: the order does not matter here)."""
    return pfm.read_pfm(path)


def write_pfm(path, width, height, pixels):
    p = array.array("f", pixels)
    if sys.byteorder != "little":
        p.byteswap()
    tmp = path + ".tmp"
    with open(tmp, "wb") as f:
        f.write(b"PF\n%d %d\n-1\n" % (width, height))
        f.write(p.tobytes())
    os.replace(tmp, path)


def caustic_index(width, height):
    """Float offsets, in a PFM (bottom row first), of the caustic region's pixels."""
    return [3 * ((height - 1 - y) * width + x) for x, y in caustic_region(width, height)]


def region_mse(a, b, index):
    return sum((a[i + k] - b[i + k]) ** 2 for i in index for k in range(3)) / (3 * len(index))


def mse_standard_error(test, reference):
    """(MSE, its standard error) from per-pixel squared errors (the 3 channels
    of a pixel share one random path, so the pixel is the independent unit)."""
    n = len(reference) // 3
    per_pixel = [0.0] * n
    for p in range(n):
        i = 3 * p
        d0, d1, d2 = test[i] - reference[i], test[i + 1] - reference[i + 1], test[i + 2] - reference[i + 2]
        per_pixel[p] = (d0 * d0 + d1 * d1 + d2 * d2) / 3.0
    mean = sum(per_pixel) / n
    var = sum((s - mean) ** 2 for s in per_pixel) / (n - 1)
    return mean, math.sqrt(var / n)


# --- running a chapter -------------------------------------------------------------------

class Runner:
    def __init__(self, c):
        self.c = c
        self.work = os.path.join(c["out"], "tradeoff")
        self.size = f"{c['size']}x{c['size']}"
        self.log = []
        self.caustic_ref_mse = {}  # scene -> the reference's own MSE over the caustic region

    def exe(self, chapter):
        return os.path.join(ROOT, self.c["build"], chapter)

    def run_once(self, chapter, scene, args, name, ref=None, timeout=None):
        """Render once; return the stats dict (None if the run exceeded timeout)."""
        pfm = os.path.join(self.work, scene, name + ".pfm")
        stats = os.path.join(self.work, scene, name + ".json")
        cmd = [self.exe(chapter), os.path.join("scenes", scene + ".scene"), "--quiet", "--size", self.size,
               "--out", pfm, "--stats", stats] + [str(a) for a in args]
        if ref:
            cmd += ["--ref", ref]
        try:
            r = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=timeout,
                               stdin=subprocess.DEVNULL)
        except subprocess.TimeoutExpired:
            return None
        if r.returncode != 0:
            raise RuntimeError(f"{' '.join(cmd)} exited {r.returncode}: {r.stderr.strip()[-2000:]}")
        with open(stats) as f:
            return json.load(f)

    def point(self, chapter, scene, args, name, ref, ref_pixels, repeats=None):
        """Render one sweep point `repeats` times (the identical image: same
        seed), time = median of prepare_s + render_s; metrics from the
        chapter's --ref.  Returns a row dict, status 'over budget' if the
        first run took longer than the cap (it is killed at the cap)."""
        repeats = self.c["repeats"] if repeats is None else repeats
        cap = self.c["cap"]
        first = self.run_once(chapter, scene, args, name, ref, timeout=cap * 1.5 + 5)
        if first is None:
            return {"status": "over budget", "time_s": None}
        times = [first["prepare_s"] + first["render_s"]]
        # Repeat only runs that are quick: the relative timing noise of a
        # long run is small, and repeating it would cost the most.
        if times[0] < 2.0:
            for _ in range(repeats - 1):
                s = self.run_once(chapter, scene, args, name + ".rep", ref, timeout=cap * 1.5 + 5)
                if s is not None:
                    times.append(s["prepare_s"] + s["render_s"])
        m = first.get("metrics") or {}
        w, h, pixels = read_pfm(os.path.join(self.work, scene, name + ".pfm"))
        mse, se = mse_standard_error(pixels, ref_pixels)
        caustic = None
        if scene == CAUSTIC_SCENE and self.caustic_ref_mse.get(scene) is not None:
            index = caustic_index(w, h)
            caustic = math.sqrt(max(region_mse(pixels, ref_pixels, index) - self.caustic_ref_mse[scene], 0.0))
        # The chapter's rmse and ours are the same quantity (a consistency check).
        if m.get("rmse") is not None and abs(math.sqrt(mse) - m["rmse"]) > 1e-3 * m["rmse"] + 1e-9:
            raise RuntimeError(f"{name}: rmse {m['rmse']} from stats but {math.sqrt(mse)} from the image")
        status = "ok" if times[0] <= cap else "over budget"
        return {"time_s": statistics.median(times), "time_min_s": min(times), "repeats": len(times),
                "prepare_s": first["prepare_s"], "render_s": first["render_s"], "rmse": m.get("rmse"),
                "relmse": m.get("relmse"), "ssim": m.get("ssim"), "psnr": m.get("psnr"), "mse_se": se,
                "spp": first.get("spp"), "patches": first.get("patches"), "iterations": first.get("iterations"),
                "caustic_rmse": caustic, "status": status, "_stats": first}


# --- the sweeps ---------------------------------------------------------------------------

def reference(run, scene):
    """Two independent MIS halves; returns (ref path, pixels, info)."""
    c = run.c
    d = os.path.join(run.work, scene)
    info_path = os.path.join(d, "reference.json")
    ref_path = os.path.join(d, "reference.pfm")
    key = {"size": c["size"], "spp_half": c["ref_spp"], "build": c["build"],
           "exe_mtime": os.path.getmtime(run.exe("04_pathtrace"))}
    if c["reuse_ref"] and os.path.exists(info_path) and os.path.exists(ref_path):
        with open(info_path) as f:
            info = json.load(f)
        if info.get("key") == key:
            run.caustic_ref_mse[scene] = info.get("caustic_mse")
            return ref_path, read_pfm(ref_path)[2], info
    args = ["--estimator", "mis", "--spp", c["ref_spp"], "--probe-samples", 32]
    a = run.run_once("04_pathtrace", scene, args + ["--seed", 900001], "ref-a")
    b = run.run_once("04_pathtrace", scene, args + ["--seed", 900002], "ref-b",
                     ref=os.path.join(d, "ref-a.pfm"))
    w, h, pa = read_pfm(os.path.join(d, "ref-a.pfm"))
    _, _, pb = read_pfm(os.path.join(d, "ref-b.pfm"))
    avg = array.array("f", [(x + y) * 0.5 for x, y in zip(pa, pb)])
    write_pfm(ref_path, w, h, avg)
    rmse_ab = b["metrics"]["rmse"]
    if scene == CAUSTIC_SCENE:
        run.caustic_ref_mse[scene] = region_mse(pa, pb, caustic_index(w, h)) / 4.0
    info = {"caustic_mse": run.caustic_ref_mse.get(scene), "key": key, "spp": 2 * c["ref_spp"], "seeds": [900001, 900002],
            "time_s": a["prepare_s"] + a["render_s"] + b["prepare_s"] + b["render_s"],
            "rmse_halves": rmse_ab, "rmse": rmse_ab / 2.0, "mse": (rmse_ab / 2.0) ** 2,
            "nonfinite_samples": a["nonfinite_samples"] + b["nonfinite_samples"]}
    with open(info_path, "w") as f:
        json.dump(info, f, indent=1)
    return ref_path, avg, info


def sweep_scene(run, scene, rows):
    c = run.c
    os.makedirs(os.path.join(run.work, scene), exist_ok=True)
    t0 = time.time()
    ref_path, ref_pixels, ref_info = reference(run, scene)
    print(f"[{scene}] reference: {ref_info['spp']} spp MIS, estimated RMSE {ref_info['rmse']:.4g} "
          f"({time.time() - t0:.0f} s)", flush=True)
    seed = [0]

    def add(method, variant, curve, setting, chapter, args, name, extra, repeats=None):
        # Path tracing: a new seed per point, so the points of a sweep are
        # independent (the slope fit weighs them as such).  Local, Whitted and
        # radiosity: one common seed (common random numbers), so every point
        # jitters its pixel samples identically and the differences between
        # points are the method's, not the jitter's.
        seed[0] += 1
        point_seed = seed[0] if method in ("pathtrace", "photonmap") else COMMON_SEED
        r = run.point(chapter, scene, list(args) + ["--seed", point_seed], name, ref_path, ref_pixels, repeats)
        r.update(extra)
        r.update({"scene": scene, "method": method, "variant": variant, "curve": curve, "setting": setting,
                  "seed": point_seed, "order": seed[0], "ref_mse": ref_info["mse"]})
        r.pop("_stats", None)
        rows.append(r)
        t = r.get("time_s")
        print(f"[{scene}] {curve:24s} {setting:22s} " +
              (f"time {t:8.4f} s  rmse {r['rmse']:.4g}" if r["status"] == "ok" else r["status"]), flush=True)
        return r

    # Path tracing: spp sweep per estimator.
    for e in ESTIMATORS:
        for n in c["pt_spp"]:
            add("pathtrace", e, f"pt-{e}", f"spp={n}", "04_pathtrace",
                ["--estimator", e, "--spp", n, "--probe-samples", 32], f"pt-{e}-{n}", {})
    # Photon mapping: progressive passes (the radius shrinks by R12 each pass).
    if os.access(run.exe("05_photonmap"), os.X_OK):
        for n in c["pm_passes"]:
            add("photonmap", "progressive", "pm", f"passes={n}", "05_photonmap",
                ["--spp", n, "--photons", c["pm_photons"], "--probe-photons", 32], f"pm-{n}", {})
    # Local illumination: light samples per emitter (per pixel sample).
    for k in c["light_samples"]:
        add("local", "light-samples", "local", f"light-samples={k}", "01_local",
            ["--light-samples", k, "--spp", c["aa_spp"], "--probe-samples", 1], f"local-{k}", {"light_samples": k})
    # Whitted: max depth (full tree), then min weight (at the deepest depth).
    for dep in c["depths"]:
        add("whitted", "max-depth", "whitted-depth", f"max-depth={dep}", "02_whitted",
            ["--max-depth", dep, "--min-weight", 0, "--spp", c["aa_spp"], "--light-samples", WHITTED_LIGHT_SAMPLES],
            f"whitted-d{dep}", {"max_depth": dep, "min_weight": 0})
    for mw in c["min_weights"]:
        add("whitted", "min-weight", "whitted-weight", f"min-weight={mw}", "02_whitted",
            ["--max-depth", max(c["depths"]), "--min-weight", mw, "--spp", c["aa_spp"],
             "--light-samples", WHITTED_LIGHT_SAMPLES], f"whitted-w{mw}",
            {"max_depth": max(c["depths"]), "min_weight": mw})
    # Radiosity: patch size x iterations per solver.  At each size the solve
    # converged to the chapter's default tolerance first, then a fixed number
    # of iterations with --tol 0.  A run over the cap stops that solver's
    # sweep: finer patches would only cost more.
    for solver in SOLVERS:
        sizes = c["patch_sizes"][:c["slow_solver_sizes"]] if solver in ("shooting", "direct") else c["patch_sizes"]
        for S in sizes:
            conv = add("radiosity", solver, f"radiosity-{solver}", f"S={S} converged", "03_radiosity",
                       ["--solver", solver, "--patch-size", S, "--spp", c["aa_spp"]], f"rad-{solver}-{S}-conv",
                       {"patch_size": S}, repeats=1 if S != c["patch_sizes"][0] else None)
            if conv["status"] != "ok":
                break
            if solver == "direct":
                continue
            over = False
            for k in (c["shoot_iters"] if solver == "shooting" else c["iters"]):
                r = add("radiosity", solver, f"radiosity-{solver}-iter", f"S={S} K={k}", "03_radiosity",
                        ["--solver", solver, "--patch-size", S, "--iterations", k, "--tol", 0,
                         "--spp", c["aa_spp"]],
                        f"rad-{solver}-{S}-k{k}", {"patch_size": S}, repeats=1)
                if r["status"] != "ok":
                    over = True
                    break
            if over:
                break
    return ref_info


# --- analysis --------------------------------------------------------------------------------

def ok_rows(rows, scene=None, curve=None):
    return [r for r in rows if r["status"] == "ok" and r.get("rmse") is not None
            and (scene is None or r["scene"] == scene) and (curve is None or r["curve"] == curve)]


def fit_slope(points):
    """Weighted least squares of y on x; points (x, y, sigma_y).  Returns (slope, its standard error)."""
    W = sum(1 / s ** 2 for _, _, s in points)
    xm = sum(x / s ** 2 for x, _, s in points) / W
    ym = sum(y / s ** 2 for _, y, s in points) / W
    sxx = sum((x - xm) ** 2 / s ** 2 for x, _, s in points)
    sxy = sum((x - xm) * (y - ym) / s ** 2 for x, y, s in points)
    return sxy / sxx, math.sqrt(1 / sxx)


def pathtrace_slope(rows, scene, estimator, ref_fraction=0.1):
    """Slope of log RMSE against log spp, with its standard error.

    Fitted over the points where the reference's own error is negligible,
    ref_mse <= ref_fraction x the point's MSE, after removing the reference's
    share (the errors are independent, so measured MSE = MSE + ref MSE), and
    without 1 spp if present (it looks through the pixel centre: a different
    estimator of the pixel's integral).
    sigma(log RMSE) = SE(MSE) / (2 (MSE - ref MSE)) from the pixels' spread.
    Returns None when fewer than 3 points qualify."""
    pts = []
    for r in ok_rows(rows, scene, f"pt-{estimator}"):
        mse = r["rmse"] ** 2
        if r["spp"] < 2 or r["ref_mse"] > ref_fraction * mse:
            continue
        corrected = mse - r["ref_mse"]
        pts.append((math.log(r["spp"]), 0.5 * math.log(corrected), r["mse_se"] / (2 * corrected), r["spp"]))
    if len(pts) < 3:
        return None
    slope, se = fit_slope([(x, y, s) for x, y, s, _ in pts])
    return {"slope": slope, "se": se, "spp": [p[3] for p in pts]}


def fmt(v, digits=3):
    if v is None:
        return "—"
    if v == 0:
        return "0"
    if abs(v) >= 1000 or abs(v) < 1e-3:
        return f"{v:.{digits}g}"
    return f"{v:.{digits}g}"


def thresholds(rows, scene, ref_rmse):
    """Round error levels (1, 3 x 10^k) between the best and the worst RMSE,
    and at least 3 x the reference's own error (below that the measured error
    is mostly the reference's)."""
    errs = [r["rmse"] for r in ok_rows(rows, scene)]
    lo, hi = max(min(errs), 3 * ref_rmse), max(errs)
    levels = []
    for k in range(-6, 4):
        for m in (1, 3):
            x = m * 10.0 ** k
            if lo <= x <= hi:
                levels.append(x)
    return sorted(levels, reverse=True)


def report(c, rows, refs, plots):
    curves_order = [f"pt-{e}" for e in ESTIMATORS] + [f"radiosity-{s}" for s in SOLVERS] + \
                   ["whitted-depth", "whitted-weight", "local"]
    curve_title = {f"pt-{e}": f"path tracing ({e})" for e in ESTIMATORS}
    curve_title.update({f"radiosity-{s}": f"radiosity ({s})" for s in SOLVERS})
    curve_title.update({"whitted-depth": "Whitted (max depth)", "whitted-weight": "Whitted (min weight)",
                        "local": "local (light samples)"})
    L = []
    L.append("# Speed against accuracy, every method (generated by tradeoff/tradeoff.py)\n")
    L.append(f"Mode: {'QUICK (a smoke run: tiny images, few points, 1 repeat)' if c['quick'] else 'full'}; "
             f"images {c['size']}x{c['size']}; build `{c['build']}`; time = median over up to {c['repeats']} "
             f"repeats of the chapter's own `prepare_s + render_s` (repeats only for runs under 2 s); errors are "
             f"the chapter's own `--ref` metrics against the reference below. Runs slower than {c['cap']:g} s "
             f"were stopped and are listed as over budget. Local, Whitted (4 light samples) and radiosity render "
             f"{c['aa_spp']} stratified samples per pixel (the reference is a pixel-area average; one sample through "
             f"the pixel centre would add an aliasing error at the light's edges above these methods' own floors); "
             f"their time includes them. All numbers: `tradeoff.csv`.\n")
    for scene in SCENES:
        ref = refs.get(scene)
        if ref is None:
            continue
        L.append(f"\n## {scene}.scene\n")
        L.append(f"![error against time](tradeoff-{scene}.png) "
                 f"![radiosity floor](tradeoff-radiosity-{scene}.png)\n")
        L.append(f"**Reference**: MIS path tracing, {ref['spp']} spp as two independent halves "
                 f"(seeds {ref['seeds'][0]}, {ref['seeds'][1]}; {ref['time_s']:.1f} s). RMSE between the halves "
                 f"{ref['rmse_halves']:.4g}, so the reference's own RMSE is about {ref['rmse']:.4g} "
                 f"(RMSE(a-b)/2). A point's measured MSE is its true MSE plus this reference MSE; "
                 f"errors below about 3x it ({3 * ref['rmse']:.3g}) are not resolved.\n")
        levels = thresholds(rows, scene, ref["rmse"])
        def pts_of(cv):
            # A radiosity solver's column takes its converged runs and its fixed-K runs.
            return ok_rows(rows, scene, cv) + (ok_rows(rows, scene, cv + "-iter") if cv.startswith("radiosity") else [])
        present = [cv for cv in curves_order if pts_of(cv)]
        # Fastest to reach each level.
        L.append("\n### Fastest to reach an error\n")
        L.append("Time (s) each method first needs to reach RMSE <= X (its cheapest run at or below X); "
                 "'never' gives the method's best RMSE in this sweep.\n")
        L.append("| RMSE <= X | fastest | " + " | ".join(curve_title[cv] for cv in present) + " |")
        L.append("|---|---|" + "---|" * len(present))
        for x in levels:
            cells, best = [], None
            for cv in present:
                pts = [r for r in pts_of(cv) if r["rmse"] <= x]
                if pts:
                    p = min(pts, key=lambda r: r["time_s"])
                    cells.append(f"{p['time_s']:.3g} ({p['setting']})")
                    if best is None or p["time_s"] < best[1]:
                        best = (cv, p["time_s"], p)
                else:
                    cells.append(f"never (best {min(r['rmse'] for r in pts_of(cv)):.3g})")
            fastest = f"**{curve_title[best[0]]}**, {best[1]:.3g} s" if best else "none"
            L.append(f"| {x:g} | {fastest} | " + " | ".join(cells) + " |")
        # Sentences from the table.
        L.append("")
        for x in levels:
            winners = []
            for cv in present:
                pts = [r for r in pts_of(cv) if r["rmse"] <= x]
                if pts:
                    winners.append((min(p["time_s"] for p in pts), cv))
            never = [curve_title[cv] for cv in present if not any(r["rmse"] <= x for r in pts_of(cv))]
            if winners:
                winners.sort()
                s = f"- RMSE <= {x:g}: fastest is {curve_title[winners[0][1]]} ({winners[0][0]:.3g} s)"
                if len(winners) > 1:
                    s += (f", {winners[1][0] / max(winners[0][0], 1e-9):.3g}x faster than the runner-up, "
                          f"{curve_title[winners[1][1]]} ({winners[1][0]:.3g} s)")
                s += "."
            else:
                s = f"- RMSE <= {x:g}: no method gets there."
            if never:
                s += " Never reached by: " + ", ".join(never) + "."
            L.append(s)
        # Floors of the biased methods.
        L.append("\n### Where each method stops improving\n")
        L.append("| method | best RMSE | at | its time (s) | best relMSE | best SSIM |")
        L.append("|---|---|---|---|---|---|")
        for cv in present:
            pts = pts_of(cv)
            b = min(pts, key=lambda r: r["rmse"])
            L.append(f"| {curve_title[cv]} | {b['rmse']:.4g} | {b['setting']} | {b['time_s']:.3g} | "
                     f"{min(r['relmse'] for r in pts):.4g} | {max(r['ssim'] for r in pts):.4f} |")
        # Monte Carlo: slope and efficiency.
        L.append("\n### Path tracing: convergence rate and efficiency\n")
        L.append("Slope of log RMSE against log spp (N^-1/2 means -0.5), weighted least squares over the points "
                 "(spp = 2 x 4^k: uniformly jittered, independent samples) where the reference's MSE is at most 10% of the point's (the reference's share "
                 "subtracted), +- its standard error from the pixels' spread. Efficiency = 1 / (MSE x time), "
                 "constant along an N^-1/2 line; median over the same points.\n")
        L.append("| estimator | slope | +- | fitted spp | efficiency 1/(MSE s) | relative to best |")
        L.append("|---|---|---|---|---|---|")
        effs = {}
        for e in ESTIMATORS:
            pts = [r for r in ok_rows(rows, scene, f"pt-{e}") if r["spp"] >= 2]
            vals = [1.0 / ((r["rmse"] ** 2 - r["ref_mse"]) * r["time_s"]) for r in pts
                    if r["rmse"] ** 2 > 10 * r["ref_mse"] and r["time_s"] > 0]
            effs[e] = statistics.median(vals) if vals else None
        top = max((v for v in effs.values() if v), default=None)
        for e in ESTIMATORS:
            f = pathtrace_slope(rows, scene, e)
            eff = effs[e]
            L.append(f"| {e} | {f['slope']:.3f} | {f['se']:.3f} | {','.join(map(str, f['spp']))} | "
                     f"{fmt(eff)} | {fmt(eff / top) if eff and top else '—'} |" if f else
                     f"| {e} | — | — | too few points | {fmt(eff)} | — |")
        # Radiosity: the discretisation floor.
        L.append("\n### Radiosity: iterations against patch size\n")
        L.append("RMSE after K iterations (`--tol 0`) at each patch size S (scene units); the error stops "
                 "falling once the iteration has converged: what remains is the discretisation (constant "
                 "patches) and, on a scene with specular objects, what radiosity does not model.\n")
        for solver in SOLVERS[:3]:
            pts = ok_rows(rows, scene, f"radiosity-{solver}-iter")
            if not pts:
                continue
            sizes = sorted({r["patch_size"] for r in pts}, reverse=True)
            L.append(f"\n{solver}:\n")
            L.append("| S | patches | RMSE at K=1 | best RMSE | K to come within 1% of the best | time then (s) |")
            L.append("|---|---|---|---|---|---|")
            for S in sizes:
                ps = sorted([r for r in pts if r["patch_size"] == S], key=lambda r: int(r["setting"].split("K=")[1]))
                best = min(r["rmse"] for r in ps)
                k1 = next(r for r in ps if r["rmse"] <= 1.01 * best)
                L.append(f"| {S:g} | {ps[0]['patches']} | {ps[0]['rmse']:.4g} | {best:.4g} | "
                         f"{k1['setting'].split('K=')[1]} | {k1['time_s']:.3g} |")
        over = [r for r in rows if r["scene"] == scene and r["status"] != "ok"]
        if over:
            L.append("\nOver budget (stopped at " + f"{c['cap']:g} s, not plotted): " +
                     ", ".join(f"{r['curve']} {r['setting']}" for r in over) + ".")
    L.extend(caustic_report(rows))
    L.append("\n## How to read this\n")
    L.append("- Unbiased Monte Carlo (path tracing) falls along N^-1/2 lines (the grey guide) without floor; "
             "the estimators differ by a constant factor in time (their efficiency).\n"
             "- Radiosity and Whitted / local illumination are biased: each has a floor set by what it leaves "
             "out (discretisation, indirect light, caustics). Cheap at coarse error, unable to go below it.\n"
             "- Times include radiosity's form factors (prepare_s) and the pixel loop, on "
             f"{os.cpu_count()} cores.")
    with open(os.path.join(c["out"], "tradeoff.md"), "w") as f:
        f.write("\n".join(L) + "\n")


# --- plots --------------------------------------------------------------------------------------

def k_of(r):
    return int(r["setting"].split("K=")[1])


def write_plot_data(c, rows, refs):
    """Whitespace-separated files for gnuplot: one per curve (time rmse relmse
    ssim), and for radiosity's iteration sweeps one per (solver, patch size)
    (K rmse time patch_size patches)."""
    data_dir = os.path.join(c["out"], "tradeoff", "data")
    os.makedirs(data_dir, exist_ok=True)
    written = {}
    for scene in SCENES:
        for curve in sorted({r["curve"] for r in rows if r["scene"] == scene}):
            pts = ok_rows(rows, scene, curve)
            if not pts:
                continue
            if curve.endswith("-iter"):
                for S in sorted({r["patch_size"] for r in pts}, reverse=True):
                    ps = sorted([r for r in pts if r["patch_size"] == S], key=k_of)
                    path = os.path.join(data_dir, f"{scene}-{curve}-S{S:g}.dat")
                    with open(path, "w") as f:
                        f.write("# K rmse time_s patch_size patches\n" + "".join(
                            f"{k_of(r)} {r['rmse']:.8g} {r['time_s']:.8g} {S:g} {r['patches']}\n" for r in ps))
                    written[(scene, curve, S)] = (path, ps[0]["patches"])
                continue
            pts = sorted(pts, key=lambda r: r["order"])  # sweep order
            path = os.path.join(data_dir, f"{scene}-{curve}.dat")
            with open(path, "w") as f:
                f.write("# time_s rmse relmse ssim\n" + "".join(
                    f"{r['time_s']:.8g} {r['rmse']:.8g} {r['relmse']:.8g} {r['ssim']:.8g}\n" for r in pts))
            written[(scene, curve)] = path
    return written


def gnuplot(script, variables):
    args = []
    for k, v in variables.items():
        args += ["-e", f"{k}={json.dumps(v) if isinstance(v, str) else repr(float(v))}"]
    r = subprocess.run(["gnuplot"] + args + [os.path.join(HERE, script)], capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"gnuplot {script}: {r.stderr.strip()}")
    if r.stderr.strip():
        print(r.stderr.strip(), file=sys.stderr)


CURVES = [f"pt-{e}" for e in ESTIMATORS] + [f"radiosity-{s}" for s in SOLVERS] + \
         ["whitted-depth", "whitted-weight", "local", "pm"]
CURVE_TITLE = {f"pt-{e}": f"path tracing ({e})" for e in ESTIMATORS}
CURVE_TITLE.update({f"radiosity-{s}": f"radiosity ({s}, converged; patch sizes)" for s in SOLVERS})
CURVE_TITLE["pm"] = "photon mapping (progressive passes)"
CURVE_TITLE.update({"whitted-depth": "Whitted (max depth)", "whitted-weight": "Whitted (min weight)",
                    "local": "local (light samples)"})


def quoted(words):
    return " ".join("'" + w.replace("'", "") + "'" for w in words)


def caustic_points(rows, curve):
    return sorted([r for r in ok_rows(rows, CAUSTIC_SCENE, curve) if r.get("caustic_rmse")],
                  key=lambda r: r["time_s"])


def rmse_at_time(points, t):
    """A curve's caustic RMSE at time t, interpolated linearly in log-log (None outside it)."""
    for a, b in zip(points, points[1:]):
        if a["time_s"] <= t <= b["time_s"] and a["time_s"] < b["time_s"]:
            w = math.log(t / a["time_s"]) / math.log(b["time_s"] / a["time_s"])
            return math.exp((1 - w) * math.log(a["caustic_rmse"]) + w * math.log(b["caustic_rmse"]))
    return None


def caustic_report(rows):
    """Markdown: the caustic region's error, photon mapping against path tracing at equal time."""
    pm, mis = caustic_points(rows, "pm"), caustic_points(rows, "pt-mis")
    if not pm or not mis:
        return []
    L = ["\n## The caustic region of cornell-spheres.scene\n",
         "RMSE over the pixels that see the floor within 80 mm of the glass ball's focus "
         "(tradeoff/caustic_region.py), the reference's own error there subtracted. Equal time: "
         "the MIS curve interpolated (log-log) at the photon map's time.\n",
         "| photon mapping | time (s) | caustic RMSE | path tracing (mis) at that time | ratio |", "|---|---|---|---|---|"]
    for r in pm:
        other = rmse_at_time(mis, r["time_s"])
        L.append(f"| {r['setting']} | {r['time_s']:.3g} | {r['caustic_rmse']:.4g} | {fmt(other, 4)} | "
                 f"{fmt(r['caustic_rmse'] / other) if other else '—'} |")
    return L


def caustic_plot(c, rows, refs, data_dir):
    curves = [cv for cv in [f"pt-{e}" for e in ESTIMATORS] + ["pm"] if caustic_points(rows, cv)]
    if "pm" not in curves:
        return []
    files = []
    for cv in curves:
        path = os.path.join(data_dir, f"{CAUSTIC_SCENE}-{cv}-caustic.dat")
        with open(path, "w") as f:
            f.write("# time_s caustic_rmse\n" + "".join(f"{r['time_s']:.8g} {r['caustic_rmse']:.8g}\n"
                                                        for r in caustic_points(rows, cv)))
        files.append(path)
    pts = [r for cv in curves for r in caustic_points(rows, cv)]
    anchor = caustic_points(rows, "pt-mis")[len(caustic_points(rows, "pt-mis")) // 2]
    ref_rmse = math.sqrt(max(refs[CAUSTIC_SCENE].get("caustic_mse") or 0.0, 1e-12))
    made = []
    for term in ("png", "svg"):
        out = os.path.join(c["out"], f"tradeoff-caustic-{CAUSTIC_SCENE}.{term}")
        gnuplot("errortime.gp", {
            "term": term, "out": out,
            "title": f"{CAUSTIC_SCENE}.scene, {c['size']}x{c['size']}: the caustic region's error against time",
            "files": " ".join(files), "names": quoted(CURVE_TITLE[cv] for cv in curves),
            "styles": " ".join(str(CURVES.index(cv) + 1) for cv in curves),
            "t0": anchor["time_s"], "e0": anchor["caustic_rmse"], "refrmse": ref_rmse,
            "tmin": min(r["time_s"] for r in pts) / 2, "tmax": max(r["time_s"] for r in pts) * 2,
            "emin": min(min(r["caustic_rmse"] for r in pts), ref_rmse) / 2,
            "emax": max(r["caustic_rmse"] for r in pts) * 2})
        made.append(out)
    return made


def plots(c, rows, refs):
    if not shutil.which("gnuplot"):
        print("gnuplot not found (Debian package gnuplot-nox): no plots", file=sys.stderr)
        return []
    data = write_plot_data(c, rows, refs)
    made = []
    for scene in SCENES:
        if scene not in refs or not ok_rows(rows, scene):
            continue
        curves = [cv for cv in CURVES if (scene, cv) in data]
        # The guide N^-1/2 (RMSE ~ time^-1/2) through MIS's middle point.
        mis = sorted(ok_rows(rows, scene, "pt-mis"), key=lambda r: r["spp"])
        anchor = mis[len(mis) // 2] if mis else ok_rows(rows, scene)[0]
        times = [r["time_s"] for r in ok_rows(rows, scene) if r["time_s"] > 0]
        errs = [r["rmse"] for r in ok_rows(rows, scene)]
        iters = sorted([key for key in data if key[0] == scene and len(key) == 3],
                       key=lambda k: (SOLVERS.index(k[1][len("radiosity-"):-len("-iter")]), -k[2]))
        sizes = sorted({k[2] for k in iters}, reverse=True)
        for term in ("png", "svg"):
            out = os.path.join(c["out"], f"tradeoff-{scene}.{term}")
            gnuplot("errortime.gp", {
                "term": term, "out": out, "title": f"{scene}.scene, {c['size']}x{c['size']}: error against time",
                "files": " ".join(data[(scene, cv)] for cv in curves),
                "names": quoted(CURVE_TITLE[cv] for cv in curves),
                "styles": " ".join(str(CURVES.index(cv) + 1) for cv in curves),
                "t0": anchor["time_s"], "e0": anchor["rmse"], "refrmse": refs[scene]["rmse"],
                "tmin": min(times) / 2, "tmax": max(times) * 2,
                "emin": min(min(errs), refs[scene]["rmse"]) / 2, "emax": max(errs) * 2})
            made.append(out)
            if iters:
                out = os.path.join(c["out"], f"tradeoff-radiosity-{scene}.{term}")
                gnuplot("radiosity.gp", {
                    "term": term, "out": out,
                    "title": f"{scene}.scene: radiosity error against iterations, one line per solver and patch size S",
                    "files": " ".join(data[k][0] for k in iters),
                    "names": quoted(f"{k[1][len('radiosity-'):-len('-iter')]} S={k[2]:g} ({data[k][1]} patches)"
                                    for k in iters),
                    "colors": " ".join(str(sizes.index(k[2]) % 8 + 1) for k in iters),
                    "dashes": " ".join(str(SOLVERS.index(k[1][len("radiosity-"):-len("-iter")]) + 1) for k in iters),
                    "refrmse": refs[scene]["rmse"]})
                made.append(out)
    if CAUSTIC_SCENE in refs:
        made += caustic_plot(c, rows, refs, os.path.join(c["out"], "tradeoff", "data"))
    return made


# --- main -------------------------------------------------------------------------------------------

def main():
    c = config()
    start = time.time()
    for ch in ("01_local", "02_whitted", "03_radiosity", "04_pathtrace"):
        if not os.access(os.path.join(ROOT, c["build"], ch), os.X_OK):
            sys.exit(f"tradeoff: {c['build']}/{ch} is missing; run make first")
    run = Runner(c)
    os.makedirs(run.work, exist_ok=True)
    print(f"tradeoff: {'QUICK' if c['quick'] else 'full'} run, {c['size']}x{c['size']}, build {c['build']}, "
          f"output {c['out']}", flush=True)
    rows, refs = [], {}
    for scene in SCENES:
        refs[scene] = sweep_scene(run, scene, rows)
    csv_path = os.path.join(c["out"], "tradeoff.csv")
    with open(csv_path + ".tmp", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=CSV_COLUMNS, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: ("" if r.get(k) is None else r.get(k)) for k in CSV_COLUMNS})
    os.replace(csv_path + ".tmp", csv_path)
    with open(os.path.join(c["out"], "tradeoff", "references.json"), "w") as f:
        json.dump({"config": {k: v for k, v in c.items()}, "references": refs}, f, indent=1)
    made = plots(c, rows, refs)
    report(c, rows, refs, made)
    print(f"tradeoff: wrote {csv_path}, {os.path.join(c['out'], 'tradeoff.md')} and {len(made)} plots "
          f"in {time.time() - start:.0f} s", flush=True)


if __name__ == "__main__":
    main()
