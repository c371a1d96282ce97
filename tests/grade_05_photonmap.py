"""Grading chapter 5 (photon mapping) against closed forms and the other methods.

Truth comes from outside the photon mapper: the furnace (L = Le / (1 - rho)),
energy conservation (in a closed furnace every photon is stored at each
landing and absorbed with probability 1 - rho, so (1 - rho) * stored power =
emitted power), Lambert's polygon formula for the irradiance under a
rectangular light, the radiosity chapter on the diffuse Cornell box, and
the path tracer (chapter 4) on cornell-spheres.scene, whose caustic is what
photon mapping is for.

Standard errors.  Pixels of one photon-mapping render are NOT independent:
every pixel of a pass reads the same photon map.  What is independent is a
whole render with another --seed, so image statistics here come from R
renders with different seeds (the standard error of their mean is the
spread of the R values over sqrt(R), with R - 1 degrees of freedom).  Stored
power, surface averages and probes come with the chapter's own standard
errors from 32 batches of independently emitted photons (31 degrees of
freedom).  Tolerances are t_bound(df, m) standard errors (tests/lib.py):
Student's t quantile at CRITERION_ALPHA / m, m being the comparisons the
criterion makes (Bonferroni), so a correct chapter fails a criterion for at
most CRITERION_ALPHA of the grading seeds (the instructor's calibration measures it).
Each test also requires its standard error to be small, so a tolerance
cannot hide a real error.

Density estimation is biased by its radius: where a test compares with a
value that is not the estimate's expectation, it says which bound it uses.
"""
import math
import os

import lib
from lib import furnace_scene  # the furnace of scenes/furnace-pt.scene with Le and rho
from lib import BATCH_DF, CRITERION_ALPHA, ROOT, radiosity_surfaces, check_bad_input, \
    check_thread_independence, finite_image, lambert_polygon_irradiance, probe, t_bound

from lib import expect_estimate, expect_surfaces_match_radiosity  # the report's sentences
from lib import CHANNELS, expect, expect_between  # several lights, probes and the radius
from lib import expect_at_least, expect_at_most, expect_close, expect_image  # the report's sentences

GRADES_NOTHING = True  # no grading, no handout: may run beside the RUN_ALONE tests (tests/run.py)

CHAPTER = "05_photonmap"
# Renders (seeds) behind an image mean: their spread gives its standard error with RENDERS - 1
# degrees of freedom.  With 5 (six renders) Student's t at 5e-5 (CRITERION_ALPHA over four
# comparisons) is 12.9 standard errors; with 15 it is 5.6, so 16 renders keep the tolerance tight.
RENDERS = 16


def mean_and_error(values):
    """The mean of independent values and its standard error (len(values) - 1 degrees of freedom)."""
    n = len(values)
    m = sum(values) / n
    return m, math.sqrt(sum((v - m) ** 2 for v in values) / (n - 1) / n)


def central_mean(img, channel=0):
    """Mean over the central half of the image (in the furnace: the back wall, more than the
    radius away from its edges, where the disc of (R11) lies wholly on the wall)."""
    w, h = img.width, img.height
    values = [img.at(x, y)[channel] for y in range(h // 4, 3 * h // 4) for x in range(w // 4, 3 * w // 4)]
    return sum(values) / len(values)


def renders(ctx, scene, seeds, *args, name="r"):
    return [ctx.render(CHAPTER, scene, "--seed", seed, *args, name=f"{name}{seed}") for seed in seeds]


# ---- bad input -------------------------------------------------------------------------------

def test_bad_options_exit_2(ctx):
    """--radius <= 0 or not finite, --photons 0, --alpha outside (0, 1]: one argv:N line, exit 2, no output."""
    for args in (["--radius", "0"], ["--radius", "-1"], ["--radius", "nan"], ["--radius", "inf"],
                 ["--photons", "0"], ["--alpha", "0"], ["--alpha", "1.5"], ["--alpha", "-0.5"],
                 ["--maps", "neither"], ["--gather", "-1"], ["--nearest", "-2"]):
        check_bad_input(ctx, CHAPTER, ["scenes/cornell.scene", "--size", "8x8", *args])


def test_scene_without_light_warns_and_is_black(ctx):
    scene = ctx.write("dark.scene", "camera eye 0 0 -5  look 0 0 0  up 0 1 0  fov 30\n"
                      "material grey diffuse 0.5 0.5 0.5\nquad wall grey  -1 -1 0  1 -1 0  1 1 0  -1 1 0\n"
                      "probe p 0 0 -0.5  0 0 -1\n")
    pfm = ctx.path("dark.pfm")
    r = ctx.run(CHAPTER, scene, "--quiet", "--size", "8x8", "--spp", 2, "--out", pfm)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 0 and len(lines) == 1 and lines[0].startswith("warning:"), r.stderr
    from lib import read_pfm
    assert all(c == 0.0 for px in read_pfm(pfm).pixels for c in px), "a scene without light must render black"


# ---- the furnace -------------------------------------------------------------------------------

def test_furnace_converges_to_Le_over_1_minus_rho(ctx):
    """Closed cube of walls with Le = 1 and albedo rho: L = Le / (1 - rho) at every pixel.
    In a uniform field the photon density is uniform, so (R11) over a disc lying on the
    wall is unbiased for any radius (0.05 here, a tenth of the central pixels' distance from
    the wall's edges): the central pixels' mean over RENDERS seeds must be within
    t_bound(RENDERS - 1, 4) standard errors (across seeds), and that error below 1 % of the
    answer.  For --maps global (the naive method) and both (direct light by light sampling)."""
    # Statistics the sanitizers make slow; the furnace runs there
    # in test_furnace_energy_stored_power.
    if lib.sanitizer_build(ctx):
        return
    bound = t_bound(RENDERS - 1, 4)
    for rho in (0.5, 0.9):
        expected = 1.0 / (1.0 - rho)
        scene = furnace_scene(ctx, rho, name=f"furnace{rho}")
        for maps in ("global", "both"):
            results = renders(ctx, scene, range(1, RENDERS + 1), "--size", "24x24", "--spp", 2, "--photons", 20000,
                              "--radius", 0.05, "--maps", maps, "--probe-photons", 32, name=f"f{rho}{maps}")
            mean, se = mean_and_error([central_mean(img) for img, _ in results])
            nonfinite = sum(s["nonfinite_samples"] for _, s in results)
            expect(nonfinite == 0, f"{nonfinite} non-finite samples in the furnace (albedo {rho}, --maps {maps}); "
                   "expected none", measured=nonfinite, expected=0, command=results[0][0].command)
            expect_estimate("mean radiance of the central pixels", mean, expected, se, bound, 0.01 * expected,
                            where=f"of the furnace (albedo {rho}, --maps {maps}, over {RENDERS} seeds)",
                            by="Le / (1 - rho)", command=results[0][0].command)


def test_furnace_energy_stored_power(ctx):
    """Energy: photons are stored at every landing and survive each with probability rho
    (Russian roulette), so the power stored in the global map is Phi_e (1 + rho + rho^2 + ...)
    = Phi_e / (1 - rho): the absorbed part (1 - rho) of it is all the power emitted.
    Within t_bound(31, 2) standard errors (32 photon batches), each below 0.5 % of the answer."""
    bound = t_bound(BATCH_DF, 2)
    for rho in (0.5, 0.9):
        scene = furnace_scene(ctx, rho, name=f"energy{rho}")
        _, s = ctx.render(CHAPTER, scene, "--size", "8x8", "--spp", 4, "--photons", 50000, "--probe-photons", 32)
        emitted = s["emitted_power"][0]
        expect_close("emitted power", emitted, 6 * 4 * math.pi * 1.0, rel=1e-9, where=f"of the furnace (albedo {rho})",
                     by="pi Le A summed over the six walls of area 4")
        stored, se = s["stored_power"]["global"][0], s["stored_power"]["global_standard_error"][0]
        expect_estimate("absorbed power (1 - rho) x stored", (1 - rho) * stored, emitted, (1 - rho) * se, bound,
                        0.005 * (1 - rho) * stored, where=f"in the furnace (albedo {rho})",
                        by="the emitted power", positive=True)
        expect_close("caustic photons stored", s["photons_stored"]["caustic"], 0, tol=0,
                     where=f"in the furnace (albedo {rho})", by="none: no mirror or glass")


def test_furnace_neumann_terms(ctx):
    """--bounces 0:0 is the emission alone (exact); 0:1 keeps Le (1 + rho) (the photons
    that landed straight from a light, reflected once), 1:1 the once-reflected light rho and 2:
    the rest: RENDERS seeds, t_bound(RENDERS - 1, 6) standard errors, each below 2 % of the
    answer (one render's mean scatters by about 4 % at --spp 4, the mean of RENDERS by 1 %)."""
    # Statistics the sanitizers make slow; the --bounces windows run there
    # in test_furnace_probe_keeps_the_bounces_window.
    if lib.sanitizer_build(ctx):
        return
    rho = 0.5
    bound = t_bound(RENDERS - 1, 6)
    scene = furnace_scene(ctx, rho, name="neumann")
    img, _ = ctx.render(CHAPTER, scene, "--size", "8x8", "--spp", 1, "--bounces", "0:0", "--photons", 1000,
                        "--probe-photons", 32, name="b00")
    expect_image("radiance", img, lambda x, y, c: 1.0, tol=0, where="of the furnace with --bounces 0:0",
                 by="exactly the emission Le = 1 (the term E)")
    for window, expected in (("0:1", 1 + rho), ("1:1", rho), ("2:", rho ** 2 / (1 - rho))):
        for maps in ("global", "both"):
            results = renders(ctx, scene, range(1, RENDERS + 1), "--size", "24x24", "--spp", 4, "--photons", 40000,
                              "--maps", maps, "--bounces", window, "--probe-photons", 32, name=f"w{maps}")
            mean, se = mean_and_error([central_mean(img) for img, _ in results])
            expect_estimate("mean radiance", mean, expected, se, bound, 0.02 * expected + 1e-3,
                            where=f"of the furnace with --bounces {window} --maps {maps}",
                            by="the Neumann term(s) Le rho^k")


def test_albedo_zero_shows_emission_only(ctx):
    scene = furnace_scene(ctx, 0.0, emission=0.5, name="black")
    for maps in ("global", "caustic", "both"):
        img, _ = ctx.render(CHAPTER, scene, "--size", "8x8", "--spp", 2, "--photons", 2000, "--maps", maps,
                            "--gather", 2, "--probe-photons", 32, name=maps)
        worst = max(abs(c - 0.5) for px in img.pixels for c in px)
        assert worst < 1e-6, f"--maps {maps}: albedo 0 furnace deviates from Le by {worst}"


# ---- probes: Lambert's polygon formula; next to a crease ------------------------------------------

def test_probe_irradiance_matches_lambert_polygon(ctx):
    """Irradiance under a 1 x 0.6 rectangle of radiance (1, 2, 3) at height 1, at a centred
    and at an off-centre tilted probe: each photon's light sent from the point it leaves the
    lamp, f Phi_p G V with f = cos / pi (the lamp is Lambertian; (R8), (R9)), expects exactly
    Lambert's formula at the probe (no disc, no blur; --radius 0.1 is the eye pass's, which the
    probes do not use).  Within t_bound(31, 6) standard errors (32 batches; 2 probes, 3 channels),
    each below 1 % of the answer (2^19 photons: 0.02-0.09 %)."""
    radiance = (1.0, 2.0, 3.0)
    rectangle = [(-0.5, 1, -0.3), (0.5, 1, -0.3), (0.5, 1, 0.3), (-0.5, 1, 0.3)]
    probes = {"centre": ((0, 0, 0), (0, 1, 0)), "offset": ((0.7, 0.2, -0.3), (-0.28, 0.96, 0.0))}
    text = ("camera eye 0 -5 0  look 0 0 0  up 0 0 1  fov 30\nimage 4 4\nbackground 0 0 0\n"
            "material lamp emitter 1 2 3\nquad light lamp  -0.5 1 -0.3  0.5 1 -0.3  0.5 1 0.3  -0.5 1 0.3\n")
    for name, (p, n) in probes.items():
        text += "probe %s  %g %g %g  %g %g %g\n" % (name, *p, *n)
    scene = ctx.write("area.scene", text)
    bound = t_bound(BATCH_DF, 3 * len(probes))
    _, stats = ctx.render(CHAPTER, scene, "--radius", 0.1, "--spp", 1, "--photons", 1000,
                          "--probe-photons", 1 << 19)
    for name, (p, n) in probes.items():
        length = math.sqrt(sum(c * c for c in n))
        n = tuple(c / length for c in n)
        got = probe(stats, name)
        for c in range(3):
            expected = lambert_polygon_irradiance(radiance[c], rectangle, p, n)
            expect_estimate("irradiance", got["irradiance"][c], expected, got["standard_error"][c], bound,
                            0.01 * expected, where=f"at probe {name} under the rectangle light, {CHANNELS[c]}",
                            by="Lambert's polygon formula at the probe", positive=True)


def test_probe_next_to_a_crease_agrees_with_path_tracing(ctx):
    """scenes/crease.scene: a floor of two triangles 0.5 degrees apart (a shallow valley, like the
    measured Cornell box's red wall), lit by a square lamp and a red wall; two probes 0.01 mm above
    the floor, 0.5 mm either side of the crease.  Chapter 4 estimates each probe's irradiance by
    walks from the probe (walk_stats.h), which no geometry near it can cut.  Chapter 5's photons
    send their light to the probe along shadow rays (no disc): the same irradiance, within
    t_bound(31, 6) standard errors of the difference (both estimates' errors combined; 2 probes,
    3 channels), each below 0.5 % of it (2^21 photons: 0.01 %; chapter 4's 2^18 walks: 0.01 %).
    A disc of the default radius (4.4 mm) around a probe, in its own triangle's plane, passes
    behind the other triangle beyond 1.15 mm of the crease: counting the photons crossing it reads
    about 35 % low."""
    scene = os.path.join(ROOT, "scenes", "crease.scene")
    bound = t_bound(BATCH_DF, 6)
    _, walks = ctx.render("04_pathtrace", scene, "--size", "4x4", "--spp", 1, "--probe-samples", 1 << 18,
                          name="crease-pt")
    _, photons = ctx.render(CHAPTER, scene, "--size", "4x4", "--spp", 1, "--photons", 1000,
                            "--probe-photons", 1 << 21, name="crease-pm")
    for name in ("left", "right"):
        reference, got = probe(walks, name), probe(photons, name)
        for c in range(3):
            expected = reference["irradiance"][c]
            se = math.hypot(got["standard_error"][c], reference["standard_error"][c])
            expect_estimate("irradiance", got["irradiance"][c], expected, se, bound, 0.005 * expected,
                            where=f"at probe {name}, 0.01 mm above a crease of 0.5 degrees, {CHANNELS[c]}",
                            by="chapter 4's walks from the probe (standard error: both combined)", positive=True)


def disc_mean(function, centre, normal, radius, rings=24, sectors=48):
    """The mean of function(point) over the disc of the given radius around centre in the plane of
    normal (midpoint rule in polar coordinates, area-weighted; the integrand is smooth there)."""
    n = normal
    a = (1.0, 0.0, 0.0) if abs(n[0]) < 0.9 else (0.0, 1.0, 0.0)
    u = [n[1] * a[2] - n[2] * a[1], n[2] * a[0] - n[0] * a[2], n[0] * a[1] - n[1] * a[0]]
    lu = math.sqrt(sum(c * c for c in u))
    u = [c / lu for c in u]
    v = [n[1] * u[2] - n[2] * u[1], n[2] * u[0] - n[0] * u[2], n[0] * u[1] - n[1] * u[0]]
    total = weight = 0.0
    for i in range(rings):
        r = radius * (i + 0.5) / rings
        for j in range(sectors):
            phi = 2 * math.pi * (j + 0.5) / sectors
            total += r * function([centre[k] + r * (math.cos(phi) * u[k] + math.sin(phi) * v[k]) for k in range(3)])
            weight += r
    return total / weight


def test_probe_sees_a_lamp_in_a_mirror(ctx):
    """A lamp of radiance (1, 2, 3) facing up at height 1 (x in [1, 1.6]), under a mirror of
    reflectance (0.9, 0.8, 0.7) at height 2; a probe at the origin, facing up, sees no lamp directly
    (it faces away) but its image in the mirror, a lamp facing down at height 3.  Light that reaches
    the probe straight from a mirror cannot be sent along a shadow ray: the photons crossing a disc
    of the eye pass's radius around the probe count (--radius 0.25, one pass), so the estimate expects
    the reflectance times Lambert's formula for the image, averaged over the disc (computed here;
    0.3 % below its value at the centre).  Within t_bound(31, 3) standard errors (32 batches,
    3 channels), each below 3 % of the answer (2^21 photons: 0.8 %)."""
    radiance, reflectance = (1.0, 2.0, 3.0), (0.9, 0.8, 0.7)
    image = [(1.0, 3.0, -0.3), (1.6, 3.0, -0.3), (1.6, 3.0, 0.3), (1.0, 3.0, 0.3)]
    scene = ctx.write("mirror.scene", "camera eye 0 -5 0  look 0 0 0  up 0 0 1  fov 30\nimage 4 4\n"
                      "material lamp emitter 1 2 3\nmaterial glass_mirror mirror 0.9 0.8 0.7\n"
                      "quad light lamp  1 1 -0.3  1 1 0.3  1.6 1 0.3  1.6 1 -0.3\n"
                      "quad mirror glass_mirror  -3 2 -3  5 2 -3  5 2 3  -3 2 3\n"
                      "probe under_mirror  0 0 0  0 1 0\n")
    _, stats = ctx.render(CHAPTER, scene, "--radius", 0.25, "--spp", 1, "--photons", 1000,
                          "--probe-photons", 1 << 21)
    got = probe(stats, "under_mirror")
    for c in range(3):
        expected = reflectance[c] * disc_mean(
            lambda x: lambert_polygon_irradiance(radiance[c], image, x, (0, 1, 0)), (0, 0, 0), (0, 1, 0), 0.25)
        expect_estimate("irradiance", got["irradiance"][c], expected, got["standard_error"][c], t_bound(BATCH_DF, 3),
                        0.03 * expected, where=f"at a probe under a mirror, {CHANNELS[c]}",
                        by="the reflectance times Lambert's formula for the lamp's image, over the probe's disc",
                        positive=True)


# ---- radiosity and photon mapping agree ------------------------------------------------------------

def test_radiosity_and_photon_mapping_agree_on_cornell_box(ctx):
    """Each surface's area-averaged exitant radiance on the diffuse Cornell box: from the
    power the photons deposit on it (L = Le + rho/pi * Phi/A, no radius, so no blur) and
    from build/03_radiosity at 50 and 25 mm patches.  The bound is grade_04's: radiosity's
    discretisation error at 25 mm is at most 2 |L_50 - L_25| (convergence of order >= 0.585),
    plus t_bound(31, 24) standard errors of the photon estimate (32 batches; 8 surfaces, 3
    channels), each below 2 %."""
    scene = "scenes/cornell.scene"
    radiosity = radiosity_surfaces(ctx, scene)
    _, stats = ctx.render(CHAPTER, scene, "--size", "8x8", "--spp", 8, "--photons", 200000,
                          "--probe-photons", 32, name="pm")
    mapped = {s["name"]: s for s in stats["surfaces"]}
    expect_surfaces_match_radiosity(mapped, radiosity, "photon mapping", "from the power the photons deposit")


# ---- convergence to the path tracer -----------------------------------------------------------------

SIZE = 32


def caustic_region(reference, floor_rows_from):
    """The caustic under the glass ball: floor pixels (rows from floor_rows_from down) in the
    right half of the image (the glass ball's side) whose reference radiance is at least 3 times
    the median floor radiance there."""
    floor = [(x, y) for y in range(floor_rows_from, reference.height) for x in range(reference.width // 2,
                                                                                     reference.width)]
    values = sorted(reference.at(x, y)[0] for x, y in floor)
    median = values[len(values) // 2]
    return [(x, y) for x, y in floor if reference.at(x, y)[0] >= 3 * median]


def region_mean(img, region, channel=0):
    return sum(img.at(x, y)[channel] for x, y in region) / len(region)


def test_bias_falls_as_radius_shrinks_and_progressive_converges(ctx):
    """cornell-spheres.scene, against chapter 4 (MIS, 4096 spp: unbiased).  The caustic
    region's mean (the caustic under the glass ball, chosen from the reference) by --maps
    both (the caustic from the caustic map) with a fixed radius (--alpha 1) of 40 and of
    10 mm, RENDERS seeds each, the same seeds for both radii: the photons are the same
    (tracing them does not depend on the radius), so the difference of the two region
    means of one seed is the blur alone, and its spread over the seeds is small.  The
    blur of a 40 mm disc spreads the caustic's light outside the region: the mean
    difference (10 mm minus 40 mm) must be positive at one-sided level CRITERION_ALPHA
    (Student's t, RENDERS - 1 degrees of freedom; measured t 12-18 against a bound of
    4.5).  And the 10 mm estimate must be the nearer to the reference (|b10| < |b40|:
    the biases are about -0.03 and -0.2, so the reference's noise, about 0.03, would
    have to be about 4 times itself to swap them).  Then progressive (--alpha 2/3
    default) with the same 40 mm start: the RMSE over the whole image against the
    reference falls from 4 to 64 passes (measured ratio 0.1-0.25, bound 0.7)."""
    # Statistics the sanitizers make slow; progressive passes and the radius run there
    # in test_radius_follows_R12.
    if lib.sanitizer_build(ctx):
        return
    scene = "scenes/cornell-spheres.scene"
    size = f"{SIZE}x{SIZE}"
    ref, _ = ctx.render("04_pathtrace", scene, "--size", size, "--spp", 4096, "--seed", 77, "--probe-samples", 32,
                        name="reference")
    region = caustic_region(ref, int(SIZE * 0.75))
    expect_at_least("caustic pixels (floor, at least 3 x the median) in chapter 4's reference render", len(region), 3,
                    by="the glass ball's caustic on the floor", command=ref.command)
    ref_mean = sum(ref.at(x, y)[0] for x, y in region) / len(region)
    means = {}
    for radius in (40, 10):
        results = renders(ctx, scene, range(1, RENDERS + 1), "--size", size, "--spp", 8, "--photons", 50000,
                          "--maps", "both", "--radius", radius, "--alpha", 1, "--probe-photons", 32,
                          name=f"r{radius}-")
        means[radius] = [region_mean(img, region) for img, _ in results]
    sharpening, se = mean_and_error([m10 - m40 for m10, m40 in zip(means[10], means[40])])
    bound = t_bound(RENDERS - 1, alpha=2 * CRITERION_ALPHA)  # one-sided at CRITERION_ALPHA
    b40, b10 = sum(means[40]) / RENDERS - ref_mean, sum(means[10]) / RENDERS - ref_mean
    expect_at_least("gain of the caustic's mean radiance (red) from --radius 40 to 10", sharpening, bound * se,
                    by=f"{bound:.2f} standard errors of {se:.3g} above 0: a smaller disc blurs the caustic less",
                    command=results[0][0].command)
    expect_at_most("|bias| of the caustic's mean radiance (red) with --radius 10", abs(b10), abs(b40),
                   by=f"the |bias| {abs(b40):.4g} with --radius 40 (against chapter 4's {ref_mean:.4g}): the bias "
                      "falls as the radius shrinks", command=results[0][0].command, words=("too large", "too small"))
    errors = []
    for passes in (4, 64):
        img, stats = ctx.render(CHAPTER, scene, "--size", size, "--spp", passes, "--photons", 30000, "--radius", 40,
                                "--probe-photons", 32, "--ref", ctx.path("reference.pfm"), name=f"p{passes}")
        errors.append(stats["metrics"]["rmse"])
        radii = stats["radius_per_pass"]
        expect(radii[0] == 40 and radii[-1] < radii[0],
               f"radius per pass with --radius 40 over {passes} passes: first {radii[0]}, last {radii[-1]}; "
               "expected 40, then smaller (progressive)", command=img.command)
    expect_at_most("RMSE after 64 progressive passes", errors[1], 0.7 * errors[0],
                   by=f"0.7 x the RMSE {errors[0]:.4g} after 4 passes: progressive photon mapping converges",
                   command=img.command, words=("too large", "too small"))


def test_radius_follows_R12(ctx):
    """radius_per_pass: r_{i+1}^2 = r_i^2 (i + alpha) / (i + 1); alpha = 1 keeps it."""
    for alpha in (0.5, 1.0):
        _, s = ctx.render(CHAPTER, "scenes/cornell.scene", "--size", "8x8", "--spp", 6, "--photons", 1000,
                          "--radius", 20, "--alpha", alpha, "--probe-photons", 32, name=f"a{alpha}")
        r = s["radius_per_pass"]
        expect(len(r) == 6 and r[0] == 20, f"radius_per_pass {r} with --spp 6 --radius 20: expected 6 passes "
               "starting at 20")
        for i in range(1, 6):
            expect_close("radius^2", r[i] ** 2, r[i - 1] ** 2 * (i + alpha) / (i + 1), rel=1e-12,
                         where=f"of pass {i + 1} with --alpha {alpha}", by="r_i^2 (i + alpha) / (i + 1) (R12)",
                         words=("too large", "too small"))


# ---- plumbing -------------------------------------------------------------------------------------

def test_scale_invariance(ctx):
    """The Cornell box scaled by 1e-4 and 1e4 (default radius: 1/200 of the scene's diagonal,
    so it scales too) renders the same image as at scale 1 with the same seed, up to
    rounding (at most 0.5 % of pixels differ by more than 1e-3 relative; mean by 1e-4)."""
    from grade_extremes import mean_radiance, scale_scene
    with open(os.path.join(ROOT, "scenes", "cornell.scene")) as f:
        text = f.read()
    images = {}
    for s in (1.0, 1e-4, 1e4):
        scene = ctx.write(f"cornell-{s:g}.scene", scale_scene(text, s))
        images[s], _ = ctx.render(CHAPTER, scene, "--size", "32x32", "--spp", 2, "--photons", 20000, "--gather", 1,
                                  "--probe-photons", 32, name=f"s{s:g}")
        assert finite_image(images[s])
    base = images[1.0]
    for s in (1e-4, 1e4):
        differing = sum(1 for a, b in zip(base.pixels, images[s].pixels)
                        if any(abs(x - y) > 1e-3 * max(abs(x), 1e-3) for x, y in zip(a, b)))
        change = abs(mean_radiance(images[s]) - mean_radiance(base)) / mean_radiance(base)
        assert differing <= 0.005 * len(base.pixels), f"scale {s:g}: {differing} pixels differ"
        assert change < 1e-4, f"scale {s:g}: mean radiance changed by {change:.2e}"


def test_threads_give_identical_bytes(ctx):
    """Photons are traced in fixed chunks with per-photon streams and joined in order."""
    for maps in ("global", "caustic", "both"):
        check_thread_independence(ctx, CHAPTER, "scenes/cornell-spheres.scene", "--size", "24x24", "--spp", 3,
                                  "--photons", 20000, "--maps", maps, "--gather", 2, "--nearest", 16,
                                  "--probe-photons", 64)


def test_sigint_writes_completed_passes(ctx):
    from grade_driver import check_sigint
    check_sigint(ctx, CHAPTER)


# ---- several lights, picked by power; probes; the density estimate's radius ----------------------

def test_lights_picked_by_power_at_probes(ctx):
    """A photon leaves light l with probability its power's share P_l and carries Phi_l / (P_l N):
    with two point lights of different power and colour, a rectangular and a spherical emitter
    (grade_04's scene: picked 61, 16, 12 and 11 % of the time), the light the photons send to each
    probe from where they leave the lights (f Phi_p G V: f = cos / pi from an emitter, 1 / (4 pi)
    from a point light) expects the four lights' closed forms at the probe (Lambert's polygon
    formula, pi L (R/d)^2 cos for the sphere, I cos / r^2 for the point lights).  4 passes (the
    probes do not use the eye pass's radius).  Within t_bound(31, 6) standard errors (32 photon
    batches; 2 probes, 3 channels), each positive and below 1.5 % of the answer."""
    from grade_04_pathtrace import SEVERAL_LIGHTS_PROBES, SEVERAL_LIGHTS_SCENE, several_lights_irradiance, unit
    scene = ctx.write("several-lights.scene", SEVERAL_LIGHTS_SCENE + "".join(
        "probe %s  %g %g %g  %g %g %g\n" % (name, *p, *n) for name, (p, n) in SEVERAL_LIGHTS_PROBES.items()))
    bound = t_bound(BATCH_DF, 3 * len(SEVERAL_LIGHTS_PROBES))
    _, stats = ctx.render(CHAPTER, scene, "--radius", 0.25, "--spp", 4, "--photons", 1000, "--probe-photons", 1 << 19)
    for name, (p, n) in SEVERAL_LIGHTS_PROBES.items():
        got = probe(stats, name)
        for c in range(3):
            expected = several_lights_irradiance(p, unit(n), c)
            expect_estimate("irradiance", got["irradiance"][c], expected, got["standard_error"][c], bound,
                            0.015 * expected, where=f"at probe {name}, {CHANNELS[c]}",
                            by="the four lights' closed forms at the probe", positive=True)


def test_furnace_probe_keeps_the_bounces_window(ctx):
    """A probe 0.01 above the furnace's floor, facing up, receives the light each photon sends it from
    where it leaves a wall (k = 0) and from every wall it lands on after k - 1 scatterings: the
    irradiance pi Le rho^k, summed over the --bounces window: 0:0 pi Le, 1:1 pi Le rho, 0:
    pi Le / (1 - rho) (rho 0.5; the floor below the probe is behind it and sends nothing).  4 passes
    (the probes do not use the eye pass's radius).  Within t_bound(31, 3) standard errors (32 photon
    batches), each below 2 % of the answer (2^19 photons: about 0.1 %, against errors of 50 % and
    more when the window is wrong)."""
    rho = 0.5
    scene = furnace_scene(ctx, rho, name="probe-furnace")
    with open(scene, "a") as f:
        f.write("probe above_floor  0.2 -0.99 0.1  0 1 0\n")
    bound = t_bound(BATCH_DF, 3)
    for window, expected in (("0:0", math.pi), ("1:1", math.pi * rho), ("0:", math.pi / (1 - rho))):
        _, stats = ctx.render(CHAPTER, scene, "--size", "4x4", "--spp", 4, "--photons", 1000,
                              "--bounces", window, "--probe-photons", 1 << 19, name="w" + window.replace(":", "_"))
        got = probe(stats, "above_floor")
        expect_estimate("irradiance", got["irradiance"][0], expected, got["standard_error"][0], bound,
                        0.02 * expected, where=f"at the furnace's floor probe with --bounces {window}",
                        by="pi Le times the Neumann terms rho^k of the window", positive=True)


def test_density_estimate_for_any_radius_and_k_nearest(ctx):
    """(R11) in the furnace (rho 0.5, Le 1, --maps global): the photons land uniformly on each wall,
    all with the same power Phi, so a fixed disc lying on the wall is unbiased for any radius:
    L = Le / (1 - rho) = 2 at --radius 0.2 (the furnace criterion uses 0.05).  With --nearest K the
    disc is the one that holds the K nearest photons, at most --radius 1, which would reach past the
    wall's edges (a disc of that radius, or one of K photons that are not the nearest, reads the
    wall too dark): pi r_K^2 times the photon density is a Gamma(K) variable and E[1 / Gamma(K)] =
    1 / (K - 1), so K Phi / (pi r_K^2) reads the reflected part Le rho / (1 - rho) = 1 as K / (K - 1),
    and (K - 1) Phi / (pi r_K^2) as 1: the K-th photon lies on the disc's rim and is counted
    (the search takes r_K^2 itself: its square root squared again rounded below it in a quarter of
    the lookups), so with K = 32 L is 2 + 1/31.  --alpha 1 (the radius kept).  The
    central pixels' mean over RENDERS seeds, within t_bound(RENDERS - 1, 2) standard errors of that,
    each below 0.5 % of the answer; the noise comes from the number of photons
    on the wall, not from K: 20,000 photons per pass for the fixed disc, 10,000 for the K nearest
    (the search visits every photon within --radius 1: the whole furnace)."""
    rho = 0.5
    scene = furnace_scene(ctx, rho, name="radius-furnace")
    bound = t_bound(RENDERS - 1, 2)
    for label, options, low, high in (("--radius 0.2", ("--radius", 0.2, "--photons", 20000), 2.0, 2.0),
                                      ("--nearest 32", ("--radius", 1, "--nearest", 32, "--photons", 10000),
                                       2 + 1 / 31, 2 + 1 / 31)):
        results = renders(ctx, scene, range(1, RENDERS + 1), "--size", "24x24", "--spp", 2, "--alpha", 1,
                          "--maps", "global", *options, "--probe-photons", 32, "--threads", 1,
                          name="k" + label.split()[-1])
        nonfinite = sum(s["nonfinite_samples"] for _, s in results)
        expect(nonfinite == 0, f"{nonfinite} non-finite samples in the furnace with {label}; expected none",
               measured=nonfinite, expected=0, command=results[0][0].command)
        mean, se = mean_and_error([central_mean(img) for img, _ in results])
        by = "Le / (1 - rho): a fixed disc on the wall" if low == high else \
            f"Le + Le rho / (1 - rho) K / (K - 1) = {high:.4g} for the K nearest (the K-th photon on the rim counted)"
        expect_between("mean radiance", mean, low - bound * se, high + bound * se, expected=(low + high) / 2,
                       where=f"of the furnace's back wall (albedo {rho}) with {label} (± {bound:.2f} standard "
                             f"errors of {se:.2g})", by=by, command=results[0][0].command)
        expect(0 < se < 0.005 * low, f"standard error of the mean radiance with {label}: {se:.3g}, expected "
               f"positive and below {0.005 * low:.3g} so that the tolerance stays tight", measured=se,
               expected=0.005 * low, command=results[0][0].command)


def test_background_lights_an_open_floor(ctx):
    """A diffuse floor (albedo 0.5, 0.3, 0.1) under nothing but the background (Lb 0.2, 0.4, 0.6):
    its radiance is rho Lb.  The background shoots no photons, so only the walks find it: --maps
    caustic (a path tracer for all but caustics) and --maps both --gather 2 (final gathering),
    whose walks that leave the scene add the background times their weight.  No photon map here,
    so pixels are independent: the pixels' mean within t_bound(P - 1, 6) standard errors (2 runs,
    3 channels), each below 1 % of the answer."""
    from grade_04_pathtrace import OPEN_FLOOR_SCENE, iid_mean
    scene = ctx.write("open-floor.scene", OPEN_FLOOR_SCENE)
    albedo, background = (0.5, 0.3, 0.1), (0.2, 0.4, 0.6)
    for maps in (("--maps", "caustic"), ("--maps", "both", "--gather", 2)):
        img, _ = ctx.render(CHAPTER, scene, "--size", "32x32", "--spp", 32, *maps, "--probe-photons", 32,
                            name=maps[1])
        for c in range(3):
            mean, se = iid_mean(img, c)
            expect_estimate("mean radiance", mean, albedo[c] * background[c], se, t_bound(len(img.pixels) - 1, 6),
                            0.01 * albedo[c] * background[c], where=f"of the floor, {CHANNELS[c]} ({' '.join(map(str, maps))})",
                            by="rho Lb", positive=True)
