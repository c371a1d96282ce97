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

Chapter 6 (when build/06_bidirectional exists): light tracing, BDPT and VCM over
their passes on five scenes, beside chapter 4's MIS path tracer and chapter 5's
progressive photon map: cornell and cornell-spheres (the full sweeps above), and
gap.scene (the light behind a 20 mm slit), sds.scene (a caustic seen in a
mirror) and smallpt.scene (smallpt's own: a sphere light mostly buried in the
ceiling, a mirror and a glass ball; not in QUICK unless SCENES names it), where
only chapters 4, 5 and 6 run.  Their references, as two halves the same way:
chapter 6's own long runs on gap and sds, BDPT on gap (unbiased; path tracing
needs hours there) and VCM on sds (the only method that renders its L S .. D S .. E
paths in minutes; consistent, as the merging radius shrinks with the passes,
but its remaining bias is not in the halves' difference); on smallpt chapter 4's
cosine estimator, which never samples the light (REFERENCES says why).  Where a
method loses for a reason of the scene's, SCENE_NOTES says it in one sentence,
in the report and on the plot.  On sds, caustic_rmse
is the RMSE over the caustic seen in the mirror (caustic_region.sds_mirror_regions,
its "caustic"), and in a full run (not QUICK; SDS_CONVERGENCE=0 skips it)
tradeoff/sds_convergence.py then measures that region properly (a reference
extrapolated from two merging radii, variance and bias apart) into OUT/sds/.  The report and targets.json compare the methods at
equal time (each curve interpolated in log-log at the others' times, the
reference's MSE subtracted), in wall-clock time (time_s, the plots' axis) and in
CPU time (cpu_s, what the children used: steadier on a shared machine); the
targets of chapter 6: BDPT at most 1/2 of path tracing's RMSE on gap, VCM within
1.1x of the better of BDPT and photon mapping on every scene, the SDS region's
error falling with VCM's time.

Outputs (OUT/): tradeoff.csv, tradeoff.md, tradeoff-<scene>.png/.svg (error
against time, log-log; cornell and cornell-spheres), tradeoff-caustic-cornell-spheres.png/.svg (the caustic
region's error against time: path tracing and photon mapping), tradeoff-radiosity-<scene>.png/.svg (error against
iterations per patch size: the discretisation floor), tradeoff-bidirectional-<scene>.png/.svg (chapters 4, 5
and 6 on each of the five scenes), sds/tradeoff-sds-region.png/.svg (sds_convergence.py), tradeoff/ (the
renders, their stats, the plot data, references.json, targets.json and targets.txt: the issue's targets as the
lines `target <scene> <ratio> = ...` that the run prints last).

SCENES=a,b,... runs only those of the five scenes (a partial run, for trying things out);
BIDIR_ONLY=1 runs on every scene only what chapter 6's comparisons need (chapter 4's MIS, chapter 5,
chapter 6); REPORT_ONLY=1 renders nothing: it reads OUT/tradeoff.csv and OUT/tradeoff/references.json
of an earlier run and writes the report, targets.json and the plots again.
"""
import array
import csv
import json
import math
import os
import resource
import shutil
import statistics
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from caustic_region import sds_mirror_regions, caustic_region  # noqa: E402

sys.path.insert(0, os.path.join(os.path.dirname(HERE), "tests"))
import pfm  # noqa: E402  (tests/pfm.py: the one PFM reader of the Python tools)

CAUSTIC_SCENE = "cornell-spheres"
SDS_SCENE = "sds"
# The scenes with a region whose error is measured apart (caustic_rmse).
REGIONS = {CAUSTIC_SCENE: caustic_region, SDS_SCENE: lambda w, h: sds_mirror_regions(w, h)["caustic"]}

SCENES = ["cornell", "cornell-spheres", "gap", "sds", "smallpt"]
# Every chapter's sweep runs on these; on the others only chapters 4 (MIS), 5 and 6.
FULL_SCENES = ["cornell", "cornell-spheres"]
# Left out of QUICK=1 unless SCENES names them: smallpt's reference (2 x 4096 spp of the cosine estimator, which
# finds the 18-unit light cap only by hitting it) and its sweep would add about a minute to the quick run, and
# its pipeline is that of gap and sds.
NOT_QUICK = ["smallpt"]
BIDIR_METHODS = ["light", "bdpt", "vcm"]
# Chapter 7's Markov chains, over mutations per pixel.  Their error is correlated (one normalisation b per image,
# chains that linger in blotches), so one image's pixels are not independent samples of it: each point is rendered
# with mlt_seeds independent seeds, its RMSE the root of their mean MSE against the reference, its mse_se the
# standard error of that mean over the seeds.
MLT_METHODS = ["pssmlt", "mmlt"]
# The reference of each scene: (chapter, its arguments, what it is); samples per pixel or passes per half
# come from the config (ref_spp for chapter 4, ref_passes for chapter 6).
PT_REFERENCE = ("04_pathtrace", ["--estimator", "mis", "--probe-samples", 32], "MIS path tracing (chapter 4)")
REFERENCES = {"cornell": PT_REFERENCE, "cornell-spheres": PT_REFERENCE,
              "gap": ("06_bidirectional", ["--method", "bdpt"], "BDPT (chapter 6)"),
              "sds": ("06_bidirectional", ["--method", "vcm"], "VCM (chapter 6)"),
              # smallpt: chapter 4's cosine estimator (BSDF sampling only), not MIS: the light is a sphere of
              # radius 600 cut by the ceiling, and every method compared here (MIS's light samples, photon
              # mapping's emission, light tracing, BDPT, VCM) samples it through the same new code, the cap of
              # common/scene.c's emitter_cap() and its power; the cosine estimator only ever hits the light, so an
              # error there shows as a disagreement instead of being built into the reference too (as in
              # bench/bench_smallpt.py).  It costs variance: the cap is small, paths find it by chance.
              "smallpt": ("04_pathtrace", ["--estimator", "cosine", "--probe-samples", 32],
                          "cosine path tracing (chapter 4, BSDF sampling only)")}
# Why a method loses on a scene, one sentence each, in the report's equal-time section and on the plot; {light}
# and {pm} are filled with what loss_measures() measured on this run's longest light-tracing and photon-mapping
# points (empty where it has none).
SCENE_NOTES = {
    "smallpt": "Light tracing loses: the mirror and glass balls are black to it, as a join to the camera cannot pass "
               "a specular surface{light}. Photon mapping loses at equal time: each pass adds one eye sample per "
               "pixel to a pass of photons, and the light's edge, seen directly and in the mirror ball, needs many "
               "eye samples{pm}.",
}
ESTIMATORS = ["hemisphere", "cosine", "light", "mis"]
SOLVERS = ["jacobi", "gauss-seidel", "shooting", "direct"]
# Whitted's soft shadows: points per emitter per pixel sample (its default is
# 16; with aa_spp pixel samples, 4 already gives hundreds per pixel).
WHITTED_LIGHT_SAMPLES = 4
COMMON_SEED = 424242

CSV_COLUMNS = ["scene", "method", "variant", "curve", "setting", "spp", "patches", "iterations", "light_samples",
               "max_depth", "min_weight", "patch_size", "seed", "time_s", "time_min_s", "repeats", "prepare_s",
               "render_s", "cpu_s", "rmse", "relmse", "ssim", "psnr", "mse_se", "ref_mse", "caustic_rmse", "pixels", "mean",
               "region_mean", "region_pixels", "seeds", "order", "status"]


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
                 bd_passes={"light": [2, 8, 32, 128], "bdpt": [2, 8, 32, 128], "vcm": [2, 8, 32, 128]},
                 ref_passes=256, bd_pm_passes=[2, 8, 32], bd_cap=10.0,
                 mlt_spp=[4, 16, 64], mlt_seeds=2, mlt_bootstrap=20000,
                 patch_sizes=[200, 100], slow_solver_sizes=1, iters=[1, 2, 4, 8, 16], shoot_iters=[1, 2],
                 depths=[0, 1, 2, 4], min_weights=[0.3, 0.03], light_samples=[1, 4, 16, 64])
    else:
        c = dict(quick=False, pm_passes=[2, 8, 32, 128, 512], pm_photons=50000, size=128, ref_spp=8192, pt_max_spp=2048, repeats=3, cap=20.0, aa_spp=64,
                 bd_passes={"light": [2, 8, 32, 128, 512], "bdpt": [2, 8, 32, 128, 512], "vcm": [2, 8, 32, 128]},
                 ref_passes=512, bd_pm_passes=[2, 8, 32, 128], bd_cap=300.0,
                 mlt_spp=[4, 16, 64, 256], mlt_seeds=4, mlt_bootstrap=100000,
                 patch_sizes=[200, 141, 100, 71, 50, 35, 25], slow_solver_sizes=7, iters=[1, 2, 3, 4, 6, 8, 12, 16, 24, 32],
                 shoot_iters=[1, 2, 3, 4, 6, 8], depths=[0, 1, 2, 3, 4, 6, 10],
                 min_weights=[0.5, 0.2, 0.1, 0.05, 0.02, 0.01], light_samples=[1, 2, 4, 8, 16, 32, 64])
    c["size"] = env_int("SIZE", c["size"])
    c["ref_spp"] = env_int("REF_SPP", c["ref_spp"])
    c["ref_passes"] = env_int("REF_PASSES", c["ref_passes"])
    c["pt_max_spp"] = env_int("PT_MAX_SPP", c["pt_max_spp"])
    c["repeats"] = env_int("REPEATS", c["repeats"])
    c["cap"] = env_float("CAP", c["cap"])
    c["mlt_seeds"] = max(2, env_int("MLT_SEEDS", c["mlt_seeds"]))
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
    wanted = [w for w in os.environ.get("SCENES", "").split(",") if w.strip()]
    unknown = [w for w in wanted if w not in SCENES]
    if unknown:
        sys.exit(f"tradeoff: SCENES: unknown {','.join(unknown)} (known: {','.join(SCENES)})")
    c["scenes"] = [sc for sc in SCENES if sc in wanted] if wanted else \
        [sc for sc in SCENES if not (quick and sc in NOT_QUICK)]
    c["bidir_only"] = os.environ.get("BIDIR_ONLY", "") not in ("", "0")
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


_region_index = {}  # (width, height, scene) -> caustic_index's answer: the geometry takes seconds


def caustic_index(width, height, scene=CAUSTIC_SCENE):
    """Float offsets, in a PFM (bottom row first), of the pixels of the scene's region (REGIONS)."""
    key = (width, height, scene)
    if key not in _region_index:
        _region_index[key] = [3 * ((height - 1 - y) * width + x) for x, y in REGIONS[scene](width, height)]
    return _region_index[key]


def region_average(a, index):
    return sum(a[i + k] for i in index for k in range(3)) / (3 * len(index))


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
        self.caustic_ref_mse = {}  # scene -> the reference's own MSE over its region (REGIONS)
        # Threads that wait passively: a spinning OpenMP thread would count as CPU time (cpu_s) and take
        # the CPU of whatever else runs on the machine.
        self.env = dict(os.environ)
        self.env.setdefault("OMP_WAIT_POLICY", "passive")

    def exe(self, chapter):
        return os.path.join(ROOT, self.c["build"], chapter)

    def run_once(self, chapter, scene, args, name, ref=None, timeout=None):
        """Render once; return the stats dict with cpu_s, the CPU seconds of the whole process (None if the
        run exceeded timeout)."""
        pfm = os.path.join(self.work, scene, name + ".pfm")
        stats = os.path.join(self.work, scene, name + ".json")
        cmd = [self.exe(chapter), os.path.join("scenes", scene + ".scene"), "--quiet", "--size", self.size,
               "--out", pfm, "--stats", stats] + [str(a) for a in args]
        if ref:
            cmd += ["--ref", ref]
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        try:
            r = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=timeout,
                               stdin=subprocess.DEVNULL, env=self.env)
        except subprocess.TimeoutExpired:
            return None
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        if r.returncode != 0:
            raise RuntimeError(f"{' '.join(cmd)} exited {r.returncode}: {r.stderr.strip()[-2000:]}")
        with open(stats) as f:
            result = json.load(f)
        result["cpu_s"] = after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime
        return result

    def point(self, chapter, scene, args, name, ref, ref_pixels, repeats=None, cap=None):
        """Render one sweep point `repeats` times (the identical image: same
        seed), time = median of prepare_s + render_s; metrics from the
        chapter's --ref.  Returns a row dict, status 'over budget' if the
        first run took longer than the cap (it is killed at the cap)."""
        repeats = self.c["repeats"] if repeats is None else repeats
        cap = self.c["cap"] if cap is None else cap
        first = self.run_once(chapter, scene, args, name, ref, timeout=cap * 1.5 + 5)
        if first is None:
            return {"status": "over budget", "time_s": None}
        times, cpus = [first["prepare_s"] + first["render_s"]], [first["cpu_s"]]
        # Repeat only runs that are quick: the relative timing noise of a
        # long run is small, and repeating it would cost the most.
        if times[0] < 2.0:
            for _ in range(repeats - 1):
                s = self.run_once(chapter, scene, args, name + ".rep", ref, timeout=cap * 1.5 + 5)
                if s is not None:
                    times.append(s["prepare_s"] + s["render_s"])
                    cpus.append(s["cpu_s"])
        m = first.get("metrics") or {}
        w, h, pixels = read_pfm(os.path.join(self.work, scene, name + ".pfm"))
        mse, se = mse_standard_error(pixels, ref_pixels)
        caustic = region_mean = None
        if scene in REGIONS and self.caustic_ref_mse.get(scene) is not None:
            index = caustic_index(w, h, scene)
            caustic = math.sqrt(max(region_mse(pixels, ref_pixels, index) - self.caustic_ref_mse[scene], 0.0))
            region_mean = region_average(pixels, index)
        # The chapter's rmse and ours are the same quantity (a consistency check).
        if m.get("rmse") is not None and abs(math.sqrt(mse) - m["rmse"]) > 1e-3 * m["rmse"] + 1e-9:
            raise RuntimeError(f"{name}: rmse {m['rmse']} from stats but {math.sqrt(mse)} from the image")
        status = "ok" if times[0] <= cap else "over budget"
        return {"time_s": statistics.median(times), "time_min_s": min(times), "repeats": len(times),
                "prepare_s": first["prepare_s"], "render_s": first["render_s"], "cpu_s": statistics.median(cpus),
                "rmse": m.get("rmse"),
                "relmse": m.get("relmse"), "ssim": m.get("ssim"), "psnr": m.get("psnr"), "mse_se": se,
                "spp": first.get("spp"), "patches": first.get("patches"), "iterations": first.get("iterations"),
                "caustic_rmse": caustic, "pixels": w * h, "mean": sum(pixels) / len(pixels), "region_mean": region_mean,
                "region_pixels": len(index) if region_mean is not None else None, "status": status, "_stats": first}

    def seeded_point(self, chapter, scene, args, name, ref, ref_pixels, seeds, cap=None):
        """One sweep point of a method whose error is correlated across pixels (chapter 7): rendered once with
        each of `seeds`; RMSE = sqrt(mean MSE over the seeds), mse_se = the standard error of that mean over
        the seeds (not over pixels), time and CPU time the medians, status ok only if every run was."""
        runs = [self.point(chapter, scene, list(args) + ["--seed", seed], f"{name}-s{k}", ref, ref_pixels, 1, cap)
                for k, seed in enumerate(seeds)]
        if any(r["status"] != "ok" for r in runs):
            return {"status": "over budget", "time_s": None, "seeds": len(seeds)}
        mses = [r["rmse"] ** 2 for r in runs]
        mean = statistics.fmean
        caustic = [r["caustic_rmse"] for r in runs]
        row = dict(runs[0])
        row.update({"time_s": statistics.median(r["time_s"] for r in runs), "time_min_s": min(r["time_s"] for r in runs),
                    "repeats": 1, "seeds": len(seeds), "cpu_s": statistics.median(r["cpu_s"] for r in runs),
                    "prepare_s": statistics.median(r["prepare_s"] for r in runs),
                    "render_s": statistics.median(r["render_s"] for r in runs),
                    "rmse": math.sqrt(mean(mses)), "mse_se": statistics.stdev(mses) / math.sqrt(len(mses)),
                    "relmse": mean(r["relmse"] for r in runs), "ssim": mean(r["ssim"] for r in runs),
                    "psnr": mean(r["psnr"] for r in runs), "mean": mean(r["mean"] for r in runs),
                    "caustic_rmse": math.sqrt(mean(e * e for e in caustic)) if None not in caustic else None,
                    "region_mean": mean(r["region_mean"] for r in runs) if runs[0]["region_mean"] is not None else None})
        return row


# --- the sweeps ---------------------------------------------------------------------------

def reference(run, scene):
    """Two independent halves of the scene's REFERENCES method; returns (ref path, pixels, info)."""
    c = run.c
    d = os.path.join(run.work, scene)
    info_path = os.path.join(d, "reference.json")
    ref_path = os.path.join(d, "reference.pfm")
    chapter, method_args, what = REFERENCES[scene]
    spp = c["ref_spp"] if chapter == "04_pathtrace" else c["ref_passes"]
    key = {"size": c["size"], "spp_half": spp, "build": c["build"], "chapter": chapter,
           "args": [str(a) for a in method_args], "exe_mtime": os.path.getmtime(run.exe(chapter))}
    if c["reuse_ref"] and os.path.exists(info_path) and os.path.exists(ref_path):
        with open(info_path) as f:
            info = json.load(f)
        if info.get("key") == key:
            run.caustic_ref_mse[scene] = info.get("caustic_mse")
            return ref_path, read_pfm(ref_path)[2], info
    args = list(method_args) + ["--spp", spp]
    a = run.run_once(chapter, scene, args + ["--seed", 900001], "ref-a")
    b = run.run_once(chapter, scene, args + ["--seed", 900002], "ref-b", ref=os.path.join(d, "ref-a.pfm"))
    w, h, pa = read_pfm(os.path.join(d, "ref-a.pfm"))
    _, _, pb = read_pfm(os.path.join(d, "ref-b.pfm"))
    avg = array.array("f", [(x + y) * 0.5 for x, y in zip(pa, pb)])
    write_pfm(ref_path, w, h, avg)
    rmse_ab = b["metrics"]["rmse"]
    region_mean = None
    if scene in REGIONS:
        run.caustic_ref_mse[scene] = region_mse(pa, pb, caustic_index(w, h, scene)) / 4.0
        region_mean = region_average(avg, caustic_index(w, h, scene))
    info = {"caustic_mse": run.caustic_ref_mse.get(scene), "key": key, "method": what, "chapter": chapter,
            "spp": 2 * spp, "seeds": [900001, 900002], "cpu_s": a["cpu_s"] + b["cpu_s"],
            "time_s": a["prepare_s"] + a["render_s"] + b["prepare_s"] + b["render_s"],
            "rmse_halves": rmse_ab, "rmse": rmse_ab / 2.0, "mse": (rmse_ab / 2.0) ** 2,
            "nonfinite_samples": a["nonfinite_samples"] + b["nonfinite_samples"],
            "mean": sum(avg) / len(avg), "region_mean": region_mean}
    with open(info_path, "w") as f:
        json.dump(info, f, indent=1)
    return ref_path, avg, info


def sweep_scene(run, scene, rows):
    c = run.c
    os.makedirs(os.path.join(run.work, scene), exist_ok=True)
    t0 = time.time()
    ref_path, ref_pixels, ref_info = reference(run, scene)
    print(f"[{scene}] reference: {ref_info['method']}, {ref_info['spp']} spp, estimated RMSE {ref_info['rmse']:.4g} "
          f"({time.time() - t0:.0f} s)", flush=True)
    full = scene in FULL_SCENES and not c["bidir_only"]
    seed = [0]

    def add(method, variant, curve, setting, chapter, args, name, extra, repeats=None, cap=None, seeds=0):
        # Path tracing: a new seed per point, so the points of a sweep are
        # independent (the slope fit weighs them as such).  Local, Whitted and
        # radiosity: one common seed (common random numbers), so every point
        # jitters its pixel samples identically and the differences between
        # points are the method's, not the jitter's.
        seed[0] += 1
        point_seed = seed[0] if method in ("pathtrace", "photonmap", "bidirectional") else COMMON_SEED
        if seeds:  # Metropolis: independent seeds seed*1000 + k, k < seeds
            point_seed = 1000 * seed[0]
            r = run.seeded_point(chapter, scene, args, name, ref_path, ref_pixels,
                                 [point_seed + k for k in range(seeds)], cap)
        else:
            r = run.point(chapter, scene, list(args) + ["--seed", point_seed], name, ref_path, ref_pixels, repeats,
                          cap)
        r.update(extra)
        r.update({"scene": scene, "method": method, "variant": variant, "curve": curve, "setting": setting,
                  "seed": point_seed, "order": seed[0], "ref_mse": ref_info["mse"]})
        r.pop("_stats", None)
        rows.append(r)
        t = r.get("time_s")
        print(f"[{scene}] {curve:24s} {setting:22s} " +
              (f"time {t:8.4f} s  rmse {r['rmse']:.4g}" if r["status"] == "ok" else r["status"]), flush=True)
        return r

    # Chapters 4 (MIS), 5 and 6 compared: fixed sweeps, so that a loaded machine (a slower wall clock) does
    # not cut them short; their cap (bd_cap) only stops a run that hangs.
    cap = c["bd_cap"]
    # Path tracing: spp sweep per estimator (MIS only on the scenes of chapter 6 alone).
    for e in ESTIMATORS if full else ["mis"]:
        for n in c["pt_spp"]:
            add("pathtrace", e, f"pt-{e}", f"spp={n}", "04_pathtrace",
                ["--estimator", e, "--spp", n, "--probe-samples", 32], f"pt-{e}-{n}", {},
                cap=cap if e == "mis" else None)
    # Photon mapping: progressive passes (the radius shrinks by R12 each pass).
    if os.access(run.exe("05_photonmap"), os.X_OK):
        for n in c["pm_passes"] if scene in FULL_SCENES else c["bd_pm_passes"]:
            add("photonmap", "progressive", "pm", f"passes={n}", "05_photonmap",
                ["--spp", n, "--photons", c["pm_photons"], "--probe-photons", 32], f"pm-{n}", {}, cap=cap)
    # Chapter 6: light tracing, BDPT and VCM over passes (one light subpath per pixel and pass; VCM's merging
    # radius shrinks by R12 each pass); passes = 2 x 4^k, as path tracing's spp.
    if os.access(run.exe("06_bidirectional"), os.X_OK):
        for m in BIDIR_METHODS:
            for n in c["bd_passes"][m]:
                r = add("bidirectional", m, f"bd-{m}", f"passes={n}", "06_bidirectional", ["--method", m, "--spp", n],
                        f"bd-{m}-{n}", {}, cap=cap)
                if r["status"] != "ok":
                    break
    # Chapter 7: PSSMLT and MMLT over mutations per pixel, each point over independent seeds (MLT_METHODS).
    if os.access(run.exe("07_metropolis"), os.X_OK):
        for m in MLT_METHODS:
            for n in c["mlt_spp"]:
                r = add("metropolis", m, f"mlt-{m}", f"mutations={n}", "07_metropolis",
                        ["--method", m, "--spp", n, "--bootstrap", c["mlt_bootstrap"]], f"mlt-{m}-{n}", {}, cap=cap,
                        seeds=c["mlt_seeds"])
                if r["status"] != "ok":
                    break
    if not full:
        return ref_info
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

def has_full_sweep(rows, scene):
    """Whether every chapter's sweep ran on the scene (FULL_SCENES, not BIDIR_ONLY)."""
    return scene in FULL_SCENES and any(r["scene"] == scene and r["method"] == "radiosity" for r in rows)


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


def report(c, rows, refs, plots, targets):
    curves_order = [f"pt-{e}" for e in ESTIMATORS] + [f"radiosity-{s}" for s in SOLVERS] + \
                   ["whitted-depth", "whitted-weight", "local", "pm", "bd-light", "bd-bdpt", "bd-vcm", "mlt-pssmlt",
                    "mlt-mmlt"]
    curve_title = {f"pt-{e}": f"path tracing ({e})" for e in ESTIMATORS}
    curve_title.update({f"radiosity-{s}": f"radiosity ({s})" for s in SOLVERS})
    curve_title.update({"whitted-depth": "Whitted (max depth)", "whitted-weight": "Whitted (min weight)",
                        "local": "local (light samples)", "pm": "photon mapping", "bd-light": "light tracing",
                        "bd-bdpt": "BDPT", "bd-vcm": "VCM", "mlt-pssmlt": "PSSMLT", "mlt-mmlt": "MMLT"})
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
    for scene in c["scenes"]:
        ref = refs.get(scene)
        if ref is None:
            continue
        full = has_full_sweep(rows, scene)
        L.append(f"\n## {scene}.scene\n")
        L.append((f"![error against time](tradeoff-{scene}.png) ![radiosity floor](tradeoff-radiosity-{scene}.png) "
                  if full else "") + f"![chapters 4, 5 and 6](tradeoff-bidirectional-{scene}.png)\n")
        L.append(f"**Reference**: {ref['method']}, {ref['spp']} spp as two independent halves "
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
        estimators = ESTIMATORS if full else ["mis"]
        for e in estimators:
            pts = [r for r in ok_rows(rows, scene, f"pt-{e}") if r["spp"] >= 2]
            vals = [1.0 / ((r["rmse"] ** 2 - r["ref_mse"]) * r["time_s"]) for r in pts
                    if r["rmse"] ** 2 > 10 * r["ref_mse"] and r["time_s"] > 0]
            effs[e] = statistics.median(vals) if vals else None
        top = max((v for v in effs.values() if v), default=None)
        for e in estimators:
            f = pathtrace_slope(rows, scene, e)
            eff = effs[e]
            L.append(f"| {e} | {f['slope']:.3f} | {f['se']:.3f} | {','.join(map(str, f['spp']))} | "
                     f"{fmt(eff)} | {fmt(eff / top) if eff and top else '—'} |" if f else
                     f"| {e} | — | — | too few points | {fmt(eff)} | — |")
        # Radiosity: the discretisation floor.
        if full:
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
    L.extend(bidirectional_report(c, rows, refs, targets))
    L.append("\n## How to read this\n")
    L.append("- Unbiased Monte Carlo (path tracing) falls along N^-1/2 lines (the grey guide) without floor; "
             "the estimators differ by a constant factor in time (their efficiency).\n"
             "- Radiosity and Whitted / local illumination are biased: each has a floor set by what it leaves "
             "out (discretisation, indirect light, caustics). Cheap at coarse error, unable to go below it.\n"
             "- Photon mapping and VCM are biased by their radius, which shrinks with the passes (R12): their "
             "error falls more slowly than N^-1/2 but keeps falling. Light tracing alone misses what the camera "
             "sees in a mirror or through glass: a floor on cornell-spheres, sds and smallpt.\n"
             "- Times include radiosity's form factors (prepare_s) and the pixel loop, on "
             f"{os.cpu_count()} cores.")
    with open(os.path.join(c["out"], "tradeoff.md"), "w") as f:
        f.write("\n".join(L) + "\n")


# --- why a method loses ----------------------------------------------------------------------------

def longest_point(rows, scene, curve):
    pts = ok_rows(rows, scene, curve)
    return max(pts, key=lambda r: r["order"]) if pts else None


def per_pixel_squared_errors(test, reference):
    return [sum((test[i + k] - reference[i + k]) ** 2 for k in range(3)) / 3.0 for i in range(0, len(reference), 3)]


def loss_measures(c, rows, scene):
    """What makes light tracing and photon mapping lose, measured on their longest points of this run (from the
    renders left in OUT/tradeoff/<scene>/): light tracing's share of pixels it leaves black (reference above 0.01)
    and their share of its MSE, its RMSE over the other pixels; photon mapping's share of rays that are photons
    (its --stats) and the share of its MSE in its worst 1% of pixels.  {} for what is missing."""
    d = os.path.join(c["out"], "tradeoff", scene)
    m = {}
    try:
        ref = read_pfm(os.path.join(d, "reference.pfm"))[2]
    except OSError:
        return m
    lt = longest_point(rows, scene, "bd-light")
    path = lt and os.path.join(d, f"bd-light-{lt['setting'].split('=')[1]}.pfm")
    if path and os.path.exists(path):
        img = read_pfm(path)[2]
        se = per_pixel_squared_errors(img, ref)
        black = [p for p in range(len(se)) if not any(img[3 * p:3 * p + 3]) and sum(ref[3 * p:3 * p + 3]) > 0.03]
        total, lost = sum(se), sum(se[p] for p in black)
        if total > 0:
            m["light"] = {"setting": lt["setting"], "black_pct": 100.0 * len(black) / len(se),
                          "black_mse_pct": 100.0 * lost / total,
                          "rmse_elsewhere": math.sqrt((total - lost) / max(len(se) - len(black), 1))}
    pm = longest_point(rows, scene, "pm")
    n = pm and pm["setting"].split("=")[1]
    if pm and os.path.exists(os.path.join(d, f"pm-{n}.pfm")) and os.path.exists(os.path.join(d, f"pm-{n}.json")):
        with open(os.path.join(d, f"pm-{n}.json")) as f:
            st = json.load(f)
        se = sorted(per_pixel_squared_errors(read_pfm(os.path.join(d, f"pm-{n}.pfm"))[2], ref), reverse=True)
        rays = sum(st.get("counters", {}).get(k, 0) for k in ("camera_rays", "walk_rays", "shadow_rays"))
        photons = st.get("photon_rays", 0)
        if sum(se) > 0 and rays + photons > 0:
            m["pm"] = {"setting": pm["setting"], "photon_pct": 100.0 * photons / (rays + photons),
                       "top1_mse_pct": 100.0 * sum(se[:max(len(se) // 100, 1)]) / sum(se)}
    return m


def scene_note(c, rows, scene):
    """SCENE_NOTES[scene] with this run's measurements filled in (None if the scene has no note)."""
    if scene not in SCENE_NOTES:
        return None
    m = loss_measures(c, rows, scene)
    lt, pm = m.get("light"), m.get("pm")
    return SCENE_NOTES[scene].format(
        light=(f": at {lt['setting']} the {lt['black_pct']:.1f}% of pixels it leaves black carry "
               f"{lt['black_mse_pct']:.0f}% of its MSE, and its RMSE elsewhere is {lt['rmse_elsewhere']:.3g}"
               if lt else ""),
        pm=(f": at {pm['setting']} {pm['photon_pct']:.0f}% of its rays are photons, and its worst 1% of pixels "
            f"carry {pm['top1_mse_pct']:.0f}% of its MSE" if pm else ""))


# --- chapter 6 at equal time ------------------------------------------------------------------------

BD_CURVES = ["pt-mis", "pm", "bd-light", "bd-bdpt", "bd-vcm", "mlt-pssmlt", "mlt-mmlt"]
CLOCKS = {"cpu_s": "CPU time", "time_s": "wall-clock time"}


def true_rmse(r, key="rmse", ref_mse=None):
    """A point's RMSE with the reference's own MSE taken out (None where the point does not resolve it: its
    MSE is within the reference's)."""
    if r.get(key) is None:
        return None
    excess = r[key] ** 2 - (r["ref_mse"] if ref_mse is None else ref_mse)
    return math.sqrt(excess) if excess > 0 else None


def curve_points(rows, scene, curve, clock, key="rmse", ref_mse=None):
    """[(time, error)] of a curve, sorted by time, the reference's MSE subtracted."""
    pts = []
    for r in ok_rows(rows, scene, curve):
        e = true_rmse(r, key, ref_mse)
        if e is not None and r.get(clock):
            pts.append((r[clock], e))
    return sorted(pts)


def error_at(points, t):
    """A curve's error at time t, interpolated linearly in log-log between its points (None outside them)."""
    if points and abs(math.log(t / points[0][0])) < 1e-9:
        return points[0][1]
    for (ta, ea), (tb, eb) in zip(points, points[1:]):
        if ta < t <= tb:
            w = math.log(t / ta) / math.log(tb / ta)
            return math.exp((1 - w) * math.log(ea) + w * math.log(eb))
    return None


def equal_time(rows, scene, clock, at_curve, key="rmse", ref_mse=None):
    """[(t, {curve: error})] at the times of at_curve's points."""
    curves = {cv: curve_points(rows, scene, cv, clock, key, ref_mse) for cv in BD_CURVES}
    return [(t, {cv: error_at(curves[cv], t) for cv in BD_CURVES}) for t, _ in curves[at_curve]]


def bidirectional_targets(rows, refs, scenes):
    """The targets of chapter 6, from this run's rows: per scene and clock, the ratios at equal time."""
    out = {}
    for scene in scenes:
        if scene not in refs or not ok_rows(rows, scene, "bd-vcm"):
            continue
        res = {"reference": refs[scene]["method"], "reference_spp": refs[scene]["spp"]}
        for clock in CLOCKS:
            vcm = []
            for t, e in equal_time(rows, scene, clock, "bd-vcm"):
                better = [e[cv] for cv in ("bd-bdpt", "pm") if e[cv] is not None]
                if e["bd-vcm"] is not None and len(better) == 2:
                    vcm.append({"t": t, "vcm": e["bd-vcm"], "bdpt": e["bd-bdpt"], "pm": e["pm"],
                                "ratio": e["bd-vcm"] / min(better)})
            res[clock] = {"vcm_over_better": vcm,
                          "vcm_worst": max((v["ratio"] for v in vcm), default=None),
                          "vcm_at_longest": vcm[-1]["ratio"] if vcm else None}
            if scene == "gap":
                bd = [{"t": t, "bdpt": e["bd-bdpt"], "pt": e["pt-mis"], "ratio": e["bd-bdpt"] / e["pt-mis"]}
                      for t, e in equal_time(rows, scene, clock, "bd-bdpt")
                      if e["bd-bdpt"] is not None and e["pt-mis"] is not None]
                res[clock].update({"bdpt_over_pt": bd,
                                   "bdpt_over_pt_median": statistics.median([b["ratio"] for b in bd]) if bd else None,
                                   "bdpt_over_pt_worst": max((b["ratio"] for b in bd), default=None)})
            if scene == SDS_SCENE and refs[scene].get("caustic_mse") is not None:
                pts = curve_points(rows, scene, "bd-vcm", clock, "caustic_rmse", 0.0)
                fit = fit_slope([(math.log(t), math.log(e), 1.0) for t, e in pts]) if len(pts) >= 3 else None
                res[clock]["sds_region_vcm"] = [{"t": t, "rmse": e} for t, e in pts]
                res[clock]["sds_region_vcm_slope"] = fit[0] if fit else None
                res[clock]["sds_region_vcm_falls"] = all(b[1] < a[1] for a, b in zip(pts, pts[1:]))
                res[clock]["sds_region_at_vcm_times"] = [
                    {"t": t, **{cv: v for cv, v in e.items()}}
                    for t, e in equal_time(rows, scene, clock, "bd-vcm", "caustic_rmse", 0.0)]
        out[scene] = res
    return out


def reference_check(rows, refs, scene, key="mean"):
    """Path tracing's longest run against the reference: its image mean (or the region's) minus the
    reference's, over the standard error sqrt(MSE / pixels) (pixels have independent errors).  Path
    tracing is unbiased, so a reference from another method that is off shows here."""
    pts = sorted(ok_rows(rows, scene, "pt-mis"), key=lambda r: r["spp"])
    ref = refs.get(scene) or {}
    if not pts or ref.get(key) is None or pts[-1].get(key) is None:
        return None
    r = pts[-1]
    if key == "mean":
        n, mse = r["pixels"], r["rmse"] ** 2
    else:
        n, mse = r["region_pixels"], (r["caustic_rmse"] or 0.0) ** 2 + (ref.get("caustic_mse") or 0.0)
    se = math.sqrt(mse / n) if n else None
    return {"spp": r["spp"], "pt": r[key], "reference": ref[key], "se": se,
            "z": (r[key] - ref[key]) / se if se else None}


def bidirectional_report(c, rows, refs, targets):
    """Markdown: chapters 4, 5 and 6 at equal time on every scene, and the targets."""
    if not targets:
        return []
    title = {"pt-mis": "path tracing (MIS)", "pm": "photon mapping", "bd-light": "light tracing",
             "bd-bdpt": "BDPT", "bd-vcm": "VCM", "mlt-pssmlt": "PSSMLT", "mlt-mmlt": "MMLT"}
    L = ["\n## Chapters 4, 5 and 6 at equal time\n",
         "Each curve's RMSE with the reference's own MSE subtracted, interpolated (log-log, between its points, "
         "never beyond them) at the times of VCM's points; '—' where a curve has no point on both sides or does "
         "not resolve its error from the reference's. CPU time (all threads, the whole process) is the plots' "
         "axis: on a shared machine it is steadier than the wall clock, given second. Targets of chapter 6: "
         "BDPT at most 1/2 of path "
         "tracing's RMSE on gap; VCM within 1.1x of the better of BDPT and photon mapping on every scene; the "
         "SDS region's error falling with VCM's time. Chapter 7 (PSSMLT, MMLT) is on the same plots and tables: "
         "its error is correlated across pixels, so each of its points is the RMSE over independent seeds "
         "(`seeds` in tradeoff.csv), its standard error over the seeds.\n"]
    for scene, res in targets.items():
        ref = refs[scene]
        L.append(f"\n### {scene}.scene\n")
        L.append(f"![chapters 4, 5 and 6](tradeoff-bidirectional-{scene}.png)\n")
        text = (f"Reference: {ref['method']}, {ref['spp']} spp as two halves, its own RMSE about "
                f"{ref['rmse']:.4g} ({ref['cpu_s']:.0f} CPU s).")
        chk = reference_check(rows, refs, scene)
        if chk and chk["z"] is not None:
            text += (f" Path tracing at {chk['spp']:.0f} spp (unbiased) against it: image mean {chk['pt']:.5g} "
                     f"against {chk['reference']:.5g}, {chk['z']:+.1f} standard errors.")
        if scene == SDS_SCENE:
            chk = reference_check(rows, refs, scene, "region_mean")
            if chk and chk["z"] is not None:
                text += (f" Over the SDS region: {chk['pt']:.5g} against {chk['reference']:.5g}, "
                         f"{chk['z']:+.1f} standard errors (path tracing finds those paths only by hitting the "
                         f"light: rare and large samples, so its mean there is low until it has found enough).")
        note = scene_note(c, rows, scene)
        if note:
            text += " " + note
        L.append(text)
        for clock, name in CLOCKS.items():
            L.append(f"\n{name}:\n")
            L.append("| t (s) | " + " | ".join(title[cv] for cv in BD_CURVES) + " | VCM / better of BDPT, PM |")
            L.append("|---|" + "---|" * (len(BD_CURVES) + 1))
            for t, e in equal_time(rows, scene, clock, "bd-vcm"):
                better = [e[cv] for cv in ("bd-bdpt", "pm") if e[cv] is not None]
                ratio = e["bd-vcm"] / min(better) if len(better) == 2 and e["bd-vcm"] else None
                L.append(f"| {t:.3g} | " + " | ".join(fmt(e[cv], 4) for cv in BD_CURVES) + f" | {fmt(ratio)} |")
            r = res[clock]
            if r["vcm_worst"] is None:
                L.append("\nVCM / better of BDPT and photon mapping: no time where all three have points.")
            else:
                L.append(f"\nVCM / better of BDPT and photon mapping: worst {fmt(r['vcm_worst'])}, at the longest "
                         f"common time {fmt(r['vcm_at_longest'])} (target <= 1.1: "
                         f"{'met at every common time' if r['vcm_worst'] <= 1.1 else 'not met at every time'}"
                         f"{'; met at the longest' if r['vcm_worst'] > 1.1 and r['vcm_at_longest'] <= 1.1 else ''}).")
            if "bdpt_over_pt" in r:
                L.append(f"BDPT / path tracing at BDPT's times: " +
                         ", ".join(f"{b['ratio']:.2f} at {b['t']:.3g} s" for b in r["bdpt_over_pt"]) +
                         f"; median {fmt(r['bdpt_over_pt_median'])} (target <= 0.5: "
                         f"{'met' if r['bdpt_over_pt_median'] is not None and r['bdpt_over_pt_median'] <= 0.5 else 'not met'}).")
            if "sds_region_vcm" in r:
                L.append("SDS region (the caustic seen in the mirror; its proper measurement: sds/sds-convergence.md), "
                         "VCM's RMSE there: " +
                         ", ".join(f"{p['rmse']:.4g} at {p['t']:.3g} s" for p in r["sds_region_vcm"]) +
                         f"; slope in log-log {fmt(r['sds_region_vcm_slope'])}"
                         f" ({'falling at every step' if r['sds_region_vcm_falls'] else 'not falling at every step'}"
                         f"). At VCM's last time the others there: " +
                         (", ".join(f"{title[cv]} {fmt(v, 4)}" for cv, v in r["sds_region_at_vcm_times"][-1].items()
                                    if cv != "t") if r["sds_region_at_vcm_times"] else "—") + ".")
    return L

def target_lines(targets, refs, clock="cpu_s"):
    """The issue's targets as lines of text, from targets.json (this run's rows, one reference a scene for every
    method), at equal CPU time: BDPT / path tracing on gap at BDPT's times (the median of them is the figure);
    VCM / the better of BDPT and photon mapping at VCM's times (the figure: at the longest time all three
    reach, beside the worst of all those times)."""
    def verdict(v, bound):
        return "met" if v is not None and v <= bound else "not met"
    L, unit = [], "CPU s" if clock == "cpu_s" else "s of wall-clock time"
    for scene, res in targets.items():
        r = res.get(clock) or {}
        ref = (f"reference {refs[scene]['method']}, {refs[scene]['spp']} "
               f"{'spp' if refs[scene].get('chapter') == '04_pathtrace' else 'passes'}")
        if r.get("bdpt_over_pt"):
            pts = ", ".join(f"{b['ratio']:.2f} at {b['t']:.3g} s" for b in r["bdpt_over_pt"])
            L.append(f"target {scene} BDPT/PT = {r['bdpt_over_pt_median']:.2f} (<= 0.5: "
                     f"{verdict(r['bdpt_over_pt_median'], 0.5)}): the median at equal {CLOCKS[clock]} over BDPT's "
                     f"{len(r['bdpt_over_pt'])} times ({pts}); {ref}")
        if r.get("vcm_over_better"):
            last = r["vcm_over_better"][-1]
            pts = ", ".join(f"{v['ratio']:.2f} at {v['t']:.3g} s" for v in r["vcm_over_better"])
            L.append(f"target {scene} VCM/min(BDPT,PM) = {last['ratio']:.2f} at {last['t']:.3g} {unit}, the longest "
                     f"time all three reach (<= 1.1: {verdict(last['ratio'], 1.1)}; worst of {len(r['vcm_over_better'])}"
                     f" times {r['vcm_worst']:.2f}: {'met' if r['vcm_worst'] <= 1.1 else 'not met'} at every "
                     f"time; {pts}); {ref}")
        elif res.get(clock) is not None:
            L.append(f"target {scene} VCM/min(BDPT,PM): no {CLOCKS[clock]} where VCM, BDPT and photon mapping all have "
                     f"points resolved above the reference's error")
    return L


SDS_SLOPE_MET = -0.25  # VCM's RMSE in the SDS caustic must fall at least like t^-1/4 (R12 with alpha 2/3: t^-1/3)


def sds_convergence(c):
    """tradeoff/sds_convergence.py into OUT/sds (the same build and size; QUICK stays quick)."""
    env = dict(os.environ, OUT=os.path.join(c["out"], "sds"), BUILD=c["build"], SIZE=str(c["size"]),
               QUICK="1" if c["quick"] else "")
    if c["quick"]:
        env.setdefault("SDS_REF_PASSES", "32")
    subprocess.run([sys.executable, os.path.join(HERE, "sds_convergence.py")], cwd=ROOT, env=env, check=True,
                   stdout=subprocess.DEVNULL)


def sds_target_line(out):
    """The issue's third target from OUT/sds/sds-convergence.json: VCM's RMSE in the SDS caustic seen in the
    mirror against CPU time (slope of the log-log fit over its budgets), beside BDPT's and path tracing's."""
    path = os.path.join(out, "sds", "sds-convergence.json")
    if not os.path.exists(path):
        return []
    with open(path) as f:
        got = json.load(f)
    vcm = [r for r in got["rows"] if r["method"] == "vcm" and r["caustic"]["rmse"]]
    slope = (got["fits"].get("caustic vcm") or [None])[0]
    if slope is None or len(vcm) < 2:
        return ["target sds VCM converging in the SDS caustic: not resolved (fewer than 2 points above the "
                "reference's noise)"]
    met = slope <= SDS_SLOPE_MET and vcm[-1]["caustic"]["rmse"] < vcm[0]["caustic"]["rmse"] / 2
    others = "; ".join(f"{lb} {r['caustic']['rmse']:.2g} (its bias "
                       f"{'unresolved' if r['caustic']['bias'] is None else format(r['caustic']['bias'], '.2g')})"
                       for lb in ("ppm", "bdpt", "pt")
                       for r in [[x for x in got["rows"] if x["method"] == lb][-1]] if r["caustic"]["rmse"])
    return [f"target sds VCM converging in the SDS caustic = slope {slope:.2f} of log RMSE on log CPU time over "
            f"{len(vcm)} budgets ({vcm[0]['cpu_s']:.3g} to {vcm[-1]['cpu_s']:.3g} s, RMSE "
            f"{vcm[0]['caustic']['rmse']:.2g} to {vcm[-1]['caustic']['rmse']:.2g}; <= {SDS_SLOPE_MET} and halved: "
            f"{'met' if met else 'not met'}; R12's alpha 2/3 predicts -1/3 or steeper); at their longest runs: "
            f"{others}; {out}/sds/sds-convergence.md"]


def print_targets(c, targets, refs):
    """The target lines on stdout and in OUT/tradeoff/targets.txt."""
    text = "\n".join(target_lines(targets, refs) + sds_target_line(c["out"])) + "\n"
    with open(os.path.join(c["out"], "tradeoff", "targets.txt"), "w") as f:
        f.write(text)
    print(text, end="", flush=True)


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
    for scene in c["scenes"]:
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
                f.write("# time_s rmse relmse ssim cpu_s\n" + "".join(
                    f"{r['time_s']:.8g} {r['rmse']:.8g} {r['relmse']:.8g} {r['ssim']:.8g} {r['cpu_s']:.8g}\n"
                    for r in pts))
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
         ["whitted-depth", "whitted-weight", "local", "pm", "bd-light", "bd-bdpt", "bd-vcm", "mlt-pssmlt", "mlt-mmlt"]
CURVE_TITLE = {f"pt-{e}": f"path tracing ({e})" for e in ESTIMATORS}
CURVE_TITLE.update({f"radiosity-{s}": f"radiosity ({s}, converged; patch sizes)" for s in SOLVERS})
CURVE_TITLE["pm"] = "photon mapping (progressive passes)"
CURVE_TITLE.update({"whitted-depth": "Whitted (max depth)", "whitted-weight": "Whitted (min weight)",
                    "local": "local (light samples)", "bd-light": "light tracing (chapter 6, passes)",
                    "bd-bdpt": "BDPT (chapter 6, passes)", "bd-vcm": "VCM (chapter 6, passes)",
                    "mlt-pssmlt": "PSSMLT (chapter 7, mutations/pixel; RMSE over seeds)",
                    "mlt-mmlt": "MMLT (chapter 7, mutations/pixel; RMSE over seeds)"})


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
    for scene in c["scenes"]:
        if scene not in refs or not ok_rows(rows, scene):
            continue
        made += bidirectional_plot(c, rows, refs, data, scene)
        if not has_full_sweep(rows, scene):
            continue
        curves = [cv for cv in CURVES if (scene, cv) in data and not cv.startswith(("bd-", "mlt-"))]
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


CPU_AXIS = "CPU time (s), all threads"


def bidirectional_plot(c, rows, refs, data, scene):
    """Chapters 4 (MIS), 5 and 6 on one scene against CPU time: tradeoff-bidirectional-<scene>.png/.svg."""
    curves = [cv for cv in BD_CURVES if (scene, cv) in data]
    if not any(cv.startswith("bd-") for cv in curves):
        return []
    pts = [r for cv in curves for r in ok_rows(rows, scene, cv) if r["cpu_s"] > 0]
    mis = sorted(ok_rows(rows, scene, "pt-mis"), key=lambda r: r["spp"])
    anchor = mis[len(mis) // 2] if mis else pts[0]
    ref = refs[scene]
    made = []
    for term in ("png", "svg"):
        out = os.path.join(c["out"], f"tradeoff-bidirectional-{scene}.{term}")
        gnuplot("errortime.gp", {
            "term": term, "out": out,
            "title": f"{scene}.scene, {c['size']}x{c['size']}: chapters 4, 5, 6"
                     f"{' and 7' if any(cv.startswith('mlt-') for cv in curves) else ''}, error against time "
                     f"(reference: {ref['method']}, {ref['spp']} spp)",
            "files": " ".join(data[(scene, cv)] for cv in curves), "names": quoted(CURVE_TITLE[cv] for cv in curves),
            "styles": " ".join(str(CURVES.index(cv) + 1) for cv in curves), "xcol": 5, "xlabel": CPU_AXIS,
            **({"note": scene_note(c, rows, scene)} if scene in SCENE_NOTES else {}),
            "t0": anchor["cpu_s"], "e0": anchor["rmse"], "refrmse": ref["rmse"],
            "tmin": min(r["cpu_s"] for r in pts) / 2, "tmax": max(r["cpu_s"] for r in pts) * 2,
            "emin": min(min(r["rmse"] for r in pts), ref["rmse"]) / 2, "emax": max(r["rmse"] for r in pts) * 2})
        made.append(out)
    return made


# --- main -------------------------------------------------------------------------------------------

def read_rows(c):
    """The rows and references of an earlier run (REPORT_ONLY=1), numbers as numbers."""
    text = ("scene", "method", "variant", "curve", "setting", "status")
    with open(os.path.join(c["out"], "tradeoff.csv")) as f:
        rows = list(csv.DictReader(f))
    for i, r in enumerate(rows):
        for k, v in r.items():
            if k not in text:
                r[k] = None if v == "" else (int(float(v)) if float(v).is_integer() and k != "time_s" else float(v))
        if r.get("order") is None:
            r["order"] = i  # rows are written in sweep order
    with open(os.path.join(c["out"], "tradeoff", "references.json")) as f:
        refs = json.load(f)["references"]
    c["scenes"] = [sc for sc in c["scenes"] if sc in refs]
    return rows, refs


def main():
    c = config()
    start = time.time()
    if os.environ.get("REPORT_ONLY", "") not in ("", "0"):
        rows, refs = read_rows(c)
        targets = bidirectional_targets(rows, refs, c["scenes"])
        with open(os.path.join(c["out"], "tradeoff", "targets.json"), "w") as f:
            json.dump(targets, f, indent=1)
        made = plots(c, rows, refs)
        report(c, rows, refs, made, targets)
        print_targets(c, targets, refs)
        print(f"tradeoff: report and {len(made)} plots again from {c['out']}/tradeoff.csv", flush=True)
        return
    for ch in ("01_local", "02_whitted", "03_radiosity", "04_pathtrace"):
        if not os.access(os.path.join(ROOT, c["build"], ch), os.X_OK):
            sys.exit(f"tradeoff: {c['build']}/{ch} is missing; run make first")
    run = Runner(c)
    os.makedirs(run.work, exist_ok=True)
    print(f"tradeoff: {'QUICK' if c['quick'] else 'full'} run, {c['size']}x{c['size']}, build {c['build']}, "
          f"output {c['out']}", flush=True)
    rows, refs = [], {}
    for scene in c["scenes"]:
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
    targets = bidirectional_targets(rows, refs, c["scenes"])
    with open(os.path.join(c["out"], "tradeoff", "targets.json"), "w") as f:
        json.dump(targets, f, indent=1)
    made = plots(c, rows, refs)
    report(c, rows, refs, made, targets)
    if SDS_SCENE in c["scenes"] and os.environ.get("SDS_CONVERGENCE", "") != "0":
        sds_convergence(c)
    print_targets(c, targets, refs)
    print(f"tradeoff: wrote {csv_path}, {os.path.join(c['out'], 'tradeoff.md')} and {len(made)} plots "
          f"in {time.time() - start:.0f} s", flush=True)


if __name__ == "__main__":
    main()
