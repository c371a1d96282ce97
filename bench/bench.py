#!/usr/bin/python3
"""`make bench`: throughput and timings.  A benchmark, not a test: it
prints numbers and never fails because the machine is slow.

usage: bench/bench.py BUILD_DIR
"""
import json
import os
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
build = sys.argv[1] if len(sys.argv) > 1 else "build"


def run(*args):
    result = subprocess.run(list(map(str, args)), cwd=ROOT, capture_output=True, text=True)
    if result.returncode:
        sys.exit(f"bench: {' '.join(map(str, args))} failed: {result.stderr}")
    return result.stdout


def chapter_stats(chapter, scene, *args):
    with tempfile.TemporaryDirectory() as tmp:
        stats = os.path.join(tmp, "s.json")
        run(os.path.join(build, chapter), scene, "--quiet", "--out", os.path.join(tmp, "x.pfm"),
            "--stats", stats, *args)
        with open(stats) as f:
            return json.load(f)


def best_of(n, chapter, scene, *args):
    """Fastest of n runs: the least disturbed by whatever else the machine does."""
    return min((chapter_stats(chapter, scene, *args) for _ in range(n)), key=lambda s: s["render_s"])


print("== incoherent ray casting (bench/bench_rays.c) ==")
print(run(os.path.join(build, "bench", "bench_rays"), "scenes/cornell.scene").rstrip())

print("\n== chapter 1 (01_local), 512x512 ==")
for scene, extra in (("scenes/cornell-point.scene", []), ("scenes/cornell.scene", ["--light-samples", "16"])):
    for threads in (1, 2):
        s = best_of(3, "01_local", scene, "--size", "512x512", "--threads", threads, *extra)
        rays = s["counters"]["camera_rays"] + s["counters"]["shadow_rays"]
        print(f"{scene:28s} threads {threads}: render {s['render_s'] * 1000:7.1f} ms, "
              f"camera {s['counters']['camera_rays'] / s['render_s'] * 1e-6:6.2f} Mrays/s, "
              f"shadow {s['counters']['shadow_rays'] / s['render_s'] * 1e-6:6.2f} Mrays/s, "
              f"all {rays / s['render_s'] * 1e-6:6.2f} Mrays/s  {' '.join(map(str, extra))}")
