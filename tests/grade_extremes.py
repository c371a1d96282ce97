"""Numerical extremes, for every chapter.

Scale (the Cornell box in kilometres and in tenths of a micrometre), grazing
views, albedo 0 and 0.999, a tiny very bright light, IOR 1 and 4, zero-area
triangles inside a mesh, a light coplanar with the ceiling.  Every image must
be finite; where an answer is known, the image must show it.

Chapter 7's image is a Markov chain's histogram: one rounding difference that
flips one acceptance sends the chain elsewhere from then on, and with albedo 0
a pixel holds Le times how often the chain landed in it.  So for it the scaled
scenes must agree in their normalisation b (the image's mean luminance, from
independent paths and the large steps: within 4 standard errors), not pixel by
pixel, and the albedo-0 image's mean is b, Le within 4 standard errors.
Chapter 6 has its extreme scales in grade_06_bidirectional.py.
"""
import math
import os
import re
import subprocess

from lib import ROOT, finite_image, lambert_polygon_irradiance, probe

GRADES_NOTHING = True  # no grading, no handout: may run beside the RUN_ALONE tests (tests/run.py)

CHAPTERS = ("01_local", "02_whitted", "03_radiosity", "03c_hierarchical", "04_pathtrace", "05_photonmap",
            "07_metropolis")  # 06: grade_06
MARKOV_CHAIN = "07_metropolis"  # its pixels are not comparable one by one (module docstring)
# Per-chapter settings that keep a 32x32 render well under a second.
QUICK = {
    "01_local": ["--light-samples", "4"],
    "02_whitted": ["--light-samples", "4"],
    "03_radiosity": ["--patch-size", "100"],
    "03c_hierarchical": ["--eps", "0.1", "--levels", "4", "--quadrature", "1", "--eps-spread", "0"],
    "04_pathtrace": ["--spp", "16"],
    "05_photonmap": ["--photons", "20000", "--probe-photons", "4096"],
    "07_metropolis": ["--spp", "4", "--bootstrap", "4000"],
}


def cornell_text():
    with open(os.path.join(ROOT, "scenes", "cornell.scene")) as f:
        return f.read()


def scale_scene(text, s):
    """The same scene with every length multiplied by s: positions and radii
    scale, directions, angles and radiances do not, and a point light's
    intensity scales by s^2 (so I / r^2 stays the same)."""
    out = []
    for line in text.splitlines():
        code = line.split("#", 1)[0]
        f = code.split()
        if not f:
            out.append(line)
            continue
        kind = f[0]

        def scaled(tokens):
            return [repr(float(t) * s) for t in tokens]
        if kind == "camera":
            f = ["camera", "eye", *scaled(f[2:5]), "look", *scaled(f[6:9]), *f[9:]]
        elif kind in ("quad", "triangle"):
            f = f[:3] + scaled(f[3:])
        elif kind == "sphere":
            f = f[:3] + scaled(f[3:7])
        elif kind == "light":
            f = f[:3] + scaled(f[3:6]) + [repr(float(t) * s * s) for t in f[6:9]]
        elif kind == "probe":
            f = f[:2] + scaled(f[2:5]) + f[5:]
        out.append(" ".join(f))
    return "\n".join(out) + "\n"


def mean_radiance(img):
    return sum(sum(px) for px in img.pixels) / (3 * len(img.pixels))


def mean_luminance(img):
    return sum(0.2126 * r + 0.7152 * g + 0.0722 * b for r, g, b in img.pixels) / len(img.pixels)


def test_scale_invariance_every_chapter(ctx):
    """The Cornell box scaled by 1e-4 and by 1e4 renders the same image as at
    scale 1 (same seed, so the same random numbers): no acne (self-hits would
    darken lit surfaces), no light leaks.  Only rounding may differ, which can
    move a ray across a triangle edge; so at most 0.5 % of the pixels may
    differ by more than 1e-3 relative, and the mean radiance by 1e-4."""
    text = cornell_text()
    for chapter in CHAPTERS:
        images, stats = {}, {}
        for s in (1.0, 1e-4, 1e4):
            scene = ctx.write(f"cornell-{s:g}.scene", scale_scene(text, s))
            extra = list(QUICK[chapter])
            if chapter == "03_radiosity":
                extra = ["--patch-size", repr(100 * s)]
            images[s], stats[s] = ctx.render(chapter, scene, "--size", "32x32", *extra, name=f"{chapter}-{s:g}")
            assert finite_image(images[s]), f"{chapter} scale {s}: non-finite pixels"
        base = images[1.0]
        for s in (1e-4, 1e4):
            mean_change = abs(mean_radiance(images[s]) - mean_radiance(base)) / mean_radiance(base)
            if chapter == MARKOV_CHAIN:
                b, b1 = stats[s]["b"], stats[1.0]["b"]
                bound = 4 * math.hypot(stats[s]["b_standard_error"], stats[1.0]["b_standard_error"])
                assert abs(b - b1) <= bound, f"{chapter} scale {s:g}: b {b} against {b1} at scale 1 (bound {bound})"
                assert abs(mean_luminance(images[s]) - b) <= 1e-5 * b, \
                    f"{chapter} scale {s:g}: the image's mean luminance {mean_luminance(images[s])} is not b = {b}"
                continue
            differing = sum(1 for a, b in zip(base.pixels, images[s].pixels)
                            if any(abs(x - y) > 1e-3 * max(abs(x), 1e-3) for x, y in zip(a, b)))
            assert differing <= 0.005 * len(base.pixels), \
                f"{chapter} scale {s:g}: {differing} of {len(base.pixels)} pixels differ (acne or leaks)"
            assert mean_change < 1e-4, f"{chapter} scale {s:g}: mean radiance changed by {mean_change:.2e}"


def test_grazing_camera_finite(ctx):
    """A camera 1e-6 mm above the floor, looking along it: every pixel finite."""
    text = cornell_text().replace("camera eye 278 273 -800  look 278 273 0",
                                  "camera eye 278 0.000001 10  look 278 0.000001 500")
    scene = ctx.write("grazing.scene", text)
    for chapter in CHAPTERS:
        img, stats = ctx.render(chapter, scene, "--size", "24x24", *QUICK[chapter], name=chapter)
        assert finite_image(img) and stats["nonfinite_samples"] == 0, f"{chapter}: non-finite at grazing view"


FURNACE = """\
camera eye 0.5 0.5 0.1  look 0.5 0.5 1  up 0 1 0  fov 60
material wall emitter {e} {e} {e}  diffuse {rho} {rho} {rho}
# every wall counter-clockwise seen from inside: normals point into the box
quad floor   wall  0 0 0  0 0 1  1 0 1  1 0 0
quad ceiling wall  0 1 0  1 1 0  1 1 1  0 1 1
quad back    wall  0 0 1  0 1 1  1 1 1  1 0 1
quad front   wall  0 0 0  1 0 0  1 1 0  0 1 0
quad left    wall  0 0 0  0 1 0  0 1 1  0 0 1
quad right   wall  1 0 0  1 0 1  1 1 1  1 1 0
"""

def test_albedo_zero_shows_emission_only(ctx):
    """Albedo 0: nothing is reflected, every chapter shows exactly Le."""
    scene = ctx.write("black.scene", FURNACE.format(e=0.5, rho=0.0))
    for chapter in CHAPTERS:
        img, stats = ctx.render(chapter, scene, "--size", "8x8", *QUICK[chapter], name=chapter)
        if chapter == MARKOV_CHAIN:  # the mean is b, a Monte Carlo estimate (strategies weigh paths differently)
            b, se = stats["b"], stats["b_standard_error"]
            assert abs(b - 0.5) <= 4 * se + 1e-9 and abs(mean_luminance(img) - b) <= 1e-5 * b, \
                f"{chapter}: albedo 0 furnace: b {b} +- {se}, image mean luminance {mean_luminance(img)}, Le 0.5"
            continue
        worst = max(abs(c - 0.5) for px in img.pixels for c in px)
        assert worst < 1e-6, f"{chapter}: albedo 0 furnace deviates from Le by {worst}"


def test_albedo_0999_furnace(ctx):
    """Albedo 0.999: L = Le / (1 - rho) = 1000 Le.  Radiosity (direct solve):
    with form-factor row sums S in [S_min, S_max] (reported in stats; 1 up
    to quadrature error) every patch lies between Le / (1 - rho S_min) and
    Le / (1 - rho S_max), plus float rounding of the image (1e-6 relative);
    path tracing within 4 standard errors of the per-pixel sample mean (paths
    of about 1000 bounces: Russian roulette must not cut them short)."""
    e, rho = 0.001, 0.999
    scene = ctx.write("furnace999.scene", FURNACE.format(e=e, rho=rho))
    expected = e / (1 - rho)
    img, stats = ctx.render("03_radiosity", scene, "--size", "8x8", "--patch-size", "0.25", "--solver", "direct")
    low = e / (1 - rho * stats["row_sum_min"]) * (1 - 1e-6)
    high = e / (1 - rho * stats["row_sum_max"]) * (1 + 1e-6)
    values = [c for px in img.pixels for c in px]
    assert low <= min(values) and max(values) <= high, \
        f"radiosity furnace 0.999: pixels in [{min(values)}, {max(values)}], bounds [{low}, {high}]"
    img, stats = ctx.render("04_pathtrace", scene, "--size", "16x16", "--spp", "64", "--max-depth", "100000",
                            "--estimator", "cosine", name="pt")
    values = [sum(px) / 3 for px in img.pixels]
    n = len(values)
    m = sum(values) / n
    se = math.sqrt(sum((v - m) ** 2 for v in values) / (n - 1) / n)
    assert finite_image(img)
    assert abs(m - expected) < 4 * se + 1e-9, f"path tracing furnace 0.999: {m:.4f} vs {expected} (4 SE = {4 * se:.4f})"
    assert se < 0.1 * expected, f"standard error {se} too large for the test to mean anything"


def tiny_light_scene(ctx):
    # 1e-6 of the Cornell light's area (130 x 105 mm -> 0.13 x 0.105 mm), 1e6 times its radiance.
    text = cornell_text()
    text = re.sub(r"^material light emitter 17 12 4", "material light emitter 17e6 12e6 4e6", text, flags=re.M)
    x0, x1, z0, z1 = 278 - 0.065, 278 + 0.065, 279.5 - 0.0525, 279.5 + 0.0525
    quad = f"quad light light  {x1} 548.7 {z0}  {x1} 548.7 {z1}  {x0} 548.7 {z1}  {x0} 548.7 {z0}"
    text = re.sub(r"^quad light light.*$", quad, text, flags=re.M)
    return ctx.write("tiny-light.scene", text), [(x1, 548.7, z0), (x1, 548.7, z1), (x0, 548.7, z1), (x0, 548.7, z0)]


def test_tiny_bright_light(ctx):
    """A light of 1e-6 of the area with 1e6 times the radiance: finite images
    in every chapter, and at the probe in full view of it the direct
    irradiance of Lambert's polygon formula (chapter 1: within 4 of its
    standard errors; radiosity's probe gathers with the same formula: 1e-6)."""
    scene, polygon = tiny_light_scene(ctx)
    expected = [lambert_polygon_irradiance(L, polygon, (400, 0, 150), (0, 1, 0)) for L in (17e6, 12e6, 4e6)]
    for chapter in CHAPTERS:
        img, stats = ctx.render(chapter, scene, "--size", "24x24", *QUICK[chapter], name=chapter)
        assert finite_image(img) and stats["nonfinite_samples"] == 0, f"{chapter}: non-finite with a tiny light"
        if chapter == "01_local":
            p = probe(stats, "floor_left_front")
            for c in range(3):
                assert abs(p["irradiance"][c] - expected[c]) <= 4 * p["standard_error"][c] + 1e-9 * expected[c], \
                    f"{chapter}: probe {p['irradiance'][c]} vs Lambert {expected[c]}"


GLASS_BALL = """\
camera eye 0 0 -5  look 0 0 0  up 0 1 0  fov 30
background 2 2 2
material glass glass {ior}
sphere ball glass  0 0 0  1
"""


def test_ior_one_is_invisible_and_four_is_finite(ctx):
    """A glass ball of IOR 1 in uniform background radiance B is invisible
    (no reflection, no bending): every pixel is B.  At IOR 4 (R = 0.36 at normal
    incidence) a lossless ball in a uniform field still shows B everywhere up
    to the depth cut (Whitted) or within 4 standard errors (path tracing):
    radiance is conserved along every path."""
    for ior in (1.0, 4.0):
        scene = ctx.write(f"ball{ior}.scene", GLASS_BALL.format(ior=ior))
        img, _ = ctx.render("02_whitted", scene, "--size", "16x16", "--max-depth", "64", name=f"w{ior}")
        worst = max(abs(c - 2.0) for px in img.pixels for c in px)
        # Whitted loses R^64 + ... at the depth cut; at IOR 4 inside, rays past the critical angle (14.5 deg)
        # bounce; 64 levels leave at most a few 1e-3 of the weight.
        assert worst < (1e-6 if ior == 1.0 else 0.02), f"Whitted, IOR {ior}: max deviation from B {worst}"
        img, _ = ctx.render("04_pathtrace", scene, "--size", "16x16", "--spp", "64", name=f"p{ior}")
        values = [sum(px) / 3 for px in img.pixels]
        n = len(values)
        m = sum(values) / n
        se = math.sqrt(sum((v - m) ** 2 for v in values) / (n - 1) / n)
        assert finite_image(img)
        assert abs(m - 2.0) <= 4 * se + 1e-6, f"path tracing, IOR {ior}: mean {m} vs B = 2 (4 SE = {4 * se})"


def test_zero_area_triangles_in_mesh(ctx):
    """An OBJ with zero-area faces mixed in: they are skipped, every chapter renders finite."""
    obj = ctx.write("mesh.obj", "v 100 0 100\nv 400 0 100\nv 400 300 100\nv 100 300 100\nv 250 150 100\n"
                                "f 1 2 3\nf 1 3 4\nf 1 1 2\nf 1 5 3\nf 2 2 2\n")
    text = cornell_text() + f"mesh panel white {obj}\n"
    scene = ctx.write("mesh.scene", text)
    for chapter in CHAPTERS:
        img, stats = ctx.render(chapter, scene, "--size", "24x24", *QUICK[chapter], name=chapter)
        assert finite_image(img) and stats["nonfinite_samples"] == 0, f"{chapter}: non-finite with a degenerate mesh"


def test_light_coplanar_with_ceiling(ctx):
    """The light exactly in the ceiling plane (as on the data page): finite
    images, and the direct irradiance at a probe is unchanged from the light
    0.1 mm lower to within the geometry change (chapter 1, 4 standard errors
    plus the 0.1 mm effect, bounded by 0.1 %)."""
    text = cornell_text().replace("548.7", "548.8")
    scene = ctx.write("coplanar.scene", text)
    for chapter in CHAPTERS:
        img, stats = ctx.render(chapter, scene, "--size", "24x24", *QUICK[chapter], name=chapter)
        assert finite_image(img) and stats["nonfinite_samples"] == 0, f"{chapter}: non-finite with a coplanar light"
    _, coplanar = ctx.render("01_local", scene, "--size", "4x4", name="c1")
    _, lowered = ctx.render("01_local", "scenes/cornell.scene", "--size", "4x4", name="c2")
    a, b = probe(coplanar, "floor_left_front"), probe(lowered, "floor_left_front")
    for c in range(3):
        bound = 4 * math.hypot(a["standard_error"][c], b["standard_error"][c]) + 1e-3 * b["irradiance"][c]
        assert abs(a["irradiance"][c] - b["irradiance"][c]) <= bound, \
            f"coplanar light: probe {a['irradiance'][c]} vs {b['irradiance'][c]} (bound {bound})"


def test_valgrind_memcheck_each_chapter(ctx):
    """valgrind memcheck on a tiny scene (the furnace box, 4x4 pixels): no
    invalid access, no definite leak."""
    if ctx.build != "build":
        return  # the sanitizer build already checks memory; valgrind and ASan do not mix
    scene = ctx.write("tiny.scene", FURNACE.format(e=0.5, rho=0.5) + "light lamp point 0.5 0.9 0.5  1 1 1\n"
                      "probe p  0.5 0 0.5  0 1 0\n")
    settings = {"01_local": ["--probe-samples", "64"], "02_whitted": [], "03_radiosity": ["--patch-size", "0.5"],
                "03c_hierarchical": ["--levels", "3", "--eps", "0.1"],
                "04_pathtrace": ["--spp", "2", "--probe-samples", "64"],
                "05_photonmap": ["--photons", "2000", "--probe-photons", "64"],
                "07_metropolis": ["--spp", "2", "--bootstrap", "200", "--chains", "4"]}
    for chapter in CHAPTERS:
        exe = os.path.join(ROOT, ctx.build, chapter)
        r = subprocess.run(["valgrind", "-q", "--error-exitcode=99", "--leak-check=full",
                            "--errors-for-leak-kinds=definite", "--show-possibly-lost=no", exe,
                            scene, "--size", "4x4", "--quiet", "--out", ctx.path("v.pfm"), "--stats",
                            ctx.path("v.json"), *settings[chapter]], cwd=ROOT, capture_output=True, text=True,
                           timeout=300)
        assert r.returncode == 0, f"{chapter}: valgrind exit {r.returncode}\n{r.stderr[-2000:]}"
