"""Chapters 4, 5 and 6 at equal CPU time on the scenes that separate them.

Scenes: cornell, cornell-spheres, gap (the light in a closet behind a 20 mm slit: eye paths
rarely find it) and sds (a caustic seen in a mirror, L S S D S E: only merging renders it).
Methods: path tracing (04, MIS), photon mapping (05), and chapter 6's light tracing, BDPT,
VCM and VCM without joins (progressive photon mapping).  Each renders 64x64 on one thread:
first 8 passes to measure its CPU seconds per pass, then as many passes as fit in
BENCH6_BUDGET CPU seconds (default 8).  The reference is the mean of two independent long
renders a and b (chapter 4 where it converges, chapter 6's BDPT on gap and VCM on sds; kept
in out/bench/ and reused); its own noise, mean((a - b)^2) / 4 per pixel, is subtracted from
each method's MSE, so a method is not charged for the reference's noise.  Prints RMSE and
relative MSE (per pixel (x - r)^2 / (r^2 + 0.01)) per scene and method, and the targets:
BDPT at most 1/2 of path tracing's RMSE on gap; VCM within 1.1x of the better of BDPT and
photon mapping.  A benchmark, not a test: it prints what it measures, met or not.
"""
import math
import os
import resource
import subprocess
import sys

from common import BUILD, ROOT

sys.path.insert(0, os.path.join(ROOT, "tests"))
from pfm import read_pfm  # noqa: E402

BUDGET = float(os.environ.get("BENCH6_BUDGET", 8))
OUT = os.path.join(ROOT, "out", "bench", "06")
REFERENCES = {"cornell": ("04_pathtrace", ["--spp", "4096", "--probe-samples", "32"]),
              "cornell-spheres": ("04_pathtrace", ["--spp", "4096", "--probe-samples", "32"]),
              "gap": ("06_bidirectional", ["--method", "bdpt", "--spp", "1024"]),
              "sds": ("06_bidirectional", ["--spp", "1024"])}
METHODS = [("pt", "04_pathtrace", ["--probe-samples", "32"]), ("pm", "05_photonmap", ["--probe-photons", "32"]),
           ("light", "06_bidirectional", ["--method", "light"]), ("bdpt", "06_bidirectional", ["--method", "bdpt"]),
           ("vcm", "06_bidirectional", []), ("ppm", "06_bidirectional", ["--connect", "off"])]


def render(chapter, scene, args, out):
    """(CPU seconds, the command) of one 64x64 single-thread render."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    cmd = [os.path.join(BUILD, chapter), os.path.join(ROOT, "scenes", scene + ".scene"), "--size", "64x64",
           "--threads", "1", "--quiet", "--out", out, *args]
    subprocess.run(cmd, check=True, stderr=subprocess.DEVNULL)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    shown = f"build/{chapter} scenes/{scene}.scene --size 64x64 --threads 1 " + " ".join(args)
    return after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime, shown


def pixels(path):
    return list(read_pfm(path)[2])  # every channel of every pixel, in file order (the same for all)


def reference(scene):
    chapter, args = REFERENCES[scene]
    halves = []
    for seed in (901, 902):
        path = os.path.join(OUT, f"ref-{scene}-{seed}.pfm")
        if not os.path.exists(path):
            render(chapter, scene, args + ["--seed", str(seed)], path)
        halves.append(pixels(path))
    return [(a + b) / 2 for a, b in zip(*halves)], [(a - b) ** 2 / 4 for a, b in zip(*halves)]


def errors(x, ref, ref_var):
    """(RMSE, relative MSE) of image x, the reference's own noise taken out."""
    mse = sum((a - r) ** 2 - v for a, r, v in zip(x, ref, ref_var)) / len(x)
    rel = sum(((a - r) ** 2 - v) / (r * r + 0.01) for a, r, v in zip(x, ref, ref_var)) / len(x)
    return math.sqrt(max(mse, 0.0)), rel


def main():
    os.makedirs(OUT, exist_ok=True)
    print(f"chapters 4, 5, 6 at {BUDGET:g} CPU seconds each, 64x64, one thread (BENCH6_BUDGET):")
    for scene in REFERENCES:
        ref, ref_var = reference(scene)
        found = {}
        for label, chapter, args in METHODS:
            cpu, _ = render(chapter, scene, args + ["--spp", "8", "--seed", "3"], os.path.join(OUT, "pilot.pfm"))
            spp = max(1, round(8 * BUDGET / max(cpu, 1e-3)))
            out = os.path.join(OUT, f"{scene}-{label}.pfm")
            cpu, cmd = render(chapter, scene, args + ["--spp", str(spp), "--seed", "7"], out)
            rmse, rel = errors(pixels(out), ref, ref_var)
            rmse, rel = rmse * math.sqrt(cpu / BUDGET), rel * cpu / BUDGET  # to the budget: error^2 ~ 1/time
            found[label] = (rmse, rel)
            print(f"  {scene:16s} {label:6s} {spp:6d} spp {cpu:6.2f} s  RMSE {rmse:.5f}  relMSE {rel:.5f}   {cmd}",
                  flush=True)
        print(f"  {scene:16s} reference noise RMSE {math.sqrt(sum(ref_var) / len(ref_var)):.5f}")
        better = min(found["bdpt"][0], found["pm"][0])
        print(f"  {scene}: VCM / better of BDPT and photon mapping {found['vcm'][0] / better:.2f} (target <= 1.1)"
              + (f"; BDPT / path tracing {found['bdpt'][0] / found['pt'][0]:.2f} (target <= 0.5)"
                 if scene == "gap" else ""), flush=True)


if __name__ == "__main__":
    main()
