"""A mesh emitter: the cost of one light sample against the mesh's triangle
count (chapters 1, 2 and 4 pick an emitter's triangle by its area share, a
binary search in the table of running area sums built once at load).
Chapter 1 at 64x64, 64 points per emitter, no shadow rays (so only the
sampling and shading are timed); the mesh is a light panel of N triangles
of unequal sizes under the ceiling of a 1 x 1 room."""
import os
import tempfile

from common import best_of

SCENE = """\
camera eye 0.5 0.5 -1.5  look 0.5 0.5 0.5  up 0 1 0  fov 40
image 64 64
material wall diffuse 0.6 0.6 0.6
material lamp emitter 5 5 5
quad floor wall  0 0 0  1 0 0  1 0 1  0 0 1
quad back wall  0 0 1  1 0 1  1 1 1  0 1 1
mesh panel lamp panel.obj
"""


def write_panel(path, n_triangles):
    """A strip of n triangles at y = 0.99, x from 0.25 to 0.75, widths growing
    with the index (unequal areas), facing down."""
    columns = n_triangles // 2
    xs = [0.25 + 0.5 * (k * (k + 1) / 2) / (columns * (columns + 1) / 2) for k in range(columns + 1)]
    with open(path, "w") as f:
        for x in xs:
            f.write(f"v {x:.9f} 0.99 0.25\nv {x:.9f} 0.99 0.75\n")
        for k in range(columns):
            a, b, c, d = 2 * k + 1, 2 * k + 2, 2 * k + 3, 2 * k + 4
            f.write(f"f {a} {c} {b}\nf {b} {c} {d}\n")


print("== a mesh light: time per light sample against its triangle count (01_local 64x64, best of 3) ==")
with tempfile.TemporaryDirectory() as tmp:
    scene = os.path.join(tmp, "mesh-light.scene")
    with open(scene, "w") as f:
        f.write(SCENE)
    for n in (100, 1000, 10000, 100000):
        write_panel(os.path.join(tmp, "panel.obj"), n)
        s = best_of(3, "01_local", scene, "--light-samples", 64, "--no-shadows", "--threads", 1)
        samples = s["counters"]["area_light_samples"]
        print(f"{n:>7} triangles: {s['render_s'] * 1e9 / samples:8.1f} ns per light sample "
              f"({samples} samples in {s['render_s']:.3f} s, 1 thread)")
