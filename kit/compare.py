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
import lib  # noqa: E402  (tests/lib.py: the report's record of commands, stubs and measured values)
import pfm  # noqa: E402  (tests/pfm.py)
import stats  # noqa: E402

KIT = os.path.dirname(os.path.abspath(__file__))
REFERENCE_SEED = 1_000_000  # reference batch b has seed REFERENCE_SEED + b; a submission's seed * 1000 + b
RENDER_TIMEOUT = 120
# The report's pictures: one render of the criterion's scene and options at PREVIEW_SIZE pixels (each
# tile of the 16 x 16 test image is then 32 x 32 pixels), with the criterion's samples per pixel
# between 4 and 256 (a few seconds), seed PREVIEW_SEED; the solution's, rendered by the same command,
# is stored in kit/reference/<criterion>.png (kit/grade.py --make-reference).  A correct submission
# that draws its random numbers as the solution does gives the same picture.
PREVIEW_SIZE = 128
PREVIEW_SEED = 1
PREVIEW_SPP = (4, 256)
PREVIEW_TIMEOUT = 60


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


def run_chapter(root, c, cmd, what="", timeout=RENDER_TIMEOUT):
    """Run the chapter command `cmd` of criterion c; CriterionFailed on a time-out or a non-zero exit."""
    try:
        r = lib.RUN_PROGRAM[0](cmd, cwd=root, timeout=timeout)
    except subprocess.TimeoutExpired:
        raise CriterionFailed(f"{what}timed out after {timeout} s")
    lib.record_todos(r.stderr)
    if r.returncode != 0:
        raise CriterionFailed(f"{c['chapter']} {' '.join(cmd[1:])}: " + describe_exit(r.returncode, r.stderr))


def render_command(exe, c, seed, out, threads=1):
    return [exe, c["scene"], "--quiet", "--size", c.get("size", "32x32"), "--spp", str(c.get("spp", 1)),
            "--seed", str(seed), "--threads", str(threads), "--out", out, *c.get("args", [])]


def render(root, build, c, seed, out, threads=1, timeout=RENDER_TIMEOUT):
    exe = os.path.join(root, build, c["chapter"])
    if not os.path.exists(exe):
        raise CriterionFailed(f"{build}/{c['chapter']} is missing (did not compile)")
    cmd = render_command(exe, c, seed, out, threads)
    run_chapter(root, c, cmd, f"seed {seed}: ", timeout)
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
    lib.record_command(c["chapter"], render_command("", c, seeds[0], "")[1:])  # the first batch's, for the report
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


def preview_criterion(c):
    """Criterion c as the report's picture renders it: PREVIEW_SIZE square, its samples per pixel
    clamped to PREVIEW_SPP (enough to recognise the scene)."""
    low, high = PREVIEW_SPP
    return dict(c, size=f"{PREVIEW_SIZE}x{PREVIEW_SIZE}", spp=min(high, max(low, c.get("spp", 1))))


def preview_path(c):
    return os.path.join(KIT, "reference", slug(c) + ".png")


def preview_command(c):
    """The command of the report's picture, as a student reruns it."""
    return lib.command_text(c["chapter"], render_command("", preview_criterion(c), PREVIEW_SEED, "")[1:])


def render_preview(root, build, c, threads):
    """(width, height, 8-bit colours) of one render of criterion c at PREVIEW_SIZE (preview_criterion),
    at most PREVIEW_TIMEOUT seconds; CriterionFailed when it fails."""
    out = os.path.join(tempfile.mkdtemp(prefix="gi-kit-"), "preview.pfm")
    w, h, pixels = render(root, build, preview_criterion(c), PREVIEW_SEED, out, threads, PREVIEW_TIMEOUT)
    return w, h, png.tone_mapped(pixels)


def make_preview(root, build, c, jobs):
    """kit/reference/<criterion>.png: the solution's picture for the report, its command kept in the
    file (the report says when the rubric's command has changed since)."""
    w, h, colours = render_preview(root, build, c, jobs)
    os.makedirs(os.path.dirname(preview_path(c)), exist_ok=True)
    png.write_png(preview_path(c), w, h, [colours[y * w:(y + 1) * w] for y in range(h)], preview_command(c))


def stored_preview(c):
    """(width, height, colours, note) of the solution's stored picture, or None when there is none;
    note says when it was made by another command than the rubric's."""
    try:
        w, h, colours = png.read_png(preview_path(c))
        made_by = png.read_png_comment(preview_path(c))
    except (OSError, ValueError):
        return None
    note = "" if made_by == preview_command(c) else f" (made by an older command: {made_by})"
    return w, h, colours, note


def alpha_per_criterion(rub):
    k = sum(1 for c in rub["criteria"] if c["kind"] == "compare")
    return rub["family_alpha"] / max(1, k)


def where_in_image(tiles, tiles_x, tiles_y):
    """"almost everywhere" or "mostly in the top left" etc. for a set of tile indices."""
    if len(tiles) >= 0.6 * tiles_x * tiles_y:
        return "almost everywhere"
    cx = sum(t % tiles_x + 0.5 for t in tiles) / len(tiles) / tiles_x
    cy = sum(t // tiles_x + 0.5 for t in tiles) / len(tiles) / tiles_y
    row = "top" if cy < 1 / 3 else "bottom" if cy > 2 / 3 else "middle"
    col = "left" if cx < 1 / 3 else "right" if cx > 2 / 3 else "centre"
    return "mostly in the " + ("centre" if (row, col) == ("middle", "centre") else f"{row} {col}"
                               if row != "middle" else f"middle {col}" if col != "centre" else "centre")


def luminance(rgb):
    return 0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2]


def run_compare(root, build, c, rub, seed, jobs, images_dir):
    """Returns (passed, p_value, message, images{student, reference, tiles}).  The message is a
    sentence for the student (how many tiles differ and which way, how far off the image mean is,
    the command); each tested quantity also goes into lib.MEASURED."""
    try:
        with open(reference_path(c)) as f:
            ref = json.load(f)
    except OSError:
        raise CriterionFailed(f"no reference {os.path.relpath(reference_path(c), KIT)}: run kit/grade.py "
                              "--make-reference in the instructor's tree")
    seeds = [seed * 1000 + b for b in range(rub["batches"])]
    command = lib.command_text(c["chapter"], render_command("", c, seeds[0], "")[1:])
    sub = summarise(batch_renders(root, build, c, seeds, jobs), ref["tile"])
    if (sub["width"], sub["height"]) != (ref["width"], ref["height"]):
        raise CriterionFailed(f"image is {sub['width']}x{sub['height']}, expected {ref['width']}x{ref['height']}")
    tests = []  # (label, p, detail, kind, index, t, measured, expected, se)
    nt = ref["tiles_x"] * ref["tiles_y"]
    for k in range(nt * 3):
        a = [row[k] for row in sub["tile_means"]]
        b = [row[k] for row in ref["tile_means"]]
        floor = (1e-6 * abs(sum(b) / len(b))) ** 2  # float rounding of exact tiles (PFM is single precision)
        t, df, p, d, se = stats.welch(a, b, floor)
        tile = k // 3
        tests.append((f"tile ({tile % ref['tiles_x']}, {tile // ref['tiles_x']}) {lib.CHANNELS[k % 3]}", p,
                      f"t = {t:.2f}, df = {df:.0f}", "tile", k, t, sum(a) / len(a), sum(b) / len(b), se))
    for ch in range(3):
        a = [sum(row[3 * t + ch] for t in range(nt)) / nt for row in sub["tile_means"]]
        b = [sum(row[3 * t + ch] for t in range(nt)) / nt for row in ref["tile_means"]]
        t, df, p, d, se = stats.welch(a, b, (1e-6 * abs(sum(b) / len(b))) ** 2)
        tests.append((f"image mean {lib.CHANNELS[ch]}", p, f"t = {t:.2f}, df = {df:.0f}", "mean", ch, t,
                      sum(a) / len(a), sum(b) / len(b), se))
        ratio, p = stats.variance_ratio(a, b)
        tests.append((f"noise of the image mean {lib.CHANNELS[ch]}", p, f"F = {ratio:.3g}", "noise", ch, ratio,
                      ratio, 1.0, None))
    adjusted = stats.holm([test[1] for test in tests])
    alpha = alpha_per_criterion(rub)
    worst = min(range(len(tests)), key=lambda i: adjusted[i])
    failing = [i for i in range(len(tests)) if adjusted[i] < alpha]
    p_value = adjusted[worst]
    marks, strength = failing_tiles(tests, adjusted, alpha, sub, ref)
    message = compare_sentence(c, tests, adjusted, alpha, marks, ref, sub, command, seeds)
    record_compare(tests, adjusted, alpha, marks, nt, command)
    images = write_pictures(root, build, c, jobs, images_dir, ref, sub, marks, strength) if images_dir else {}
    return not failing, p_value, message, images


PREVIEW = {}  # what the last write_pictures showed: {"command", "student", "reference"} (kit/criterion.py)


def write_pictures(root, build, c, jobs, images_dir, ref, sub, marks, strength):
    """The report's pictures of criterion c: the student's render and the solution's (stored) at
    PREVIEW_SIZE with the test's tile grid and the failing tiles marked, and when a tile fails the
    tile map.  A
    picture that cannot be had (the preview render fails, no stored preview) falls back to the test's
    small mean image, enlarged, and PREVIEW says why."""
    os.makedirs(images_dir, exist_ok=True)
    tiles_x, tiles_y = ref["tiles_x"], ref["tiles_y"]
    PREVIEW.clear()
    PREVIEW["command"] = preview_command(c)
    PREVIEW["grid"] = (f"{tiles_x} x {tiles_y} tiles (each {ref['tile']} x {ref['tile']} pixels of the "
                       f"{ref['width']} x {ref['height']} test renders)")
    try:
        student = render_preview(root, build, c, jobs)
        PREVIEW["student"] = f"one render: {PREVIEW['command']}"
    except CriterionFailed as e:
        student = (sub["width"], sub["height"], png.tone_mapped(sub["pixel_mean"]))
        PREVIEW["student"] = (f"the {sub['width']}x{sub['height']} test renders' mean (the picture's own render "
                              f"failed: {str(e)[:300]})")
    solution = stored_preview(c)
    if solution is None:
        solution = (ref["width"], ref["height"], png.tone_mapped(ref["pixel_mean"]), "")
        PREVIEW["reference"] = (f"the {ref['width']}x{ref['height']} reference mean (no "
                                f"{os.path.relpath(preview_path(c), KIT)}: kit/grade.py --make-reference)")
    else:
        PREVIEW["reference"] = f"the same command with the solution{solution[3]}"
    name = slug(c)
    images = {"student": name + "-student.png", "reference": name + "-reference.png"}
    png.write_marked(os.path.join(images_dir, images["student"]), *student[:3], tiles_x, tiles_y, marks)
    png.write_marked(os.path.join(images_dir, images["reference"]), *solution[:3], tiles_x, tiles_y, marks)
    if marks:  # a map of nothing says nothing: a passed criterion's pictures carry no mark at all
        images["tiles"] = name + "-tiles.png"
        png.write_tile_map(os.path.join(images_dir, images["tiles"]), *solution[:3], tiles_x, tiles_y, marks,
                           strength)
    return images


def failing_tiles(tests, adjusted, alpha, sub, ref):
    """({tile: +1 brighter / -1 darker}, {tile: relative difference of its luminance, capped at 1})
    for the tiles with a failing channel; the sign is the sign of that tile's most significant
    failing channel."""
    marks, best = {}, {}
    for i, test in enumerate(tests):
        if test[3] != "tile" or adjusted[i] >= alpha:
            continue
        tile = test[4] // 3
        if tile not in best or adjusted[i] < best[tile]:
            best[tile] = adjusted[i]
            marks[tile] = 1 if test[5] > 0 else -1
    strength = {}
    for tile in marks:
        a = luminance([sum(row[3 * tile + ch] for row in sub["tile_means"]) / sub["batches"] for ch in range(3)])
        b = luminance([sum(row[3 * tile + ch] for row in ref["tile_means"]) / ref["batches"] for ch in range(3)])
        strength[tile] = min(1.0, abs(a - b) / abs(b)) if b else 1.0
    return marks, strength


def compare_sentence(c, tests, adjusted, alpha, marks, ref, sub, command, seeds):
    """"12 of 16 tiles too dark (mostly in the top left), the image mean 23 % too dark (...)"."""
    nt = ref["tiles_x"] * ref["tiles_y"]
    dark = [t for t, s in marks.items() if s < 0]
    bright = [t for t, s in marks.items() if s > 0]
    parts = []
    for tiles, word in ((dark, "too dark"), (bright, "too bright")):
        if tiles:
            parts.append(f"{len(tiles)} of {nt} tiles {word} ({where_in_image(tiles, ref['tiles_x'], ref['tiles_y'])}, "
                         f"marked {'blue' if word == 'too dark' else 'orange'} in the picture)")
    means = [(i, test) for i, test in enumerate(tests) if test[3] == "mean"]
    a = luminance([test[6] for _, test in means])
    b = luminance([test[7] for _, test in means])
    failed_means = [i for i, _ in means if adjusted[i] < alpha]
    per_channel = ", ".join(f"{lib.CHANNELS[test[4]]} {lib.number(test[6])} vs {lib.number(test[7])} "
                            f"± {test[8]:.2g} ({t_text(test[5])})" for _, test in means)
    mean_text = lib.deviation("image mean", a, b) or "equal"
    if failed_means:
        parts.append(f"the image mean is {mean_text}: {per_channel}")
    noisy = [test for i, test in enumerate(tests) if test[3] == "noise" and adjusted[i] < alpha]
    if noisy:
        parts.append(f"the image mean is noisier than the solution's: its variance over the batches is "
                     f"{max(test[6] for test in noisy):.3g} x the solution's at the same samples (F test)")
    ran = (f"Ran {command} with {len(seeds)} seeds ({seeds[0]}-{seeds[-1]}) against the solution's "
           f"{ref['batches']} renders")
    statistic = (f"{len(tests)} tests: Welch's t per tile and channel and on the image mean, F on its noise, "
                 f"Holm-adjusted, alpha = {alpha:.2g}")
    if parts:
        text = "; ".join(parts)
        return (text[0].upper() + text[1:] + f". {ran}. ({statistic}; smallest adjusted p = {min(adjusted):.2g})")
    within = "equal" if a == b else (f"{lib.percent((a - b) / b) if b else lib.number(a - b)} "
                                     f"{'brighter' if a > b else 'darker'}, within the noise")
    return (f"All {nt} tiles and the image mean agree with the solution's (the image mean {within}: "
            f"{per_channel}). {ran}. ({statistic}; smallest adjusted p = {min(adjusted):.3g})")


def t_text(t):
    """Welch's t as a student reads it; exact renders (no noise) give huge values."""
    return f"t = {t:.1f}" if abs(t) < 1000 else ("t > 1000" if t > 0 else "t < -1000")


def record_compare(tests, adjusted, alpha, marks, nt, command):
    """The image means per channel and the number of differing tiles, into lib.MEASURED."""
    for i, test in enumerate(tests):
        if test[3] == "mean":
            lib.measurement("image mean", test[6], test[7], adjusted[i] >= alpha,
                            f"Welch's t, Holm-adjusted p >= {alpha:.2g} (p = {adjusted[i]:.2g})",
                            where=lib.CHANNELS[test[4]], se=test[8], by="the solution's renders", command=command)
        elif test[3] == "noise":
            lib.measurement("variance of the image mean / the solution's", test[6], 1.0, adjusted[i] >= alpha,
                            f"not larger by the F test, Holm-adjusted p >= {alpha:.2g}", where=lib.CHANNELS[test[4]],
                            command=command, words=("too noisy", "less noisy"))
    lib.measurement("tiles that differ from the solution's", len(marks), 0, not marks, "none", command=command,
                    words=("too many", "too few"))


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
    lib.record_command(c["chapter"], cmd[1:], out)
    run_chapter(root, c, cmd)
    try:
        data = lib.read_json(os.path.join(out, "s.json"))
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
    """Each surface's radiance (R, G, B) within surface_tolerance (relative) of the solution's;
    the message names the surfaces that are off, which way and by how much."""
    with open(reference_path(c)) as f:
        ref = json.load(f)["surfaces"]
    got = surfaces_of(root, build, c)
    command = lib.COMMANDS[-1] if lib.COMMANDS else None
    tol = rub["surface_tolerance"]
    off = []
    for name, r in ref.items():
        if name not in got:
            off.append(f"{name}: missing from the stats")
            lib.expect(False, f"surface {name}: missing from the stats' surfaces", command=command)
            continue
        bad = [ch for ch in range(3) if not (math.isfinite(got[name][ch]) and
                                             abs(got[name][ch] - r[ch]) <= tol * abs(r[ch]) + 1e-6)]
        a, b = luminance(got[name]), luminance(r)
        channels = ", ".join(f"{lib.CHANNELS[ch]} {lib.number(got[name][ch])} vs {lib.number(r[ch])}"
                             for ch in (bad or range(3)))
        lib.measurement("radiance", a, b, not bad, f"± {tol:.1%} per channel", where=f"of surface {name}",
                               by="the solution's", command=command)
        if bad:
            off.append(f"{name} {lib.deviation('radiance', a, b) or 'off in colour'} ({channels})")
    ran = f"ran {command}" if command else ""
    shared = [n for n in ref if n in got and luminance(ref[n])]
    if shared and not off:  # the closest call, for a passed criterion
        n = max(shared, key=lambda n: abs(luminance(got[n]) / luminance(ref[n]) - 1))
        ran = f"the largest difference {lib.percent(luminance(got[n]) / luminance(ref[n]) - 1)} on {n}; " + ran
    if off:
        return (False, None, f"{len(off)} of {len(ref)} surfaces off by more than {tol:.1%}: " + "; ".join(off[:6]) +
                ("; ..." if len(off) > 6 else "") + f". {ran[:1].upper()}{ran[1:]}.", {})
    return True, None, f"All {len(ref)} surfaces within {tol:.1%} of the solution's radiance; {ran}.", {}
