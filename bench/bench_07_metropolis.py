"""Metropolis light transport (chapter 7) against BDPT (chapter 6) at equal time on Veach's door ajar.

scenes/door-ajar.scene: the lamp is in the far room, its light reaches the camera's room only
through the crack of a door open 4 degrees. Each method renders BENCH7_SIZE x BENCH7_SIZE (default
128, the scene's own image; at 64 x 64 MLT gains less: its error is mostly correlated over whole
regions, which smaller pixels do not make worse, while BDPT's noise per pixel grows) for --time
BENCH7_SECONDS (default 10; the budget counts MLT's bootstrap) on one thread, BENCH7_SEEDS times
(default 8; four were too few: one seed can move the ratio by a tenth) with seeds BENCH7_FIRST_SEED
(default 100), +1, ...: MLT's error is correlated (one b per image, chains that linger), so its
per-pixel error is measured over independent runs, never within one.
Methods: MMLT (chapter 7's default), PSSMLT, and BDPT (chapter 6 --method bdpt); BENCH7_METHODS
picks (mmlt,pssmlt,bdpt). BENCH7_SCENE renders another scene; BENCH7_DOOR_DEGREES=D the door ajar
opened D degrees instead of 4 (a copy of the scene in out/bench/07/: how the ratio depends on the
crack). The reference is the mean of two independent BDPT renders a and b of
BENCH7_REFERENCE_SECONDS each (default 300, two threads; kept in out/bench/07/ by scene and size,
and reused); its own noise, mean((a - b)^2) / 4 per pixel, is subtracted from each method's MSE.
Seeds are interleaved across methods (load changes hit all alike).  Prints, per method, the RMSE over
seeds and pixels (and its spread: min/median/max and the RMSE of each seed), the
image mean against the reference's, mutations or passes per pixel; then the target: MMLT's RMSE at
most half of BDPT's.  A benchmark, not a test: it prints what it measures, met or not.

    /usr/bin/python3 bench/bench_07_metropolis.py        (BENCH7_SECONDS=30 BENCH7_SEEDS=16 ... to vary;
                                                          BENCH7_MLT_ARGS="--chains 16" adds chapter 7's options)
"""
import json
import math
import os
import re
import subprocess
import sys

from common import BUILD, ROOT

sys.path.insert(0, os.path.join(ROOT, "tests"))
from pfm import read_pfm  # noqa: E402

SIZE = int(os.environ.get("BENCH7_SIZE", "128"))
SECONDS = float(os.environ.get("BENCH7_SECONDS", "10"))
SEEDS = int(os.environ.get("BENCH7_SEEDS", "8"))
FIRST_SEED = int(os.environ.get("BENCH7_FIRST_SEED", "100"))  # seeds FIRST_SEED, FIRST_SEED + 1, ...
REFERENCE_SECONDS = float(os.environ.get("BENCH7_REFERENCE_SECONDS", "300"))
METHODS = os.environ.get("BENCH7_METHODS", "mmlt,pssmlt,bdpt").split(",")
SCENE = os.environ.get("BENCH7_SCENE", "scenes/door-ajar.scene")
DOOR_DEGREES = os.environ.get("BENCH7_DOOR_DEGREES")
OUT = os.path.join(ROOT, "out", "bench", "07")
MLT_ARGS = os.environ.get("BENCH7_MLT_ARGS", "").split()  # more options for chapter 7's runs, to try other settings
RUNS = {"mmlt": ("07_metropolis", ["--method", "mmlt", *MLT_ARGS]),
        "pssmlt": ("07_metropolis", ["--method", "pssmlt", *MLT_ARGS]), "bdpt": ("06_bidirectional", ["--method", "bdpt"])}


def door_opened(degrees):
    """A copy of door-ajar.scene (in OUT) with its door, 1 m wide and hinged at x = 1.5, z = 4, turned `degrees`."""
    with open(os.path.join(ROOT, "scenes", "door-ajar.scene")) as f:
        text = f.read()
    angle = math.radians(float(degrees))
    x, z = 1.5 + math.cos(angle), 4.0 + math.sin(angle)
    door, count = re.subn(r"^quad door .*$", f"quad door white  1.5 0 4.0  {x:.4f} 0 {z:.4f}  {x:.4f} 2.05 {z:.4f}  "
                          "1.5 2.05 4.0", text, flags=re.M)
    if count != 1:
        sys.exit("bench: scenes/door-ajar.scene has no line 'quad door ...' to turn")
    os.makedirs(OUT, exist_ok=True)
    path = os.path.join(OUT, f"door-ajar-{degrees}deg.scene")
    with open(path, "w") as f:
        f.write(door)
    return path


if DOOR_DEGREES:
    SCENE = door_opened(DOOR_DEGREES)
STEM = os.path.splitext(os.path.basename(SCENE))[0]


def render(chapter, args, name):
    """Render the scene into out/bench/07/NAME.pfm; return (pixels as a flat list, stats)."""
    os.makedirs(OUT, exist_ok=True)
    pfm, stats = os.path.join(OUT, name + ".pfm"), os.path.join(OUT, name + ".json")
    command = [os.path.join(BUILD, chapter), SCENE, "--size", f"{SIZE}x{SIZE}", "--quiet", "--out", pfm,
               "--stats", stats, *map(str, args)]
    print("  " + " ".join(command[:1] + [os.path.relpath(c, ROOT) if c.startswith(ROOT) else c
                                        for c in command[1:]]), flush=True)
    result = subprocess.run(command, cwd=ROOT, capture_output=True, text=True)
    if result.returncode:
        sys.exit(f"bench: {' '.join(command)} failed: {result.stderr}")
    with open(stats) as f:
        return list(read_pfm(pfm)[2]), json.load(f)


def reference():
    """Two independent long BDPT renders (reused when present): their mean and its noise per pixel."""
    halves = []
    for seed in (9001, 9002):
        name = f"reference-{STEM}-{SIZE}-{seed}"
        pfm = os.path.join(OUT, name + ".pfm")
        if os.path.exists(pfm):
            halves.append(list(read_pfm(pfm)[2]))
        else:
            halves.append(render("06_bidirectional", ["--method", "bdpt", "--time", REFERENCE_SECONDS, "--threads", 2,
                                                      "--seed", seed], name)[0])
    a, b = halves
    mean = [(x + y) / 2 for x, y in zip(a, b)]
    noise = sum((x - y) ** 2 for x, y in zip(a, b)) / len(a) / 4  # the MSE of the mean of the two
    return mean, noise


def main():
    print(f"bench_07_metropolis: {SCENE} at {SIZE}x{SIZE}, {SECONDS:g} s a run on one thread, {SEEDS} seeds; "
          f"load average {os.getloadavg()[0]:.2f} (2 threads of a shared machine make wall-clock noisy)")
    ref, ref_noise = reference()
    ref_mean = sum(ref) / len(ref)
    print(f"reference (BDPT, 2 x {REFERENCE_SECONDS:g} s): mean {ref_mean:.5g}, its own MSE {ref_noise:.3g} "
          "(subtracted below)")
    rmse = {}
    results = {method: ([], [], []) for method in METHODS}
    for i in range(SEEDS):  # interleaved: seed i of every method, then seed i + 1, so load changes hit all alike
        for method in METHODS:
            chapter, args = RUNS[method]
            img, stats = render(chapter, [*args, "--time", SECONDS, "--threads", 1, "--seed", FIRST_SEED + i],
                                f"{method}-{STEM}-{SIZE}-{i}")
            per_seed, means, counts = results[method]
            per_seed.append(sum((x - r) ** 2 for x, r in zip(img, ref)) / len(ref))
            means.append(sum(img) / len(img))
            counts.append(stats["spp"])
    for method in METHODS:
        chapter = RUNS[method][0]
        per_seed, means, counts = results[method]
        mse = max(0.0, sum(per_seed) / SEEDS - ref_noise)
        rmse[method] = math.sqrt(mse)
        per_rmse = sorted(math.sqrt(max(0.0, m - ref_noise)) for m in per_seed)
        seeds = (f"min {per_rmse[0]:.4g}, median {per_rmse[len(per_rmse) // 2]:.4g}, max {per_rmse[-1]:.4g}; "
                 + ", ".join(f"{math.sqrt(max(0.0, m - ref_noise)):.4g}" for m in per_seed))
        print(f"{method:7s} RMSE {rmse[method]:.4g} (relative {rmse[method] / ref_mean:.3f}; per seed {seeds}); "
              f"image mean {sum(means) / SEEDS:.5g} vs {ref_mean:.5g}; {min(counts)}-{max(counts)} "
              f"{'mutations' if chapter == '07_metropolis' else 'passes'} per pixel")
    print(f"load average at the end {os.getloadavg()[0]:.2f}")
    if "mmlt" in rmse and "bdpt" in rmse and rmse["bdpt"] > 0:
        ratio = rmse["mmlt"] / rmse["bdpt"]
        print(f"target door-ajar MMLT/BDPT RMSE = {ratio:.2f} at {SECONDS:g} s (<= 0.5: "
              f"{'met' if ratio <= 0.5 else 'not met'})")


if __name__ == "__main__":
    main()
