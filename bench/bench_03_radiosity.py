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


def run(*args):
    """Run the chapter in a child process under /usr/bin/time; return its stats and peak RSS in MiB."""
    with tempfile.TemporaryDirectory() as tmp:
        stats, rss = os.path.join(tmp, "s.json"), os.path.join(tmp, "rss")
        command = [os.path.join(BUILD, "03_radiosity"), "scenes/cornell.scene", "--quiet", "--size", "64x64",
                   "--out", os.path.join(tmp, "x.pfm"), "--stats", stats, *map(str, args)]
        timed = os.path.exists("/usr/bin/time")
        if timed:
            command = ["/usr/bin/time", "-f", "%M", "-o", rss] + command
        result = subprocess.run(command, cwd=ROOT, capture_output=True, text=True)
        if result.returncode:
            sys.exit(f"bench: 03_radiosity {' '.join(map(str, args))} failed: {result.stderr}")
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
