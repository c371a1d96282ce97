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
Held-out variants (kit/heldout/<criterion>.json, instructor-only, never in a handout): the
          same criterion under a camera (compare) or patch size (surfaces) nobody sees in the
          handout, drawn at random by kit/grade.py --make-heldout and stored with the seed that drew
          it and the solution's reference for it.  The instructor's grading grades the held-out
          variant instead of the public one (graded_variant), so a submission that replays the
          public numbers of kit/reference/ (which the handout ships for the student's self-check)
          fails; the cost of a grading is unchanged.
"""
import concurrent.futures
import json
import math
import os
import random
import re
import shutil
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
    """The solution's numbers criterion c is graded against: kit/reference/ (public, in the handout)
    or, for a held-out variant (graded_variant), kit/heldout/."""
    return heldout_path(c) if c.get("heldout") else os.path.join(KIT, "reference", slug(c) + ".json")


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
    try:
        with concurrent.futures.ThreadPoolExecutor(max_workers=max(1, jobs)) as pool:
            futures = [pool.submit(render, root, build, c, s, os.path.join(scratch, f"b{s}.pfm")) for s in seeds]
            images = [f.result() for f in futures]
    finally:  # read into memory: the files are not needed (a calibration renders thousands)
        shutil.rmtree(scratch, ignore_errors=True)
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
    os.makedirs(os.path.dirname(reference_path(c)), exist_ok=True)
    with open(reference_path(c), "w") as f:
        json.dump(reference_data(root, build, c, rub, jobs), f, separators=(",", ":"))


def reference_data(root, build, c, rub, jobs):
    """The solution's reference_batches renders of criterion c, summarised (tile means per batch)."""
    seeds = [REFERENCE_SEED + b for b in range(rub["reference_batches"])]
    data = summarise(batch_renders(root, build, c, seeds, jobs), rub["tile"])
    data.update({"criterion": c["name"], "chapter": c["chapter"], "scene": c["scene"], "args": c.get("args", []),
                 "size": c.get("size"), "spp": c.get("spp"), "seeds": [seeds[0], seeds[-1]]})
    r7 = lambda v: float("%.7g" % v)  # noqa: E731
    data["tile_means"] = [[r7(v) for v in row] for row in data["tile_means"]]
    data["pixel_mean"] = [[r7(v) for v in p] for p in data["pixel_mean"]]
    data["pixel_var"] = [[r7(v) for v in p] for p in data["pixel_var"]]
    return data


def preview_criterion(c):
    """Criterion c as the report's picture renders it: PREVIEW_SIZE square, its samples per pixel
    clamped to PREVIEW_SPP (enough to recognise the scene).  A held-out variant's picture is the
    public camera's: the held-out solution's picture is not shown (it would give its tile means
    away to whoever reads the report)."""
    low, high = PREVIEW_SPP
    c = public_criterion(c)
    return dict(c, size=f"{PREVIEW_SIZE}x{PREVIEW_SIZE}", spp=min(high, max(low, c.get("spp", 1))))


def preview_path(c):
    return os.path.join(KIT, "reference", slug(c) + ".png")


def preview_command(c):
    """The command of the report's picture, as a student reruns it."""
    return lib.command_text(c["chapter"], render_command("", preview_criterion(c), PREVIEW_SEED, "")[1:])


def render_preview(root, build, c, threads):
    """(width, height, 8-bit colours) of one render of criterion c at PREVIEW_SIZE (preview_criterion),
    at most PREVIEW_TIMEOUT seconds; CriterionFailed when it fails."""
    scratch = tempfile.mkdtemp(prefix="gi-kit-")
    try:
        w, h, pixels = render(root, build, preview_criterion(c), PREVIEW_SEED, os.path.join(scratch, "preview.pfm"),
                              threads, PREVIEW_TIMEOUT)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
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
    tests = compare_tests(sub, ref)
    adjusted = stats.holm([test[1] for test in tests])
    alpha = alpha_per_criterion(rub)
    worst = min(range(len(tests)), key=lambda i: adjusted[i])
    failing = [i for i in range(len(tests)) if adjusted[i] < alpha]
    p_value = adjusted[worst]
    marks, strength = failing_tiles(tests, adjusted, alpha, sub, ref)
    message = compare_sentence(c, tests, adjusted, alpha, marks, ref, sub, command, seeds)
    record_compare(tests, adjusted, alpha, marks, ref["tiles_x"] * ref["tiles_y"], command, bool(c.get("heldout")))
    images = write_pictures(root, build, c, jobs, images_dir, ref, sub, marks, strength) if images_dir else {}
    return not failing, p_value, message, images


def compare_tests(sub, ref):
    """The criterion's tests of the submission's summary against the reference's, before Holm:
    [(label, p, detail, kind, index, t, measured, expected, se)]."""
    tests = []
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
    return tests


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
    if c.get("heldout"):
        PREVIEW["grid"] += (f"; the test renders were made from {c['heldout']}, the pictures from the public "
                            "camera: the marks show the same tiles of this view")
    try:
        student = render_preview(root, build, c, jobs)
        PREVIEW["student"] = f"one render: {PREVIEW['command']}"
    except CriterionFailed as e:
        student = (sub["width"], sub["height"], png.tone_mapped(sub["pixel_mean"]))
        PREVIEW["student"] = (f"the {sub['width']}x{sub['height']} test renders' mean (the picture's own render "
                              f"failed: {str(e)[:300]})")
    solution = stored_preview(c)
    if solution is None:
        shown = ref
        if c.get("heldout"):  # the public reference's mean image (the held-out file has none)
            with open(reference_path(public_criterion(c))) as f:
                shown = json.load(f)
        solution = (shown["width"], shown["height"], png.tone_mapped(shown["pixel_mean"]), "")
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
    if c.get("heldout"):  # the held-out solution's numbers stay the instructor's: only which way
        per_channel = ", ".join(f"{lib.CHANNELS[test[4]]} {'darker' if test[6] < test[7] else 'brighter'}"
                                for _, test in means)
        mean_text = "darker" if a < b else "brighter" if a > b else "equal"
    if failed_means:
        parts.append(f"the image mean is {mean_text}: {per_channel}")
    noisy = [test for i, test in enumerate(tests) if test[3] == "noise" and adjusted[i] < alpha]
    if noisy:
        parts.append(f"the image mean is noisier than the solution's: its variance over the batches is "
                     f"{max(test[6] for test in noisy):.3g} x the solution's at the same samples (F test)")
    ran = (f"Ran {command} with {len(seeds)} seeds ({seeds[0]}-{seeds[-1]}) against the solution's "
           f"{ref['batches']} renders" + (f" from {c['heldout']}" if c.get("heldout") else ""))
    statistic = (f"{len(tests)} tests: Welch's t per tile and channel and on the image mean, F on its noise, "
                 f"Holm-adjusted, alpha = {alpha:.2g}")
    if parts:
        text = "; ".join(parts)
        return (text[0].upper() + text[1:] + f". {ran}. ({statistic}; smallest adjusted p = {min(adjusted):.2g})")
    within = "equal" if a == b else (f"{lib.percent((a - b) / b) if b else lib.number(a - b)} "
                                     f"{'brighter' if a > b else 'darker'}, within the noise")
    if c.get("heldout"):
        within = "within the noise"
    return (f"All {nt} tiles and the image mean agree with the solution's (the image mean {within}: "
            f"{per_channel}). {ran}. ({statistic}; smallest adjusted p = {min(adjusted):.3g})")


def t_text(t):
    """Welch's t as a student reads it; exact renders (no noise) give huge values."""
    return f"t = {t:.1f}" if abs(t) < 1000 else ("t > 1000" if t > 0 else "t < -1000")


def record_compare(tests, adjusted, alpha, marks, nt, command, heldout=False):
    """The image means per channel and the number of differing tiles, into lib.MEASURED; for a
    held-out variant the solution's means are not given, only whether they agree."""
    for i, test in enumerate(tests):
        if test[3] == "mean" and heldout:
            word = "agrees" if adjusted[i] >= alpha else "darker" if test[6] < test[7] else "brighter"
            lib.MEASURED.append({"quantity": "image mean", "where": lib.CHANNELS[test[4]], "measured": test[6],
                                 "expected": None, "standard_error": test[8], "allowed": None, "limit": None,
                                 "passed": adjusted[i] >= alpha, "command": command,
                                 "text": f"Image mean {lib.CHANNELS[test[4]]}: measured {lib.number(test[6])} ± "
                                         f"{test[8]:.2g}; against the held-out solution's (not shown): {word}"})
        elif test[3] == "mean":
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
    try:
        run_chapter(root, c, cmd)
        try:
            data = lib.read_json(os.path.join(out, "s.json"))
            surfaces = {s["name"]: s["radiance"] for s in data["surfaces"]}
            converged, residual = data.get("converged"), data.get("residual")
        except (OSError, ValueError, KeyError, TypeError) as e:
            raise CriterionFailed(f"no readable 'surfaces' in the stats: {e}")
    finally:
        shutil.rmtree(out, ignore_errors=True)
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
    if c.get("heldout"):
        ran += f" ({c['heldout']})"
    shared = [n for n in ref if n in got and luminance(ref[n])]
    if shared and not off:  # the closest call, for a passed criterion
        n = max(shared, key=lambda n: abs(luminance(got[n]) / luminance(ref[n]) - 1))
        ran = f"the largest difference {lib.percent(luminance(got[n]) / luminance(ref[n]) - 1)} on {n}; " + ran
    if off:
        return (False, None, f"{len(off)} of {len(ref)} surfaces off by more than {tol:.1%}: " + "; ".join(off[:6]) +
                ("; ..." if len(off) > 6 else "") + f". {ran[:1].upper()}{ran[1:]}.", {})
    return True, None, f"All {len(ref)} surfaces within {tol:.1%} of the solution's radiance; {ran}.", {}


# ---- held-out variants (kit/heldout/: the instructor's only, never in a handout) -----------------------

HELDOUT = os.path.join(KIT, "heldout")
# How far a held-out variant is from its public criterion: far enough that a replay of the public
# numbers fails (most tile means move by many times the test's noise; checked when it is drawn,
# replay_of_public), near enough that it is the same scene seen almost the same way.
# A draw is only rejected when a replay would pass the criterion (never seen): a stricter rule
# (at first, "the replay fails half the tile tests") picks references whose batches happen to
# scatter little, which makes the solution fail the noise test (measured in the instructor's calibration).
EYE_SHIFT = (0.03, 0.05)    # the eye moves this share of its distance to the look point, in a random direction
FOV_CHANGE = (2.0, 4.0)     # degrees, wider or narrower at random
PATCH_FACTOR = (0.8, 0.95)  # radiosity's --patch-size times a random factor in this range
REPLAY_MIN_SURFACES = 1     # a surfaces draw is kept when this many surfaces move by twice the tolerance (exact numbers)
DRAWS = 5                   # draws tried before giving up
RENDER_KEYS = ("scene", "args", "size", "spp", "patch_size", "tol", "iterations")  # what a criterion runs


def heldout_path(c):
    return os.path.join(HELDOUT, slug(c) + ".json")


def render_options(c):
    """The rubric row's options that decide what criterion c runs."""
    return {k: c[k] for k in RENDER_KEYS if k in c}


def graded_variant(c, public=False):
    """Criterion c as the instructor grades it: its held-out variant where kit/heldout/ has one (an
    instructor's tree; a handout has none), with "heldout" (what differs, for the report) and
    "public" (the rubric's options); else c (the public reference).  ValueError when the held-out
    file is unreadable or was made for other options than the rubric row's."""
    if public or c["kind"] not in ("compare", "surfaces") or not os.path.exists(heldout_path(c)):
        return c
    where = os.path.relpath(heldout_path(c), os.path.dirname(KIT))
    try:
        with open(heldout_path(c)) as f:
            data = json.load(f)
        made_for, graded, text = data["public"], data["graded"], data["description"]
    except (OSError, ValueError, KeyError) as e:
        raise ValueError(f"{where}: unreadable ({e}): kit/grade.py --make-heldout makes it again")
    if made_for != render_options(c):
        raise ValueError(f"{where}: made for other options than kit/rubric.json's row '{c['name']}' "
                         f"({json.dumps(made_for)}): kit/grade.py --make-heldout makes it again")
    return dict(c, **graded, heldout=text, public=made_for)


def public_criterion(c):
    """The public criterion of a held-out variant (graded_variant); c itself otherwise."""
    if not c.get("heldout"):
        return c
    return dict({k: v for k, v in c.items() if k not in RENDER_KEYS + ("heldout", "public")}, **c["public"])


def set_option(args, name, value):
    """args with option `name` given `value`: replaced where args has it, else appended."""
    args = list(args)
    if name in args:
        args[args.index(name) + 1] = value
        return args
    return args + [name, value]


def camera_of(root, c):
    """(eye, look, fov) criterion c renders with: its --eye/--look/--fov, else its scene's camera."""
    with open(os.path.join(root, c["scene"])) as f:
        words = next((line.split("#")[0].split()[1:] for line in f if line.split()[:1] == ["camera"]), None)
    if words is None:
        raise ValueError(f"{c['scene']}: no camera statement")
    camera = {key: words[words.index(key) + 1:words.index(key) + 1 + n] for key, n in (("eye", 3), ("look", 3), ("fov", 1))}
    args = c.get("args", [])
    for key in ("eye", "look", "fov"):
        if "--" + key in args:
            camera[key] = args[args.index("--" + key) + 1].split(",")
    return [float(v) for v in camera["eye"]], [float(v) for v in camera["look"]], float(camera["fov"][0])


def draw_variant(root, c, rng):
    """(the options that change, a description for the report, the random choice) of one held-out
    variant of criterion c drawn with rng: another camera (compare) or patch size (surfaces)."""
    if c["kind"] == "surfaces":
        size, factor = c.get("patch_size", 50), rng.uniform(*PATCH_FACTOR)
        new = round(size * factor, 2)
        return ({"patch_size": new}, f"a held-out --patch-size {new:g} (not the handout's {size:g})",
                {"patch_size_factor": round(factor, 4)})
    eye, look, fov = camera_of(root, c)
    direction = [rng.gauss(0.0, 1.0) for _ in range(3)]
    norm = math.sqrt(sum(d * d for d in direction))
    share = rng.uniform(*EYE_SHIFT)
    new_eye = [e + share * math.dist(eye, look) * d / norm for e, d in zip(eye, direction)]
    new_fov = fov + rng.choice((-1.0, 1.0)) * rng.uniform(*FOV_CHANGE)
    args = set_option(c.get("args", []), "--eye", ",".join(f"{v:.6g}" for v in new_eye))
    args = set_option(args, "--fov", f"{new_fov:.6g}")
    return ({"args": args}, f"a held-out camera (not the handout's: the eye moved {share:.1%} of its distance "
                            f"to the look point, fov {new_fov:.4g} instead of {fov:.4g} degrees)",
            {"eye_shift_share": round(share, 4), "eye_shift_direction": [round(d / norm, 4) for d in direction],
             "fov_change_degrees": round(new_fov - fov, 4)})


def replay_of_public(c, public_ref, heldout_ref):
    """How the held-out variant grades a submission that replays the public reference (the handout's
    kit/reference/): {"fails", "share of tile tests failed" or "surfaces off", ...}."""
    with open(os.path.join(KIT, "rubric.json")) as f:  # the alpha kit/criterion.py grades with
        rub = json.load(f)
    if c["kind"] == "surfaces":
        tol = rub["surface_tolerance"]
        off = sorted(name for name, r in heldout_ref["surfaces"].items() if name not in public_ref["surfaces"] or
                     any(abs(p - h) > 2 * tol * abs(h) + 1e-6 for p, h in zip(public_ref["surfaces"][name], r)))
        return {"fails": len(off) >= REPLAY_MIN_SURFACES, "surfaces_off_by_twice_the_tolerance": off,
                "surfaces": len(heldout_ref["surfaces"])}
    mean_row = [sum(column) / len(column) for column in zip(*public_ref["tile_means"])]
    tests = compare_tests({"tile_means": [mean_row] * rub["batches"]}, heldout_ref)
    adjusted = stats.holm([test[1] for test in tests])
    alpha = alpha_per_criterion(rub)
    tile_tests = [i for i, test in enumerate(tests) if test[3] == "tile"]
    failed = sum(1 for i in tile_tests if adjusted[i] < alpha)
    moved = sorted(abs(tests[i][6] - tests[i][7]) / tests[i][8] if tests[i][8] else math.inf for i in tile_tests)
    return {"fails": min(adjusted) < alpha, "tile_tests_failed": failed,
            "tile_tests": len(tile_tests), "smallest_adjusted_p": float("%.3g" % min(adjusted)),
            "median_tile_shift_in_standard_errors": float("%.3g" % moved[len(moved) // 2]), "alpha": alpha}


def make_heldout(root, build, c, rub, jobs, log=print):
    """kit/heldout/<criterion>.json: a held-out variant of compare or surfaces criterion c and the
    solution's reference for it.  Its random seed is the existing file's (re-rendering after the
    solution changed keeps the choice; delete the file to draw anew), else a fresh one; a draw a
    replay of the public reference would pass (replay_of_public) is drawn again.  The public
    reference (kit/reference/) must exist."""
    try:
        with open(heldout_path(c)) as f:
            seed = int(json.load(f)["seed"])
    except (OSError, ValueError, KeyError, TypeError):
        seed = random.SystemRandom().randrange(1 << 32)
    with open(reference_path(c)) as f:
        public_ref = json.load(f)
    rng = random.Random(seed)
    for draw in range(1, DRAWS + 1):
        graded, text, choice = draw_variant(root, c, rng)
        variant = dict(c, **graded, heldout=text, public=render_options(c))
        if c["kind"] == "surfaces":
            data = {"surfaces": surfaces_of(root, build, variant)}
        else:  # without the mean image: a report's fallback picture must not show the held-out one
            data = {k: v for k, v in reference_data(root, build, variant, rub, jobs).items()
                    if k not in ("pixel_mean", "pixel_var")}
        replay = replay_of_public(c, public_ref, data)
        if replay["fails"]:
            break
        log(f"{slug(c)}: draw {draw} rejected, a replay of the public reference would pass it: {replay}")
    else:
        raise RuntimeError(f"{slug(c)}: no held-out variant in {DRAWS} draws that a replay of the public reference fails")
    about = {"criterion": c["name"], "chapter": c["chapter"], "description": text, "public": render_options(c),
             "graded": graded, "seed": seed, "draw": draw, "choice": choice, "replay_of_public": replay,
             "made_by": "kit/grade.py --make-heldout (compare.make_heldout: random.Random(seed), draw number 'draw')"}
    os.makedirs(HELDOUT, exist_ok=True)
    with open(heldout_path(c), "w") as f:
        json.dump(dict(about, **{k: v for k, v in data.items() if k not in about}), f, separators=(",", ":"))
    return about
