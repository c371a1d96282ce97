"""Every chapter method on smallpt's own scene (scenes/smallpt.scene), at smallpt's wall time.

SMALLPT=/path/to/smallpt (Kevin Beason's smallpt.cpp built with OpenMP; not part of this
repository: third-party code is not committed) is run as `smallpt 256 256 192` (its usual
argument is the spp; the width and height are accepted by the copy we measured with, others
render 1024x768 and the bench says so) in a scratch directory with OMP_NUM_THREADS=2; its wall
time T is the budget each method then gets (--time T --threads 2): chapter 4's path tracer
(mis and cosine), chapter 5's photon mapping, chapter 6's light tracing, BDPT and VCM.
Repeated BENCH_SMALLPT_REPEATS times (default 3), smallpt and the methods interleaved, so a
change of the machine's load hits all alike; min / median / max over the repeats, and the load.

Error: MSE over pixels and channels of the linear radiance clamped to [0, 1] (smallpt's range:
it clamps each subpixel's mean).  Each against its own long reference, cached in out/bench/smallpt/:
the chapters against the mean of two chapter-4 renders with the cosine estimator (BSDF sampling
only: independent of the light-sampling code the methods differ in; BENCH_SMALLPT_REF_SPP each,
default 4096), smallpt against smallpt at BENCH_SMALLPT_REF_SPP spp (its tent filter and clamp
are part of its answer).  The references' own noise, mean((a - b)^2) / 4, is subtracted for the
chapters.  smallpt writes image.ppm (8-bit, gamma 2.2: read back by x^2.2) or, if it does,
image.pfm (linear).  Rays: the chapters' --stats counters; smallpt's if it prints `rays N` on
stderr (the instrumented copy does: one ray per path vertex), else not shown.
Targets: the best method's MSE at least 3x lower than smallpt's; no chapter-6 method worse than
smallpt; the path tracer's rays/s at least 1.5x smallpt's.  A benchmark: prints met or not.
"""
import json
import os
import re
import statistics
import struct
import subprocess
import sys
import tempfile
import time

from common import BUILD, ROOT

sys.path.insert(0, os.path.join(ROOT, "tests"))
from pfm import read_pfm  # noqa: E402

SMALLPT = os.environ.get("SMALLPT")
REPEATS = int(os.environ.get("BENCH_SMALLPT_REPEATS", "3"))
REF_SPP = int(os.environ.get("BENCH_SMALLPT_REF_SPP", "4096"))
SCENE = os.path.join(ROOT, "scenes", "smallpt.scene")
OUT = os.path.join(ROOT, "out", "bench", "smallpt")
W, H = 256, 192
METHODS = [("pt mis", "04_pathtrace", ["--estimator", "mis"]), ("pt cosine", "04_pathtrace", ["--estimator", "cosine"]),
           ("pm", "05_photonmap", []), ("light", "06_bidirectional", ["--method", "light"]),
           ("bdpt", "06_bidirectional", ["--method", "bdpt"]), ("vcm", "06_bidirectional", ["--method", "vcm"])]
RAY_COUNTERS = ["camera_rays", "bounce_rays", "shadow_rays", "eye_rays", "walk_rays"]


def clamped(values):
    return [min(max(v, 0.0), 1.0) for v in values]


def smallpt(spp, workdir):
    """(wall seconds, rays or None, clamped linear pixels in PFM order) of one smallpt run."""
    start = time.monotonic()
    result = subprocess.run([SMALLPT, str(spp), str(W), str(H)], cwd=workdir, capture_output=True, text=True,
                            env={**os.environ, "OMP_NUM_THREADS": "2"}, check=True)
    wall = time.monotonic() - start
    rays = re.search(r"rays (\d+)", result.stderr)
    pfm = os.path.join(workdir, "image.pfm")
    if os.path.exists(pfm):
        w, h, px = read_pfm(pfm)[:3]
        px = list(px)
    else:
        with open(os.path.join(workdir, "image.ppm")) as f:
            tokens = f.read().split()
        w, h = int(tokens[1]), int(tokens[2])
        rows = [[(int(v) / 255) ** 2.2 for v in tokens[4 + 3 * w * y:4 + 3 * w * (y + 1)]] for y in range(h)]
        px = [v for row in reversed(rows) for v in row]  # PFM order: bottom row first
    if (w, h) != (W, H):
        sys.exit(f"bench_smallpt: {SMALLPT} rendered {w}x{h}, not {W}x{H}: it needs `smallpt SPP W H`")
    return wall, int(rays.group(1)) if rays else None, clamped(px)


def chapter(name, args, out, stats):
    subprocess.run([os.path.join(BUILD, name), SCENE, "--threads", "2", "--quiet", "--out", out, "--stats", stats,
                    *args], check=True, stderr=subprocess.DEVNULL, cwd=ROOT)
    with open(stats) as f:
        s = json.load(f)
    rays = sum(s["counters"].get(k, 0) for k in RAY_COUNTERS) + s.get("light_rays", 0) + s.get("photon_rays", 0)
    return s, rays, clamped(read_pfm(out)[2])


def references():
    os.makedirs(OUT, exist_ok=True)
    halves = []
    for seed in (901, 902):
        path = os.path.join(OUT, f"ref-cosine-{REF_SPP}-{seed}.pfm")
        if not os.path.exists(path):
            chapter("04_pathtrace", ["--estimator", "cosine", "--spp", str(REF_SPP), "--seed", str(seed)], path,
                    os.path.join(OUT, "ref.json"))
        halves.append(clamped(read_pfm(path)[2]))
    ours = [(a + b) / 2 for a, b in zip(*halves)]
    noise = statistics.fmean((a - b) ** 2 / 4 for a, b in zip(*halves))
    path = os.path.join(OUT, f"ref-smallpt-{REF_SPP}.pfm")
    if not os.path.exists(path):
        with tempfile.TemporaryDirectory() as tmp:
            px = smallpt(REF_SPP, tmp)[2]
        with open(path, "wb") as f:  # written back as PFM (clamped linear)
            f.write(f"PF\n{W} {H}\n-1\n".encode())
            f.write(struct.pack(f"<{len(px)}f", *px))
    return ours, noise, list(read_pfm(path)[2])


def mse(a, b):
    return statistics.fmean((x - y) ** 2 for x, y in zip(a, b))


def spread(values):
    v = sorted(values)
    return f"{v[0]:.5f} / {statistics.median(v):.5f} / {v[-1]:.5f}"


def main():
    if not SMALLPT or not os.access(SMALLPT, os.X_OK):
        print("bench_smallpt: SMALLPT is not set to a smallpt executable: skipped (targets not measured). "
              "Build Kevin Beason's smallpt.cpp with g++ -O3 -fopenmp and set SMALLPT=/path/to/it.")
        return
    ours, noise, theirs = references()
    print(f"smallpt's scene {W}x{H}, 2 threads; references: 2 x {REF_SPP} spp chapter 4 cosine (noise {noise:.2e} "
          f"subtracted), smallpt {REF_SPP} spp; their difference (filter, clamp) {mse(ours, theirs):.5f}")
    results = {name: [] for name, _, _ in METHODS}
    sp, loads = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(REPEATS):
            loads.append(os.getloadavg()[0])
            wall, rays, px = smallpt(256, tmp)
            sp.append((wall, rays, mse(px, theirs)))
            for name, ch, args in METHODS:
                s, rays_ch, px = chapter(ch, [*args, "--time", f"{wall:.3f}", "--spp", "16777216", "--seed", str(r + 1)],
                                         os.path.join(tmp, "m.pfm"), os.path.join(tmp, "m.json"))
                results[name].append((s["render_s"], rays_ch / s["render_s"], mse(px, ours) - noise, rays_ch / s["render_s"] /
                                      (rays / wall) if rays else None))
    print(f"load (1-min average) at each repeat: {', '.join(f'{l:.1f}' for l in loads)}")
    print(f"smallpt 256 spp: wall {spread([w for w, _, _ in sp])} s, MSE {spread([m for _, _, m in sp])}" +
          (f", {spread([r / w * 1e-6 for w, r, _ in sp])} Mrays/s" if sp[0][1] else ", rays not reported"))
    print(f"{'method':10} {'MSE min / median / max':28} {'smallpt MSE / it (median)':26} {'Mrays/s (median)':17} rays/s vs smallpt")
    ratio = {}
    for name, rows in results.items():
        ratios = [sp[i][2] / rows[i][2] for i in range(len(rows))]
        ratio[name] = statistics.median(ratios)
        speed = [x[3] for x in rows if x[3]]
        print(f"{name:10} {spread([x[2] for x in rows]):28} {ratio[name]:<26.2f} {statistics.median(x[1] for x in rows) * 1e-6:<17.2f}"
              f" {spread(speed) if speed else 'n/a'}")
    best = max(ratio, key=ratio.get)
    print(f"target best method ({best}) MSE >= 3x lower than smallpt's at its time: {ratio[best]:.2f}x "
          f"({'met' if ratio[best] >= 3 else 'NOT met'})")
    for name in ("light", "bdpt", "vcm"):
        print(f"target {name} no worse than smallpt: smallpt / {name} = {ratio[name]:.2f} "
              f"({'met' if ratio[name] >= 1 else 'NOT met'})")
    speed = [x[3] for x in results["pt mis"] if x[3]]
    if speed:
        print(f"target path tracer rays/s >= 1.5x smallpt's: {statistics.median(speed):.2f}x "
              f"({'met' if statistics.median(speed) >= 1.5 else 'NOT met'})")


if __name__ == "__main__":
    main()
