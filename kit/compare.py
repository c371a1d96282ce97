"""Criteria that compare a submission's renders with the solution's (kit/reference/).

compare:  B renders with B seeds (one batch each); per tile of TxT pixels and
          per colour channel, the B tile means of the submission against the
          reference's R tile means by Welch's t-test; also the image mean per
          channel (Welch) and the variance of the image mean (one-sided F:
          the submission must not be noisier, which catches streams shared by
          pixels or samples).  Holm's correction over all these tests; the
          criterion fails when the smallest Holm-adjusted p-value is below
          alpha_c = family_alpha / (number of compare criteria in the rubric).
surfaces: 03_radiosity's per-surface radiance (stats key "surfaces", exact up
          to the solver's tolerance) within a relative tolerance of the
          solution's.
"""
import concurrent.futures
import json
import math
import os
import re
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import png  # noqa: E402

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "tests"))
import pfm  # noqa: E402  (tests/pfm.py)
import stats  # noqa: E402

KIT = os.path.dirname(os.path.abspath(__file__))
REFERENCE_SEED = 1_000_000  # reference batch b has seed REFERENCE_SEED + b; a submission's seed * 1000 + b
RENDER_TIMEOUT = 120


class CriterionFailed(Exception):
    pass


def slug(c):
    return c["chapter"] + "--" + re.sub(r"[^a-z0-9]+", "-", c["name"].lower()).strip("-")


def reference_path(c):
    return os.path.join(KIT, "reference", slug(c) + ".json")


def read_pfm(path):
    try:
        width, height, floats = pfm.read_pfm(path)
    except ValueError as e:
        raise CriterionFailed(f"{os.path.basename(path)}: {str(e).split(': ', 1)[-1]}")
    return width, height, pfm.pixels_top_first(width, height, floats)


def describe_exit(code, stderr):
    tail = stderr.strip()[-600:]
    if code < 0:
        import signal
        try:
            name = signal.Signals(-code).name
        except ValueError:
            name = str(-code)
        return f"crashed ({name}){': ' + tail if tail else ''}"
    return f"exit status {code}{': ' + tail if tail else ''}"


def run_chapter(root, c, cmd, what=""):
    """Run the chapter command `cmd` of criterion c; CriterionFailed on a time-out or a non-zero exit."""
    try:
        r = subprocess.run(cmd, cwd=root, capture_output=True, text=True, timeout=RENDER_TIMEOUT,
                           stdin=subprocess.DEVNULL, errors="replace")
    except subprocess.TimeoutExpired:
        raise CriterionFailed(f"{what}timed out after {RENDER_TIMEOUT} s")
    if r.returncode != 0:
        raise CriterionFailed(f"{c['chapter']} {' '.join(cmd[1:])}: " + describe_exit(r.returncode, r.stderr))


def render(root, build, c, seed, out, threads=1):
    exe = os.path.join(root, build, c["chapter"])
    if not os.path.exists(exe):
        raise CriterionFailed(f"{build}/{c['chapter']} is missing (did not compile)")
    cmd = [exe, c["scene"], "--quiet", "--size", c.get("size", "32x32"), "--spp", str(c.get("spp", 1)),
           "--seed", str(seed), "--threads", str(threads), "--out", out, *c.get("args", [])]
    run_chapter(root, c, cmd, f"seed {seed}: ")
    if not os.path.exists(out):
        raise CriterionFailed(f"seed {seed}: exit 0 but no output image {os.path.basename(out)}")
    w, h, pixels = read_pfm(out)
    bad = sum(1 for p in pixels for v in p if not math.isfinite(v))
    if bad:
        raise CriterionFailed(f"seed {seed}: {bad} NaN or infinite pixel values")
    return w, h, pixels


def batch_renders(root, build, c, seeds, jobs):
    """[(w, h, pixels)] for each seed, rendered jobs at a time."""
    scratch = tempfile.mkdtemp(prefix="gi-kit-")
    with concurrent.futures.ThreadPoolExecutor(max_workers=max(1, jobs)) as pool:
        futures = [pool.submit(render, root, build, c, s, os.path.join(scratch, f"b{s}.pfm")) for s in seeds]
        images = [f.result() for f in futures]
    sizes = {(w, h) for w, h, _ in images}
    if len(sizes) != 1:
        raise CriterionFailed(f"renders of different sizes {sorted(sizes)}")
    return images


def summarise(images, tile):
    """Per-batch tile means [batch][tile * 3 + channel], per-pixel mean and variance over batches."""
    w, h, _ = images[0]
    tx, ty = w // tile, h // tile
    tile_means = []
    for _, _, px in images:
        row = []
        for j in range(ty):
            for i in range(tx):
                cells = [px[(j * tile + y) * w + i * tile + x] for y in range(tile) for x in range(tile)]
                row += [sum(p[ch] for p in cells) / len(cells) for ch in range(3)]
        tile_means.append(row)
    n = len(images)
    mean = [tuple(sum(im[2][k][ch] for im in images) / n for ch in range(3)) for k in range(w * h)]
    var = [tuple(sum((im[2][k][ch] - mean[k][ch]) ** 2 for im in images) / (n - 1) for ch in range(3))
           for k in range(w * h)]
    return {"width": w, "height": h, "tile": tile, "tiles_x": tx, "tiles_y": ty, "batches": n,
            "tile_means": tile_means, "pixel_mean": mean, "pixel_var": var}


def make_reference(root, build, c, rub, jobs):
    seeds = [REFERENCE_SEED + b for b in range(rub["reference_batches"])]
    data = summarise(batch_renders(root, build, c, seeds, jobs), rub["tile"])
    data.update({"criterion": c["name"], "chapter": c["chapter"], "scene": c["scene"], "args": c.get("args", []),
                 "size": c.get("size"), "spp": c.get("spp"), "seeds": [seeds[0], seeds[-1]]})
    r7 = lambda v: float("%.7g" % v)  # noqa: E731
    data["tile_means"] = [[r7(v) for v in row] for row in data["tile_means"]]
    data["pixel_mean"] = [[r7(v) for v in p] for p in data["pixel_mean"]]
    data["pixel_var"] = [[r7(v) for v in p] for p in data["pixel_var"]]
    os.makedirs(os.path.dirname(reference_path(c)), exist_ok=True)
    with open(reference_path(c), "w") as f:
        json.dump(data, f, separators=(",", ":"))


def alpha_per_criterion(rub):
    k = sum(1 for c in rub["criteria"] if c["kind"] == "compare")
    return rub["family_alpha"] / max(1, k)


def run_compare(root, build, c, rub, seed, jobs, images_dir):
    """Returns (passed, p_value, message, images{student, reference, heat})."""
    try:
        with open(reference_path(c)) as f:
            ref = json.load(f)
    except OSError:
        raise CriterionFailed(f"no reference {os.path.relpath(reference_path(c), KIT)}: run kit/grade.py "
                              "--make-reference in the instructor's tree")
    seeds = [seed * 1000 + b for b in range(rub["batches"])]
    sub = summarise(batch_renders(root, build, c, seeds, jobs), ref["tile"])
    if (sub["width"], sub["height"]) != (ref["width"], ref["height"]):
        raise CriterionFailed(f"image is {sub['width']}x{sub['height']}, expected {ref['width']}x{ref['height']}")
    tests = []  # (label, p, detail)
    nt = ref["tiles_x"] * ref["tiles_y"]
    channel = "RGB"
    for k in range(nt * 3):
        a = [row[k] for row in sub["tile_means"]]
        b = [row[k] for row in ref["tile_means"]]
        floor = (1e-6 * abs(sum(b) / len(b))) ** 2  # float rounding of exact tiles (PFM is single precision)
        t, df, p, d, se = stats.welch(a, b, floor)
        tile = k // 3
        tests.append((f"tile ({tile % ref['tiles_x']}, {tile // ref['tiles_x']}) {channel[k % 3]}", p,
                      f"mean {sum(a) / len(a):.5g} vs reference {sum(b) / len(b):.5g}, t = {t:.2f}, df = {df:.0f}"))
    for ch in range(3):
        a = [sum(row[3 * t + ch] for t in range(nt)) / nt for row in sub["tile_means"]]
        b = [sum(row[3 * t + ch] for t in range(nt)) / nt for row in ref["tile_means"]]
        t, df, p, d, se = stats.welch(a, b, (1e-6 * abs(sum(b) / len(b))) ** 2)
        tests.append((f"image mean {channel[ch]}", p, f"{sum(a) / len(a):.5g} vs reference {sum(b) / len(b):.5g}, "
                      f"t = {t:.2f}, df = {df:.0f}"))
        ratio, p = stats.variance_ratio(a, b)
        tests.append((f"noise of the image mean {channel[ch]}", p, f"variance {ratio:.3g} x the reference's "
                      f"at the same spp (F test, one-sided)"))
    adjusted = stats.holm([p for _, p, _ in tests])
    alpha = alpha_per_criterion(rub)
    worst = min(range(len(tests)), key=lambda i: adjusted[i])
    failing = [i for i in range(len(tests)) if adjusted[i] < alpha]
    p_value = adjusted[worst]
    if failing:
        shown = "; ".join(f"{tests[i][0]}: {tests[i][2]} (Holm p = {adjusted[i]:.2g})" for i in failing[:4])
        message = f"{len(failing)} of {len(tests)} tests below alpha = {alpha:.2g}: {shown}"
    else:
        message = f"{len(tests)} tests, smallest Holm-adjusted p = {p_value:.3g} ({tests[worst][0]}) >= {alpha:.2g}"
    images = {}
    if images_dir:
        os.makedirs(images_dir, exist_ok=True)
        w, h = ref["width"], ref["height"]
        name = slug(c)
        images["student"] = name + "-student.png"
        images["reference"] = name + "-reference.png"
        images["heat"] = name + "-error.png"
        png.write_image(os.path.join(images_dir, images["student"]), w, h, sub["pixel_mean"])
        png.write_image(os.path.join(images_dir, images["reference"]), w, h, [tuple(p) for p in ref["pixel_mean"]])
        z = []
        for k in range(w * h):
            worst_z = 0.0
            for ch in range(3):
                se2 = sub["pixel_var"][k][ch] / sub["batches"] + ref["pixel_var"][k][ch] / ref["batches"]
                d = sub["pixel_mean"][k][ch] - ref["pixel_mean"][k][ch]
                zz = abs(d) / math.sqrt(se2) if se2 > 0 else (0.0 if abs(d) < 1e-6 else 99.0)
                worst_z = max(worst_z, zz)
            z.append(worst_z / 2.0)
        png.write_heat(os.path.join(images_dir, images["heat"]), w, h, z)
    return not failing, p_value, message, images


# ---- radiosity's surfaces ---------------------------------------------------------------------------

def surfaces_of(root, build, c):
    exe = os.path.join(root, build, c["chapter"])
    if not os.path.exists(exe):
        raise CriterionFailed(f"{build}/{c['chapter']} is missing (did not compile)")
    out = tempfile.mkdtemp(prefix="gi-kit-")
    cmd = [exe, c["scene"], "--quiet", "--size", "8x8", "--spp", "1", "--patch-size", str(c.get("patch_size", 50)),
           "--tol", str(c.get("tol", 1e-6)),
           "--iterations", str(c.get("iterations", 500)), "--out", os.path.join(out, "s.pfm"),
           "--stats", os.path.join(out, "s.json"),
           *c.get("args", [])]
    run_chapter(root, c, cmd)
    try:
        with open(os.path.join(out, "s.json")) as f:
            data = json.load(f)
        surfaces = {s["name"]: s["radiance"] for s in data["surfaces"]}
        converged, residual = data.get("converged"), data.get("residual")
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise CriterionFailed(f"no readable 'surfaces' in the stats: {e}")
    if converged is False:
        raise CriterionFailed(f"the solver did not converge in {c.get('iterations', 500)} iterations "
                              f"(residual {residual}, --tol {c.get('tol', 1e-6)})")
    return surfaces


def make_surfaces_reference(root, build, c):
    os.makedirs(os.path.dirname(reference_path(c)), exist_ok=True)
    with open(reference_path(c), "w") as f:
        json.dump({"criterion": c["name"], "surfaces": surfaces_of(root, build, c)}, f, indent=1)


def run_surfaces(root, build, c, rub):
    with open(reference_path(c)) as f:
        ref = json.load(f)["surfaces"]
    got = surfaces_of(root, build, c)
    tol = rub["surface_tolerance"]
    bad = []
    for name, r in ref.items():
        if name not in got:
            bad.append(f"{name}: missing")
            continue
        for ch in range(3):
            v = got[name][ch]
            if not (math.isfinite(v) and abs(v - r[ch]) <= tol * abs(r[ch]) + 1e-6):
                bad.append(f"{name} {'RGB'[ch]}: {v:.5g} vs solution {r[ch]:.5g}")
    if bad:
        return False, None, f"{len(bad)} surface channels off by more than {tol:.1%}: " + "; ".join(bad[:4]), {}
    return True, None, f"{len(ref)} surfaces within {tol:.1%} of the solution", {}
