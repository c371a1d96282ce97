#!/usr/bin/python3
"""Hierarchical against uniform radiosity on the Cornell box, after tradeoff.py.

    make tradeoff            # runs this after the main sweep (its reference image is reused)
    make tradeoff QUICK=1

Error against time: uniform Jacobi (03_radiosity) over patch sizes and 03c_hierarchical over --eps,
RMSE against the main sweep's path-traced reference (OUT/tradeoff/cornell/reference.pfm),
time = prepare_s + render_s from the chapter's --stats (median of REPEATS for runs < 2 s).
And the hierarchy's link count against its element count: Hanrahan et al.'s claim is O(n)
links for a fixed --eps: measured at --eps 0.02 with --levels 4..8 (the elements grow, the
oracle stays), and along the accuracy sweep, where --eps falls as the elements grow.  Outputs (OUT/): tradeoff-hierarchical.csv,
tradeoff-hierarchical-error.png/.svg, tradeoff-hierarchical-links.png/.svg and a summary
printed on stdout.
"""
import csv
import json
import math
import os
import statistics
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
HERE = os.path.dirname(os.path.abspath(__file__))


def main():
    quick = os.environ.get("QUICK", "") not in ("", "0")
    build = os.environ.get("BUILD", "build") or "build"
    out = os.environ.get("OUT", "") or ("out/quick" if quick else "out")
    size = int(os.environ.get("SIZE", "") or (32 if quick else 128))
    aa_spp = int(os.environ.get("AA_SPP", "") or (16 if quick else 64))
    repeats = int(os.environ.get("REPEATS", "") or (1 if quick else 3))
    work = os.path.join(ROOT, out, "tradeoff", "cornell")
    ref = os.path.join(work, "reference.pfm")
    if not os.path.exists(ref):
        sys.exit(f"hierarchical.py: {ref} is missing; run tradeoff/tradeoff.py first")
    points = [("uniform", "--patch-size", S) for S in ([200, 100] if quick else [200, 100, 71, 50, 35, 25])]
    points += [("hierarchical", "--eps", e) for e in ([0.1, 0.04] if quick else [0.1, 0.04, 0.02, 0.01, 0.005])]
    # Links against elements at a fixed --eps: the elements grow with --levels (Hanrahan et al.'s O(n)).
    points += [("fixed-eps", "--levels", n) for n in ([4, 5, 6] if quick else [4, 5, 6, 7, 8])]
    rows = []
    for method, option, value in points:
        name = f"hier-{method}-{value}"
        program = "03_radiosity" if method == "uniform" else "03c_hierarchical"
        args = [os.path.join(ROOT, build, program), "scenes/cornell.scene", "--quiet", "--size",
                f"{size}x{size}", "--spp", str(aa_spp), "--ref", ref, "--out", os.path.join(work, name + ".pfm"),
                "--stats", os.path.join(work, name + ".json"), option, str(value)]
        if method != "uniform":  # the benchmark's settings (bench/bench_03_radiosity.py)
            args += ["--quadrature", "1", "--eps-spread", "7e-4"]
        if method == "fixed-eps":
            args += ["--eps", "0.02"]
        times = []
        for k in range(repeats):
            subprocess.run(args, cwd=ROOT, check=True, stdout=subprocess.DEVNULL)
            with open(os.path.join(work, name + ".json")) as f:
                s = json.load(f)
            times.append(s["prepare_s"] + s["render_s"])
            if times[0] >= 2.0:
                break
        row = {"method": method, "setting": f"{option[2:]}={value}", "patches": s["patches"],
               "elements": s.get("elements", ""), "links": s.get("links", ""), "time_s": statistics.median(times),
               "rmse": s["metrics"]["rmse"]}
        rows.append(row)
        print(f"[hierarchical] {method:12s} {row['setting']:16s} patches {row['patches']:>7} "
              f"links {row['links']!s:>9} time {row['time_s']:8.3f} s rmse {row['rmse']:.4g}", flush=True)
    csv_path = os.path.join(ROOT, out, "tradeoff-hierarchical.csv")
    with open(csv_path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    data = {}
    for method in ("uniform", "hierarchical", "fixed-eps"):
        path = os.path.join(work, f"hier-{method}.dat")
        with open(path, "w") as f:
            for r in rows:
                if r["method"] == method:
                    f.write(f"{r['time_s']} {r['rmse']} {r['elements'] or r['patches']} {r['links'] or 0}\n")
        data[method] = path
    def slope_of(method):
        pts = [r for r in rows if r["method"] == method]
        xs, ys = [math.log(r["elements"]) for r in pts], [math.log(r["links"]) for r in pts]
        mx, my = sum(xs) / len(xs), sum(ys) / len(ys)
        return sum((x - mx) * (y - my) for x, y in zip(xs, ys)) / sum((x - mx) ** 2 for x in xs)

    slope, sweep_slope = slope_of("fixed-eps"), slope_of("hierarchical")
    for term in ("png", "svg"):
        for kind in ("error", "links"):
            target = os.path.join(ROOT, out, f"tradeoff-hierarchical-{kind}.{term}")
            r = subprocess.run(["gnuplot", "-e", f"term='{term}'; out='{target}'; kind='{kind}'; "
                                f"uniform='{data['uniform']}'; hierarchical='{data['hierarchical']}'; "
                                f"fixed='{data['fixed-eps']}'; slope={slope}; sweep_slope={sweep_slope}", os.path.join(HERE, "hierarchical.gp")], capture_output=True, text=True)
            if r.returncode:
                sys.exit(f"gnuplot hierarchical.gp: {r.stderr.strip()}")
    print(f"[hierarchical] links against elements: slope {slope:.2f} on log-log at --eps 0.02 over --levels "
          f"(1 = O(n)), {sweep_slope:.2f} along the --eps sweep; wrote {csv_path} "
          f"and tradeoff-hierarchical-error/links.png/.svg", flush=True)


if __name__ == "__main__":
    main()
