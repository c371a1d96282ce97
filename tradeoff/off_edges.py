#!/usr/bin/python3
"""Chapters 4, 5 and 6 of a trade-off run, measured off the light's edges.

    python3 tradeoff/off_edges.py OUT        (OUT of tradeoff.py: out, out/quick, ...)

A few pixels carry most of the whole-image RMSE: those half on the light (radiance 17 next
to 0 on the Cornell box, 757 on sds), its image in the mirror, the slit's beam on gap.  There
path tracing's jittered camera rays estimate worst and light tracing's joins to the camera
best; at 128 x 128 they are 122 of the Cornell box's 16,384 pixels.  This reads the run's
images (OUT/tradeoff/<scene>/*.pfm) and prints each curve's RMSE over the other pixels,
those whose reference has no jump above EDGE_JUMP to a 4-neighbour, the reference's own
noise ((a - b)^2 / 4 per channel) subtracted; then, at each VCM point's CPU time, the
others interpolated (log-log) as in tradeoff.md.  Standard library only.
"""
import csv
import math
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(os.path.dirname(HERE), "tests"))
import pfm  # noqa: E402

EDGE_JUMP = 3.0
CURVES = ("pt-mis", "pm", "bd-light", "bd-bdpt", "bd-vcm")


def image_name(row):
    """The sweep's file name of a row (tradeoff.py's sweep_scene)."""
    n = row["setting"].split("=")[1]
    return f"{row['curve']}-{n}" if row["curve"] in ("pt-mis", "pm") else f"bd-{row['curve'][3:]}-{n}"


def off_edge_channels(ref, width, height):
    lum = [sum(ref[3 * p:3 * p + 3]) / 3 for p in range(width * height)]
    keep = []
    for p in range(width * height):
        x, y = p % width, p // width
        near = [q for q, ok in ((p - 1, x > 0), (p + 1, x < width - 1), (p - width, y > 0),
                                (p + width, y < height - 1)) if ok]
        if all(abs(lum[q] - lum[p]) <= EDGE_JUMP for q in near):
            keep += [3 * p, 3 * p + 1, 3 * p + 2]
    return keep


def error_at(points, t):
    pts = sorted(p for p in points if p[1])
    for (ta, ea), (tb, eb) in zip(pts, pts[1:]):
        if ta <= t <= tb:
            w = math.log(t / ta) / math.log(tb / ta) if tb > ta else 0.0
            return math.exp((1 - w) * math.log(ea) + w * math.log(eb))
    return None


def fmt(v):
    return "—" if v is None else f"{v:.4g}"


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__.strip())
    out = sys.argv[1]
    with open(os.path.join(out, "tradeoff.csv")) as f:
        rows = [r for r in csv.DictReader(f) if r["curve"] in CURVES and r["status"] == "ok"]
    for scene in dict.fromkeys(r["scene"] for r in rows):
        d = os.path.join(out, "tradeoff", scene)
        w, h, a = pfm.read_pfm(os.path.join(d, "ref-a.pfm"))
        b = pfm.read_pfm(os.path.join(d, "ref-b.pfm"))[2]
        ref = [(x + y) / 2 for x, y in zip(a, b)]
        noise = [(x - y) ** 2 / 4 for x, y in zip(a, b)]
        keep = off_edge_channels(ref, w, h)
        curves = {}
        for r in rows:
            if r["scene"] == scene:
                img = pfm.read_pfm(os.path.join(d, image_name(r) + ".pfm"))[2]
                mse = sum((img[i] - ref[i]) ** 2 - noise[i] for i in keep) / len(keep)
                curves.setdefault(r["curve"], []).append((float(r["cpu_s"]), math.sqrt(mse) if mse > 0 else None))
        print(f"\n{scene}: {w * h - len(keep) // 3} of {w * h} pixels on an edge left out; RMSE off them at VCM's "
              f"CPU times (s):")
        print("  t      " + "  ".join(f"{cv:>9s}" for cv in CURVES) + "  VCM / better of BDPT, PM")
        for t, e in sorted(p for p in curves.get("bd-vcm", []) if p[1]):
            at = {cv: error_at(curves.get(cv, []), t) for cv in CURVES}
            better = min(at["bd-bdpt"], at["pm"]) if at["bd-bdpt"] and at["pm"] else None
            print(f"  {t:<6.3g} " + "  ".join(f"{fmt(at[cv]):>9s}" for cv in CURVES) +
                  f"  {fmt(e / better) if better else '—'}")
        if scene == "gap":
            ratios = [(t, e / error_at(curves["pt-mis"], t)) for t, e in sorted(curves.get("bd-bdpt", []))
                      if e and error_at(curves["pt-mis"], t)]
            print("  BDPT / path tracing at BDPT's times: " + ", ".join(f"{q:.2f} at {t:.3g} s" for t, q in ratios))


if __name__ == "__main__":
    main()
