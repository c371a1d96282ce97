"""Chapters 4, 5 and 6 at equal CPU time on the scenes that separate them.

Scenes: cornell, cornell-spheres, gap (the light in a closet behind a 20 mm slit: eye paths
rarely find it) and sds (a caustic seen in a mirror, L S S D S E: only merging renders it).
Methods: path tracing (04, MIS), photon mapping (05), and chapter 6's light tracing, BDPT,
VCM and VCM without joins (progressive photon mapping).  Each renders 64x64 (BENCH6_SIZE=N: NxN)
on one thread: first 8 passes to measure its CPU seconds per pass, then, for each budget of
BENCH6_BUDGETS (CPU seconds, default 2,8), as many passes as fit in it, BENCH6_REPEATS times
(default 1) with different seeds: its MSE is the mean over the repeats, its CPU time the
least (the run least disturbed by whatever else the machine does), and its error is scaled
to the budget exactly by error^2 ~ 1/time.  BENCH6_METHODS=pt,pm,bdpt,vcm picks methods
(the targets need these four).  The reference is the mean of two independent long
renders a and b (chapter 4 where it converges, chapter 6's BDPT on gap and VCM on sds; kept
in out/bench/06/ by size and reused; on two threads, which gives the same image); its own
noise, mean((a - b)^2) / 4 per pixel, is subtracted from each method's MSE, so a method is
not charged for the reference's noise.  BENCH6_COST_ROUNDS=N (default 0: off) takes each method's CPU time
per pass instead from N rounds of short runs of every method in turn (pass_costs), the least of each: on a
loaded machine the CPU time of the long runs varies by 10-50 % with what runs beside them.  Prints RMSE,
relative MSE (per pixel (x - r)^2 / (r^2 + 0.01)) and the RMSE off the light's edges (the
pixels whose reference jumps by more than EDGE_JUMP to a neighbour left out: there a pixel
half on the light, radiance 17 next to 0, is what path tracing's jittered camera rays
estimate worst and light tracing's joins to the camera best; at 64x64 they are 52 pixels
of the Cornell box, 1.3 %, and 96 % of path tracing's MSE) per scene and method, and the
targets, one line each at each budget (`target gap BDPT/PT = 0.50 at 8 CPU s (<= 0.5: met;
...)`), all of them again at the end: BDPT at most 1/2 of path tracing's RMSE on gap; VCM
within 1.1x of the better of BDPT and photon mapping (the whole image's RMSE, the issue's
figure; the ratio off the light's edges beside it); on sds also over the mirror ball without the
light's images in it (caustic_region.sds_mirror_regions: the whole image and "off the edges" there
are a few fireflies of the light seen through mirror and glass).  BENCH6_SCENES=a,b picks scenes.
BENCH6_VCM_ARGS="--alpha A ..." adds options to VCM's runs (not to the references), to try a setting;
BENCH6_VCM_RADIUS_SCALE=F runs VCM with F times its default first radius at this size (2 at 128x128:
chapter 5's default radius, which does not shrink with the image).
A benchmark, not a test: it prints what it measures, met or not.
"""
import json
import math
import os
import resource
import subprocess
import sys

from common import BUILD, ROOT

sys.path.insert(0, os.path.join(ROOT, "tests"))
sys.path.insert(0, os.path.join(ROOT, "tradeoff"))
from pfm import read_pfm  # noqa: E402
from caustic_region import sds_mirror_regions  # noqa: E402

SIZE = int(os.environ.get("BENCH6_SIZE", "64"))
REPEATS = int(os.environ.get("BENCH6_REPEATS", "1"))
COST_ROUNDS = int(os.environ.get("BENCH6_COST_ROUNDS", "0"))
COST_PASSES = 32  # a short run's passes (x8 for path tracing's spp): the scene's set-up is under 2 % of it
# CPU seconds per method: the targets are printed at each (BENCH6_BUDGETS=2,8; BENCH6_BUDGET=8 alone).
BUDGETS = [float(b) for b in (os.environ.get("BENCH6_BUDGETS") or os.environ.get("BENCH6_BUDGET") or "2,8").split(",")]
EDGE_JUMP = 3.0  # radiance: the light's edges (17 next to 0), not the walls' shading (below 2)
OUT = os.path.join(ROOT, "out", "bench", "06")
REFERENCES = {"cornell": ("04_pathtrace", ["--spp", "4096", "--probe-samples", "32"]),
              "cornell-spheres": ("04_pathtrace", ["--spp", "4096", "--probe-samples", "32"]),
              "gap": ("06_bidirectional", ["--method", "bdpt", "--spp", "1024"]),
              "sds": ("06_bidirectional", ["--spp", "1024"])}
# Probes (cornell, cornell-spheres) at their fewest samples in every chapter: their cost is the run's, not a pass's
# (chapter 6's default 16384 a probe added 5 ms to BDPT's and VCM's pass on cornell at 128x128, 32 passes).
FEW_PROBES = ["--probe-samples", "32"]
VCM_ARGS = os.environ.get("BENCH6_VCM_ARGS", "").split()
VCM_RADIUS_SCALE = float(os.environ.get("BENCH6_VCM_RADIUS_SCALE", "1"))
METHODS = [("pt", "04_pathtrace", FEW_PROBES), ("pm", "05_photonmap", ["--probe-photons", "32"]),
           ("light", "06_bidirectional", ["--method", "light", *FEW_PROBES]),
           ("bdpt", "06_bidirectional", ["--method", "bdpt", *FEW_PROBES]), ("vcm", "06_bidirectional", [*FEW_PROBES, *VCM_ARGS]),
           ("ppm", "06_bidirectional", ["--connect", "off", *FEW_PROBES])]


def render(chapter, scene, args, out, threads=1):
    """(CPU seconds, the command) of one SIZE x SIZE render."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    size = f"{SIZE}x{SIZE}"
    cmd = [os.path.join(BUILD, chapter), os.path.join(ROOT, "scenes", scene + ".scene"), "--size", size,
           "--threads", str(threads), "--quiet", "--out", out, *args]
    subprocess.run(cmd, check=True, stderr=subprocess.DEVNULL)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    shown = f"{os.path.relpath(BUILD, ROOT)}/{chapter} scenes/{scene}.scene --size {size} --threads {threads} " + \
        " ".join(args)
    return after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime, shown


def vcm_radius_args(scene):
    """--radius for VCM's runs on scene: VCM_RADIUS_SCALE times the first radius chapter 6 picks at this size
    (its stats' last_radius after one pass); none when the scale is 1."""
    if VCM_RADIUS_SCALE == 1.0:
        return []
    stats = os.path.join(OUT, "radius.json")
    render("06_bidirectional", scene, ["--spp", "1", "--stats", stats, *FEW_PROBES], os.path.join(OUT, "radius.pfm"))
    with open(stats) as f:
        return ["--radius", repr(VCM_RADIUS_SCALE * json.load(f)["last_radius"])]


def pixels(path):
    return list(read_pfm(path)[2])  # every channel of every pixel, in file order (the same for all)


def reference(scene):
    chapter, args = REFERENCES[scene]
    halves = []
    for seed in (901, 902):
        path = os.path.join(OUT, f"ref-{scene}-{seed}.pfm" if SIZE == 64 else f"ref-{scene}-{SIZE}-{seed}.pfm")
        if not os.path.exists(path):
            render(chapter, scene, args + ["--seed", str(seed)], path, threads=2)
        halves.append(pixels(path))
    return [(a + b) / 2 for a, b in zip(*halves)], [(a - b) ** 2 / 4 for a, b in zip(*halves)]


def off_edges(ref, width=SIZE, height=SIZE):
    """Indices (into the flat channel list) of the pixels without a jump above EDGE_JUMP in the reference's
    mean of the channels to a 4-neighbour."""
    lum = [sum(ref[3 * p:3 * p + 3]) / 3 for p in range(width * height)]
    keep = []
    for p in range(width * height):
        x, y = p % width, p // width
        near = [q for q, ok in ((p - 1, x > 0), (p + 1, x < width - 1), (p - width, y > 0), (p + width, y < height - 1))
                if ok]
        if all(abs(lum[q] - lum[p]) <= EDGE_JUMP for q in near):
            keep += [3 * p, 3 * p + 1, 3 * p + 2]
    return keep


def errors(x, ref, ref_var, keep, region=None):
    """(RMSE, relative MSE, RMSE over the channels in keep, RMSE over the channels in region or None) of image x,
    the reference's own noise taken out."""
    mse = sum((a - r) ** 2 - v for a, r, v in zip(x, ref, ref_var)) / len(x)
    rel = sum(((a - r) ** 2 - v) / (r * r + 0.01) for a, r, v in zip(x, ref, ref_var)) / len(x)
    off = sum((x[i] - ref[i]) ** 2 - ref_var[i] for i in keep) / max(len(keep), 1)
    inside = sum((x[i] - ref[i]) ** 2 - ref_var[i] for i in region) / len(region) if region else None
    return (math.sqrt(max(mse, 0.0)), rel, math.sqrt(max(off, 0.0)),
            None if inside is None else math.sqrt(max(inside, 0.0)))


def mean_errors(runs):
    """errors()'s tuple over repeated runs: RMSEs as the root of the mean MSE, relative MSE as the mean."""
    def root_mean_square(values):
        return None if values[0] is None else math.sqrt(sum(v * v for v in values) / len(values))
    rmse, rel, off, inside = zip(*runs)
    return root_mean_square(rmse), sum(rel) / len(rel), root_mean_square(off), root_mean_square(inside)


def mirror_region(width=SIZE, height=SIZE):
    """Channel indices (PFM order, bottom row first) of sds.scene's mirror ball without the light's images in it
    (caustic_region.sds_mirror_regions: only there are the scene's L S .. D S E paths measured without the
    fireflies of the light seen through mirror and glass, E S .. S L, which only an eye path that hits the
    13 mm light renders)."""
    return [3 * ((height - 1 - y) * width + x) + k for x, y in sds_mirror_regions(width, height)["mirror"]
            for k in range(3)]


def target_lines(scene, found):
    """The issue's targets as lines, from {budget: {method: (RMSE, relative MSE, RMSE off the edges)}}: the
    figure is the whole image's RMSE (the issue's), the ratio off the light's edges beside it."""
    L = []
    for budget in sorted(found):
        f = found[budget]
        if not all(m in f for m in ("pt", "pm", "bdpt", "vcm")):
            continue
        if f["vcm"][3] is not None:
            q = f["vcm"][3] / min(f["bdpt"][3], f["pm"][3])
            L.append(f"target {scene} VCM/min(BDPT,PM) in the mirror ball (the SDS paths, no light image) = {q:.2f} "
                     f"at {budget:g} CPU s (<= 1.1: {'met' if q <= 1.1 else 'not met'})")
        if scene == "gap":
            q, off = f["bdpt"][0] / f["pt"][0], f["bdpt"][2] / f["pt"][2]
            L.append(f"target {scene} BDPT/PT = {q:.2f} at {budget:g} CPU s (<= 0.5: "
                     f"{'met' if q <= 0.5 else 'not met'};"
                     f" off the light's edges {off:.2f})")
        q = f["vcm"][0] / min(f["bdpt"][0], f["pm"][0])
        off = f["vcm"][2] / min(f["bdpt"][2], f["pm"][2])
        L.append(f"target {scene} VCM/min(BDPT,PM) = {q:.2f} at {budget:g} CPU s (<= 1.1: "
                 f"{'met' if q <= 1.1 else 'not met'}; off the light's edges {off:.2f})")
    return L


def pass_costs(scene, methods):
    """CPU seconds per pass (per 8 spp for path tracing) of each method: the least over COST_ROUNDS rounds of one
    short run of each method in turn, so that every method meets the machine's load alike and the quietest
    round counts (the CPU time of a run beside another job's is inflated: two cores share caches, or are one)."""
    cost = {}
    for _ in range(COST_ROUNDS):
        for label, chapter, args in methods:
            passes = COST_PASSES * (8 if label == "pt" else 1)
            used, _ = render(chapter, scene, args + ["--spp", str(passes), "--seed", "5"],
                             os.path.join(OUT, "cost.pfm"))
            cost[label] = min(cost.get(label, math.inf), used / passes)
    return cost


def main():
    os.makedirs(OUT, exist_ok=True)
    print(f"chapters 4, 5, 6 at {', '.join(f'{b:g}' for b in BUDGETS)} CPU seconds each, {SIZE}x{SIZE}, one thread, "
          f"{REPEATS} run(s) each (BENCH6_BUDGETS, BENCH6_SIZE, BENCH6_REPEATS); one reference a scene for every "
          f"method and budget; load: {os.getloadavg()[0]:.1f}")
    wanted = [w for w in os.environ.get("BENCH6_SCENES", "").split(",") if w]
    picked = [w for w in os.environ.get("BENCH6_METHODS", "").split(",") if w]
    targets = []
    for scene in [sc for sc in REFERENCES if not wanted or sc in wanted]:
        ref, ref_var = reference(scene)
        keep = off_edges(ref)
        region = mirror_region() if scene == "sds" else None
        found = {b: {} for b in BUDGETS}
        methods = [(label, chapter, args + (vcm_radius_args(scene) if label == "vcm" else []))
                   for label, chapter, args in METHODS if not picked or label in picked]
        cost = pass_costs(scene, methods) if COST_ROUNDS > 0 else {}
        if cost:
            print(f"  {scene:16s} CPU ms per pass (least of {COST_ROUNDS} rounds of {COST_PASSES}): " +
                  ", ".join(f"{m} {c * 1000 * (8 if m == 'pt' else 1):.1f}" for m, c in cost.items()), flush=True)
        for label, chapter, args in methods:
            cpu, _ = render(chapter, scene, args + ["--spp", "8", "--seed", "3"], os.path.join(OUT, "pilot.pfm"))
            for budget in BUDGETS:
                spp = max(1, round(8 * budget / max(cpu, 1e-3)))
                out = os.path.join(OUT, f"{scene}-{label}-{budget:g}.pfm" if SIZE == 64 else
                                   f"{scene}-{label}-{budget:g}-{SIZE}.pfm")
                runs = []
                for rep in range(REPEATS):
                    seed = 7 + BUDGETS.index(budget) + 100 * rep
                    used, cmd = render(chapter, scene, args + ["--spp", str(spp), "--seed", str(seed)], out)
                    runs.append((used, errors(pixels(out), ref, ref_var, keep, region)))
                used = cost[label] * spp if cost else min(u for u, _ in runs)
                rmse, rel, off, inside = mean_errors([e for _, e in runs])
                scale = math.sqrt(used / budget)  # to the budget: error^2 ~ 1/time
                rmse, rel, off = rmse * scale, rel * scale ** 2, off * scale
                inside = None if inside is None else inside * scale
                found[budget][label] = (rmse, rel, off, inside)
                print(f"  {scene:16s} {label:6s} {budget:4g} s {spp:6d} spp {used:6.2f} s  RMSE {rmse:.5f}  relMSE "
                      f"{rel:.5f}  RMSE off the light's edges {off:.5f}" +
                      ("" if inside is None else f"  in the mirror ball {inside:.5f}") + f"   {cmd}", flush=True)
        print(f"  {scene:16s} reference noise RMSE {math.sqrt(sum(ref_var) / len(ref_var)):.5f}; "
              f"{(len(ref) - len(keep)) // 3} pixels on the light's edges; load {os.getloadavg()[0]:.1f}")
        lines = target_lines(scene, found)
        targets += lines
        print("\n".join("  " + line for line in lines), flush=True)
    print("\n".join(targets))


if __name__ == "__main__":
    main()
