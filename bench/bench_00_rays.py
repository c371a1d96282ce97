"""Incoherent ray casting on the Cornell box (bench/bench_rays.c)."""
import os

from common import BUILD, run

print("== incoherent ray casting (bench/bench_rays.c) ==")
print(run(os.path.join(BUILD, "bench", "bench_rays"), "scenes/cornell.scene").rstrip())
print("-- the same rays, sorted so that neighbours take the same path (what incoherence costs) --")
print(run(os.path.join(BUILD, "bench", "bench_rays"), "scenes/cornell.scene", "--sorted").rstrip())
