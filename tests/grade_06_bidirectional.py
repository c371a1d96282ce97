"""Grading chapter 6 (bidirectional methods) against closed forms and the other methods.

Truth comes from outside the chapter: the furnace (L = Le / (1 - rho), and Le rho^k for the
term K^k E), the path tracer (chapter 4: every strategy's image must agree with it, unweighted
and weighted), radiosity (chapter 3) on a diffuse scene, chapter 5's progressive photon mapping
(what --connect off must equal in expectation, blur and all), and the chapter's own --check
(on random paths, the weights of all strategies add to 1, and each join carries the path
integral's integrand over the density that (R14) says it was drawn with).

Standard errors.  Pixels of one render are not independent (light tracing adds a light path to
any pixel; merging reads every light vertex of the pass), so image statistics come from R
renders with different seeds: the standard error of their mean is their spread over sqrt(R),
with R - 1 degrees of freedom.  A comparison of two methods adds the two squared standard errors
and keeps the smaller degrees of freedom.  Tolerances are t_bound(df, m) standard errors: the
Student's t quantile at CRITERION_ALPHA / m for the m comparisons of a test.  Each test also asks
for its standard errors to be small, so that a tolerance cannot hide a real error.

Image comparisons are over tiles of the image (2 x 2 or 4 x 4 of them, each channel).  Probes and
per-surface means (a sensor in the camera's place, sensor_sample) come with the chapter's own
standard errors, from 32 independent batches (walk_stats.h), as chapter 4's.
"""
import math
import os

import lib

from lib import furnace_scene  # the furnace of scenes/furnace-pt.scene with Le and rho
from lib import BATCH_DF, ROOT, check_bad_input, check_thread_independence, finite_image, probe, t_bound
from lib import CHANNELS, expect, expect_at_most, expect_estimate

GRADES_NOTHING = True  # no grading, no handout: may run beside the RUN_ALONE tests (tests/run.py)

CHAPTER = "06_bidirectional"
RENDERS = 32  # seeds behind every image mean: 31 degrees of freedom


# An open stage: a floor, a back wall 0.3 above it, a light above both, nothing touching.  An
# unweighted join of two surface points (G ~ 1 / d^2) has infinite variance where surfaces meet (a
# room's corners); here d is bounded below, so every single strategy has a finite variance, and the
# light is large enough for the strategies (0, t) (the eye subpath hits it by chance).
STAGE = """\
camera eye 0 1.2 -4  look 0 0.8 1  up 0 1 0  fov 50
background 0 0 0
material white diffuse 0.8 0.8 0.8
material red diffuse 0.8 0.3 0.2
material light emitter 4 4 4
quad floor white  -2 0 -2  -2 0 2  2 0 2  2 0 -2
quad back red  2 0.3 2  -2 0.3 2  -2 2.3 2  2 2.3 2
quad light light  -0.75 2.5 -0.75  0.75 2.5 -0.75  0.75 2.5 0.75  -0.75 2.5 0.75
"""


def mean_and_error(values):
    n = len(values)
    m = sum(values) / n
    return m, math.sqrt(sum((v - m) ** 2 for v in values) / (n - 1) / n)


def tile_values(img, tiles):
    """{(tile x, tile y, channel): mean} over a tiles x tiles grid of the image."""
    w, h = img.width // tiles, img.height // tiles
    out = {}
    for ty in range(tiles):
        for tx in range(tiles):
            pixels = [img.at(x, y) for y in range(ty * h, (ty + 1) * h) for x in range(tx * w, (tx + 1) * w)]
            for c in range(3):
                out[(tx, ty, c)] = sum(p[c] for p in pixels) / len(pixels)
    return out


def tile_estimates(ctx, chapter, scene, args, name, renders=RENDERS, tiles=2):
    """{tile: (mean, standard error)} over `renders` seeds; and the first image's command.  One thread:
    the renders are small, and an image does not depend on the thread count (a test checks it)."""
    images = [ctx.render(chapter, scene, "--seed", 100 + i, "--threads", 1, *args, name=f"{name}{i}")[0]
              for i in range(renders)]
    for img in images:
        expect(finite_image(img), f"{chapter} {' '.join(map(str, args))}: the image has non-finite pixels",
               command=img.command)
    per = [tile_values(img, tiles) for img in images]
    return {key: mean_and_error([p[key] for p in per]) for key in per[0]}, images[0].command


def channel_means(tiles):
    """The image's mean per channel, from the tile means of tile_values or tile_estimates."""
    value = {key: v[0] if isinstance(v, tuple) else v for key, v in tiles.items()}
    return [sum(v for (tx, ty, c), v in value.items() if c == channel) / (len(value) // 3) for channel in range(3)]


def sanitizers_run_once(ctx, scene, runs):
    """Under the sanitizers (lib.sanitizer_build) a statistics test renders each of its runs (chapter,
    args) once at 8 x 8 and 1 sample per pixel (unless args say more) and checks it finite: its code
    runs under ASan and UBSan, its statistics in the plain pass only.  False in the plain pass."""
    if not lib.sanitizer_build(ctx):
        return False
    for chapter, args in runs:
        img, stats = ctx.render(chapter, scene, "--size", "8x8", "--spp", 1, *args, name="sanitized")
        expect(finite_image(img) and stats["nonfinite_samples"] == 0,
               f"{chapter} {' '.join(map(str, args))}: non-finite pixels or samples", command=img.command)
    return True


def expect_tiles_agree(quantity, got, reference, comparisons, by, max_relative_se, command, df=RENDERS - 1):
    """Each tile mean of `got` within t_bound(df, comparisons) combined standard errors of `reference`'s,
    each standard error below max_relative_se of the image's mean in that channel."""
    bound, scale = t_bound(df, comparisons), channel_means(reference)
    for key, (mean, se) in got.items():
        ref_mean, ref_se = reference[key]
        tx, ty, c = key
        expect_estimate(quantity, mean, ref_mean, math.hypot(se, ref_se), bound, max_relative_se * scale[c],
                        where=f"in tile ({tx}, {ty}), {CHANNELS[c]}", by=by, command=command)


# ---- bad input ----------------------------------------------------------------------------------

def test_bad_options_exit_2(ctx):
    """Values out of range: one argv:N line, exit 2, no output."""
    for args in (["--method", "photon"], ["--merge", "maybe"], ["--connect"], ["--strategy", "1"],
                 ["--strategy", "-1,2"], ["--strategy", "1,2,3"], ["--strategy", "0,1"], ["--strategy", "1,99"],
                 ["--radius", "0"], ["--radius", "nan"], ["--alpha", "0"], ["--alpha", "1.5"], ["--check", "-1"],
                 ["--bounces", "3:2"]):
        check_bad_input(ctx, CHAPTER, ["scenes/cornell.scene", "--size", "8x8", *args])


def test_pinhole_and_specular_are_explained_not_nan(ctx):
    """The camera is a pinhole: strategy (s, 0), a light path hitting it by chance, cannot happen.
    --strategy 2,0 says so in a warning and renders black (not NaN); light tracing alone says it
    cannot see mirrors and glass."""
    img, stats = ctx.render(CHAPTER, "scenes/cornell.scene", "--size", "8x8", "--spp", 2, "--strategy", "2,0")
    expect(finite_image(img) and max(max(p) for p in img.pixels) == 0.0 and stats["nonfinite_samples"] == 0,
           "--strategy 2,0 (a light path that hits the pinhole): expected a black, finite image")
    r = ctx.run(CHAPTER, "scenes/cornell.scene", "--size", "8x8", "--spp", 1, "--strategy", "2,0", "--quiet",
                "--out", ctx.path("s20.pfm"))
    expect("pinhole" in r.stderr and "warning" in r.stderr,
           f"--strategy 2,0: expected a warning that names the pinhole camera, got {r.stderr.strip()!r}")
    r = ctx.run(CHAPTER, "scenes/cornell-spheres.scene", "--size", "8x8", "--spp", 1, "--method", "light",
                "--quiet", "--out", ctx.path("light.pfm"))
    expect("mirror" in r.stderr and "warning" in r.stderr,
           f"--method light on a scene with a mirror: expected a warning, got {r.stderr.strip()!r}")


# ---- the furnace ------------------------------------------------------------------------------

def test_furnace_every_method(ctx):
    """The furnace with rho = 0.5, Le = 1: L = 2 everywhere, and the term K^2 E alone (--bounces 2:2)
    is 0.25.  Light tracing, BDPT, VCM and --connect off (progressive photon mapping: merging at the
    first eye vertex only, exact in the furnace, where the light is uniform, on the central half of
    the image, more than the radius from the walls' edges).  Image means over RENDERS seeds (the
    central half), within t_bound(RENDERS - 1, 5) standard errors of the closed form, each below
    1 %.  Not VCM with a large radius: before facdd27 it merged at every eye vertex, near the cube's edges too,
    where a disc of radius 0.4 reaches past the wall (merging there carries half of the light, and
    the image read 2.5 % dark, 5.3 standard errors, for grading seed 608)."""
    scene = furnace_scene(ctx, 0.5)
    cases = [("light", ["--method", "light", "--spp", 48], 2.0), ("bdpt", ["--method", "bdpt"], 2.0),
             ("vcm", [], 2.0), ("ppm", ["--connect", "off", "--radius", 0.4, "--spp", 8], 2.0),
             ("bdpt 2:2", ["--method", "bdpt", "--bounces", "2:2", "--spp", 12], 0.25)]
    if sanitizers_run_once(ctx, scene, [(CHAPTER, args + ["--spp", 1]) for _, args, _ in cases]):
        return
    bound = t_bound(RENDERS - 1, len(cases))
    for label, args, expected in cases:
        values = []
        for i in range(RENDERS):
            img, stats = ctx.render(CHAPTER, scene, "--size", "16x16", "--spp", 4, "--seed", 10 + i, "--threads", 1,
                                    *args,
                                    name=f"f{i}")
            centre = [img.at(x, y)[0] for y in range(4, 12) for x in range(4, 12)]
            values.append(sum(centre) / len(centre))
        mean, se = mean_and_error(values)
        expect_estimate("furnace radiance (central half)", mean, expected, se, bound, 0.01 * expected,
                        where=f"by {label}", by="Le rho^k summed over the kept terms (R6)", command=img.command)


# ---- the chapter's self-check: weights add to 1, densities are the samplers' -------------------------

def test_weights_add_to_one_and_densities_match_sampling(ctx):
    """--check N draws N pairs of subpaths (no Russian roulette, so a subpath's weight is exactly the
    product of f cos / p) and makes every join (s, t).  For each, the power-heuristic weights of all
    the strategies the method has for that path must add to 1 (|sum - 1| < 1e-9), and its value must
    be the path integral's integrand over the density (R14) gives it (|C p / f - 1| < 1e-4; paths
    through mirrors or glass are skipped there, f being a delta).  The Cornell box (diffuse), the
    point light with the Phong floor, the spheres (mirror, glass); each method's set of strategies.
    There no density or integrand may leave a double's normal range (out_of_range: counted, not
    compared).  The gap scene, in millimetres and without --bounces, has subpaths of up to 64
    vertices whose densities and integrands underflow (G ~ 1e-6 / mm^2 an edge): those are
    counted, the rest compared (before, the subnormal ones gave |C p / f - 1| up to 0.015 or inf)."""
    runs = [("scenes/cornell.scene", ["--bounces", "0:5", "--check", 1500]),
            ("scenes/cornell-point.scene", ["--bounces", "0:5", "--check", 1500]),
            ("scenes/cornell-spheres.scene", ["--bounces", "0:5", "--check", 1500]),
            ("scenes/cornell-spheres.scene", ["--bounces", "0:5", "--check", 1500, "--method", "bdpt"]),
            ("scenes/cornell.scene", ["--bounces", "0:5", "--check", 1500, "--method", "light"]),
            ("scenes/gap.scene", ["--check", 200, "--seed", 2])]  # its joins compared per path vary widely: at
    # --check 80 the kit's calibration saw 920 and 948 of them for two grading seeds in 29 (below the 1000 asked)
    for scene, args in runs:
        _, stats = ctx.render(CHAPTER, scene, "--size", "16x16", "--spp", 1, *args, name="check")
        check = stats["check"]
        where = f"on {os.path.basename(scene)} {' '.join(map(str, args))}"
        compared = check["connections"] - check["out_of_range"]
        expect(compared > 1000, f"{where}: {compared} joins compared ({check['connections']} tested, "
                                f"{check['out_of_range']} out of range), expected more than 1000")
        if "gap" not in scene:
            expect(check["out_of_range"] == 0, f"{where}: {check['out_of_range']} joins with a density or integrand "
                                               "out of a double's normal range, expected none (metres, <= 6 edges)")
        expect_at_most("largest |sum of the weights - 1|", check["worst_weight_sum_error"], 1e-9, where=where,
                       by="1e-9: the weights of a path over all strategies add to 1 (R15)")
        expect_at_most("largest |C p / f - 1|", check["worst_f_over_p_error"], 1e-4, where=where,
                       by="1e-4: a join carries (R13)'s integrand over (R14)'s density")


# ---- agreement with the other methods -----------------------------------------------------------

def test_agrees_with_path_tracing_on_cornell_box(ctx):
    """scenes/cornell.scene against chapter 4 (MIS), by the chapters' own error bars (32 batch means,
    31 degrees of freedom).  The probes: the chapter puts a sensor at the probe in the camera's
    place (sensor_sample) and joins light subpaths to eye subpaths from it, by --method light (a
    light subpath's vertices joined to the probe) and bdpt (every join, weighted by the power
    heuristic; vcm's probes are bdpt's: one light subpath per sample is no density estimate).  Light
    tracing skips floor_center: it stands 12 mm from the tall block's foot, and a light vertex on
    the block beside it joins with G ~ 1 / d^2, a tail too heavy for 32 batches to measure (2.6 %
    where bdpt has 0.3 %).  The per-surface mean radiances ("surfaces", --surface-samples) by bdpt
    only (light tracing's joins to points near a room's corners have no finite variance).  Each
    within t_bound(31, m) combined standard errors (m = all comparisons), each standard error below
    1 % of the probe's value, and for a surface below 4 % of the surfaces' mean radiance in that
    channel or 1 % of its own, the larger (the tall block's lit top is 5 times the mean).  Then
    VCM's image (whose merging these do not use): the means of 2 x 2 tiles (each channel) over
    RENDERS seeds against chapter 4's, within t_bound(RENDERS - 1, 12) combined standard errors,
    each below 4 % of the image's mean; merging is biased by its radius, but weighted against the
    joins it is a small part of a diffuse scene."""
    scene, size = "scenes/cornell.scene", ["--size", "4x4", "--spp", 1, "--probe-samples", 1 << 16]
    if lib.sanitizer_build(ctx):  # statistics the sanitizers make slow: the sensor's code runs, few samples
        for method in ("light", "bdpt", "vcm"):
            _, stats = ctx.render(CHAPTER, scene, "--size", "4x4", "--spp", 1, "--probe-samples", 256,
                                  "--surface-samples", 64, "--method", method, name="few")
            values = [v for p in stats["probes"] for v in p["irradiance"] + p["standard_error"]]
            values += [v for s in stats["surfaces"] for v in s["radiance"] + s["standard_error"]]
            finite = all(isinstance(v, (int, float)) and math.isfinite(v) for v in values)
            expect(finite and len(stats["surfaces"]) == 17,
                   f"--method {method}: probes and surfaces not all finite, or not 17 surfaces")
        return
    _, reference = ctx.render("04_pathtrace", scene, *size, "--surface-samples", 8192, name="pt")
    light_image, light = ctx.render(CHAPTER, scene, *size, "--method", "light", name="light")
    bdpt_image, bdpt = ctx.render(CHAPTER, scene, *size, "--method", "bdpt", "--surface-samples", 8192, name="bdpt")
    surfaces = {s["name"]: s for s in reference["surfaces"]}
    expect(sorted(surfaces) == sorted(s["name"] for s in bdpt.get("surfaces", [])),
           f"surfaces of the Cornell box: chapter 6 {sorted(s['name'] for s in bdpt.get('surfaces', []))}, "
           f"chapter 4 {sorted(surfaces)}: expected the same", command=bdpt_image.command)
    bound = t_bound(BATCH_DF, 3 * (2 * len(reference["probes"]) - 1 + len(surfaces)))
    scale = [sum(s["radiance"][c] for s in surfaces.values() if s["name"] != "light") / (len(surfaces) - 1)
             for c in range(3)]
    for method, stats, command in (("light", light, light_image.command), ("bdpt", bdpt, bdpt_image.command)):
        for p in reference["probes"]:
            if method == "light" and p["name"] == "floor_center":
                continue
            got = probe(stats, p["name"])
            for c in range(3):
                expect_estimate("irradiance", got["irradiance"][c], p["irradiance"][c],
                                math.hypot(got["standard_error"][c], p["standard_error"][c]), bound,
                                0.01 * p["irradiance"][c], where=f"at probe {p['name']} by --method {method}, "
                                f"{CHANNELS[c]}", by="chapter 4's walks from the probe (both errors combined)",
                                positive=True, command=command)
    for s in bdpt["surfaces"]:
        ref = surfaces[s["name"]]
        for c in range(3):
            expect_estimate("mean radiance", s["radiance"][c], ref["radiance"][c],
                            math.hypot(s["standard_error"][c], ref["standard_error"][c]), bound,
                            max(0.04 * scale[c], 0.01 * ref["radiance"][c]),
                            where=f"of surface {s['name']} by --method bdpt, {CHANNELS[c]}",
                            by="chapter 4's surface mean (both errors combined)", command=bdpt_image.command)
    reference, _ = tile_estimates(ctx, "04_pathtrace", scene, ["--size", "16x16", "--spp", 64,
                                                               "--probe-samples", 32], "pt")
    got, command = tile_estimates(ctx, CHAPTER, scene, ["--size", "16x16", "--spp", 8, "--probe-samples", 32], "vcm")
    expect_tiles_agree("mean radiance by --method vcm", got, reference, 12, "chapter 4's (MIS)", 0.04, command)


def test_agrees_with_radiosity_on_diffuse_box(ctx):
    """A diffuse room (the Cornell box without its blocks, 16 x 16): BDPT's tile means (4 x 4 tiles,
    RENDERS seeds) against build/03_radiosity's image at 60 and 30 mm patches, both --bounces 1:
    (the light seen directly would compare the two images' antialiasing of its edges, not the light
    transport).  The bound is grade_04's: radiosity's discretisation error at 30 mm is at most
    2 |I_60 - I_30| per tile, plus t_bound(RENDERS - 1, 48) standard errors of BDPT's mean (each
    below 4 % of the image's mean).  Radiosity's images take 256 samples per pixel: a pixel is the
    mean over its square, and at 4 samples their jitter alone moved a tile by 5 % from seed to seed
    (0.0213 and 0.0227 for one tile whose 256-sample mean is 0.0206)."""
    text = open(os.path.join(ROOT, "scenes", "cornell.scene")).read()
    room = ctx.write("room.scene", "\n".join(line for line in text.splitlines()
                                             if not line.startswith(("quad short", "quad tall", "probe"))) + "\n")
    if sanitizers_run_once(ctx, room, [(CHAPTER, ["--method", "bdpt", "--bounces", "1:"])]):
        return
    radiosity = {}
    for h in (60, 30):
        img, _ = ctx.render("03_radiosity", room, "--size", "16x16", "--spp", 256, "--bounces", "1:", "--patch-size",
                            h, "--tol", "1e-7", "--iterations", 10000, name=f"radiosity{h}")
        radiosity[h] = tile_values(img, 4)
    got, command = tile_estimates(ctx, CHAPTER, room, ["--size", "16x16", "--spp", 8, "--method", "bdpt",
                                                       "--bounces", "1:"], "bd", tiles=4)
    bound, scale = t_bound(RENDERS - 1, 48), channel_means(radiosity[30])
    for key, (mean, se) in got.items():
        r25, r50 = radiosity[30][key], radiosity[60][key]
        tx, ty, c = key
        expect_estimate("mean radiance", mean, r25, se, bound + 2 * abs(r50 - r25) / max(se, 1e-12),
                        0.04 * scale[c], where=f"in tile ({tx}, {ty}), {CHANNELS[c]}",
                        by=f"radiosity at 30 mm patches (60 mm: {r50:.5g}), within twice their difference + "
                           f"{bound:.2f} standard errors", command=command)


def test_each_strategy_alone_is_unbiased(ctx):
    """A path of k edges is the term K^(k-1) E.  For k = 3 every strategy (s, t) with s + t = 4, each
    alone and unweighted (--strategy s,t), is an unbiased estimate of it: its 2 x 2 tile means agree
    with chapter 4's --bounces 2:2 (STAGE, RENDERS seeds each), within t_bound(RENDERS - 1, 84)
    combined standard errors (7 strategies, 12 tile means each), each below 6 % of the image's mean.
    And k = 2 for (0, 3), (1, 2), (2, 1) against --bounces 1:1."""
    scene = ctx.write("stage.scene", STAGE)
    # (2, 2) at 16 samples a pixel: at 8 its standard error passed the 6 % guard for 2 grading seeds in 29 (the
    # kit's calibration: 2 % and 9 % over it).
    every = ((3, ((0, 4), (1, 3), (2, 2), (3, 1)), (256, 8, 16, 8)), (2, ((0, 3), (1, 2), (2, 1)), (64, 8, 8)))
    if sanitizers_run_once(ctx, scene, [(CHAPTER, ["--bounces", f"{k - 1}:{k - 1}", "--strategy", f"{s},{t}"])
                                        for k, strategies, _ in every for s, t in strategies]):
        return
    for k, strategies, spp in every:
        window = f"{k - 1}:{k - 1}"
        reference, _ = tile_estimates(ctx, "04_pathtrace", scene, ["--size", "16x16", "--spp", 64, "--bounces",
                                                                   window, "--probe-samples", 32], f"pt{k}-")
        for (s, t), n in zip(strategies, spp):
            got, command = tile_estimates(ctx, CHAPTER, scene, ["--size", "16x16", "--spp", n, "--bounces", window,
                                                                "--strategy", f"{s},{t}"], f"s{s}t{t}-")
            expect_tiles_agree(f"mean radiance of strategy ({s},{t}) alone", got, reference, 84,
                               f"chapter 4's --bounces {window} (the same term K^{k - 1} E)", 0.06, command)


def test_merge_off_is_bdpt_and_connect_off_is_progressive_photon_mapping(ctx):
    """--method vcm --merge off is BDPT: the same image, byte for byte.  --connect off is chapter 5's
    --maps global (progressive photon mapping: the same photons per pass, one per pixel, the same
    radius and alpha, so the same blur): on cornell-spheres (caustics) their 2 x 2 tile means over
    RENDERS seeds agree within t_bound(RENDERS - 1, 12) combined standard errors, each below 5 %."""
    outputs = []
    for args in (["--method", "bdpt"], ["--merge", "off"]):
        pfm = ctx.path("same.pfm")
        r = ctx.run(CHAPTER, "scenes/cornell-spheres.scene", "--size", "12x12", "--spp", 2, "--quiet", "--out", pfm,
                    *args)
        expect(r.returncode == 0, f"{CHAPTER} {' '.join(args)}: exit {r.returncode}: {r.stderr.strip()}")
        with open(pfm, "rb") as f:
            outputs.append(f.read())
    expect(outputs[0] == outputs[1], "--merge off and --method bdpt gave different images; expected the same bytes")
    scene, common = "scenes/cornell-spheres.scene", ["--size", "32x32", "--spp", 4, "--radius", 15, "--alpha", 0.7]
    if sanitizers_run_once(ctx, scene, [(CHAPTER, ["--connect", "off", "--radius", 15])]):
        return
    reference, _ = tile_estimates(ctx, "05_photonmap", scene, common + ["--maps", "global", "--photons", 1024,
                                                                       "--probe-photons", 32], "pm")
    got, command = tile_estimates(ctx, CHAPTER, scene, common + ["--connect", "off"], "ppm")
    expect_tiles_agree("mean radiance by --connect off", got, reference, 12, "chapter 5's --maps global", 0.05,
                       command)


# ---- plumbing -----------------------------------------------------------------------------------

def test_threads_give_identical_bytes(ctx):
    """Light subpaths are stored and added in a fixed order: the image does not depend on the thread count."""
    check_thread_independence(ctx, CHAPTER, "scenes/cornell-spheres.scene", "--size", "24x24", "--spp", 3)


def test_extreme_scales_stay_finite(ctx):
    """The Cornell box scaled by 1e-60 and 1e60 (densities per unit area of 1e120 and 1e-120): every
    pixel finite, no sample rejected as non-finite, and the image mean within 1 % of the box's at
    scale 1 with the same seed (the same paths)."""
    text = open(os.path.join(ROOT, "scenes", "cornell.scene")).read().splitlines()

    def scaled(line, factor):
        """Positions times factor: a quad's or triangle's numbers, a probe's, the camera's eye and look."""
        words, out, last = line.split(), [], ""
        for i, w in enumerate(words):
            scale = i >= {"quad": 3, "triangle": 3, "probe": 2}.get(words[0], 1 << 30) or last in ("eye", "look")
            try:
                out.append(repr(float(w) * factor) if scale else w)
            except ValueError:
                out.append(w)
            last = w if not w[-1].isdigit() else last
        return " ".join(out)

    means = {}
    for factor in (1.0, 1e-60, 1e60):
        scene = ctx.write(f"scaled{factor:g}.scene", "\n".join(scaled(line, factor) for line in text) + "\n")
        img, stats = ctx.render(CHAPTER, scene, "--size", "12x12", "--spp", 4, "--radius", 5 * factor,
                                name="scaled")
        expect(finite_image(img) and stats["nonfinite_samples"] == 0,
               f"the Cornell box scaled by {factor:g}: non-finite pixels or samples", command=img.command)
        means[factor] = sum(p[0] for p in img.pixels) / len(img.pixels)
    for factor in (1e-60, 1e60):
        expect(abs(means[factor] - means[1.0]) <= 0.01 * means[1.0],
               f"image mean of the Cornell box scaled by {factor:g}: {means[factor]:.6g}, expected "
               f"{means[1.0]:.6g} (scale 1) within 1 %")
