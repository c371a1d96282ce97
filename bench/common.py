"""Helpers for the benchmark scripts bench/bench_*.py."""
import json
import os
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BUILD = os.environ.get("BENCH_BUILD", "build")


def run(*args):
    result = subprocess.run(list(map(str, args)), cwd=ROOT, capture_output=True, text=True)
    if result.returncode:
        sys.exit(f"bench: {' '.join(map(str, args))} failed: {result.stderr}")
    return result.stdout


def chapter_stats(chapter, scene, *args):
    """Run build/<chapter> on scene and return its --stats object."""
    with tempfile.TemporaryDirectory() as tmp:
        stats = os.path.join(tmp, "s.json")
        run(os.path.join(BUILD, chapter), scene, "--quiet", "--out", os.path.join(tmp, "x.pfm"),
            "--stats", stats, *args)
        with open(stats) as f:
            return json.load(f)


def best_of(n, chapter, scene, *args):
    """Fastest of n runs: the one least disturbed by whatever else the machine does."""
    return min((chapter_stats(chapter, scene, *args) for _ in range(n)), key=lambda s: s["render_s"])
