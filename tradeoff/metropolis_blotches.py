#!/usr/bin/python3
"""What Metropolis light transport's error looks like: the same scene at a short and a long time, MMLT beside BDPT.

    python3 tradeoff/metropolis_blotches.py        (run by `make tradeoff`; QUICK=1: 32x32, 0.25 s and 1 s)

For each scene of SCENES (the Cornell box, where independent paths find the light easily, and Veach's door ajar,
where they do not), chapter 6's BDPT and chapter 7's MMLT render --time SHORT and --time LONG seconds on one thread
(MLT's budget counts its bootstrap).  The panels go side by side through the viewer's headless mode (the same
labels as `make demo`: method, mutations or passes per pixel, time) into OUT/metropolis-blotches.png, in rows
of four per time: the Cornell box's BDPT and MMLT, then the door's.  At the short time BDPT's error is
independent per-pixel noise and MLT's is blotches, patches of pixels where a chain lingered: correlated error,
which is why the sweep measures MLT over independent seeds.  docs/metropolis-blotches.png is a copy of the full
run's figure.

Environment: QUICK=1, BUILD=build, OUT=out (QUICK: out/quick), SIZE=N, SHORT=SECONDS, LONG=SECONDS.
"""
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCENES = ["cornell", "door-ajar"]
METHODS = [("06_bidirectional", ["--method", "bdpt"]), ("07_metropolis", ["--method", "mmlt"])]


def main():
    quick = os.environ.get("QUICK", "") not in ("", "0")
    build = os.environ.get("BUILD", "build") or "build"
    out = os.environ.get("OUT", "") or ("out/quick" if quick else "out")
    size = int(os.environ.get("SIZE", "") or (32 if quick else 128))
    short = float(os.environ.get("SHORT", "") or (0.25 if quick else 1.0))
    long_ = float(os.environ.get("LONG", "") or (1.0 if quick else 16.0))
    work = os.path.join(ROOT, out, "metropolis-blotches")
    os.makedirs(work, exist_ok=True)
    panels = []
    for seconds in (short, long_):
        for scene in SCENES:
            for chapter, args in METHODS:
                name = os.path.join(work, f"{scene}-{chapter}-{seconds:g}s")
                command = [os.path.join(ROOT, build, chapter), os.path.join("scenes", scene + ".scene"), "--quiet",
                           "--size", f"{size}x{size}", "--threads", "1", "--seed", "7", "--time", str(seconds),
                           "--spp", "1000000", "--out", name + ".pfm", "--stats", name + ".json", *args]
                print("metropolis_blotches: " + " ".join(os.path.relpath(c, ROOT) if c.startswith(ROOT) else c
                                                          for c in command), flush=True)
                subprocess.run(command, cwd=ROOT, check=True, stdin=subprocess.DEVNULL)
                panels.append(name + ".pfm")
    picture = os.path.join(ROOT, out, "metropolis-blotches.png")
    width = 4 * (size if quick else 300)
    subprocess.run([os.path.join(ROOT, build, "viewer"), "--headless", "--size", f"{width}x{width // 2 + 120}",
                    "--out", picture, *panels], cwd=ROOT, check=True, stdout=subprocess.DEVNULL,
                   stdin=subprocess.DEVNULL)
    print(f"metropolis_blotches: {os.path.relpath(picture, ROOT)}", flush=True)


if __name__ == "__main__":
    sys.exit(main())
