"""Helpers shared by the grading tests: run a chapter, read its outputs.

Standard library only (Debian's /usr/bin/python3), so `make test` needs no
Python packages.
"""
import json
import math
import os
import struct
import subprocess
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


class Context:
    """What a test needs: the build directory under test and a scratch dir."""

    def __init__(self, build):
        self.build = build
        self.scratch = tempfile.mkdtemp(prefix="gi-test-")

    def path(self, name):
        return os.path.join(self.scratch, name)

    def write(self, name, text):
        p = self.path(name)
        with open(p, "w") as f:
            f.write(text)
        return p

    def run(self, chapter, *args, timeout=600):
        """Run build/<chapter> with args from the repo root; return the CompletedProcess."""
        exe = os.path.join(ROOT, self.build, chapter)
        return subprocess.run([exe, *map(str, args)], cwd=ROOT, capture_output=True, text=True,
                              timeout=timeout, stdin=subprocess.DEVNULL)

    def render(self, chapter, scene, *args, name="render", timeout=600):
        """Render to PFM + stats in scratch; return (image, stats). Fails loudly on a non-zero exit."""
        pfm, stats = self.path(name + ".pfm"), self.path(name + ".json")
        result = self.run(chapter, scene, "--quiet", "--out", pfm, "--stats", stats, *args, timeout=timeout)
        assert result.returncode == 0, f"{chapter} {scene} {' '.join(map(str, args))} exited " \
                                       f"{result.returncode}: {result.stderr.strip()}"
        return read_pfm(pfm), read_json(stats)


class Image:
    def __init__(self, width, height, pixels):
        self.width, self.height, self.pixels = width, height, pixels  # pixels: list of (r,g,b), top row first

    def at(self, x, y):
        return self.pixels[y * self.width + x]


def read_pfm(path):
    with open(path, "rb") as f:
        data = f.read()
    parts = data.split(b"\n", 3)
    assert parts[0] == b"PF", f"{path}: not a colour PFM"
    width, height = map(int, parts[1].split())
    scale = float(parts[2])
    endian = "<" if scale < 0 else ">"
    floats = struct.unpack(endian + "%df" % (3 * width * height), parts[3][:12 * width * height])
    rows = []
    for y in range(height - 1, -1, -1):  # PFM stores the bottom row first
        base = 3 * width * y
        rows.extend(tuple(floats[base + 3 * x:base + 3 * x + 3]) for x in range(width))
    return Image(width, height, rows)


def read_json(path):
    with open(path) as f:
        return json.load(f)


def probe(stats, name):
    for p in stats["probes"]:
        if p["name"] == name:
            return p
    raise AssertionError(f"no probe {name} in stats")


def lambert_polygon_irradiance(radiance, polygon, point, normal):
    """Irradiance at `point` (unit `normal`) from a Lambertian polygon of
    constant radiance, by Lambert's contour formula:
        E = L/2 * sum_i beta_i * (n . (r_i x r_{i+1}) / |r_i x r_{i+1}|)
    where r_i are the unit vectors to the vertices and beta_i the angle
    between consecutive ones (the polygon must be fully above the plane and
    its vertices ordered so the sum is positive)."""
    def sub(a, b): return [a[k] - b[k] for k in range(3)]
    def dot(a, b): return sum(a[k] * b[k] for k in range(3))
    def cross(a, b): return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    def unit(a):
        length = math.sqrt(dot(a, a))
        return [c / length for c in a]
    rs = [unit(sub(v, point)) for v in polygon]
    total = 0.0
    for i in range(len(rs)):
        a, b = rs[i], rs[(i + 1) % len(rs)]
        c = cross(a, b)
        # atan2(|a x b|, a.b), not acos(a.b): accurate for the tiny angles a
        # small or distant polygon subtends, where the terms nearly cancel.
        beta = math.atan2(math.sqrt(dot(c, c)), dot(a, b))
        total += beta * dot(normal, unit(c))
    return abs(total) / 2.0 * radiance


def finite_image(img):
    return all(math.isfinite(c) for px in img.pixels for c in px)
