"""The same rays through common/ and through Embree (bench/bench_embree.c).

Scenes: the Cornell box, smallpt's spheres (SMALLPT below, from another
branch: skipped until the file exists), procedural knobbly tori of 10^3 .. 10^6 triangles
and the scanned bunny and dragon (bench/meshes.py).  Writes into out/bench/:
embree.json (every run's numbers and the load average around it), embree.md
(the tables) and embree-throughput.png (1 thread, million rays per second
against triangle count, ours and Embree's).

Environment: BENCH_REPEATS (7), BENCH_SIZES (exponents, "3,4,5,6"),
BENCH_SCANS ("bunny,dragon-res4,dragon-res3,dragon-res2,dragon"; "none"),
BENCH_IMAGE (rays per set as an image, "512x512"), BENCH_EMBREE_FAST=1
(Embree without its robust flag), BENCH_BUILDS_ONLY=1 (time the builds
only: no rays, no ray table, no plot; into embree-builds.json and .md).

The builds: ours at 1 thread and at all threads, Embree's each on a device
of its own ("threads=1", or the default) made for it alone: two Embree
devices alive at once both build on all threads, whatever their "threads".
The table gives each build's CPU / wall time, the threads that worked.
"""
import json
import os
import shutil
import statistics
import subprocess

import meshes
from common import BUILD, ROOT, run

OUT = os.path.join(ROOT, "out", "bench")
SETS = ("camera", "bounce", "shadow", "miss")  # miss: rays leaving the scene's box (the fixed cost of a ray)
SMALLPT = "scenes/smallpt.scene"


def scenes():
    """(label, path, kind) of every scene to bench, generating meshes as needed."""
    chosen = [("cornell", "scenes/cornell.scene", "scene")]
    if os.path.exists(os.path.join(ROOT, SMALLPT)):
        chosen.append(("smallpt", SMALLPT, "scene"))
    else:
        print(f"smallpt: {SMALLPT} does not exist yet: skipped")
    for e in os.environ.get("BENCH_SIZES", "3,4,5,6").split(","):
        if e.strip():
            chosen.append((f"torus 10^{e.strip()}", meshes.procedural_scene(10 ** int(e)), "procedural"))
    scans = os.environ.get("BENCH_SCANS", "bunny,dragon-res4,dragon-res3,dragon-res2,dragon")
    for name in scans.split(","):
        if name.strip() and name.strip() != "none":
            try:
                chosen.append((name.strip(), meshes.scan_scene(name.strip()), "scan"))
            except (OSError, subprocess.CalledProcessError) as e:
                print(f"{name}: cannot fetch or convert the scan ({e}): skipped")
    return chosen


def three(values):
    return min(values), statistics.median(values), max(values)


def ratios(ours, theirs):
    return three([a / b for a, b in zip(ours, theirs)])


def busy(build, wall, cpu):
    """The median CPU / wall time of one kind of build (how many threads worked), or "?" in old results."""
    if cpu not in build:
        return "?"
    return f"{statistics.median(c / w for c, w in zip(build[cpu], build[wall])):.2f}"


def table(results):
    lines = ["| scene | triangles | rays | threads | ours Mrays/s | Embree Mrays/s | ours/Embree min / median / max "
             "| hit or blocked, ours / Embree | disagreements | load |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        for s in [] if r.get("builds_only") else r["sets"]:
            for t in s["timing"]:
                lo, mid, hi = ratios(t["ours_mrays"], t["embree_mrays"])
                n = max(s["rays"], 1)
                lines.append(f"| {r['label']} | {r['triangles']} | {s['name']} {s['rays']} | {t['threads']} | "
                             f"{statistics.median(t['ours_mrays']):.2f} | {statistics.median(t['embree_mrays']):.2f} | "
                             f"{lo:.2f} / **{mid:.2f}** / {hi:.2f} | {100 * s['found_ours'] / n:.2f} / "
                             f"{100 * s['found_embree'] / n:.2f} % | {s['disagreements']} "
                             f"({100 * s['disagreements'] / n:.3f} %, {s['disagreements_at_ends']} at ends) | "
                             f"{r['load'][0]:.1f}-{r['load'][1]:.1f} |")
    lines += ["", "| scene | primitives | build ours (ms, 1 thread / all) | Embree 1 thread | Embree all | ours/Embree 1 thread "
              "min / median / max | ours/Embree all | CPU/wall ours 1 / all, Embree 1 / all "
              "| bytes/primitive ours (heap) | Embree held (peak) |",
              "|---|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        b, m, n = r["build"], r["memory_bytes"], r["primitives"]
        one, every = ratios(b["ours_s"], b["embree_1_thread_s"]), ratios(b["ours_all_threads_s"], b["embree_all_threads_s"])
        lines.append(f"| {r['label']} | {n} | {1e3 * statistics.median(b['ours_s']):.3f} / "
                     f"{1e3 * statistics.median(b['ours_all_threads_s']):.3f} | "
                     f"{1e3 * statistics.median(b['embree_1_thread_s']):.3f} | "
                     f"{1e3 * statistics.median(b['embree_all_threads_s']):.3f} | "
                     f"{one[0]:.2f} / **{one[1]:.2f}** / {one[2]:.2f} | {every[0]:.2f} / {every[1]:.2f} / {every[2]:.2f} | "
                     f"{busy(b, 'ours_s', 'ours_cpu_s')} / {busy(b, 'ours_all_threads_s', 'ours_all_threads_cpu_s')}, "
                     f"{busy(b, 'embree_1_thread_s', 'embree_1_thread_cpu_s')} / "
                     f"{busy(b, 'embree_all_threads_s', 'embree_all_threads_cpu_s')} | "
                     f"{m['ours_arrays'] / n:.0f} ({m['ours_heap_growth'] / n:.0f}) | "
                     f"{m['embree_held'] / n:.0f} ({m['embree_peak'] / n:.0f}) |")
    return "\n".join(lines) + "\n"


def plot(results):
    """Million rays per second against triangles, 1 thread: one CSV per implementation and kind, one PNG."""
    gnuplot = shutil.which("gnuplot")
    files = []
    for kind in ("procedural", "scan"):
        rows = sorted((r for r in results if r["kind"] == kind), key=lambda r: r["triangles"])
        if not rows:
            continue
        path = os.path.join(OUT, f"embree-{kind}.csv")
        with open(path, "w") as f:
            f.write("# triangles " + " ".join(f"ours_{s} embree_{s}" for s in SETS) + "\n")
            for r in rows:
                cols = []
                for s in r["sets"]:
                    t = next(t for t in s["timing"] if t["threads"] == 1)
                    cols += [statistics.median(t["ours_mrays"]), statistics.median(t["embree_mrays"])]
                f.write(f"{r['triangles']} " + " ".join(f"{c:.4g}" for c in cols) + "\n")
        files.append(path)
    if not gnuplot or not files:
        print("gnuplot missing or no mesh scene: no plot")
        return
    png = os.path.join(OUT, "embree-throughput.png")
    procedural = next((f for f in files if "procedural" in f), "")
    scan = next((f for f in files if "scan" in f), "")
    subprocess.run([gnuplot, "-e", f"out='{png}'; procedural='{procedural}'; scan='{scan}'",
                    os.path.join(ROOT, "bench", "embree.gp")], check=True)
    print(f"plot: {os.path.relpath(png, ROOT)}")


def main():
    program = os.path.join(BUILD, "bench", "bench_embree")
    print("== the same rays through common/ and through Embree (bench/bench_embree.c) ==")
    if not os.path.exists(os.path.join(ROOT, program)):
        print("Embree is missing (Debian's libembree-dev; make deps-bench installs it): skipped")
        return
    repeats = os.environ.get("BENCH_REPEATS", "7")
    extra = ["--fast"] if os.environ.get("BENCH_EMBREE_FAST") == "1" else []
    builds_only = os.environ.get("BENCH_BUILDS_ONLY") == "1"
    extra += ["--builds-only"] if builds_only else []
    name = "embree-builds" if builds_only else "embree"  # builds only: the full results stay
    os.makedirs(os.path.join(OUT, name), exist_ok=True)
    results = []
    for label, path, kind in scenes():
        out = os.path.join(OUT, name, label.replace(" ", "-").replace("^", "") + ".json")
        before = os.getloadavg()[0]
        print(f"-- {label} (load {before:.1f}) --")
        print(run(program, path, "--repeats", repeats, "--size", os.environ.get("BENCH_IMAGE", "512x512"),
                  "--json", out, *extra).rstrip())
        with open(out) as f:
            result = json.load(f)
        result.update(label=label, kind=kind, load=[before, os.getloadavg()[0]])
        results.append(result)
    with open(os.path.join(OUT, name + ".json"), "w") as f:
        json.dump(results, f, indent=1)
    text = table(results)
    with open(os.path.join(OUT, name + ".md"), "w") as f:
        f.write(text)
    print(text)
    if not builds_only:
        plot(results)


if __name__ == "__main__":
    main()
