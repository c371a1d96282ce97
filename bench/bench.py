#!/usr/bin/python3
"""`make bench`: runs every bench/bench_*.py in order.  A benchmark, not a
test: it prints numbers and never fails because the machine is slow.

usage: bench/bench.py BUILD_DIR
"""
import glob
import os
import runpy
import sys

here = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, here)
os.environ["BENCH_BUILD"] = sys.argv[1] if len(sys.argv) > 1 else "build"
for script in sorted(glob.glob(os.path.join(here, "bench_*.py"))):
    runpy.run_path(script, run_name="__main__")
    print()
