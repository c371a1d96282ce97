"""Grading chapter 1 (local illumination) against closed forms.

Each test builds a tiny scene whose answer is known from outside the
renderer: the inverse-square cosine law (R1), Lambert's polygon formula for
the irradiance from a rectangular emitter, and the BRDF formulas written
out again here in Python.
"""
import glob
import math
import os

from lib import (CHANNELS, CRITERION_ALPHA, ROOT, check_bad_input, check_probes_match_lambert,
                 check_thread_independence, expect, expect_between, expect_close, finite_image, kit_stats,
                 lambert_polygon_irradiance, probe)
from lib import BATCH_DF, t_bound

GRADES_NOTHING = True  # no grading, no handout: may run beside the RUN_ALONE tests (tests/run.py)

CHAPTER = "01_local"

# A floor (normal +y) seen from straight above, for pixel-exact checks.
FLOOR_SCENE = """\
camera eye 0 10 0  look 0 0 0  up 0 0 1  fov 30
image 9 9
material floor {floor_material}
quad floor floor  -50 0 -50  -50 0 50  50 0 50  50 0 -50
{extra}
"""


def test_point_light_probe_inverse_square_cosine(ctx):
    """(R1): E = I cos(theta) / r^2 at probes of several orientations, to rounding."""
    light, intensity = (0.3, 2.0, -0.4), (5.0, 6.0, 7.0)
    probes = {"up": ((0, 0, 0), (0, 1, 0)), "tilted": ((1, 0, 1), (0.6, 0.8, 0)),
              "far": ((3, 0, -2), (0, 1, 0))}
    extra = "light lamp point %g %g %g  %g %g %g\n" % (*light, *intensity)
    for name, (p, n) in probes.items():
        extra += "probe %s  %g %g %g  %g %g %g\n" % (name, *p, *n)
    scene = ctx.write("point.scene", FLOOR_SCENE.format(floor_material="diffuse 0.5 0.5 0.5", extra=extra))
    _, stats = ctx.render(CHAPTER, scene)
    for name, (p, n) in probes.items():
        d = [light[k] - p[k] for k in range(3)]
        r2 = sum(c * c for c in d)
        cos_theta = sum(d[k] * n[k] for k in range(3)) / math.sqrt(r2)
        got = probe(stats, name)
        for c in range(3):
            expected = intensity[c] * max(cos_theta, 0.0) / r2
            expect_close("irradiance", got["irradiance"][c], expected, rel=1e-12,
                         where=f"at probe {name}, {CHANNELS[c]}", by="I cos/r^2 (R1)")
            expect_close("standard error of the irradiance", got["standard_error"][c], 0.0, tol=0.0,
                         where=f"at probe {name} (a point light alone is exact)")


def test_point_light_pixel_is_R1(ctx):
    """The pixel looking straight down at the floor: L = rho/pi * I cos / r^2 (float rounding)."""
    rho, intensity, light = 0.5, 40.0, (1.0, 3.0, 0.5)
    scene = ctx.write("pixel.scene", FLOOR_SCENE.format(
        floor_material=f"diffuse {rho} {rho} {rho}",
        extra="light lamp point %g %g %g  %g %g %g" % (*light, intensity, intensity, intensity)))
    img, _ = ctx.render(CHAPTER, scene)
    # The centre pixel of a 9x9 image looks exactly along the view axis, at (0, 0, 0).
    r2 = sum(c * c for c in light)
    expected = rho / math.pi * intensity * light[1] / math.sqrt(r2) / r2
    got = img.at(4, 4)[0]
    expect_close("radiance of the centre pixel", got, expected, rel=1e-6, where="(the floor under a point light)",
                 by="rho/pi I cos/r^2 (R1)")


def test_shadow_ray_blocks_point_light(ctx):
    """A probe under an opaque square sees nothing of the light; --no-shadows restores I cos/r^2."""
    extra = ("quad blocker floor  -1 1 -1  1 1 -1  1 1 1  -1 1 1\n"
             "light lamp point 0 2 0  8 8 8\nprobe under 0 0 0  0 1 0\n")
    scene = ctx.write("shadow.scene", FLOOR_SCENE.format(floor_material="diffuse 0.5 0.5 0.5", extra=extra))
    _, stats = ctx.render(CHAPTER, scene)
    expect_close("irradiance", max(probe(stats, "under")["irradiance"]), 0.0, tol=0.0,
                 where="at a probe under an opaque square", by="its shadow ray is blocked")
    _, stats = ctx.render(CHAPTER, scene, "--no-shadows", name="noshadow")
    expect_close("irradiance", probe(stats, "under")["irradiance"][0], 8.0 / 4.0, tol=1e-12,
                 where="at the same probe with --no-shadows, red", by="I cos/r^2 (R1)")


def area_light_scene(ctx, radiance, probes):
    text = ("camera eye 0 -5 0  look 0 0 0  up 0 0 1  fov 30\nimage 4 4\n"
            "material lamp emitter %g %g %g\n" % radiance +
            "material ground diffuse 0.5 0.5 0.5\n"
            # unit square at height 1, vertex order so the normal points down (-y)
            "quad light lamp  -0.5 1 -0.5  0.5 1 -0.5  0.5 1 0.5  -0.5 1 0.5\n"
            "quad ground ground  -9 -0.01 -9  -9 -0.01 9  9 -0.01 9  9 -0.01 -9\n")
    for name, (p, n) in probes.items():
        text += "probe %s  %g %g %g  %g %g %g\n" % (name, *p, *n)
    return ctx.write("area.scene", text)


def test_area_light_probe_converges_to_lambert_formula(ctx):
    """A unit square of radiance L at height 1: E = 0.7522747 L under its centre
    (Lambert's polygon formula), and the formula again for an off-centre,
    tilted probe.  Tolerance: t_bound(31, 6) standard errors as estimated by the
    chapter from 32 independent batches (Student's t at CRITERION_ALPHA over the
    2 probes x 3 channels; 4 standard errors would be a false alarm 4e-4 times
    per probe at 31 degrees of freedom); the standard error itself must be below
    0.5 % so the tolerance stays tight."""
    radiance = (1.0, 2.0, 3.0)
    square = [(-0.5, 1, -0.5), (0.5, 1, -0.5), (0.5, 1, 0.5), (-0.5, 1, 0.5)]
    probes = {"centre": ((0, 0, 0), (0, 1, 0)),
              "offset": ((0.7, 0.2, -0.3), (-0.28, 0.96, 0.0))}
    scene = area_light_scene(ctx, radiance, probes)
    _, stats = ctx.render(CHAPTER, scene, "--probe-samples", 262144)
    assert abs(lambert_polygon_irradiance(1.0, square, (0, 0, 0), (0, 1, 0)) - 0.7522747) < 1e-7
    check_probes_match_lambert(stats, square, radiance, probes, 0.005)


def test_area_light_error_shrinks_with_samples(ctx):
    """Standard error falls like N^-1/2: 16x the samples, 1/4 the error.  Each standard error the
    chapter reports comes from 32 batch means (31 degrees of freedom), so the ratio of two is
    itself noisy: a flat band of 30 % around 4 failed the solution for 12 % of grading seeds
    (the instructor's calibration measures it).  Eight probes at one place, each with random numbers of its own, pool
    8 x 31 degrees of freedom: if the error falls like N^-1/2, the ratio of the summed squared
    standard errors divided by 16 follows F(248, 248) (normal batch means), and it must lie
    between its two-sided CRITERION_ALPHA quantiles (a ratio of errors between about 3.2 and 5.0)."""
    probes = {f"centre{i}": ((0, 0, 0), (0, 1, 0)) for i in range(8)}
    scene = area_light_scene(ctx, (1.0, 1.0, 1.0), probes)
    variances = []
    for n in (4096, 65536):
        _, stats = ctx.render(CHAPTER, scene, "--probe-samples", n, name=f"n{n}")
        variances.append(sum(probe(stats, name)["standard_error"][0] ** 2 for name in probes))
    df = 31 * len(probes)
    upper = kit_stats.f_quantile(CRITERION_ALPHA / 2, df, df)  # F(d, d): the lower quantile is 1 / upper
    expect(variances[1] > 0, f"the standard errors at 65536 samples are {math.sqrt(variances[1]):.3g}: a Monte Carlo "
           "estimate of an area light's irradiance must have a positive standard error", measured=variances[1])
    f = variances[0] / variances[1] / 16
    expect_between("ratio of the standard errors at 4096 and 65536 samples", 4 * math.sqrt(f),
                   4 / math.sqrt(upper), 4 * math.sqrt(upper), expected=4.0,
                   by=f"N^-1/2: 16x the samples, 1/4 the error (band: F test at alpha {CRITERION_ALPHA})")


def blinn_phong_expected(normalised, kd, ks, exponent, n, w_i, w_o, irradiance_perp):
    def dot(a, b): return sum(a[k] * b[k] for k in range(3))
    cos_i = dot(n, w_i)
    h = [w_i[k] + w_o[k] for k in range(3)]
    length = math.sqrt(dot(h, h))
    lobe = (dot(n, h) / length) ** exponent
    specular = ks * (exponent + 8) / (8 * math.pi) * lobe * cos_i if normalised else ks * lobe
    return (kd / math.pi * cos_i + specular) * irradiance_perp


def test_blinn_phong_pixel_classic_and_normalised(ctx):
    """The centre pixel of a glossy floor, light off to the side: both Blinn-Phong
    forms as written out in the chapter's comment, recomputed here."""
    kd, ks, exponent, light, intensity = 0.4, 0.5, 20.0, (3.0, 6.0, 0.0), 100.0
    scene = ctx.write("glossy.scene", FLOOR_SCENE.format(
        floor_material=f"phong kd {kd} {kd} {kd} ks {ks} {ks} {ks} exp {exponent}",
        extra="light lamp point %g %g %g  %g %g %g" % (*light, intensity, intensity, intensity)))
    r2 = sum(c * c for c in light)
    w_i = [c / math.sqrt(r2) for c in light]
    for normalised in (False, True):
        args = ["--model", "blinn"] + (["--normalised"] if normalised else [])
        img, _ = ctx.render(CHAPTER, scene, *args, name=f"n{normalised}")
        expected = blinn_phong_expected(normalised, kd, ks, exponent, (0, 1, 0), w_i, (0, 1, 0), intensity / r2)
        got = img.at(4, 4)[0]
        expect_close("radiance of the centre pixel", got, expected, rel=1e-6,
                     where=f"({'normalised' if normalised else 'classic'} Blinn-Phong)",
                     by="the chapter's Blinn-Phong formula, recomputed")


def test_ambient_term_is_albedo_times_ambient(ctx):
    """No lights: a Lambertian surface under uniform ambient radiance La reflects rho * La."""
    scene = ctx.write("ambient.scene", FLOOR_SCENE.format(floor_material="diffuse 0.25 0.5 0.75", extra=""))
    img, _ = ctx.render(CHAPTER, scene, "--ambient", 2.0)
    got = img.at(4, 4)
    for c, rho in enumerate((0.25, 0.5, 0.75)):
        assert abs(got[c] - 2.0 * rho) < 1e-6, f"channel {c}: {got[c]} vs rho La = {2 * rho}"


def test_cornell_image_finite_and_light_exact(ctx):
    """The Cornell box: every pixel finite, none rejected, and the pixel that sees
    the light shows its radiance (17, 12, 4) exactly (with ambient 0 nothing else
    reaches the eye from a downward-facing emitter)."""
    img, stats = ctx.render(CHAPTER, "scenes/cornell.scene", "--size", "64x64", "--light-samples", 4)
    assert finite_image(img), "non-finite pixels in the Cornell image"
    assert stats["nonfinite_samples"] == 0
    # The light's centre (278, 548.7, 279.5) projects to the top middle of the image.
    top = [img.at(x, y) for y in range(0, 10) for x in range(28, 36)]
    assert (17.0, 12.0, 4.0) in [tuple(round(c, 5) for c in px) for px in top], "no pixel sees the light's radiance"
    # Direct light reaches the floor: the probe under the light is lit, and the
    # floor is brighter than the (unlit) ceiling.
    assert probe(stats, "floor_left_front")["irradiance"][0] > 0.0, "a probe in view of the light gets no light"


def test_bounces_window_splits_the_neumann_terms(ctx):
    """--bounces in chapter 1 (R6): 0:0 is the emission seen directly (E), 1:1 the
    direct light of (R1) (KE), 2: the ambient term standing in for K^2 E and
    beyond (rho La), 2:2 nothing; and the three windows add up to the full image."""
    scene = ctx.write("bounces.scene", FLOOR_SCENE.format(
        floor_material="diffuse 0.25 0.5 0.75",
        extra="light lamp point 0 3 0  4 4 4\nmaterial glow emitter 2 3 4\nquad glow glow "
              "-1 0.01 -1  -1 0.01 1  1 0.01 1  1 0.01 -1\n"))
    windows = {w: ctx.render(CHAPTER, scene, "--ambient", 2.0, "--bounces", w, name=w.replace(":", "_"))[0]
               for w in ("0:", "0:0", "1:1", "2:", "2:2")}
    centre, edge = windows["0:"].at(4, 4), (4, 0)  # the emitter's centre; the floor beside it
    for c in range(3):
        expect_close("radiance", windows["0:0"].at(4, 4)[c], (2.0, 3.0, 4.0)[c], tol=0.0,
                     where=f"of the emitter with --bounces 0:0, {CHANNELS[c]}", by="its emission E exactly",
                     command=windows["0:0"].command)
        expect_close("radiance", windows["0:0"].at(*edge)[c], 0.0, tol=0.0,
                     where=f"of the floor with --bounces 0:0, {CHANNELS[c]}", by="the floor emits nothing",
                     command=windows["0:0"].command)
    direct = windows["1:1"].at(*edge)
    expect(direct[0] > 0, f"radiance of the floor with --bounces 1:1 (direct light KE), red: measured {direct[0]:.5g}, "
           "expected > 0 (the point light shines on it): too dark", measured=direct[0], command=windows["1:1"].command)
    expect_close("red / blue of the floor's direct light", direct[0] / direct[2], 0.25 / 0.75, tol=1e-6,
                 where="with --bounces 1:1", by="the albedo's ratio 0.25 / 0.75", command=windows["1:1"].command)
    for c, rho in enumerate((0.25, 0.5, 0.75)):
        expect_close("radiance", windows["2:"].at(*edge)[c], 2.0 * rho, tol=1e-6,
                     where=f"of the floor with --bounces 2:, {CHANNELS[c]}", by="the ambient term rho La alone",
                     command=windows["2:"].command)
    brightest = max(max(p) for p in windows["2:2"].pixels)
    expect_close("brightest pixel radiance", brightest, 0.0, tol=0.0, where="with --bounces 2:2",
                 by="black: the ambient term stands for bounces 2 and up", command=windows["2:2"].command)
    for k in range(len(windows["0:"].pixels)):
        parts = [windows[w].pixels[k] for w in ("0:0", "1:1", "2:")]
        assert all(abs(sum(p[c] for p in parts) - windows["0:"].pixels[k][c]) <= 1e-5 * (1 + abs(centre[c]))
                   for c in range(3)), f"pixel {k}: E + KE + ambient differs from the full image"


def test_threads_give_identical_bytes(ctx):
    """The per-pixel generator makes the image independent of the thread count."""
    check_thread_independence(ctx, CHAPTER, "scenes/cornell.scene", "--size", "48x48", "--spp", 4)


def test_bad_command_lines_exit_2(ctx):
    check_bad_input(ctx, CHAPTER, ["scenes/cornell.scene", "--frobnicate"], "argv:")
    check_bad_input(ctx, CHAPTER, ["scenes/cornell.scene", "--spp", "0"], "argv:")
    check_bad_input(ctx, CHAPTER, ["scenes/cornell.scene", "--size", "12"], "argv:")
    check_bad_input(ctx, CHAPTER, ["scenes/cornell.scene", "--bounces", "3:1"], "argv:")
    check_bad_input(ctx, CHAPTER, ["scenes/cornell.scene", "--model", "torrance"], "argv:")
    check_bad_input(ctx, CHAPTER, ["scenes/does-not-exist.scene"], "scenes/does-not-exist.scene:")


def test_failed_render_keeps_existing_output(ctx):
    """A bad scene must not overwrite what is already under the output name."""
    out = ctx.write("keep.pfm", "previous contents")
    r = ctx.run(CHAPTER, "tests/bad/" + os.path.basename(sorted(glob.glob(os.path.join(ROOT, "tests/bad/*.scene")))[0]),
                "--out", out)
    assert r.returncode == 2
    with open(out) as f:
        assert f.read() == "previous contents"
    r = ctx.run(CHAPTER, "scenes/cornell.scene", "--size", "8x8", "--out", "/nonexistent-dir/x.pfm")
    assert r.returncode == 2 and r.stderr.startswith("/nonexistent-dir/x.pfm:"), r.stderr


def test_two_point_lights_and_an_area_light_add_at_probes(ctx):
    """(R1) summed over every light: two point lights of different power and colour beside a
    square emitter.  At each probe E = Lambert's polygon formula for the square plus
    I_k cos / r_k^2 for each point light k (none is shadowed), within t_bound(31, 9)
    standard errors of the area light's estimate (the point lights are exact), and that
    standard error positive and below 0.5 % of the answer so the tolerance stays tight."""
    radiance = (1.0, 2.0, 3.0)
    square = [(-0.5, 1, -0.5), (0.5, 1, -0.5), (0.5, 1, 0.5), (-0.5, 1, 0.5)]
    lights = {"bright": ((2.0, 0.5, 0.0), (8.0, 6.0, 4.0)), "dim": ((-1.5, 0.4, 1.0), (0.5, 1.0, 2.0))}
    probes = {"centre": ((0, 0, 0), (0, 1, 0)), "offset": ((0.7, 0.2, -0.3), (-0.28, 0.96, 0.0)),
              "left": ((-1.0, 0.0, 0.5), (0.0, 1.0, 0.0))}
    text = open(area_light_scene(ctx, radiance, probes)).read()
    for name, (p, intensity) in lights.items():
        text += "light %s point %g %g %g  %g %g %g\n" % (name, *p, *intensity)
    scene = ctx.write("lights.scene", text)
    _, stats = ctx.render(CHAPTER, scene, "--probe-samples", 262144)
    bound = t_bound(BATCH_DF, 3 * len(probes))
    for name, (p, n) in probes.items():
        length = math.sqrt(sum(c * c for c in n))
        n = [c / length for c in n]
        got = probe(stats, name)
        for c in range(3):
            area = lambert_polygon_irradiance(radiance[c], square, p, n)
            points = 0.0
            for position, intensity in lights.values():
                d = [position[k] - p[k] for k in range(3)]
                r2 = sum(x * x for x in d)
                points += intensity[c] * max(sum(d[k] * n[k] for k in range(3)) / math.sqrt(r2), 0.0) / r2
            expected = area + points
            se = got["standard_error"][c]
            expect_close("irradiance", got["irradiance"][c], expected, se=se, bound=bound,
                         where=f"at probe {name}, {CHANNELS[c]}",
                         by=f"area light {area:.5g} (Lambert) + point lights {points:.5g} (I cos/r^2)")
            expect(0 < se < 0.005 * expected, f"standard error of the irradiance at probe {name}: {se:.3g}, expected "
                   f"positive and below 0.5 % of {expected:.5g} so the tolerance stays tight", measured=se)
