"""Chapter 3 (radiosity) on the Cornell box at about 1,000 and 10,000 patches:
form-factor time, solve time and peak memory, for the matrix solvers and for
shooting (which stores no matrix).  Target: 10,000 patches to residual 1e-3
in under 30 s on 2 cores.  Shooting recomputes every form factor it needs
per shot (memory O(n), time several n^2 form factors), so it is measured at
1,000 patches only.  A benchmark, not a test."""
import json
import os
import resource
import subprocess
import sys
import tempfile

from common import BUILD, ROOT


REFERENCE = "docs/reference/cornell-256x256.pfm"  # the image metric's truth (docs/reference/README.md)


def run(*args, size="64x64", program="03_radiosity"):
    """Run a chapter (3, or 03c_hierarchical) in a child process under /usr/bin/time; return its stats and
    peak RSS in MiB."""
    with tempfile.TemporaryDirectory() as tmp:
        stats, rss = os.path.join(tmp, "s.json"), os.path.join(tmp, "rss")
        command = [os.path.join(BUILD, program), "scenes/cornell.scene", "--quiet", "--size", size,
                   "--out", os.path.join(tmp, "x.pfm"), "--stats", stats, *map(str, args)]
        if size == "256x256":
            command += ["--ref", REFERENCE]
        timed = os.path.exists("/usr/bin/time")
        if timed:
            command = ["/usr/bin/time", "-f", "%M", "-o", rss] + command
        result = subprocess.run(command, cwd=ROOT, capture_output=True, text=True)
        if result.returncode:
            sys.exit(f"bench: {program} {' '.join(map(str, args))} failed: {result.stderr}")
        with open(stats) as f:
            s = json.load(f)
        if timed:
            with open(rss) as f:
                peak_kib = float(f.read().split()[-1])
        else:  # the largest child of this process so far: an upper bound
            peak_kib = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    return s, peak_kib / 1024.0


print("== chapter 3 (03_radiosity), Cornell box, residual 1e-3 ==")
print(f"{'patch size':>10} {'solver':>12} {'patches':>8} {'form factors':>13} {'solve':>8} {'iterations':>10} "
      f"{'residual':>9} {'peak RSS':>10}")
for size, solvers in ((50, ("jacobi", "gauss-seidel", "shooting")), (16, ("jacobi", "gauss-seidel"))):
    for solver in solvers:
        s, peak = run("--patch-size", size, "--solver", solver, "--tol", "1e-3")
        total = s["formfactor_s"] + s["solve_s"]
        print(f"{size:>10} {solver:>12} {s['patches']:>8} {s['formfactor_s']:>11.2f} s {s['solve_s']:>6.2f} s "
              f"{s['iterations']:>10} {s['residual']:>9.2g} {peak:>7.0f} MiB"
              f"{'   total %.1f s (target < 30 s)' % total if s['patches'] > 5000 else ''}")

# ---- hierarchical radiosity ----------------------------------------------------------------------
# Targets: the Cornell box with 1e5 leaf elements in under 60 s and 1 GiB on 2 cores; the error of
# the uniform 9,063-patch solve (16 mm) reached in at most 1/3 of its time on both metrics: each
# surface's mean radiance against path tracing (--surface-samples), RMS of the relative error over
# surfaces and channels (the light left out: its emission dominates); and the image's relative MSE
# against docs/reference/cornell-256x256.pfm (every run at 256 x 256 with --ref).  Times are medians of
# REPEATS runs (default 3); the machine's load average is printed with them.
import math
import statistics

REPEATS = int(os.environ.get("REPEATS", "3"))


def surface_error(stats, truth):
    errors = [s["radiance"][c] / truth[s["name"]]["radiance"][c] - 1 for s in stats["surfaces"] if s["name"] != "light"
              for c in range(3)]
    return math.sqrt(sum(e * e for e in errors) / len(errors))


def median_run(*args, program="03_radiosity"):
    """At the reference's size, so that each run gives both metrics (the image's relative MSE and
    the surfaces' error); the time is the solve's (form factors and iterations), not the image's."""
    runs = [run(*args, size="256x256", program=program) for _ in range(REPEATS)]
    times = [s["formfactor_s"] + s["solve_s"] for s, _ in runs]
    return runs[0][0], statistics.median(times), max(peak for _, peak in runs), times


def load():
    return "load average %.1f %.1f %.1f" % os.getloadavg()


with tempfile.TemporaryDirectory() as tmp:
    stats_path = os.path.join(tmp, "pt.json")
    result = subprocess.run([os.path.join(BUILD, "04_pathtrace"), "scenes/cornell.scene", "--quiet", "--size", "8x8",
                             "--spp", "1", "--probe-samples", "32", "--surface-samples", str(1 << 19),
                             "--out", os.path.join(tmp, "pt.pfm"), "--stats", stats_path], cwd=ROOT)
    if result.returncode:
        sys.exit("bench: 04_pathtrace failed")
    with open(stats_path) as f:
        truth = {s["name"]: s for s in json.load(f)["surfaces"]}

print(f"\n== hierarchical against uniform, Cornell box, residual 1e-3, median of {REPEATS} ({load()}) ==")
print(f"{'method':>28} {'patches':>8} {'elements':>9} {'links':>10} {'time':>8} {'peak RSS':>9} {'surfaces':>9} "
      f"{'image':>9}")
uniform, uniform_time, peak, _ = median_run("--patch-size", 16, "--tol", "1e-3")
uniform_error = {"surfaces": surface_error(uniform, truth), "image": uniform["metrics"]["relmse"]}
print(f"{'uniform 16 mm (jacobi)':>28} {uniform['patches']:>8} {'':>9} {'':>10} {uniform_time:>6.2f} s "
      f"{peak:>5.0f} MiB {100 * uniform_error['surfaces']:>8.2f}% {uniform_error['image']:>9.2e}")
reached = {}
# The sweep's settings: --eps-spread 7e-4 (the second pass) and --quadrature 1 (two points per near
# link) are the fastest way found to the uniform solve's error (README, "Benchmarks").
# eps in steps of sqrt(2): the time to reach an error is the first run that reaches it, so a coarser
# grid would overstate it (by up to the step's ratio of times).
for eps in (1.6e-1, 1.1e-1, 8e-2, 5.6e-2, 4e-2, 2.8e-2, 2e-2, 1.4e-2, 1e-2, 5e-3):
    s, t, peak, times = median_run("--eps", eps, "--eps-spread", 7e-4, "--quadrature", 1, "--tol", "1e-3",
                                   program="03c_hierarchical")
    error = {"surfaces": surface_error(s, truth), "image": s["metrics"]["relmse"]}
    note = ""
    if s["patches"] >= 100000:
        note = f"   1e5 leaves: {t:.1f} s (target < 60 s), {peak:.0f} MiB (target < 1024)"
    for metric in error:
        if metric not in reached and error[metric] <= uniform_error[metric]:
            reached[metric] = (eps, t)
    print(f"{'hierarchical eps %g' % eps:>28} {s['patches']:>8} {s['elements']:>9} {s['links']:>10} {t:>6.2f} s "
          f"{peak:>5.0f} MiB {100 * error['surfaces']:>8.2f}% {error['image']:>9.2e}{note}")
# Both metrics, one ratio each: the hierarchical solve's time to the uniform 16 mm solve's error
# over the uniform solve's time (target <= 1/3 on both).
for metric, what in (("surfaces", "per-surface means (RMS relative error)"), ("image", "image (relative MSE)")):
    if metric in reached:
        eps, t = reached[metric]
        print(f"{what}: uniform 16 mm error {uniform_error[metric]:.3g} reached at eps {eps:g} in {t:.1f} s = "
              f"{t / uniform_time:.2f} of the uniform time (target <= 1/3)")
    else:
        print(f"{what}: uniform 16 mm error {uniform_error[metric]:.3g} not reached by the hierarchical solves "
              f"above (target: in <= 1/3 of {uniform_time:.1f} s): not met")
print(load())
