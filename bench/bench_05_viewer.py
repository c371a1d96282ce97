"""The viewer: frames per second of a four-panel compare grid at 1280x720 on
the headless backends (llvmpipe: the CPU does the GPU's work), and of the
GLSL Blinn-Phong raster of the Cornell box re-rendered each frame as when
orbiting.  A benchmark: it prints numbers, it never fails on a slow machine."""
import os
import subprocess
import tempfile

from common import BUILD, ROOT, run

FRAMES = 60
viewer = os.path.join(ROOT, BUILD, "viewer")
print(f"== viewer (build/viewer): four 512x512 panels at 1280x720, {FRAMES} frames ==")
if not os.access(viewer, os.X_OK):
    print("viewer not built: skipped")
else:
    with tempfile.TemporaryDirectory() as tmp:
        inputs = []
        for k in range(4):
            pfm = os.path.join(tmp, f"panel{k}.pfm")
            run(os.path.join(BUILD, "01_local"), "scenes/cornell.scene", "--quiet", "--size", "512x512",
                "--light-samples", "1", "--seed", k + 1, "--out", pfm)
            inputs.append(pfm)
        env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
        for backend in ("egl", "osmesa"):
            for label, extra in (("grid", []), ("grid + heat map", ["--diff", "1"])):
                result = subprocess.run([viewer, "--headless", "--backend", backend, "--size", "1280x720",
                                         "--frames", str(FRAMES), *extra, *inputs], cwd=ROOT, capture_output=True,
                                        text=True, env=env)
                line = next((l for l in result.stdout.splitlines() if l.startswith("frames")), None)
                print(f"{backend:7s} {label:16s} " + (line if line else f"failed: {result.stderr.strip()[-300:]}"))
        for backend in ("egl", "osmesa"):
            result = subprocess.run([viewer, "--raster", "scenes/cornell-point.scene", "--headless", "--backend",
                                     backend, "--size", "1280x720", "--frames", str(FRAMES)], cwd=ROOT,
                                    capture_output=True, text=True, env=env)
            line = next((l for l in result.stdout.splitlines() if l.startswith("frames")), None)
            print(f"{backend:7s} {'raster + ch. 1':16s} " + (line if line else f"failed: {result.stderr.strip()[-300:]}")
                  + "  (the GLSL raster re-rendered every frame)")
