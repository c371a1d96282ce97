#!/usr/bin/python3
"""Does VCM render the SDS caustic of scenes/sds.scene ever better?  Error in the caustic seen in the mirror
against CPU time, for VCM, progressive photon mapping (VCM --connect off), BDPT and path tracing.

    python3 tradeoff/sds_convergence.py        BUILD=build OUT=out/sds SIZE=128 SDS_REF_PASSES=1024
                                               (about 12 CPU minutes; run by make tradeoff)
    QUICK=1 python3 tradeoff/sds_convergence.py  (64x64, fewer passes: the pipeline in about 3 CPU minutes)

The region (caustic_region.sds_mirror_regions, geometry, not a threshold on a noisy image): "caustic", the
pixels wholly on the mirror ball whose reflected rays reach the floor past the glass ball within 150 mm of the
glass ball's focus (33 pixels at 128 x 128: the caustic L S S D S E and its halo); "mirror", every pixel wholly
on the mirror ball (696).  Both leave out the light's own image in the mirror and its neighbours (E S L: a
13 mm light 100 times brighter, which only an eye path that hits it renders: the noisiest pixels in the image,
and no caustic), and the ball's rim (pixels half on the ball, half on the wall behind it).

The reference is a long VCM run: two independent halves a and b at the default radius and two more, c and d,
at half that radius (same passes), averaged.  Its own noise, per channel ((a - b)^2 + (c - d)^2) / 16 (the
variance of the mean of the four in expectation), is subtracted from every measured MSE.  Its bias is not, so
it is bounded: merging blurs by the radius r, a bias B r^2 (R12's analysis), so the half-radius pair has a
quarter of the default pair's and the four's mean 5/8 of it; the pairs' difference, 3/4 of the default pair's
bias, is measured over the region (its mean square less the pairs' noise, plus two standard errors: an upper
bound), and printed.  (Richardson's extrapolation, (4 (c + d)/2 - (a + b)/2) / 3, would cancel the bias to first
order at twice the noise: on 128 x 128 the pairs' difference is below their noise, so it would only add noise.)

Each method runs at every budget twice (seeds 1 and 2, one thread each, CPU time from the child's rusage):
the mean of the two runs' MSE is the point, half the mean squared difference of the two images is one run's
variance, and MSE - variance its squared bias.  The slope of log RMSE on log CPU time is fitted over VCM's
points and compared with progressive photon mapping's: with R12's alpha = 2/3 the variance falls like
N^-alpha and the squared bias like r^4 ~ N^-2(1 - alpha), so the MSE like N^-2/3 and the RMSE like t^-1/3
(Knaus & Zwicker 2011) once merging's error dominates; the unbiased joins and path tracing t^-1/2.

Outputs in OUT: sds-convergence.csv (every run), sds-convergence.md (the table, the fits, the reference),
tradeoff-sds-region.png/.svg (the plot: the caustic and the mirror, RMSE, VCM's bias and standard deviation).
Renders are kept (OUT/renders/) and reused when the build's executable and the command are the same.
"""
import json
import math
import os
import resource
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(ROOT, "tests"))
from caustic_region import sds_mirror_regions  # noqa: E402
import pfm  # noqa: E402

QUICK = os.environ.get("QUICK", "") not in ("", "0")
BUILD = os.environ.get("BUILD", "build") or "build"
OUT = os.environ.get("OUT", "") or ("out/quick/sds" if QUICK else "out/sds")
SIZE = int(os.environ.get("SIZE", "") or (64 if QUICK else 128))
PASSES = [4, 16] if QUICK else [4, 16, 64, 256]
PT_SPP = [16, 64] if QUICK else [16, 64, 256, 1024]
REF_PASSES = int(os.environ.get("SDS_REF_PASSES", "") or (64 if QUICK else 1024))
REF_THREADS = 2
ALPHA = 2.0 / 3.0  # chapter 6's default radius shrink (R12)
METHODS = [("vcm", "VCM", "06_bidirectional", []),
           ("ppm", "PPM (VCM --connect off)", "06_bidirectional", ["--connect", "off"]),
           ("bdpt", "BDPT", "06_bidirectional", ["--method", "bdpt"]),
           ("pt", "path tracing (MIS)", "04_pathtrace", ["--estimator", "mis", "--probe-samples", "32"])]
REGIONS = ("caustic", "mirror")


def render(chapter, args, name, threads=1):
    """(CPU seconds, floats bottom row first, stats) of one render of sds.scene; reused if already made by the
    same executable with the same command."""
    exe = os.path.join(ROOT, BUILD, chapter)
    base = os.path.join(ROOT, OUT, "renders", name)
    cmd = [exe, os.path.join(ROOT, "scenes", "sds.scene"), "--quiet", "--size", f"{SIZE}x{SIZE}",
           "--threads", str(threads), "--out", base + ".pfm", "--stats", base + ".json", *args]
    key = {"cmd": cmd, "exe_mtime": os.path.getmtime(exe)}
    try:
        with open(base + ".key") as f:
            kept = json.load(f)
        if kept["key"] == key:
            with open(base + ".json") as f:
                return kept["cpu_s"], pfm.read_pfm(base + ".pfm")[2], json.load(f)
    except (OSError, ValueError, KeyError):
        pass
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run(cmd, check=True, stderr=subprocess.DEVNULL, env=dict(os.environ, OMP_WAIT_POLICY="passive"))
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime
    with open(base + ".key", "w") as f:
        json.dump({"key": key, "cpu_s": cpu}, f)
    with open(base + ".json") as f:
        return cpu, pfm.read_pfm(base + ".pfm")[2], json.load(f)


def first_radius(stats):
    """The first pass's radius, from the last one and R12's recurrence r_i^2 = r_(i-1)^2 (i - 1 + alpha) / i."""
    r = stats["last_radius"]
    for p in range(2, stats["passes"] + 1):
        r /= math.sqrt((p - 1 + stats["alpha"]) / p)
    return r


def channel_index(pixels_xy):
    """Float offsets (bottom row first, as read_pfm) of the channels of the pixels (x, y), top row 0."""
    return [3 * ((SIZE - 1 - y) * SIZE + x) + k for x, y in pixels_xy for k in range(3)]


def reference():
    """(reference floats, its noise variance per float, info): the mean of two VCM pairs, radius r and r/2."""
    runs = {}
    for label, seed in (("a", 900001), ("b", 900002)):
        runs[label] = render("06_bidirectional", ["--spp", str(REF_PASSES), "--seed", str(seed)], f"ref-{label}",
                             REF_THREADS)
    r0 = first_radius(runs["a"][2])
    for label, seed in (("c", 900003), ("d", 900004)):
        runs[label] = render("06_bidirectional", ["--spp", str(REF_PASSES), "--seed", str(seed),
                                                  "--radius", repr(r0 / 2)], f"ref-{label}", REF_THREADS)
    a, b, c, d = (runs[k][1] for k in "abcd")
    wide = [(x + y) / 2 for x, y in zip(a, b)]
    narrow = [(x + y) / 2 for x, y in zip(c, d)]
    wide_noise = [(x - y) ** 2 / 4 for x, y in zip(a, b)]
    narrow_noise = [(x - y) ** 2 / 4 for x, y in zip(c, d)]
    ref = [(w + n) / 2 for w, n in zip(wide, narrow)]
    noise = [(w + n) / 4 for w, n in zip(wide_noise, narrow_noise)]
    info = {"passes": REF_PASSES, "radius": r0, "cpu_s": sum(v[0] for v in runs.values()),
            "wide": wide, "narrow": narrow, "wide_noise": wide_noise, "narrow_noise": narrow_noise}
    return ref, noise, info


def mean_at(values, index):
    return sum(values[i] for i in index) / len(index)


def sweep(ref, noise, regions):
    """Rows: per method and budget, CPU seconds and per region RMSE, one run's standard deviation and bias."""
    rows = []
    for label, title, chapter, args in METHODS:
        for n in PT_SPP if label == "pt" else PASSES:
            runs = [render(chapter, args + ["--spp", str(n), "--seed", str(seed)], f"{label}-{n}-s{seed}")
                    for seed in (1, 2)]
            row = {"method": label, "title": title, "budget": n, "cpu_s": sum(r[0] for r in runs) / 2}
            for name, index in regions.items():
                ref_mse = mean_at(noise, index)
                mse = sum(mean_at([(x - y) ** 2 for x, y in zip(r[1], ref)], index) for r in runs) / 2 - ref_mse
                var = mean_at([(x - y) ** 2 / 2 for x, y in zip(runs[0][1], runs[1][1])], index)
                sums = [[sum(r[1][index[i + k]] for k in range(3)) for i in range(0, len(index), 3)] for r in runs]
                row[name] = {"rmse": math.sqrt(mse) if mse > 0 else None, "sd": math.sqrt(var),
                             "bias": math.sqrt(mse - var) if mse > var else None, "mse": mse, "var": var,
                             "mean": sum(sums[0] + sums[1]) / (2 * len(index)),
                             "mean_se": math.sqrt(sum((x - y) ** 2 / 4 for x, y in zip(*sums))) / len(index)}
            rows.append(row)
            print(f"  {label:5s} {n:5d}  {row['cpu_s']:7.2f} CPU s  " + "  ".join(
                f"{name} RMSE {fmt(row[name]['rmse'])} (sd {fmt(row[name]['sd'])}, bias {fmt(row[name]['bias'])})"
                for name in regions), flush=True)
    return rows


def fmt(v, digits=3):
    return "—" if v is None else f"{v:.{digits}g}"


def fit(points):
    """Least-squares slope and intercept of log error on log time, or None with fewer than 2 points."""
    pts = [(math.log(t), math.log(e)) for t, e in points if e]
    if len(pts) < 2:
        return None
    mx, my = sum(p[0] for p in pts) / len(pts), sum(p[1] for p in pts) / len(pts)
    sxx = sum((p[0] - mx) ** 2 for p in pts)
    slope = sum((p[0] - mx) * (p[1] - my) for p in pts) / sxx
    return slope, my - slope * mx


def top_share(values, index, count=5):
    """The share of sum(values over index's pixels) in its `count` largest pixels."""
    per_pixel = sorted((sum(values[index[i + k]] for k in range(3)) for i in range(0, len(index), 3)), reverse=True)
    total = sum(per_pixel)
    return sum(per_pixel[:count]) / total if total > 0 else 0.0


def reference_quality(info, ref, noise, regions, rows):
    """Per region: the reference's noise RMSE, the default pair's bias (4/3 of the pairs' difference: measured,
    and an upper bound 2 standard errors up) and so the reference's (5/8 of it), the share of the noise in its 5
    worst pixels, and path tracing's longest runs against its mean (z: in their standard errors; path tracing is
    unbiased, but finds these paths only by hitting the light: rare, large samples)."""
    out = {}
    for name, index in regions.items():
        per_pixel = [sum((info["wide"][i + k] - info["narrow"][i + k]) ** 2 - info["wide_noise"][i + k]
                         - info["narrow_noise"][i + k] for k in range(3)) / 3 for i in index[::3]]
        m = sum(per_pixel) / len(per_pixel)
        se = math.sqrt(sum((v - m) ** 2 for v in per_pixel) / max(len(per_pixel) - 1, 1) / len(per_pixel))
        wide_bias = 4 / 3 * math.sqrt(m) if m > 0 else None
        wide_bound = 4 / 3 * math.sqrt(max(m + 2 * se, 0.0))
        q = {"pixels": len(index) // 3, "noise_rmse": math.sqrt(mean_at(noise, index)),
             "wide_bias": wide_bias, "wide_bias_bound": wide_bound, "ref_bias_bound": 5 / 8 * wide_bound,
             "noise_top5": top_share(noise, index), "mean": mean_at(ref, index),
             "wide_mean": mean_at(info["wide"], index), "narrow_mean": mean_at(info["narrow"], index)}
        pt = [r for r in rows if r["method"] == "pt"]
        if pt:
            p = pt[-1][name]
            q.update(pt_spp=pt[-1]["budget"], pt_mean=p["mean"], pt_z=(p["mean"] - q["mean"]) / p["mean_se"])
        out[name] = q
    return out


STYLE = {"vcm": "lc rgb '#2ca02c' lw 3 pt 7 ps 1.1", "ppm": "lc rgb '#ff7f0e' lw 2.5 pt 11 ps 1.2",
         "bdpt": "lc rgb '#1f3fbf' lw 2.5 pt 5 ps 1.0", "pt": "lc rgb '#d62728' lw 2.5 pt 13 ps 1.1"}
REGION_TITLE = {"caustic": "the caustic seen in the mirror", "mirror": "the whole mirror ball"}


def plot(rows, quality, fits, regions):
    """OUT/tradeoff-sds-region.png/.svg: one panel per region, RMSE against CPU time, log-log."""
    data = os.path.join(ROOT, OUT, "data")
    os.makedirs(data, exist_ok=True)
    files = {}
    for name in regions:
        for label, *_ in METHODS:
            path = os.path.join(data, f"{name}-{label}.dat")
            with open(path, "w") as f:
                f.write("# cpu_s rmse sd bias\n")
                for r in rows:
                    if r["method"] == label and r[name]["rmse"]:
                        f.write(f"{r['cpu_s']:.6g} {r[name]['rmse']:.6g} {r[name]['sd']:.6g} "
                                f"{r[name]['bias'] or float('nan'):.6g}\n")
            files[(name, label)] = path
    made = []
    for term in ("png", "svg"):
        out = os.path.join(ROOT, OUT, f"tradeoff-sds-region.{term}")
        g = [("set terminal pngcairo size 1500,900 font 'DejaVu Sans,11' noenhanced" if term == "png" else
              "set terminal svg size 1500,900 font 'DejaVu Sans,11' noenhanced dynamic"),
             f"set output '{out}'", "set multiplot layout 1,2 title "
             f"'sds.scene {SIZE}x{SIZE}: error in the SDS caustic seen in the mirror against CPU time (two runs a "
             f"point; the reference: VCM 4 x {REF_PASSES} passes, radius r and r/2; its noise subtracted)'", "set logscale xy", "set format x '%g'", "set format y '%g'",
             "set xlabel 'CPU time (s), one thread'", "set ylabel 'RMSE against the reference'",
             "set grid xtics ytics mxtics mytics lc rgb '#dddddd'",
             "set key outside below center horizontal maxcols 2 Left reverse samplen 2 box",
             "set xlabel offset 0,0.6", "set bmargin 13"]
        for name, index in regions.items():
            vcm = [r for r in rows if r["method"] == "vcm" and r[name]["rmse"]]
            q = quality[name]
            pts = [(r["cpu_s"], r[name][k]) for r in rows for k in ("rmse", "sd", "bias") if r[name][k]]
            lo = min([e for _, e in pts] + [q["noise_rmse"], q["ref_bias_bound"]])
            t0, e0 = (vcm[0]["cpu_s"], vcm[0][name]["rmse"]) if vcm else (1, 1)
            fv = fits.get((name, "vcm"))
            g += [f"set title '{REGION_TITLE[name]} ({q['pixels']} pixels)"
                  + (f": VCM slope {fv[0]:.2f}" if fv else "") + "'",
                  f"set xrange [{min(t for t, _ in pts) / 1.5}:{max(t for t, _ in pts) * 1.5}]",
                  f"set yrange [{lo / 2}:{max(e for _, e in pts) * 2}]"]
            curves = [f"'{files[(name, lb)]}' using 1:2 with linespoints {STYLE[lb]} title '{title}'"
                      for lb, title, *_ in METHODS if os.path.getsize(files[(name, lb)]) > 30]
            curves += [f"'{files[(name, 'vcm')]}' using 1:4 with points lc rgb '#2ca02c' pt 6 ps 1.5 "
                       "title 'VCM: its bias (where resolved)'",
                       f"'{files[(name, 'vcm')]}' using 1:3 with lines lc rgb '#2ca02c' lw 1.5 dt 3 "
                       "title 'VCM: standard deviation of one run'",
                       f"{e0} * ({t0} / x) ** (1.0 / 3) with lines lc rgb '#888888' lw 1.5 dt 4 "
                       "title 't^-1/3 (PPM with alpha 2/3)'",
                       f"{e0} * ({t0} / x) ** 0.5 with lines lc rgb '#444444' lw 1 dt 2 title 't^-1/2'",
                       f"{q['noise_rmse']} with lines lc rgb '#999999' lw 1 dt 1 title 'noise of the reference'"]
            curves.append(f"{q['ref_bias_bound']} with lines lc rgb '#bb88bb' lw 1 dt 1 "
                          "title 'bound on the bias of the reference (not subtracted)'")
            g.append("plot " + ", ".join(curves))
        g.append("unset multiplot")
        subprocess.run(["gnuplot"], input="\n".join(g) + "\n", text=True, check=True)
        made.append(out)
    return made


def write_outputs(rows, quality, fits, regions):
    """OUT/sds-convergence.csv and .md, the plot; the summary on stdout."""
    with open(os.path.join(ROOT, OUT, "sds-convergence.csv"), "w") as f:
        f.write("method,budget,cpu_s," + ",".join(f"{n}_{k}" for n in regions for k in ("rmse", "sd", "bias"))
                + "\n")
        for r in rows:
            f.write(f"{r['method']},{r['budget']},{r['cpu_s']:.4f}," + ",".join(
                "" if r[n][k] is None else f"{r[n][k]:.6g}" for n in regions for k in ("rmse", "sd", "bias"))
                + "\n")
    lines = [f"# The SDS caustic of sds.scene against CPU time ({SIZE}x{SIZE}, build {BUILD})", ""]
    for name in regions:
        q = quality[name]
        lines += [f"## {REGION_TITLE[name]}: {q['pixels']} pixels", "",
                  f"Reference: mean {q['mean']:.4g} (radius r pair {q['wide_mean']:.4g}, r/2 pair "
                  f"{q['narrow_mean']:.4g}); its noise RMSE {q['noise_rmse']:.3g} ({100 * q['noise_top5']:.0f} % "
                  f"of its noise in 5 pixels, subtracted); bias of the radius r pair {fmt(q['wide_bias'])} "
                  f"(at most {q['wide_bias_bound']:.2g}), so the reference's at most {q['ref_bias_bound']:.2g} "
                  f"(not subtracted)."
                  + (f" Path tracing at {q['pt_spp']} spp x 2: mean {q['pt_mean']:.4g}, {q['pt_z']:+.1f} standard "
                     f"errors from the reference's." if "pt_z" in q else ""), "",
                  "| method | budget | CPU s | RMSE | one run's sd | bias |", "|---|---|---|---|---|---|"]
        for r in rows:
            e = r[name]
            lines.append(f"| {r['title']} | {r['budget']} | {r['cpu_s']:.2f} | {fmt(e['rmse'])} | {fmt(e['sd'])} "
                         f"| {fmt(e['bias'])} |")
        lines.append("")
        for label, title, *_ in METHODS:
            f_all, f_last = fits.get((name, label)), fits.get((name, label + "-last3"))
            if f_all:
                lines.append(f"- {title}: slope of log RMSE on log CPU time {f_all[0]:.2f} over all its points"
                             + (f", {f_last[0]:.2f} over the last three" if f_last else ""))
        lines.append("")
    with open(os.path.join(ROOT, OUT, "sds-convergence.md"), "w") as f:
        f.write("\n".join(lines) + "\n")
    made = plot(rows, quality, fits, regions)
    print("\n".join(lines))
    print(f"sds_convergence: wrote {OUT}/sds-convergence.csv, .md, .json and {', '.join(made)}")


def main():
    os.makedirs(os.path.join(ROOT, OUT, "renders"), exist_ok=True)
    print(f"sds_convergence: {SIZE}x{SIZE}, build {BUILD}, output {OUT}", flush=True)
    found = sds_mirror_regions(SIZE, SIZE)
    regions = {k: channel_index(found[k]) for k in REGIONS}
    ref, noise, info = reference()
    print(f"  reference: VCM, 2 x {REF_PASSES} passes at radius {info['radius']:.3g} and 2 x {REF_PASSES} at "
          f"{info['radius'] / 2:.3g}, averaged ({info['cpu_s']:.0f} CPU s)", flush=True)
    rows = sweep(ref, noise, regions)
    quality = reference_quality(info, ref, noise, regions, rows)
    fits = {}
    for name in regions:
        for label, *_ in METHODS:
            pts = [(r["cpu_s"], r[name]["rmse"]) for r in rows if r["method"] == label]
            fits[(name, label)] = fit(pts)
            fits[(name, label + "-last3")] = fit(pts[-3:])
    json.dump({'rows': rows, 'quality': quality, 'fits': {f'{a} {b}': v for (a, b), v in fits.items()}},
              open(os.path.join(ROOT, OUT, 'sds-convergence.json'), 'w'), indent=1)
    write_outputs(rows, quality, fits, regions)


if __name__ == "__main__":
    main()
