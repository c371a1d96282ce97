"""Grading chapter 4 (path tracing) against closed forms and other methods.

Truth comes from outside the path tracer: the furnace (a closed room of
emitting diffuse walls, where the Neumann series (R6) is a geometric series
with sum Le / (1 - rho)), Lambert's polygon formula for the irradiance under
a rectangular light, the inverse-square law (R1), the radiosity chapter on
the diffuse Cornell box, and statistics (every estimator has the same
expectation; the error falls like N^-1/2).

Monte Carlo tolerances of the graded tests (kit/rubric.json) are
t_bound(df, m) estimated standard errors (tests/lib.py): Student's t quantile
for the degrees of freedom of the standard error, at CRITERION_ALPHA / m for
the m comparisons of the test, so a correct chapter fails one in at most
CRITERION_ALPHA of the grading seeds (the instructor's calibration measures it).  The
tests only `make test` runs keep a flat four standard errors (their seeds are
fixed).  Each test says where its standard error comes from.  Two
standard-error estimators are used:
  * iid pixels: in the furnace every pixel has the same expectation, so the
    pixel values are independent draws of one distribution and the sample
    standard deviation over pixels / sqrt(P) is the error of their mean;
  * paired pixels: to compare two renders A and B of a scene whose pixels
    differ in expectation, d_p = A_p - B_p are independent across pixels
    (each pixel has its own random streams) and have mean 0 if A and B agree,
    so the mean of d has variance sum(Var d_p) / P^2, estimated by
    sum(d_p^2) / P^2.
Each test also demands that its standard error is small (relative to the
answer) so the tolerance cannot hide a real error.
"""
import math
import os

from lib import furnace_scene  # the furnace of scenes/furnace-pt.scene with Le and rho
from lib import (BATCH_DF, ROOT, check_bad_input, check_probes_match_lambert, check_thread_independence,
                 finite_image, kit_stats, probe, radiosity_surfaces, read_pfm, t_bound)

from lib import expect_estimate, expect_surfaces_match_radiosity  # the report's sentences
from lib import CHANNELS, expect, expect_close, lambert_polygon_irradiance  # several lights, MIS
from lib import expect_at_least, expect_image  # the report's sentences

GRADES_NOTHING = True  # no grading, no handout: may run beside the RUN_ALONE tests (tests/run.py)

CHAPTER = "04_pathtrace"
ESTIMATORS = ("hemisphere", "cosine", "light", "mis")


def iid_mean(img, channel=0):
    """Mean over pixels and its standard error from the pixel sample variance."""
    values = [p[channel] for p in img.pixels]
    n = len(values)
    mean = sum(values) / n
    variance = sum((v - mean) ** 2 for v in values) / (n - 1)
    return mean, math.sqrt(variance / n)


def paired_difference(a, b, channel):
    """Mean of A - B over pixels and its standard error sqrt(sum d^2) / P (see the module docstring)."""
    d = [pa[channel] - pb[channel] for pa, pb in zip(a.pixels, b.pixels)]
    return sum(d) / len(d), math.sqrt(sum(x * x for x in d)) / len(d)


def image_mean(img, channel):
    return sum(p[channel] for p in img.pixels) / len(img.pixels)


# ---- the furnace -----------------------------------------------------------------------------

def test_furnace_converges_to_Le_over_1_minus_rho(ctx):
    """Closed box of walls emitting Le = 1 with albedo rho: L = Le / (1 - rho) at every
    pixel, E = pi L at the probe.  rho = 0.99 needs walks of ~100 bounces: Russian
    roulette must keep them (--max-depth 100000 so nothing is cut; the stats must say so).
    Standard errors: iid pixels for the image, 32 batch means for the probe.
    Estimators: mis and cosine for every rho; hemisphere only for rho = 0.5 -- with
    uniform directions the per-bounce weight 2 rho cos(theta) has E[w^2] = 4 rho^2 / 3 > 1
    for rho > 0.87, so its variance is infinite there and no standard error means
    anything (light sampling alone has the same problem at the box's edges, where G of
    R8 is unbounded; it is tested on the Cornell box and under a rectangle instead).
    Tolerances: t_bound over the 14 comparisons (7 renders, image and probe), with the
    degrees of freedom of the pixels (1023) and of the probe's batch means (31)."""
    renders = 7
    for rho in (0.5, 0.9, 0.99):
        expected = 1.0 / (1.0 - rho)
        scene = furnace_scene(ctx, rho, name=f"furnace{rho}")
        for estimator in ("mis", "cosine") + (("hemisphere",) if rho == 0.5 else ()):
            img, stats = ctx.render(CHAPTER, scene, "--size", "32x32", "--spp", 16, "--max-depth", 100000,
                                    "--estimator", estimator, "--probe-samples", 8192, name=f"f{rho}{estimator}")
            expect(stats["nonfinite_samples"] == 0 and stats["truncated_paths"] == 0 and
                   stats["biased_by_max_depth"] is False,
                   f"the furnace (albedo {rho}, --estimator {estimator}, --max-depth 100000): "
                   f"{stats['nonfinite_samples']} non-finite samples, {stats['truncated_paths']} walks cut, "
                   f"biased_by_max_depth {stats['biased_by_max_depth']}; expected 0, 0 and false (Russian roulette "
                   "ends the walks, not the depth limit)", command=img.command)
            mean, se = iid_mean(img)
            bound = t_bound(len(img.pixels) - 1, 2 * renders)
            expect_estimate("mean radiance", mean, expected, se, bound, 0.01 * expected,
                            where=f"of the furnace (albedo {rho}, --estimator {estimator})", by="Le / (1 - rho)")
            p = probe(stats, "floor_centre")
            e, e_se = p["irradiance"][0], p["standard_error"][0]
            bound = t_bound(BATCH_DF, 2 * renders)
            expect_estimate("irradiance", e, math.pi * expected, e_se, bound, 0.02 * math.pi * expected,
                            where=f"at the furnace's floor probe (albedo {rho}, --estimator {estimator})",
                            by="pi Le / (1 - rho)", positive=True)


def test_furnace_neumann_partial_sums(ctx):
    """--bounces 0:k keeps E + KE + ... + K^k E = Le (1 + rho + ... + rho^k) in the furnace,
    and k:k the single term Le rho^k.  0:0 is exact (every pixel sees Le); the
    others within t_bound standard errors of the pixel mean (iid pixels, 1023 degrees of
    freedom; 18 comparisons: 6 windows, 3 estimators)."""
    rho = 0.5
    scene = furnace_scene(ctx, rho)
    img, _ = ctx.render(CHAPTER, scene, "--size", "16x16", "--spp", 4, "--bounces", "0:0", name="b00")
    expect_image("radiance", img, lambda x, y, c: 1.0, tol=0, where="of the furnace with --bounces 0:0",
                 by="exactly the emission Le = 1 (the term E)")
    for window, expected in (("0:1", 1 + rho), ("0:2", 1 + rho + rho ** 2), ("0:5", (1 - rho ** 6) / (1 - rho)),
                             ("1:1", rho), ("3:3", rho ** 3), ("2:", rho ** 2 / (1 - rho))):
        for estimator in ("mis", "cosine", "hemisphere"):
            img, stats = ctx.render(CHAPTER, scene, "--size", "32x32", "--spp", 128, "--bounces", window,
                                    "--estimator", estimator, "--probe-samples", 32, name=f"b{estimator}")
            mean, se = iid_mean(img)
            bound = t_bound(len(img.pixels) - 1, 18)
            expect_estimate("mean radiance", mean, expected, se, bound, 0.01 * expected,
                            where=f"of the furnace with --bounces {window} --estimator {estimator}",
                            by="the Neumann partial sum Le (rho^a + ... + rho^b)")


def test_max_depth_cuts_and_says_so(ctx):
    """--max-depth 3 cuts every walk after 3 bounces: the furnace then shows exactly the
    partial sum Le (1 + rho + rho^2 + rho^3) (biased low; t_bound standard errors of the
    pixel mean, 1023 degrees of freedom), and the stats must report the cut walks."""
    rho = 0.9
    scene = furnace_scene(ctx, rho)
    img, stats = ctx.render(CHAPTER, scene, "--size", "32x32", "--spp", 16, "--max-depth", 3,
                            "--probe-samples", 32)
    expected = 1 + rho + rho ** 2 + rho ** 3
    mean, se = iid_mean(img)
    expect_estimate("mean radiance", mean, expected, se, t_bound(len(img.pixels) - 1), 0.01 * expected,
                    where="of the furnace (albedo 0.9) with --max-depth 3", by="Le (1 + rho + rho^2 + rho^3)")
    expect(stats["truncated_paths"] > 0 and stats["biased_by_max_depth"] is True,
           f"the stats with --max-depth 3: {stats['truncated_paths']} walks cut, biased_by_max_depth "
           f"{stats['biased_by_max_depth']}; expected walks cut and true (the cut was not reported)", command=img.command)
    r = ctx.run(CHAPTER, scene, "--quiet", "--size", "8x8", "--spp", 1, "--max-depth", 2, "--out", ctx.path("m.pfm"))
    expect(r.returncode == 0 and "max-depth" in r.stderr,
           f"exit status {r.returncode} and stderr {r.stderr.strip()[:200]!r}; expected exit 0 and a warning that "
           "names --max-depth (the image is biased low)")


def test_furnace_surfaces_key(ctx):
    """"surfaces": each wall's area-averaged radiance is Le / (1 - rho) = 10 (rho = 0.9),
    within 4 standard errors from 32 batch means, with the area of a 2 x 2 wall."""
    scene = furnace_scene(ctx, 0.9)
    _, stats = ctx.render(CHAPTER, scene, "--size", "8x8", "--spp", 1, "--surface-samples", 16384,
                          "--probe-samples", 32)
    surfaces = stats["surfaces"]
    assert sorted(s["name"] for s in surfaces) == sorted(["floor", "ceiling", "back", "front", "left", "right"])
    for s in surfaces:
        assert abs(s["area"] - 4.0) < 1e-12
        for c in range(3):
            se = s["standard_error"][c]
            assert 0 < se < 0.01 * 10
            assert abs(s["radiance"][c] - 10.0) <= 4 * se, f"{s['name']}: {s['radiance'][c]} vs 10 (4 se {4 * se})"


# ---- the estimators agree -----------------------------------------------------------------

def check_estimators_agree(ctx, scene, size, spp, label, relative_power=None):
    """Every estimator against mis by paired pixel differences.  All use the same seed:
    a sample's first random numbers place the camera ray in the pixel, so the images
    share their camera rays and the pixel-footprint noise (a pixel half on the light,
    half on the ceiling) cancels in the difference; what remains is the difference of
    the estimators.  The paired standard error needs only that pixels are independent
    of each other, not that A and B are."""
    images = {}
    for estimator in ESTIMATORS:
        img, stats = ctx.render(CHAPTER, scene, "--size", size, "--spp", spp[estimator], "--seed", 11,
                                "--estimator", estimator, "--probe-samples", 32, name=f"{label}-{estimator}")
        assert stats["nonfinite_samples"] == 0 and finite_image(img)
        images[estimator] = img
    for estimator in ESTIMATORS[:-1]:
        for c in range(3):
            d, se = paired_difference(images[estimator], images["mis"], c)
            mean = image_mean(images["mis"], c)
            power = (relative_power or {}).get(estimator, 0.03)
            assert 4 * se < power * mean, f"{label} {estimator} channel {c}: standard error {se} too large"
            assert abs(d) <= 4 * se, \
                f"{label}: {estimator} - mis = {d:.5f} in channel {c} (image mean {mean:.4f}, 4 se = {4 * se:.3g})"
    return images


def test_estimators_agree_on_cornell_box(ctx):
    """hemisphere, cosine, light and mis have the same expectation on the Cornell box:
    the mean of each image minus the mis image is within 4 paired standard errors of 0,
    and 4 standard errors are below 3 % of the mean."""
    check_estimators_agree(ctx, "scenes/cornell.scene", "32x32",
                           {"hemisphere": 1024, "cosine": 1024, "light": 256, "mis": 256}, "cornell")


GLOSSY_GLASS_SCENE = """\
camera eye 278 273 -800  look 278 273 0  up 0 1 0  fov 39.3076
background 0 0 0
material white diffuse 0.725 0.71 0.68
material red   diffuse 0.63 0.065 0.05
material green diffuse 0.14 0.45 0.091
material light emitter 17 12 4  diffuse 0.78 0.78 0.78
material glossy phong kd 0.3 0.3 0.3 ks 0.6 0.6 0.6 exp 20
material mirror mirror 0.9 0.9 0.9
material glass glass 1.5
quad floor     white  552.8 0 0      0 0 0          0 0 559.2       549.6 0 559.2
quad ceiling   white  556 548.8 0    556 548.8 559.2  0 548.8 559.2  0 548.8 0
quad back_wall glossy 549.6 0 559.2  0 0 559.2      0 548.8 559.2   556 548.8 559.2
quad right_wall_green green  0 0 559.2  0 0 0       0 548.8 0       0 548.8 559.2
triangle left_wall_red_a red  552.8 0 0  549.6 0 559.2  556 548.8 559.2
triangle left_wall_red_b red  552.8 0 0  556 548.8 559.2  556 548.8 0
quad light light  343 548.7 227  343 548.7 332  213 548.7 332  213 548.7 227
sphere mirror_ball mirror  385 100 370  100
sphere glass_ball  glass   175 100 190  100
"""


def test_estimators_agree_with_phong_mirror_and_glass(ctx):
    """The same agreement with a glossy (normalised Phong) back wall, a mirror ball and a
    glass ball (exact Fresnel; its caustic on the floor): the lobe sampling, the
    Fresnel choice and MIS on specular chains must all be unbiased.  4 standard errors
    must be below 3 % of the mean for light sampling, 5 % for cosine directions (which
    find the light through the glass only by chance), and 8 % for uniform directions
    (hemisphere): they
    rarely find the exponent-20 lobe's reflection of the light or the light through
    the glass, its error falls slowly (doubling the samples gained only 10 % here), so
    it is held to 8 % -- a bias above 8 % would still show.  The difference between
    hemisphere and importance sampling on this scene is what the chapter is about."""
    scene = ctx.write("glossy.scene", GLOSSY_GLASS_SCENE)
    check_estimators_agree(ctx, scene, "24x24", {"hemisphere": 1024, "cosine": 1024, "light": 256, "mis": 256},
                           "glossy", relative_power={"hemisphere": 0.08, "cosine": 0.05})


GLOSSY_FLOOR_SCENE = """\
camera eye 0 1.2 -3  look 0 0 0.5  up 0 1 0  fov 40
background 0 0 0
material lamp emitter 5 5 5
material gloss phong kd 0 0 0 ks 0.8 0.8 0.8 exp 20
quad floor gloss  -3 0 -3  -3 0 4  3 0 4  3 0 -3
quad light lamp  -1.5 1.5 1  1.5 1.5 1  1.5 1.5 3  -1.5 1.5 3
"""


def glossy_floor_batches(ctx, scene, runs):
    """16 batch means of the image's mean (the direct light, --bounces 1:1) per (estimator, first seed,
    spp) of runs, each batch its own seed; ({estimator: means}, {estimator: a command})."""
    batches, commands = {}, {}
    for estimator, first_seed, spp in runs:
        batches[estimator] = []
        for b in range(16):
            img, stats = ctx.render(CHAPTER, scene, "--size", "16x16", "--spp", spp, "--bounces", "1:1",
                                    "--estimator", estimator, "--seed", first_seed + b, "--probe-samples", 32,
                                    "--threads", 1, name=f"{estimator}{b}")
            expect(stats["nonfinite_samples"] == 0 and finite_image(img),
                   f"{stats['nonfinite_samples']} non-finite samples on the glossy floor (--estimator {estimator}); "
                   "expected none and a finite image", command=img.command)
            batches[estimator].append(sum(image_mean(img, c) for c in range(3)) / 3)
            commands.setdefault(estimator, img.command)
    return batches, commands


def test_lobe_sampling_agrees_with_light_sampling(ctx):
    """Direct light (--bounces 1:1) reflected by a purely glossy floor (normalised Phong, kd 0, so
    every direction the cosine estimator draws comes from the lobe, exponent 20) under a large
    white light, by two methods: the cosine estimator, whose weight f cos / p divides by the lobe's
    pdf (exercises 4.4, 4.5), and the light estimator, whose f L_e cos / p_light of K E does not
    use that pdf at all (points on the light; what its walk then finds counts 0): the truth here.
    16 renders (batches) of each, with seeds of their own (--threads 1: tiny renders); Welch's t
    on the 16 + 16 image means (over pixels and the three channels, which are equal here: grey ks,
    white light), both variances counted, Welch-Satterthwaite degrees of freedom, tolerance
    t_bound(df) standard errors.  The tolerance must be below 2 % of the image mean, so the
    standard error is below 0.5 %: a pdf off by a constant factor shows as the image off by its
    inverse, and a lobe pdf normalised by (n + 2) instead of (n + 1) (22/21, 4.5 %) lands more
    than 5 standard errors beyond the tolerance."""
    scene = ctx.write("glossy-floor.scene", GLOSSY_FLOOR_SCENE)
    batches, commands = glossy_floor_batches(ctx, scene, (("cosine", 1, 512), ("light", 101, 512)))
    lobe, light = batches["cosine"], batches["light"]
    t, df, _, d, se = kit_stats.welch(lobe, light)
    bound = t_bound(df)
    mean = sum(light) / len(light)
    expect(mean > 0 and bound * se < 0.02 * mean,
           f"tolerance of cosine against light: {bound:.2f} x {se:.3g}, expected below 2 % of the image mean "
           f"{mean:.4g} so that it stays tight", measured=bound * se, expected=0.02 * mean, command=commands["light"])
    expect_close("image mean", sum(lobe) / len(lobe), mean, se=se, bound=bound,
                 where="of direct light on a purely glossy floor, directions drawn from the lobe (--estimator cosine)",
                 by="--estimator light, which does not use the lobe's pdf", command=commands["cosine"])


def test_caustic_under_glass_ball(ctx):
    """scenes/cornell-spheres.scene: the glass ball focuses the light onto the floor.
    Probe irradiance at the caustic, with the Neumann terms that pass through the
    ball (--bounces 2:2: the two refractions) must be far above the same
    terms at a floor point beside it; 4 standard errors apart at least."""
    path = os.path.join(ROOT, "scenes", "cornell-spheres.scene")
    if not os.path.exists(path):
        path = ctx.write("spheres.scene", GLOSSY_GLASS_SCENE)
    with open(path) as f:
        text = f.read()
    # The glass ball's centre and radius from the scene file.
    for line in text.splitlines():
        parts = line.split()
        if len(parts) >= 7 and parts[0] == "sphere" and parts[1] == "glass_ball":
            cx, cy, cz, radius = map(float, parts[3:7])
    light = (278.0, 548.7, 279.5)
    # The ball acts as a lens: rays from the light through the ball converge
    # below it, beyond the ball, on the line from the light through its centre.
    t = cy / (light[1] - cy)  # continue from the centre down to the floor, y = 0
    focus = (cx + (cx - light[0]) * t, 0.0, cz + (cz - light[2]) * t)
    aside = (cx + 2.2 * radius, 0.0, cz)  # beside the ball, in its open view of the light
    scene = ctx.write("caustic.scene", text + "\nprobe caustic %g 0.01 %g 0 1 0\nprobe aside %g 0.01 %g 0 1 0\n"
                      % (focus[0], focus[2], aside[0], aside[2]))
    _, stats = ctx.render(CHAPTER, scene, "--size", "8x8", "--spp", 1, "--probe-samples", 1 << 17,
                          "--bounces", "2:2")
    c, a = probe(stats, "caustic"), probe(stats, "aside")
    se = math.hypot(c["standard_error"][0], a["standard_error"][0])
    expect_at_least("irradiance (--bounces 2:2, red) at the caustic under the glass ball", c["irradiance"][0],
                    max(2 * a["irradiance"][0], a["irradiance"][0] + 4 * se),
                    by=f"twice and 4 standard errors above the {a['irradiance'][0]:.4g} beside the ball: the ball "
                       "focuses the light (no caustic otherwise)")


def test_neumann_terms_add_up(ctx):
    """Images of 0:0, 1:1 and 2: add up to the full image (0:) in expectation
    (paired pixel differences, 4 standard errors; one seed for all, so the camera rays
    are shared and the light's edge pixels cancel, as in check_estimators_agree)."""
    scene = "scenes/cornell.scene"
    parts = []
    for window in ("0:0", "1:1", "2:", "0:"):
        img, _ = ctx.render(CHAPTER, scene, "--size", "24x24", "--spp", 256, "--seed", 21, "--bounces", window,
                            "--probe-samples", 32, name="w" + window.replace(":", "_"))
        parts.append(img)
    from lib import Image
    total = Image(24, 24, [tuple(a[c] + b[c] + d[c] for c in range(3))
                           for a, b, d in zip(parts[0].pixels, parts[1].pixels, parts[2].pixels)])
    for c in range(3):
        d, se = paired_difference(total, parts[3], c)
        assert 4 * se < 0.02 * image_mean(parts[3], c), f"channel {c}: standard error {se} too large"
        assert abs(d) <= 4 * se, f"channel {c}: E + KE + (K^2 E + ...) - L = {d:.5f} (4 se {4 * se:.3g})"
    # Direct illumination is a large part of the Cornell box, indirect is not zero.
    assert image_mean(parts[2], 0) > 0.1 * image_mean(parts[3], 0), "no indirect light" 


# ---- convergence -----------------------------------------------------------------------------

def test_rmse_falls_like_inverse_sqrt_samples(ctx):
    """RMSE against a reference of 4096 spp (independent seed) at 2, 8, 32 and 128 spp:
    the least-squares slope of log RMSE against log N is within [-0.6, -0.4].
    The RMSE is taken over the rows below the light: the few pixels on the light's
    edge have a Bernoulli error (light 17 or ceiling 0.1) so large that they alone
    would decide the RMSE, and the RMSE of a handful of pixels is itself too noisy
    for a slope.  The counts are not perfect squares, so the driver jitters pixel
    positions uniformly rather than stratifying them (stratified pixels converge
    faster than N^-1/2 at edges).  The reference's own noise raises the RMSE at
    128 spp by sqrt(1 + 128/4096) = 1.6 %, flattening the slope by about 0.007."""
    scene = "scenes/cornell.scene"
    size, first_row = 24, 6  # the light covers rows 2-4 of 24
    reference, _ = ctx.render(CHAPTER, scene, "--size", f"{size}x{size}", "--spp", 4096, "--seed", 99,
                              "--probe-samples", 32, name="reference")
    points = []
    for n in (2, 8, 32, 128):
        img, _ = ctx.render(CHAPTER, scene, "--size", f"{size}x{size}", "--spp", n, "--seed", n,
                            "--probe-samples", 32, name=f"n{n}")
        squares = [(a[c] - b[c]) ** 2 for a, b in zip(img.pixels[first_row * size:],
                                                      reference.pixels[first_row * size:]) for c in range(3)]
        points.append((math.log(n), 0.5 * math.log(sum(squares) / len(squares))))
    mx = sum(x for x, _ in points) / len(points)
    my = sum(y for _, y in points) / len(points)
    slope = sum((x - mx) * (y - my) for x, y in points) / sum((x - mx) ** 2 for x, _ in points)
    assert -0.6 <= slope <= -0.4, f"log-log slope of RMSE against spp is {slope:.3f} ({points})"


# ---- probes ------------------------------------------------------------------------------------

def area_light_scene(ctx, radiance, probes):
    text = ("camera eye 0 -5 0  look 0 0 0  up 0 0 1  fov 30\nimage 4 4\nbackground 0 0 0\n"
            "material lamp emitter %g %g %g\n" % radiance +
            # a 1 x 0.6 rectangle at height 1, vertex order so the normal points down (-y)
            "quad light lamp  -0.5 1 -0.3  0.5 1 -0.3  0.5 1 0.3  -0.5 1 0.3\n")
    for name, (p, n) in probes.items():
        text += "probe %s  %g %g %g  %g %g %g\n" % (name, *p, *n)
    return ctx.write("area.scene", text)


def test_probe_irradiance_matches_lambert_polygon(ctx):
    """Irradiance under a 1 x 0.6 rectangle of radiance (1, 2, 3) at height 1, at a centred
    and at an off-centre tilted probe, by every estimator: Lambert's polygon formula
    within t_bound standard errors (32 batch means; 24 comparisons: 4 estimators, 2 probes,
    3 channels), each below 1 % of the answer.  Directions alone (hemisphere, cosine) find
    the light rarely: with 2^18 walks their standard error at the tilted probe was 0.78 of
    that 1 % on average and above it for 1 grading seed in 20 (a false failure), so they
    get 2^20 walks (half the error); light sampling needs only 2^18."""
    radiance = (1.0, 2.0, 3.0)
    rectangle = [(-0.5, 1, -0.3), (0.5, 1, -0.3), (0.5, 1, 0.3), (-0.5, 1, 0.3)]
    probes = {"centre": ((0, 0, 0), (0, 1, 0)), "offset": ((0.7, 0.2, -0.3), (-0.28, 0.96, 0.0))}
    scene = area_light_scene(ctx, radiance, probes)
    for estimator in ESTIMATORS:
        walks = 1 << 20 if estimator in ("hemisphere", "cosine") else 1 << 18
        _, stats = ctx.render(CHAPTER, scene, "--estimator", estimator, "--probe-samples", walks, name=estimator)
        check_probes_match_lambert(stats, rectangle, radiance, probes, 0.01, estimator,
                                   comparisons=3 * len(probes) * len(ESTIMATORS))


POINT_LIGHT_SCENE = """\
camera eye 0 10 0  look 0 0 0  up 0 0 1  fov 30
image 8 8
material floor diffuse 0.5 0.5 0.5
quad floor floor  -50 0 -50  -50 0 50  50 0 50  50 0 -50
light lamp point 1 3 0.5  40 40 40
probe under 0.5 0 0.25  0 1 0
"""


def test_point_light_warning_and_inverse_square(ctx):
    """A point light cannot be hit by a sampled direction: hemisphere and cosine must warn
    on stderr that the image misses it; light sampling gets (R1) at the probe with
    --bounces 0:0 (direct irradiance I cos / r^2, exact: one deterministic sample)."""
    scene = ctx.write("point.scene", POINT_LIGHT_SCENE)
    for estimator in ("hemisphere", "cosine"):
        r = ctx.run(CHAPTER, scene, "--quiet", "--estimator", estimator, "--out", ctx.path(f"{estimator}.pfm"))
        expect(r.returncode == 0 and "warning" in r.stderr and "point light" in r.stderr,
               f"--estimator {estimator} with a point light: exit status {r.returncode}, stderr "
               f"{r.stderr.strip()[:200]!r}; expected exit 0 and a warning that the image misses the point light "
               "(a sampled direction never hits a point)")
    for estimator in ("light", "mis"):
        r = ctx.run(CHAPTER, scene, "--quiet", "--estimator", estimator, "--out", ctx.path(f"{estimator}.pfm"))
        expect(r.returncode == 0 and "warning" not in r.stderr,
               f"--estimator {estimator} with a point light: exit status {r.returncode}, stderr "
               f"{r.stderr.strip()[:200]!r}; expected exit 0 and no warning (light sampling reaches point lights)")
        _, stats = ctx.render(CHAPTER, scene, "--estimator", estimator, "--bounces", "0:0", name=estimator)
        d = (0.5, 3.0, 0.25)
        r2 = sum(x * x for x in d)
        expected = 40.0 * d[1] / math.sqrt(r2) / r2
        expect_close("irradiance", probe(stats, "under")["irradiance"][0], expected, rel=1e-9,
                     where=f"at the probe under the point light, red (--estimator {estimator} --bounces 0:0)",
                     by="I cos / r^2 (R1)")


# ---- radiosity and path tracing agree -------------------------------------------------------

def test_radiosity_and_path_tracing_agree_on_cornell_box(ctx):
    """Each surface's area-averaged exitant radiance on the diffuse Cornell box, from
    build/03_radiosity (patches of 50 and 25 mm, Jacobi to --tol 1e-7 so the solve
    itself adds nothing) and from path tracing (--surface-samples, 32 batch means).

    The bound: radiosity's error is the discretisation error (constant radiance per
    patch, form factors by quadrature).  If it falls like h^p with p >= 0.585 the
    error at 25 mm is at most 2 |L_50 - L_25| (e_25 = |L_50 - L_25| / (2^p - 1));
    piecewise-constant elements converge at least linearly (p = 1) away from
    singularities, so this is a safe bound.  Add t_bound standard errors of the path
    tracer's mean (32 batch means; the comparisons are the surfaces' channels) and require
    |L_pt - L_25| <= 2 |L_50 - L_25| + t_bound se per surface and channel.
    Patches are one-sided in radiosity; the path tracer reports the front side
    (normal as in the file) too."""
    scene = "scenes/cornell.scene"
    radiosity = radiosity_surfaces(ctx, scene)
    _, stats = ctx.render(CHAPTER, scene, "--size", "8x8", "--spp", 1, "--surface-samples", 1 << 16,
                          "--probe-samples", 32, name="pt")
    traced = {s["name"]: s for s in stats["surfaces"]}
    expect_surfaces_match_radiosity(traced, radiosity, "path tracing", "surface average")


# ---- plumbing -----------------------------------------------------------------------------------

def test_threads_give_identical_bytes(ctx):
    """The driver's per-sample streams make the image independent of the thread count."""
    check_thread_independence(ctx, CHAPTER, "scenes/cornell-spheres.scene", "--size", "24x24", "--spp", 8,
                              "--probe-samples", 32)


def test_time_budget_gives_valid_image(ctx):
    """--time renders progressive passes and still writes a finite image and stats."""
    img, stats = ctx.render(CHAPTER, "scenes/cornell-small-light.scene", "--size", "24x24", "--time", 0.5,
                            "--probe-samples", 32)
    assert finite_image(img) and stats["spp"] >= 1 and stats["nonfinite_samples"] == 0
    assert stats["counters"]["bounce_rays"] > 0 and stats["counters"]["shadow_rays"] > 0


def test_bad_options_exit_2(ctx):
    for args in (["--estimator", "photon"], ["--estimator"], ["--rr-depth", "-1"], ["--max-depth", "x"],
                 ["--probe-samples", "0"], ["--surface-samples", "-5"], ["--bounces", "2:1"]):
        check_bad_input(ctx, CHAPTER, ["scenes/cornell.scene", *args])


def test_rr_depth_0_is_said_to_act_as_1(ctx):
    """--rr-depth 0 is valid but does what --rr-depth 1 does (the first
    scattering is bounce 1): one warning line says so, and the images agree."""
    a, _ = ctx.render(CHAPTER, "scenes/cornell.scene", "--size", "16x16", "--spp", 4, "--rr-depth", 1, name="rr1")
    r = ctx.run(CHAPTER, "scenes/cornell.scene", "--quiet", "--size", "16x16", "--spp", 4, "--rr-depth", 0,
                "--out", ctx.path("rr0.pfm"))
    assert r.returncode == 0 and sum("--rr-depth 0" in line for line in r.stderr.splitlines()) == 1, r.stderr
    assert read_pfm(ctx.path("rr0.pfm")).pixels == a.pixels, "--rr-depth 0 and 1 should give the same image"


# ---- several lights, picked by power (issue: the choice among lights) ------------------------

SEVERAL_LIGHTS_SCENE = """\
camera eye 0 -5 0  look 0 0 0  up 0 0 1  fov 30
image 4 4
background 0 0 0
material lamp emitter 1 2 3
material globe emitter 6 4 2
quad light lamp  -0.5 1 -0.3  0.5 1 -0.3  0.5 1 0.3  -0.5 1 0.3
sphere globe globe  -1.2 1.2 0.8  0.15
light bright point  1.5 0.8 0.6  2 1.5 1
light dim point  -0.8 0.6 -1.0  0.2 0.4 0.6
"""
# name: (position, normal); every light is wholly above each probe's horizon and none shadows another's.
SEVERAL_LIGHTS_PROBES = {"centre": ((0.0, 0.0, 0.0), (0.0, 1.0, 0.0)),
                         "offset": ((0.7, 0.2, -0.3), (-0.28, 0.96, 0.0))}


def sphere_irradiance(radiance, centre, radius, point, normal):
    """Irradiance at `point` (unit `normal`) from a Lambertian sphere of constant radiance wholly
    above the point's horizon: pi L (R / d)^2 cos(theta), theta the angle between the normal and
    the direction to the centre at distance d (the sphere acts as a point of intensity pi R^2 L)."""
    d = [centre[k] - point[k] for k in range(3)]
    dist = math.sqrt(sum(c * c for c in d))
    cos_theta = sum(normal[k] * d[k] for k in range(3)) / dist
    assert math.acos(max(-1.0, min(1.0, cos_theta))) + math.asin(radius / dist) < math.pi / 2, "sphere below horizon"
    return math.pi * radiance * (radius / dist) ** 2 * cos_theta


def point_light_irradiance(intensity, position, point, normal):
    """(R1): I cos(theta) / r^2 (0 below the horizon)."""
    d = [position[k] - point[k] for k in range(3)]
    r2 = sum(c * c for c in d)
    return intensity * max(0.0, sum(normal[k] * d[k] for k in range(3))) / r2 ** 1.5


def several_lights_irradiance(point, normal, channel):
    """The closed form at a probe of SEVERAL_LIGHTS_SCENE: Lambert's polygon formula for the
    rectangle, the sphere's pi L (R/d)^2 cos, and I cos / r^2 for each point light."""
    rectangle = [(-0.5, 1, -0.3), (0.5, 1, -0.3), (0.5, 1, 0.3), (-0.5, 1, 0.3)]
    return (lambert_polygon_irradiance((1.0, 2.0, 3.0)[channel], rectangle, point, normal)
            + sphere_irradiance((6.0, 4.0, 2.0)[channel], (-1.2, 1.2, 0.8), 0.15, point, normal)
            + point_light_irradiance((2.0, 1.5, 1.0)[channel], (1.5, 0.8, 0.6), point, normal)
            + point_light_irradiance((0.2, 0.4, 0.6)[channel], (-0.8, 0.6, -1.0), point, normal))


def unit(v):
    length = math.sqrt(sum(c * c for c in v))
    return tuple(c / length for c in v)


def test_lights_picked_by_power_at_probes(ctx):
    """Next-event estimation picks one light per sample, with probability its power over the
    total, and divides by that chance (R9): with two point lights of different power and colour,
    a rectangular emitter and a spherical one (powers 19, 5, 3.8 and 3.6 W: picked 61, 16, 12 and
    11 % of the time) the probes' irradiance is the sum of every light's closed form (Lambert's
    polygon formula, pi L (R/d)^2 cos for the sphere, I cos / r^2 for the point lights), by
    --estimator light and mis (hemisphere and cosine never find a point light).  --bounces 0:0
    (the emitters reflect nothing anyway).  Within t_bound(31, 12) standard errors (32 batch
    means; 2 estimators, 2 probes, 3 channels), each positive and below 1 % of the answer.  A pick
    that is not the power's share, or a light's contribution not divided by its own chance, moves
    the sum by tens of per cent."""
    scene = ctx.write("several-lights.scene", SEVERAL_LIGHTS_SCENE + "".join(
        "probe %s  %g %g %g  %g %g %g\n" % (name, *p, *n) for name, (p, n) in SEVERAL_LIGHTS_PROBES.items()))
    bound = t_bound(BATCH_DF, 2 * 3 * len(SEVERAL_LIGHTS_PROBES))
    for estimator in ("light", "mis"):
        _, stats = ctx.render(CHAPTER, scene, "--estimator", estimator, "--bounces", "0:0",
                              "--probe-samples", 1 << 18, name=estimator)
        for name, (p, n) in SEVERAL_LIGHTS_PROBES.items():
            got = probe(stats, name)
            for c in range(3):
                expected = several_lights_irradiance(p, unit(n), c)
                expect_estimate("irradiance", got["irradiance"][c], expected, got["standard_error"][c], bound,
                                0.01 * expected, where=f"at probe {name}, {CHANNELS[c]} (--estimator {estimator})",
                                by="Lambert's formula, pi L (R/d)^2 cos and I cos / r^2 summed over the four lights",
                                positive=True)


# ---- MIS: its weights add up to one -------------------------------------------------------------

MIS_FLOOR_SCENE = """\
camera eye 0 1.2 -3  look 0 0 0.5  up 0 1 0  fov 40
background 0 0 0
material small emitter 15 15 15
material large emitter 1 1 1
material gloss phong kd 0.15 0.15 0.15 ks 0.6 0.6 0.6 exp 50
quad floor gloss  -3 0 -3  -3 0 4  3 0 4  3 0 -3
quad large_light large  -2 1.5 1.5  2 1.5 1.5  2 1.5 3.5  -2 1.5 3.5
quad small_light small  -0.2 1 0.4  0.2 1 0.4  0.2 1 0.8  -0.2 1 0.8
"""


def test_mis_agrees_with_light_and_cosine_on_a_glossy_floor(ctx):
    """MIS counts a path to a light once in expectation only if its two shares (the light
    sample's w(p_light, p_bsdf) and the walk's 1 - w of the same two densities) add up to one,
    with p_bsdf the density sample_bsdf really draws (the cosine and the Phong lobe mixed) and
    p_light that of sample_light (the pick by power included).  Direct light (--bounces 1:1) on a
    floor that is mostly glossy (kd 0.15, ks 0.6, exponent 50), under a small bright light and a
    large dim one (powers 2.5 pi and 10 pi: picked 20 and 80 % of the time), where both shares
    are far from 0 and 1: --estimator mis against light (no share: every path from a light
    sample) and against cosine (no light sample: every path the walk finds), each of them
    unbiased whatever the weights.  16 renders (batches) of each, seeds of their own (cosine
    directions find the small light rarely: 1024 samples per pixel, the others 256); Welch's t
    on the 16 + 16 image means (pixels and the three equal channels), Welch-Satterthwaite degrees
    of freedom, tolerance t_bound(df, 2) standard errors, which must be below 2 % of the image
    mean."""
    scene = ctx.write("mis-floor.scene", MIS_FLOOR_SCENE)
    batches, commands = glossy_floor_batches(ctx, scene, (("mis", 1, 256), ("light", 101, 256), ("cosine", 201, 1024)))
    mis = batches["mis"]
    for other in ("light", "cosine"):
        t, df, _, d, se = kit_stats.welch(mis, batches[other])
        bound = t_bound(df, 2)
        mean = sum(batches[other]) / len(batches[other])
        expect(mean > 0 and bound * se < 0.02 * mean,
               f"tolerance of mis against {other}: {bound:.2f} x {se:.3g}, expected below 2 % of the image mean "
               f"{mean:.4g} so that it stays tight", measured=bound * se, expected=0.02 * mean,
               command=commands[other])
        expect_close("image mean", sum(mis) / len(mis), mean, se=se, bound=bound,
                     where="of direct light on a glossy floor by --estimator mis",
                     by=f"--estimator {other}, which does not use the MIS weights", command=commands["mis"])


# ---- the background -----------------------------------------------------------------------------

OPEN_FLOOR_SCENE = """\
camera eye 0 3 0  look 0 0 0.01  up 0 0 1  fov 40
background 0.2 0.4 0.6
material ground diffuse 0.5 0.3 0.1
quad floor ground  -50 0 -50  -50 0 50  50 0 50  50 0 -50
probe up 0.3 0 0.2  0 1 0
"""


def test_background_lights_an_open_floor(ctx):
    """A diffuse floor (albedo 0.5, 0.3, 0.1) under nothing but the background (Lb 0.2, 0.4, 0.6):
    every direction above a floor point leaves the scene, so its radiance is rho Lb and a probe on
    it receives pi Lb (no light, no other surface).  A walk that escapes adds the background times
    its throughput, and MIS counts it fully (no light sample can find it).  Cosine, light and mis
    draw directions like f cos: every sample is exactly rho Lb, every probe walk pi Lb (to
    rounding: 1e-6 relative); hemisphere has noise: the pixels' mean (iid pixels: every pixel has
    the same expectation) and the probe within t_bound standard errors (6 comparisons: 3 channels
    of the image, 3 of the probe), each below 1 % of the answer."""
    scene = ctx.write("open-floor.scene", OPEN_FLOOR_SCENE)
    albedo, background = (0.5, 0.3, 0.1), (0.2, 0.4, 0.6)
    for estimator in ESTIMATORS:
        img, stats = ctx.render(CHAPTER, scene, "--size", "32x32", "--spp", 16, "--estimator", estimator,
                                "--probe-samples", 1 << 16, name=estimator)
        got = probe(stats, "up")
        for c in range(3):
            expected_pixel, expected_probe = albedo[c] * background[c], math.pi * background[c]
            where = f"{CHANNELS[c]} (--estimator {estimator})"
            if estimator == "hemisphere":
                mean, se = iid_mean(img, c)
                expect_estimate("mean radiance", mean, expected_pixel, se, t_bound(len(img.pixels) - 1, 6),
                                0.01 * expected_pixel, where=f"of the floor, {where}", by="rho Lb", positive=True)
                expect_estimate("irradiance", got["irradiance"][c], expected_probe, got["standard_error"][c],
                                t_bound(BATCH_DF, 6), 0.01 * expected_probe, where=f"at probe up, {where}",
                                by="pi Lb", positive=True)
            else:
                worst = max(img.pixels, key=lambda p: abs(p[c] - expected_pixel))[c]
                expect_close("pixel radiance", worst, expected_pixel, rel=1e-6,
                             where=f"of the floor farthest from rho Lb, {where}", by="rho Lb")
                expect_close("irradiance", got["irradiance"][c], expected_probe, rel=1e-6,
                             where=f"at probe up, {where}", by="pi Lb")
