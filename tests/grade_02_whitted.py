"""Grading chapter 2 (Whitted ray tracing) against closed forms.

The truths used here come from outside the renderer: a mirror multiplies
radiance by its colour; a lossless dielectric in a uniform environment is
invisible (R + T = 1, summed over the whole ray tree); the Fresnel
reflectance at normal incidence ((n-1)/(n+1))^2 and the geometric series of
internal reflections it starts; Snell's law traced again in Python (the
sideways shift of a slab); total internal reflection beyond asin(n_t/n_i);
Beer-Lambert's exponential.  Images are 1 sample per pixel through pixel
centres, so there is no Monte Carlo noise in any of these tests: with point
lights only, every pixel is a deterministic sum, compared to float rounding.
(The Fresnel function itself is unit-tested in tests/test_optics.c.)
"""
import math
import os

from lib import (CHANNELS, check_bad_input, check_thread_independence, expect, expect_at_least, expect_at_most,
                 expect_between, expect_close, expect_image, finite_image)

GRADES_NOTHING = True  # no grading, no handout: may run beside the RUN_ALONE tests (tests/run.py)

CHAPTER = "02_whitted"
FLOAT = 2e-6  # relative rounding of float32 pixels after a few double operations


def sub(a, b): return [a[k] - b[k] for k in range(3)]
def add(a, b): return [a[k] + b[k] for k in range(3)]
def scale(a, s): return [a[k] * s for k in range(3)]
def dot(a, b): return sum(a[k] * b[k] for k in range(3))
def cross(a, b): return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
def unit(a): return scale(a, 1.0 / math.sqrt(dot(a, a)))


def camera_ray(eye, look, up, fov, width, height, px, py):
    """The pinhole camera of common/scene.c: vertical fov, image y down."""
    forward = unit(sub(look, eye))
    right = unit(cross(forward, up))
    true_up = cross(right, forward)
    half_h = math.tan(math.radians(fov) / 2)
    half_w = half_h * width / height
    sx = (2 * px / width - 1) * half_w
    sy = (1 - 2 * py / height) * half_h
    return unit(add(forward, add(scale(right, sx), scale(true_up, sy))))


def box_quads(name, material, centre, half, angle_deg):
    """Six quads of a box turned about y, each wound so its normal points out."""
    a = math.radians(angle_deg)
    c, s = math.cos(a), math.sin(a)

    def corner(sx, sy, sz):
        x, y, z = sx * half[0], sy * half[1], sz * half[2]
        return [centre[0] + c * x + s * z, centre[1] + y, centre[2] - s * x + c * z]
    faces = {"xp": [(1, -1, -1), (1, 1, -1), (1, 1, 1), (1, -1, 1)], "xn": [(-1, -1, -1), (-1, -1, 1), (-1, 1, 1), (-1, 1, -1)],
             "yp": [(-1, 1, -1), (-1, 1, 1), (1, 1, 1), (1, 1, -1)], "yn": [(-1, -1, -1), (1, -1, -1), (1, -1, 1), (-1, -1, 1)],
             "zp": [(-1, -1, 1), (1, -1, 1), (1, 1, 1), (-1, 1, 1)], "zn": [(-1, -1, -1), (-1, 1, -1), (1, 1, -1), (1, -1, -1)]}
    lines = []
    for face, corners in faces.items():
        p = [corner(*v) for v in corners]
        normal = cross(sub(p[1], p[0]), sub(p[2], p[0]))
        assert dot(normal, sub(scale(add(add(p[0], p[1]), add(p[2], p[3])), 0.25), centre)) > 0
        lines.append(f"quad {name}_{face} {material}  " + "  ".join(" ".join(repr(v) for v in q) for q in p))
    return "\n".join(lines) + "\n"


def fresnel_normal(n):
    return ((n - 1) / (n + 1)) ** 2


# ---- mirrors -----------------------------------------------------------------------

MIRROR_SCENE = """\
camera eye 0 5 -5  look 0 0 0  up 0 1 0  fov 30
image 15 11
background {background}
material silver mirror 0.9 0.6 0.3
material sky emitter 5 1 0.5
quad floor silver  -100 0 -100  -100 0 100  100 0 100  100 0 -100
light lamp point  0 3 0  50 50 50
{extra}
"""


def test_mirror_pixel_is_colour_times_reflected_radiance(ctx):
    """Every pixel sees a mirror (0.9, 0.6, 0.3) and, in it, either a constant
    emitter wall of radiance (5, 1, 0.5) or the background (2, 3, 4): the pixel
    is the colour times that radiance, to float rounding.  The point light
    above the mirror adds nothing (a mirror has no diffuse part, and a point
    is never seen in it).  With --max-depth 0 the reflected ray is not
    traced and the mirror is black; --bounces keeps the reflection only in
    windows that contain the term K^1 E."""
    colour = (0.9, 0.6, 0.3)
    wall = "quad wall sky  -1000 -1 60  -1000 1000 60  1000 1000 60  1000 -1 60"  # normal -z, toward the mirror
    cases = {"emitter": ("0 0 0", wall, (5.0, 1.0, 0.5)), "background": ("2 3 4", "", (2.0, 3.0, 4.0))}
    for name, (background, extra, seen) in cases.items():
        scene = ctx.write(f"mirror-{name}.scene", MIRROR_SCENE.format(background=background, extra=extra))
        img, stats = ctx.render(CHAPTER, scene, name=name)
        seeing = f"(the mirror {colour} reflecting the {name} of radiance {seen})"
        expect_image("radiance of the mirror", img, lambda x, y, c: colour[c] * seen[c], rel=FLOAT, where=seeing,
                     by="mirror colour x the radiance it reflects")
        expect_close("reflected rays", stats["counters"]["reflected_rays"], img.width * img.height, tol=0,
                     by="one per pixel: every pixel sees the mirror", command=img.command)
        img, stats = ctx.render(CHAPTER, scene, "--max-depth", 0, name=name + "-depth0")
        expect_image("radiance of the mirror with --max-depth 0", img, lambda x, y, c: 0.0, tol=0, where=seeing,
                     by="black: the reflected ray is not traced")
        expect_close("branches cut by --max-depth 0", stats["counters"]["depth_limited_branches"],
                     img.width * img.height, tol=0, by="one per pixel", command=img.command)
        # (R6): light seen in the mirror has been reflected once, the term K^1 E.
        for window, factor in (("1:1", 1.0), ("0:0", 0.0), ("2:", 0.0)):
            img, _ = ctx.render(CHAPTER, scene, "--bounces", window, name=name + "-bounces")
            for c in range(3):
                expect_close(f"radiance of the mirror with --bounces {window}", img.at(7, 5)[c],
                             factor * colour[c] * seen[c], tol=FLOAT * seen[c],
                             where=f"at pixel (7, 5), {CHANNELS[c]} {seeing}", command=img.command,
                             by=f"{factor:g} x colour x radiance: what a mirror shows is the term K^1 E")


# ---- glass: energy and the series of internal reflections ------------------------------

SPHERE_SCENE = """\
camera eye 0 0 -10  look 0 0 0  up 0 1 0  fov {fov}
image {size} {size}
background {background}
material glass glass {glass}
sphere ball glass  0 0 0  1
{extra}
"""


def test_glass_ball_in_uniform_light_is_invisible(ctx):
    """A clear glass ball (n = 1.5, and an 'air bubble' n = 1/1.5) under a uniform
    background B: whatever it reflects and refracts comes from B, and R + T = 1
    at each interface, so every pixel equals B except for the light the tree
    loses at --max-depth D.  A ray inside a sphere meets the surface at the
    same angle every time, so after D levels the loss is T R^(D-1) <=
    max_R (1-R) R^(D-1) = (1/D)(1 - 1/D)^(D-1), 0.93 % for D = 40, and
    nothing can exceed B.  The centre pixel (normal incidence, R = 0.04)
    loses less than 1e-50: it must be B to float rounding.  Checked for the
    exact Fresnel formula and for Schlick's (which also has T = 1 - R)."""
    depth, background = 40, 1.5
    bound = (1 / depth) * (1 - 1 / depth) ** (depth - 1)
    for ior in (1.5, 1 / 1.5):
        for formula in ("exact", "schlick"):
            scene = ctx.write("furnace.scene", SPHERE_SCENE.format(fov=12, size=33, background=f"{background} " * 3,
                                                                   glass=ior, extra=""))
            img, stats = ctx.render(CHAPTER, scene, "--max-depth", depth, "--fresnel", formula, name="furnace")
            low = min(min(px) for px in img.pixels)
            high = max(max(px) for px in img.pixels)
            ball = f"of the glass ball (n = {ior:.4f}, --fresnel {formula}) under a uniform background"
            band = dict(expected=background, where=ball, command=img.command,
                        by=f"the background B: R + T = 1, less at most {bound:.2%} lost at --max-depth {depth}")
            expect_between("radiance of the brightest pixel", high, background * (1 - bound) - FLOAT,
                           background * (1 + FLOAT), **band)
            expect_between("radiance of the darkest pixel", low, background * (1 - bound) - FLOAT,
                           background * (1 + FLOAT), **band)
            expect_image("radiance", img, lambda x, y, c: background, rel=FLOAT, pixels=[(16, 16)],
                         where=f"(the centre) {ball}", by="B: at normal incidence the tree loses less than 1e-50")
            expect(stats["counters"]["refracted_rays"] > 0,
                   f"refracted rays: {stats['counters']['refracted_rays']}, expected more than 0 (the ball refracts)",
                   measured=stats["counters"]["refracted_rays"], expected=1)


def test_tinted_ball_centre_pixel_series(ctx):
    """The ray through the ball's centre meets both surfaces at normal incidence
    (R = 0.04, T = 0.96), in front of a black background and an emitter wall of
    radiance 1 behind the ball.  Light reaching the eye: it crosses the ball
    once, then any even number of extra internal reflections, a geometric
    series.  With the tint t as a filter on entering (default) the series is
        T t T (1 + R^2 + R^4 + ...) = t T^2 / (1 - R^2);
    with --absorption D (Beer-Lambert, a = t^(2r/D) per crossing of the
    diameter 2r) it is
        T^2 a / (1 - R^2 a^2).
    The reflection from the front sees the black background behind the camera."""
    tint, distance, radius = 0.6, 0.5, 1.0
    R = fresnel_normal(1.5)
    T = 1 - R
    wall = "material sky emitter 1 1 1\nquad wall sky  -100 -100 5  -100 100 5  100 100 5  100 -100 5"
    scene = ctx.write("tinted.scene", SPHERE_SCENE.format(fov=12, size=9, background="0 0 0",
                                                          glass=f"1.5 {tint} 1 1", extra=wall))
    img, _ = ctx.render(CHAPTER, scene, "--max-depth", 30, name="filter")
    expected = [tint * T * T / (1 - R * R), T * T / (1 - R * R), None]
    centre = "(the centre, through the ball tinted 0.6 in red) "
    expect_image("radiance", img, lambda x, y, c: expected[c], rel=FLOAT, pixels=[(4, 4)],
                 where=centre + "with the tint as a filter", by="the series t T^2 / (1 - R^2) (red), T^2 / (1 - R^2)")
    img, stats = ctx.render(CHAPTER, scene, "--max-depth", 30, "--absorption", distance, name="beer")
    a = tint ** (2 * radius / distance)
    beer = centre + f"with --absorption {distance} (Beer-Lambert)"
    expect_close("radiance", img.at(4, 4)[0], T * T * a / (1 - R * R * a * a), rel=FLOAT, where=f"{beer}, red",
                 by="T^2 a / (1 - R^2 a^2) with a = t^(2r/D)", command=img.command)
    expect_close("radiance", img.at(4, 4)[1], T * T / (1 - R * R), tol=FLOAT, where=f"{beer}, green",
                 by="T^2 / (1 - R^2): an untinted channel is not absorbed", command=img.command)
    expect_close("absorption distance in the stats", stats["absorption_distance"], distance, tol=0,
                 by="--absorption", command=img.command)


def test_bubble_rim_total_internal_reflection(ctx):
    """An air bubble seen from water: relative index n = 1/1.33 < 1.  Behind it an
    emitter wall of radiance 1, elsewhere black.  Pixels whose ray meets the
    bubble beyond the critical angle asin(n) = 48.75 deg are totally
    reflected, R = 1 exactly, and (when the mirrored ray heads for the wall,
    computed here) show the wall's radiance 1 exactly.  The centre pixel
    passes straight through: (1 - R)/(1 + R) with R = ((1 - n)/(1 + n))^2
    (the series T^2 (1 + R^2 + ...)).  Ray-sphere geometry and the camera are
    recomputed in Python."""
    n, size, fov = 1 / 1.33, 41, 12
    eye, look, up = [0, 0, -10], [0, 0, 0], [0, 1, 0]
    wall = "material sky emitter 1 1 1\nquad wall sky  -1000 -1000 5  -1000 1000 5  1000 1000 5  1000 -1000 5"
    scene = ctx.write("bubble.scene", SPHERE_SCENE.format(fov=fov, size=size, background="0 0 0", glass=repr(n),
                                                          extra=wall))
    img, stats = ctx.render(CHAPTER, scene, "--max-depth", 30)
    critical = math.degrees(math.asin(n))
    rim = []
    for y in range(size):
        for x in range(size):
            d = camera_ray(eye, look, up, fov, size, size, x + 0.5, y + 0.5)
            b = dot(eye, d)  # |eye + t d|^2 = 1
            disc = b * b - (dot(eye, eye) - 1)
            if disc <= 0:
                continue
            p = add(eye, scale(d, -b - math.sqrt(disc)))  # the near hit; the normal is p (unit sphere)
            cos_i = -dot(d, p)
            theta = math.degrees(math.acos(min(1.0, cos_i)))
            mirrored = sub(d, scale(p, 2 * dot(d, p)))
            if theta > critical + 0.5 and mirrored[2] > 0.05:
                rim.append((x, y))
    assert len(rim) >= 20, f"only {len(rim)} rim pixels beyond the critical angle: the test scene is wrong"
    expect_image("radiance", img, lambda x, y, c: 1.0, tol=FLOAT, pixels=rim,
                 where=f"on the air bubble's rim (beyond the critical angle {critical:.2f} deg)",
                 by="the wall's radiance 1: total internal reflection, R = 1")
    R = fresnel_normal(n)
    expect_image("radiance", img, lambda x, y, c: (1 - R) / (1 + R) if c == 0 else None, tol=FLOAT,
                 pixels=[(size // 2, size // 2)], where="(the centre of the air bubble)",
                 by="(1 - R) / (1 + R), R = ((1 - n) / (1 + n))^2")
    expect(stats["counters"]["total_internal_reflections"] > 0,
           f"total internal reflections counted: {stats['counters']['total_internal_reflections']}, expected more "
           "than 0 (the bubble's rim reflects totally)", measured=stats["counters"]["total_internal_reflections"],
           expected=1, command=img.command)


# ---- refraction through a slab ---------------------------------------------------------------

def snell(d, normal, n_i, n_t):
    """Refract unit d at a surface with unit normal facing d, by angles:
    keep the tangential direction, set sin(theta_t) = n_i sin(theta_i) / n_t."""
    cos_i = -dot(d, normal)
    tangential = add(d, scale(normal, cos_i))
    sin_t = n_i / n_t * math.sqrt(max(0.0, 1 - cos_i * cos_i))
    assert sin_t < 1
    along = unit(tangential) if dot(tangential, tangential) > 0 else [0, 0, 0]
    return add(scale(along, sin_t), scale(normal, -math.sqrt(1 - sin_t * sin_t)))


def plane_hit(origin, d, point, normal):
    t = dot(sub(point, origin), normal) / dot(d, normal)
    return add(origin, scale(d, t))


def test_slab_shifts_the_view_sideways(ctx):
    """A camera looks through a glass slab (n = 1.5, thickness 8, turned 40 deg
    about the vertical) at a wall whose left half (x < 0) glows with radiance 1.
    Each ray leaves the slab parallel to itself, shifted sideways by
    d sin(theta - theta_t) / cos(theta_t); where it then meets the wall decides
    whether the pixel is bright (> 0.5: about T^2 = 0.9) or dark (< 0.5: only
    light after two internal reflections, R^2 < 1 %).  Traced again here in
    Python by Snell's law, for every pixel of the middle row; pixels whose
    prediction lies within 0.05 of the edge are skipped.  The edge must move by
    at least three pixels (it is about 3.8) compared with the view without the slab."""
    width, height, fov = 64, 9, 6
    eye, look, up = [0, 0, -40], [0, 0, 0], [0, 1, 0]
    thickness, angle, n = 8.0, 40.0, 1.5
    wall = ("material sky emitter 1 1 1\n"
            "quad wall sky  -100 -100 10  -100 100 10  0 100 10  0 -100 10\n")
    slab = "material glass glass 1.5\n" + box_quads("slab", "glass", (0, 0, 0), (40, 30, thickness / 2), angle)
    base = f"camera eye 0 0 -40  look 0 0 0  up 0 1 0  fov {fov}\nimage {width} {height}\nbackground 0 0 0\n"
    with_slab, _ = ctx.render(CHAPTER, ctx.write("slab.scene", base + wall + slab), name="slab")
    without, _ = ctx.render(CHAPTER, ctx.write("noslab.scene", base + wall), name="noslab")

    a = math.radians(angle)
    front_normal = [-math.sin(a), 0, -math.cos(a)]  # the face toward the camera, outward
    front_point = scale(front_normal, thickness / 2)
    back_point = scale(front_normal, -thickness / 2)
    y = height // 2
    edges, predicted = {}, {}
    for label, img in (("slab", with_slab), ("no slab", without)):
        wrong = []
        for x in range(width):
            d = camera_ray(eye, look, up, fov, width, height, x + 0.5, y + 0.5)
            if label == "slab":
                entry = plane_hit(eye, d, front_point, front_normal)
                inside = snell(d, front_normal, 1.0, n)
                exit_point = plane_hit(entry, inside, back_point, front_normal)
                out = snell(inside, front_normal, n, 1.0)  # the normal on the side the ray comes from
                if x == width // 2:  # the displacement formula, for the record
                    theta = math.acos(-dot(d, front_normal))
                    theta_t = math.asin(math.sin(theta) / n)
                    offset = sub(exit_point, eye)
                    shift = math.sqrt(dot(offset, offset) - dot(offset, d) ** 2)
                    assert abs(dot(out, d) - 1) < 1e-12
                    assert abs(shift - thickness * math.sin(theta - theta_t) / math.cos(theta_t)) < 1e-9
                origin, direction = exit_point, out
            else:
                origin, direction = eye, d
            wall_x = plane_hit(origin, direction, [0, 0, 10], [0, 0, -1])[0]
            value = img.at(x, y)[0]
            predicted[label] = predicted.get(label, 0) + (wall_x < 0)
            if abs(wall_x) < 0.05:
                continue
            if (wall_x < 0) != (value > 0.5):
                wrong.append(f"column {x} radiance {value:.3g}, expected {'above' if wall_x < 0 else 'below'} 0.5 "
                             f"(its ray meets the wall at x = {wall_x:.3f}, the {'glowing' if wall_x < 0 else 'dark'} "
                             "half)")
        edges[label] = sum(1 for x in range(width) if img.at(x, y)[0] > 0.5)  # bright columns, on one side
        expect(not wrong, f"{len(wrong)} columns of the middle row{' through the slab' if label == 'slab' else ''} "
               f"see the wrong half of the wall (Snell's law traced in Python): {wrong[0] if wrong else ''}; "
               f"{edges[label]} bright columns, expected {predicted[label]}: the view is shifted "
               f"{'too little' if edges[label] > predicted[label] else 'too much'} to the side",
               measured=edges[label], expected=predicted[label], command=img.command)
    moved = abs(edges["slab"] - edges["no slab"])
    expect_at_least("sideways shift of the wall's edge through the slab, in pixels", moved, 3,
                    by="d sin(theta - theta_t) / cos(theta_t), about 3.8 pixels", command=with_slab.command)


# ---- shadow rays through glass -------------------------------------------------------------

PLATE_SCENE = """\
camera eye 0 0.5 -4  look 0 0 0  up 0 1 0  fov 20
image 9 9
background 0 0 0
material floor diffuse 0.5 0.5 0.5
material glass glass 1.5 {tint} 1 1
quad floor floor  -10 0 -10  -10 0 10  10 0 10  10 0 -10
light lamp point  0 5 0  100 100 100
""" + box_quads("plate", "glass", (0, 1.1, 0), (1, 0.1, 1), 0)


def test_shadow_ray_through_glass_plate(ctx):
    """The floor point under a horizontal glass plate (thickness 0.2), lit by a
    point light straight above it through the plate, seen from below the
    plate.  (R1): L = rho/pi I / r^2 times what the plate lets through along
    the shadow ray: (1 - R)^2 = 0.96^2 at normal incidence (the shadow ray
    counts no internal reflections), times the tint t (a filter), or
    t^(0.2 / D) with --absorption D (Beer-Lambert).  With --shadows opaque the
    plate blocks the light: 0."""
    tint = 0.5
    scene = ctx.write("plate.scene", PLATE_SCENE.format(tint=tint))
    unshadowed = 0.5 / math.pi * 100 / 25
    T2 = (1 - fresnel_normal(1.5)) ** 2
    cases = [((), [tint * T2, T2]), (("--absorption", 0.4), [tint ** 0.5 * T2, T2]),
             (("--shadows", "opaque"), [0.0, 0.0]), (("--no-shadows",), [1.0, 1.0])]
    for args, factors in cases:
        img, _ = ctx.render(CHAPTER, scene, *args, name="plate")
        expect_image("radiance", img, lambda x, y, c: unshadowed * factors[c] if c < 2 else None,
                     tol=FLOAT * unshadowed, pixels=[(4, 4)],
                     where=f"of the floor under the glass plate ({' '.join(map(str, args)) or 'default shadows'})",
                     by=f"rho/pi I / r^2 (R1) x {' and '.join(f'{f:.4g}' for f in factors)} (red and green) that the "
                        "plate lets through along the shadow ray")


# ---- pruning ---------------------------------------------------------------------------------

def point_lit_cornell_spheres(ctx):
    """scenes/cornell-spheres.scene with its area light replaced by a point light,
    so a 1-spp image has no noise and two renders differ only by the tree."""
    with open(os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                           "scenes", "cornell-spheres.scene")) as f:
        text = f.read()
    text = text.replace("quad light light", "# quad light light")
    text += "\nlight lamp point  278 500 279.5  60000 50000 40000\n"
    return ctx.write("cornell-spheres-point.scene", text)


def test_pruning_cuts_rays_and_keeps_the_image(ctx):
    """Hall & Greenberg's adaptive depth: --min-weight W skips every branch whose
    weight (the product of reflection/transmission coefficients from the eye)
    is below W.  Each skipped branch would have added at most W times the
    radiance it sees, and every term of the tree is non-negative, so:
     - the pruned image is nowhere brighter than the full one;
     - its error is small: we require the mean absolute error below W times
       the mean radiance of the image (a pruned branch carries less than W of
       a typical radiance), and print the numbers;
     - the rays traced (reflected + refracted + shadow) fall by at least 20 %."""
    scene = point_lit_cornell_spheres(ctx)
    full, full_stats = ctx.render(CHAPTER, scene, "--size", "64x64", "--max-depth", 12, name="full")
    expect_close("branches pruned without --min-weight", full_stats["counters"]["pruned_branches"], 0, tol=0,
                 command=full.command)
    report = []
    for weight in (0.01, 0.05):
        pruned, stats = ctx.render(CHAPTER, scene, "--size", "64x64", "--max-depth", 12, "--min-weight", weight,
                                   name=f"w{weight}")
        diffs = [f[c] - p[c] for f, p in zip(full.pixels, pruned.pixels) for c in range(3)]
        brightest = min(range(len(diffs)), key=lambda i: diffs[i])
        expect_at_most(f"radiance a pixel gained by --min-weight {weight}", -diffs[brightest],
                       FLOAT * max(max(px) for px in full.pixels),
                       where=f"(pixel ({brightest // 3 % 64}, {brightest // 3 // 64}), {CHANNELS[brightest % 3]})",
                       by="none: a pruned branch only removes light, every term of the tree is >= 0",
                       command=pruned.command)
        mean_error = sum(abs(x) for x in diffs) / len(diffs)
        mean_radiance = sum(sum(px) for px in full.pixels) / len(diffs)

        def traced(s): return sum(s["counters"][k] for k in ("reflected_rays", "refracted_rays", "shadow_rays"))
        saving = 1 - traced(stats) / traced(full_stats)
        report.append(f"W={weight}: {stats['counters']['pruned_branches']} branches pruned, rays -{saving:.1%}, "
                      f"mean abs error {mean_error:.3g} = {mean_error / mean_radiance:.3%} of the mean radiance "
                      f"{mean_radiance:.3g}, max error {max(diffs):.3g}")
        expect_at_least(f"branches pruned by --min-weight {weight}", stats["counters"]["pruned_branches"], 1,
                        command=pruned.command)
        expect_at_least(f"share of rays saved by --min-weight {weight}", saving, 0.2,
                        by="reflected + refracted + shadow rays against the full tree", command=pruned.command)
        expect_at_most(f"mean absolute error of the image pruned by --min-weight {weight}", mean_error,
                       weight * mean_radiance, by=f"{weight} x the mean radiance {mean_radiance:.3g}",
                       command=pruned.command, words=("too large", "too small"))
    print("; ".join(report))


# ---- statistics, robustness ------------------------------------------------------------------

def test_stats_histogram_and_ray_counts(ctx):
    """The depth histogram has --max-depth + 1 bins and counts every camera ray
    once; the Cornell spheres need reflected and refracted rays."""
    img, stats = ctx.render(CHAPTER, "scenes/cornell-spheres.scene", "--size", "32x32", "--max-depth", 6,
                            "--light-samples", 2)
    histogram = stats["depth_histogram"]
    expect_close("bins of the depth histogram", len(histogram), 7, tol=0, by="--max-depth 6, plus one",
                 command=img.command)
    expect_close("camera rays in the depth histogram", sum(histogram), 32 * 32, tol=0, by="one per pixel of 32x32",
                 command=img.command)
    expect_close("camera rays counted", stats["counters"]["camera_rays"], 32 * 32, tol=0, by="one per pixel of 32x32",
                 command=img.command)
    expect(histogram[0] > 0 and sum(histogram[1:]) > 0,
           f"depth histogram {histogram}: expected rays that end at depth 0 (the walls) and rays that go deeper "
           "(the mirror and glass balls)", command=img.command)
    for key in ("shadow_rays", "reflected_rays", "refracted_rays", "pruned_branches", "depth_limited_branches"):
        expect(key in stats["counters"], f"the stats' counters have no '{key}'", command=img.command)
    for key in ("reflected_rays", "refracted_rays"):
        expect_at_least(key.replace("_", " "), stats["counters"][key], 1, by="the balls reflect and refract",
                        command=img.command)
    expect(finite_image(img), "every pixel finite (no NaN or infinity)", command=img.command)


def test_grazing_incidence_stays_finite(ctx):
    """Rays that graze glass and mirror surfaces (the eye in the plane of a glass
    face and of a mirror, tangent rays at sphere rims) and the three scenes of
    this chapter: every pixel finite, no sample rejected."""
    grazing = ("camera eye 0 0 -6  look 0 0 0  up 0 1 0  fov 50\nimage 40 40\nbackground 0.5 0.6 0.7\n"
               "material glass glass 1.5\nmaterial water glass 0.75\nmaterial silver mirror 0.9 0.9 0.9\n"
               "material white diffuse 0.7 0.7 0.7\n"
               "quad mirror_floor silver  -9 0 -9  -9 0 9  9 0 9  9 0 -9\n"   # the eye is in its plane
               + box_quads("slab", "glass", (1, 1.2, 0), (1, 1, 1), 0) +      # its face x = 0 contains the eye
               "sphere ball glass  -1.5 1 0  0.8\nsphere bubble water  0 -1.2 0  0.8\n"
               "quad wall white  -9 -9 9  -9 9 9  9 9 9  9 -9 9\n"
               "light lamp point  0 6 -3  50 50 50\n")
    scene = ctx.write("grazing.scene", grazing)
    renders = [(scene, ("--spp", 4))] + [(f"scenes/{name}.scene", ("--size", "48x36", "--light-samples", 1))
                                         for name in ("cornell-spheres", "glass-slab", "bubble")]
    for path, args in renders:
        for formula in ("exact", "schlick"):
            img, stats = ctx.render(CHAPTER, path, "--fresnel", formula, *args, name="grazing")
            assert finite_image(img), f"{path} ({formula}): non-finite pixels"
            assert stats["nonfinite_samples"] == 0, f"{path} ({formula}): {stats['nonfinite_samples']} rejected"


def test_threads_give_identical_bytes(ctx):
    """The per-sample generator makes the image independent of the thread count."""
    check_thread_independence(ctx, CHAPTER, "scenes/cornell-spheres.scene", "--size", "40x40", "--spp", 4,
                              "--light-samples", 2)


def test_bad_materials_are_file_line_errors(ctx):
    """The parser rejects an IOR <= 0, a negative colour and a non-finite number
    in a material with 'file:line:' (the material is on line 3), exit 2."""
    bad = ["glass 0", "glass -1.5", "glass nan", "glass inf", "glass 1e999", "glass 1.5 -0.1 1 1",
           "glass 1.5 1 nan 1", "mirror -0.2 0.5 0.5", "mirror 0.5 inf 0.5", "diffuse 0.5 -0.5 0.5",
           "diffuse nan 0.5 0.5", "emitter -1 1 1", "emitter 1 inf 1", "phong kd 0.5 0.5 0.5 ks 0.1 0.1 0.1 exp nan",
           "phong kd 0.5 0.5 -0.5 ks 0.1 0.1 0.1 exp 10"]
    for k, material in enumerate(bad):
        path = ctx.write(f"bad{k}.scene", "camera eye 0 0 -5  look 0 0 0  up 0 1 0  fov 40\n"
                                          "# a bad material on the next line\n"
                                          f"material m {material}\n"
                                          "sphere s m  0 0 0  1\n")
        check_bad_input(ctx, CHAPTER, [path], f"{path}:3:")


def test_bad_command_lines_exit_2(ctx):
    for args in (["--max-depth", "-1"], ["--max-depth", "65"], ["--max-depth", "two"], ["--min-weight", "1.5"],
                 ["--min-weight", "-0.1"], ["--min-weight", "nan"], ["--fresnel", "fast"], ["--fresnel"],
                 ["--shadows", "soft"], ["--absorption", "0"], ["--absorption", "inf"], ["--model", "cook"]):
        check_bad_input(ctx, CHAPTER, ["scenes/cornell-spheres.scene", *args], "argv:")
