"""Chapter 5 (photon mapping): throughput, and the caustic against chapter 4 at equal time.

  1. photons per second and density estimates (lookups) per second on cornell-spheres,
     256x256, 2 threads (from the stats counters);
  2. the caustic region of cornell-spheres.scene (tradeoff/caustic_region.py: the pixels
     that see the floor within 80 mm of the glass ball's focus; about 600 at 256x256):
     its RMSE after T seconds of `05_photonmap` (defaults: --maps both, progressive) and
     of `04_pathtrace --estimator mis`, for T = 5 and 20 s.  Target: the photon map's
     RMSE at most 1/5 of the path tracer's at equal time.

The reference is chapter 4 (MIS, unbiased), rendered as two independent halves of
BENCH5_REF_SPP samples each (default 2048: about 3 minutes on 2 cores; kept in
out/bench/ and reused while the executable is unchanged).  Its own error in the
region, MSE(a - b) / 4, is subtracted from each measured MSE (the reference is
independent of the image tested, so their squared errors add).  A benchmark, not a
test: it prints what it measures, met or not.
"""
import array
import json
import math
import os
import subprocess
import sys

from common import BUILD, ROOT, chapter_stats

sys.path.insert(0, os.path.join(ROOT, "tradeoff"))
sys.path.insert(0, os.path.join(ROOT, "tests"))
from caustic_region import caustic_region  # noqa: E402
import pfm  # noqa: E402  (tests/pfm.py: the one PFM reader of the Python tools)

SCENE = "scenes/cornell-spheres.scene"
SIZE = 256
REF_SPP = int(os.environ.get("BENCH5_REF_SPP", "2048") or 2048)
TIMES = [float(t) for t in os.environ.get("BENCH5_TIMES", "5 20").split()]


def read_pfm(path):
    return pfm.read_pfm(path)  # tests/pfm.py


def region_indices(width, height):
    """Float offsets of the region's pixels in a PFM (bottom row first)."""
    return [3 * ((height - 1 - y) * width + x) for x, y in caustic_region(width, height)]


def region_mse(a, b, index):
    return sum((a[i + c] - b[i + c]) ** 2 for i in index for c in range(3)) / (3 * len(index))


def render(chapter, out, *args):
    cmd = [os.path.join(BUILD, chapter), SCENE, "--quiet", "--size", f"{SIZE}x{SIZE}", "--out", out,
           "--stats", out + ".json", *map(str, args)]
    r = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    if r.returncode:
        sys.exit(f"bench: {' '.join(cmd)} failed: {r.stderr}")
    with open(out + ".json") as f:
        return json.load(f)


def reference(directory):
    """(pixels of the mean of two halves, its estimated MSE in the region), cached."""
    key = {"spp": REF_SPP, "mtime": os.path.getmtime(os.path.join(ROOT, BUILD, "04_pathtrace")), "size": SIZE}
    paths = [os.path.join(directory, f"caustic-ref-{h}.pfm") for h in "ab"]
    key_path = os.path.join(directory, "caustic-ref.json")
    cached = os.path.exists(key_path) and all(map(os.path.exists, paths))
    if not cached or json.load(open(key_path)) != key:
        for seed, path in zip((5001, 5002), paths):
            render("04_pathtrace", path, "--spp", REF_SPP, "--seed", seed, "--probe-samples", 32)
        with open(key_path, "w") as f:
            json.dump(key, f)
    (w, h, a), (_, _, b) = read_pfm(paths[0]), read_pfm(paths[1])
    index = region_indices(w, h)
    mean = array.array("f", [(x + y) * 0.5 for x, y in zip(a, b)])
    return mean, region_mse(a, b, index) / 4.0, index


def throughput():
    s = chapter_stats("05_photonmap", SCENE, "--size", f"{SIZE}x{SIZE}", "--spp", 8, "--threads", 2,
                      "--probe-photons", 32)
    c, t = s["counters"], s["render_s"]
    photons = 8 * s["photons_per_pass"]
    print(f"cornell-spheres {SIZE}x{SIZE}, 8 passes of {s['photons_per_pass']} photons, 2 threads: "
          f"{t:.2f} s, {photons / t * 1e-6:.2f} M photons/s (incl. the eye pass), "
          f"{c['photon_lookups'] / t * 1e-6:.2f} M lookups/s, "
          f"{s['photons_stored']['global'] / 8:.0f} global and {s['photons_stored']['caustic'] / 8:.0f} caustic "
          f"photons stored per pass")


def caustic_at_equal_time():
    directory = os.path.join(ROOT, "out", "bench")
    os.makedirs(directory, exist_ok=True)
    ref, ref_mse, index = reference(directory)
    print(f"caustic region: {len(index)} pixels; reference 2 x {REF_SPP} spp MIS, its own RMSE there "
          f"{math.sqrt(ref_mse):.4f}")
    for t in TIMES:
        rmse = {}
        for label, chapter, args in (("pathtrace mis", "04_pathtrace", ["--estimator", "mis", "--probe-samples", 32]),
                                     ("photonmap", "05_photonmap", ["--probe-photons", 32])):
            out = os.path.join(directory, f"caustic-{chapter}-{t:g}.pfm")
            s = render(chapter, out, "--time", t, "--seed", 7, *args)
            raw = region_mse(read_pfm(out)[2], ref, index)
            # The reference's own noise is subtracted; an error not clearly above
            # it (less than a quarter of its MSE more) cannot be told from zero.
            rmse[label] = math.sqrt(raw - ref_mse) if raw > 1.25 * ref_mse else None
            shown = f"{rmse[label]:.4f}" if rmse[label] is not None else \
                f"not measurable (below the reference's own error {math.sqrt(ref_mse):.4f})"
            print(f"  T = {t:4g} s  {label:14s} {s['spp']:5d} spp/passes  caustic RMSE {shown}")
        if rmse["photonmap"] is None or rmse["pathtrace mis"] is None:
            print(f"  T = {t:4g} s  photon map / path tracer: not measured (a better reference is needed)")
            continue
        ratio = rmse["photonmap"] / rmse["pathtrace mis"]
        print(f"  T = {t:4g} s  photon map / path tracer = {ratio:.3f}   "
              f"[target <= 0.2: {'met' if ratio <= 0.2 else 'NOT met'}]")


if __name__ == "__main__":
    print("== chapter 5 (05_photonmap) ==")
    throughput()
    caustic_at_equal_time()
