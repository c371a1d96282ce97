"""Grading chapter 03c (hierarchical radiosity) against closed forms, conservation and
chapter 3's uniform solve.

Truth comes from outside the chapter:
  - the closed furnace: every leaf's row sum s (its links' form factors and its
    ancestors') bounds L between Le / (1 - rho s_min) and Le / (1 - rho s_max), and
    the Neumann terms (R6) of the windows add up;
  - chapter 3's uniform solve and chapter 4's path tracing, per surface and probe,
    within both discretisation errors (the hierarchical one bounded by its --eps);
  - geometry: the floor under a box is inside a solid and black.
"""
import math
import os

import grade_03_radiosity
import lib
from lib import CHANNELS, check_thread_independence, expect, expect_between, expect_close, probe
from grade_03_radiosity import (check_meshed_ball, check_smooth_t_vertices, furnace, read_ply,
                                row_sum_bounds, surfaces)

GRADES_NOTHING = True  # no grading, no handout: may run beside the RUN_ALONE tests (tests/run.py)

CHAPTER = "03c_hierarchical"
UNIFORM = "03_radiosity"  # chapter 3: the uniform solve it approximates


def check_exit_2(ctx, args):
    return grade_03_radiosity.check_exit_2(ctx, args, chapter=CHAPTER)

HIER = ["--quadrature", 2]


def test_hierarchical_furnace_and_bounces(ctx):
    """scenes/furnace.scene by chapter 03c: every surface, pixel and leaf
    within the row-sum bounds; --bounces 0:0 is Le exactly, 1:1 is Le rho s within
    the bounds of s, and the windows 0:1 and 2: add up to 0: (the Neumann terms, R6)."""
    # Whole solves the sanitizers make slow: the furnace, its row-sum bounds and --bounces 1:1 run
    # there in test_hierarchical_matches_the_furnace_and_the_uniform_solve.
    if lib.sanitizer_build(ctx):
        return
    args = [*HIER, "--eps", 2e-2, "--levels", 6, "--size", "16x16", "--tol", 1e-10, "--iterations", 1000]
    img, stats = ctx.render(CHAPTER, "scenes/furnace.scene", *args, name="hfull")
    assert stats["solver_used"] == "hierarchical" and stats["converged"]
    assert stats["elements"] > stats["patches"] >= 6 and stats["links"] > 0 and 1 <= stats["levels"] <= 6
    lo, hi = row_sum_bounds(stats, 0.25, 0.5)
    assert 0.5 < stats["row_sum_min"] <= stats["row_sum_max"] < 1.5
    for s in stats["surfaces"]:
        assert lo <= s["radiance"][0] <= hi, f"{s['name']}: {s['radiance'][0]} not in [{lo}, {hi}]"
        assert abs(s["radiance"][0] - 0.5) < 0.01, f"{s['name']}: surface mean {s['radiance'][0]}, expected 0.5"
    assert all(lo <= px[0] <= hi for px in img.pixels)
    parts = {}
    for window in ("0:0", "1:1", "0:1", "2:"):
        parts[window], _ = ctx.render(CHAPTER, "scenes/furnace.scene", *args, "--bounces", window,
                                      name="hb" + window.replace(":", "_"))
    assert all(px == (0.25, 0.25, 0.25) for px in parts["0:0"].pixels)
    s_lo, s_hi = stats["row_sum_min"], stats["row_sum_max"]
    assert all(0.25 * 0.5 * s_lo * (1 - 1e-6) <= px[0] <= 0.25 * 0.5 * s_hi * (1 + 1e-6) for px in parts["1:1"].pixels)
    for a, b, full in zip(parts["0:1"].pixels, parts["2:"].pixels, img.pixels):
        assert abs(a[1] + b[1] - full[1]) <= 1e-5 * full[1], f"0:1 + 2: = {a[1] + b[1]}, 0: = {full[1]}"


def test_hierarchical_agrees_with_uniform_and_path_tracing(ctx):
    """Cornell box: per-surface means of chapter 03c (--eps 1e-2) against the
    uniform 25 mm solve and against path tracing, and the probes against the uniform.

    The bound.  The uniform solve's discretisation error is at most 2 |L_50 - L_25|
    (as in grade_04's agreement test); the hierarchical solve's has two parts: what
    halving --eps still changes (2 |L(2 eps) - L(eps)|), and the oracle's: a link
    made at F < eps spreads its transfer evenly over the receiver and weighs the
    source evenly, while the kernel varies across them by about their size over
    their distance, itself O(sqrt(eps)) when F < eps.  We allow 0.5 sqrt(eps) of the
    surface's radiance plus the scene's mean reflected radiance (the incident light
    the error is a fraction of): 5 % at eps = 1e-2; measured, the block sides are
    2-4 % low and the largest use of the bound is about a quarter.  The solves stop at
    --levels 5: the bound leaves out the error of stopping early, and its largest use
    is the same as at the default 8 (0.24 of the bound), at a quarter of the time."""
    # Statistics the sanitizers make slow; the hierarchical solve runs there
    # in test_hierarchical_matches_the_furnace_and_the_uniform_solve.
    if lib.sanitizer_build(ctx):
        return
    common = ["--size", "8x8", "--tol", 1e-7, "--iterations", 10000]
    runs = {}
    for key, args in {"h2": [*HIER, "--levels", 5, "--eps", 2e-2], "h1": [*HIER, "--levels", 5, "--eps", 1e-2],
                      "u50": ["--patch-size", 50], "u25": ["--patch-size", 25]}.items():
        chapter = UNIFORM if key[0] == "u" else CHAPTER
        _, runs[key] = ctx.render(chapter, "scenes/cornell.scene", *common, *args, name=key)
    _, traced = ctx.render("04_pathtrace", "scenes/cornell.scene", "--size", "8x8", "--spp", 1,
                           "--surface-samples", 1 << 16, "--probe-samples", 32, name="pt")
    S = {key: surfaces(stats) for key, stats in runs.items()}
    pt = surfaces(traced)
    assert set(pt) == set(S["h1"]) == set(S["u25"])
    reflecting = [s for name, s in S["h1"].items() if name != "light"]
    area = sum(s["area"] for s in reflecting)
    mean = [sum(s["area"] * s["radiance"][c] for s in reflecting) / area for c in range(3)]
    for name in pt:
        for c in range(3):
            h, h2 = S["h1"][name]["radiance"][c], S["h2"][name]["radiance"][c]
            own = 0.5 * math.sqrt(1e-2) * (h + mean[c]) + 2 * abs(h2 - h)
            uniform = 2 * abs(S["u50"][name]["radiance"][c] - S["u25"][name]["radiance"][c])
            assert abs(h - S["u25"][name]["radiance"][c]) <= own + uniform, \
                f"{name}[{c}]: hierarchical {h:.5f}, uniform {S['u25'][name]['radiance'][c]:.5f}, bound {own + uniform:.3g}"
            assert abs(h - pt[name]["radiance"][c]) <= own + 4 * pt[name]["standard_error"][c], \
                f"{name}[{c}]: hierarchical {h:.5f}, path tracing {pt[name]['radiance'][c]:.5f}"
    for p in runs["u25"]["probes"]:
        for c in range(3):
            h = probe(runs["h1"], p["name"])["irradiance"][c]
            h2 = probe(runs["h2"], p["name"])["irradiance"][c]
            e50, e25 = probe(runs["u50"], p["name"])["irradiance"][c], p["irradiance"][c]
            bound = 0.5 * math.sqrt(1e-2) * (h + math.pi * mean[c]) + 2 * abs(h2 - h) + 2 * abs(e50 - e25)
            assert abs(h - e25) <= bound, f"probe {p['name']}[{c}]: hierarchical {h:.5f}, uniform {e25:.5f}"
    # Memory O(elements + links), not O(patches^2).
    h = runs["h1"]
    assert h["matrix_bytes"] == 0 and h["hierarchy_bytes"] < 64 * (h["elements"] + h["links"]) + 4096 * h["elements"]


def test_hierarchical_second_pass_follows_the_light(ctx):
    """--eps-spread: the second pass refines where the first pass's solution says a
    link is too coarse (a bright source, or a source whose leaves differ).  On the
    Cornell box at --eps 4e-2 it must bring the per-surface means closer to path
    tracing: RMS relative error over surfaces and channels at most 3/4 of the first
    pass's (measured at --levels 5: 3.4 % one pass, 0.5 % two; at the default 8 levels
    3.3 % and 0.3 %, four times slower).  Both are measured against the
    same path-traced means, so its noise (about 0.3 % per surface at 2^18 walks)
    adds the same floor to both; a second pass that changed nothing would fail."""
    # Whole solves the sanitizers make slow: the second pass (--eps-spread, the default) runs there in
    # test_hierarchical_matches_the_furnace_and_the_uniform_solve's furnace.
    if lib.sanitizer_build(ctx):
        return
    common = ["--size", "8x8", "--tol", 1e-6, *HIER, "--eps", 4e-2, "--levels", 5]
    _, traced = ctx.render("04_pathtrace", "scenes/cornell.scene", "--size", "8x8", "--spp", 1,
                           "--surface-samples", 1 << 18, "--probe-samples", 32, name="pt2")
    pt = surfaces(traced)
    errors, runs = {}, {}
    for key, spread in (("one", 0), ("two", 1e-3)):
        _, runs[key] = ctx.render(CHAPTER, "scenes/cornell.scene", *common, "--eps-spread", spread, name="sp" + key)
        S = surfaces(runs[key])
        e = [S[n]["radiance"][c] / pt[n]["radiance"][c] - 1 for n in pt if n != "light" for c in range(3)]
        errors[key] = math.sqrt(sum(x * x for x in e) / len(e))
    assert errors["two"] <= 0.75 * errors["one"], errors
    one, two = runs["one"], runs["two"]
    assert one["first_pass_links"] == one["links"] and two["first_pass_links"] < two["links"]
    for bad in ("-1e-3", "nan", "1.5", "x"):
        line = check_exit_2(ctx, ["scenes/cornell.scene", "--eps-spread", bad])
        assert line.startswith("argv:3:") and "--eps-spread" in line, line


def test_hierarchical_tiny_bright_light(ctx):
    """A light a hundredth the Cornell light's area and a hundred times as bright
    (scenes/cornell-small-light.scene): the second pass weighs its links by its
    brightness, capped, so the solve stays within a few times the Cornell box's
    links (uncapped it passed the 40 M link limit) and agrees with path tracing per
    surface within the bound of the agreement test above, 0.5 sqrt(eps) of the
    surface's radiance plus the scene's mean, and 4 standard errors.  At --levels 6
    (a quarter of the time): 0.46 of the Cornell box's links; uncapped 4.7 times."""
    # Whole solves the sanitizers make slow: the second pass's brightness runs there in
    # test_hierarchical_matches_the_furnace_and_the_uniform_solve's furnace (the cap is a min).
    if lib.sanitizer_build(ctx):
        return
    eps = 2e-2
    args = ["--size", "8x8", "--quadrature", 1, "--eps", eps, "--eps-spread", 7e-4, "--levels", 6]
    _, small = ctx.render(CHAPTER, "scenes/cornell-small-light.scene", *args, name="small")
    _, normal = ctx.render(CHAPTER, "scenes/cornell.scene", *args, name="normal")
    assert small["links"] < 2 * normal["links"], (small["links"], normal["links"])
    _, traced = ctx.render("04_pathtrace", "scenes/cornell-small-light.scene", "--size", "8x8", "--spp", 1,
                           "--surface-samples", 1 << 16, "--probe-samples", 32, name="pt_small")
    S, pt = surfaces(small), surfaces(traced)
    reflecting = [x for name, x in S.items() if name != "light"]
    area = sum(x["area"] for x in reflecting)
    for name in pt:
        for c in range(3):
            mean = sum(x["area"] * x["radiance"][c] for x in reflecting) / area
            h, t = S[name]["radiance"][c], pt[name]["radiance"][c]
            bound = 0.5 * math.sqrt(eps) * (h + mean) + 4 * pt[name]["standard_error"][c]
            assert abs(h - t) <= bound, f"{name}[{c}]: hierarchical {h:.5f}, path tracing {t:.5f}, bound {bound:.3g}"


def test_hierarchical_floor_under_a_box_carries_no_light(ctx):
    """The floor under the short box is inside a solid: no light reaches it, so
    its leaves must be black, while the floor just outside the box is lit.  An
    element across the box's edge gathers light on its exposed part only;
    spreading that over the buried part too would light the floor under the
    box and darken the strip beside it (the box sides see that strip at F up
    to 0.5).  Flat shading: each face carries its leaf's radiance.  --levels 6: leaves
    of 9 mm on the floor, fine enough for strips 20 mm wide, at a third of the time."""
    ply = ctx.path("h.ply")
    ctx.render(CHAPTER, "scenes/cornell.scene", "--size", "8x8", *HIER, "--eps", 8e-2, "--levels", 6,
               "--shading", "flat", "--out", ply, name="buried")
    vertices, faces = read_ply(ply)
    footprint = [(130, 65), (82, 225), (240, 272), (290, 114)]  # the short box's base (x, z), scenes/cornell.scene
    buried, beside = [], []
    for face in faces:
        corners = [vertices[i] for i in face]
        if any(abs(v[1]) > 1e-6 for v in corners):
            continue  # not the floor
        x, z = sum(v[0] for v in corners) / len(corners), sum(v[2] for v in corners) / len(corners)
        inside_by = min(side_distances(footprint, x, z))
        if inside_by > 10:
            buried.append(max(corners[0][3:6]))
        elif -30 < inside_by < -10:
            beside.append(min(corners[0][3:6]))
    assert len(buried) >= 4 and len(beside) >= 4, (len(buried), len(beside))
    assert max(buried) == 0.0, f"a floor leaf under the box has radiance {max(buried)}"
    assert min(beside) > 0.0, "a floor leaf beside the box is black"


def side_distances(polygon, x, z):
    """Signed distances from (x, z) to the lines of a convex polygon's sides, positive inside."""
    sides = list(zip(polygon, polygon[1:] + polygon[:1]))
    orientation = 1 if sum(ax * bz - bx * az for (ax, az), (bx, bz) in sides) > 0 else -1
    return [orientation * ((bx - ax) * (z - az) - (bz - az) * (x - ax)) / math.hypot(bx - ax, bz - az)
            for (ax, az), (bx, bz) in sides]


def test_hierarchical_independent_of_threads(ctx):
    # --levels 4: both passes and parallel refinement rounds (725 k links), at 2/3 of 5's time under the sanitizers
    check_thread_independence(ctx, CHAPTER, "scenes/cornell.scene", "--size", "16x16", *HIER, "--eps", 5e-2,
                              "--levels", 4)


def test_hierarchical_default_levels_fit_the_element_limit(ctx):
    """scenes/bubble.scene has 246 roots: --levels 8 could make 2.15e7 elements,
    past the limit of 1.6e7, and is refused when asked for; the default instead
    goes as deep as the limit allows (7: 5.4e6 elements at worst) and runs."""
    args = ["scenes/bubble.scene", "--quadrature", "1", "--eps", "0.1", "--eps-spread", "0"]
    _, stats = ctx.render(CHAPTER, *args[:1], "--size", "8x8", *args[1:], name="bubble")
    assert stats["levels"] == 7, stats["levels"]
    out = ctx.path("refused.png")
    r = ctx.run(CHAPTER, *args, "--levels", "8", "--out", out)
    line = r.stderr.strip().splitlines()[-1]  # after the warning that glass spheres are not meshed
    assert r.returncode == 2 and not os.path.exists(out), (r.returncode, r.stderr)
    assert line.startswith("argv:") and "--levels 8" in line and "limit" in line, line


def test_hierarchical_bad_eps_and_levels_exit_2(ctx):
    for bad in ("0", "-1e-3", "nan", "inf", "1.5", "x"):
        line = check_exit_2(ctx, ["scenes/cornell.scene", "--eps", bad])
        assert line.startswith("argv:3:") and "--eps" in line, line
    # 15 roots split 12 levels deep could make 2.5e8 elements: refused before allocating, naming the limit.
    line = check_exit_2(ctx, ["scenes/cornell.scene", "--levels", "12"])
    assert line.startswith("argv:3:") and "--levels 12" in line and "limit" in line, line
    # The surface-to-surface table would need every patch-to-patch form factor: not an option here.
    line = check_exit_2(ctx, ["scenes/cornell.scene", "--formfactors", ctx.path("f.csv")])
    assert "--formfactors" in line and not os.path.exists(ctx.path("f.csv")), line




# ---- criteria for the paths the exercises do not tag ---------------------------------------------------

def test_hierarchical_matches_the_furnace_and_the_uniform_solve(ctx):
    """chapter 03c (refinement oracle, links, gather, push-pull) against what it
    approximates, in little time.  (1) The closed furnace of side 2 (every wall Le = 0.25,
    rho = 0.5): every surface and pixel within the bounds its leaf row sums allow
    (row_sum_bounds), and --bounces 1:1 is Le rho s with s in [s_min, s_max].  (2) The
    Cornell box, per surface and channel, against the uniform solve, with the bound of
    test_hierarchical_agrees_with_uniform_and_path_tracing: the hierarchical solve's own
    error 0.5 sqrt(eps) (L + mean reflected L) + 2 |L(2 eps) - L(eps)|, the uniform one's
    2 |L_100 - L_50|.  Deterministic (no random numbers): nothing to calibrate."""
    scene = furnace(ctx, 0.25, 0.5, name="hfurnace")
    args = [*HIER, "--eps", 2e-2, "--levels", 4, "--tol", 1e-10, "--iterations", 1000]
    img, stats = ctx.render(CHAPTER, scene, *args, name="hf")
    expect(stats["solver_used"] == "hierarchical" and stats["converged"] and stats["links"] > 0,
           f"the furnace by chapter 03c: solver used {stats['solver_used']}, converged "
           f"{stats['converged']}, {stats['links']} links; expected hierarchical, converged, links > 0")
    lo, hi = row_sum_bounds(stats, 0.25, 0.5)
    expect(0.5 < stats["row_sum_min"] <= stats["row_sum_max"] < 1.5,
           f"leaf row sums {stats['row_sum_min']:.4g} .. {stats['row_sum_max']:.4g}: expected between 0.5 and 1.5 "
           "(a closed box sums to 1)")
    band = dict(by="Le / (1 - rho s) for the leaf row sums s", command=img.command)
    def off(v, centre): return abs(v - centre) if math.isfinite(v) else math.inf
    worst = max(stats["surfaces"], key=lambda s: off(s["radiance"][0], (lo + hi) / 2))
    expect_between("radiance", worst["radiance"][0], lo, hi, where=f"of surface {worst['name']}, red, in the furnace "
                   "", **band)
    pixel = max(img.pixels, key=lambda px: off(px[0], (lo + hi) / 2))[0]
    expect_between("radiance of the pixel farthest off", pixel, lo, hi, where="red, in the furnace "
                   "", **band)
    once, _ = ctx.render(CHAPTER, scene, *args, "--bounces", "1:1", name="hf11")
    s_lo, s_hi = stats["row_sum_min"], stats["row_sum_max"]
    low, high = 0.125 * s_lo * (1 - 1e-6), 0.125 * s_hi * (1 + 1e-6)
    pixel = max(once.pixels, key=lambda px: off(px[0], (low + high) / 2))[0]
    expect_between("radiance of the pixel farthest off", pixel, low, high,
                   where="red, in the furnace (--bounces 1:1)",
                   by="the first bounce Le rho s for the leaf row sums s", command=once.command)
    common = ["--size", "8x8", "--tol", 1e-7, "--iterations", 10000, "--quadrature", 1]
    eps = 4e-2
    runs = {}
    for key, extra in {"h": ["--eps", eps, "--eps-spread", 0], "h2": ["--eps", 2 * eps, "--eps-spread", 0],
                       "u100": ["--patch-size", 100], "u50": ["--patch-size", 50]}.items():
        chapter = UNIFORM if key[0] == "u" else CHAPTER
        _, stats = ctx.render(chapter, "scenes/cornell.scene", *common, *extra, name="hc" + key)
        runs[key] = surfaces(stats)
    reflecting = [s for name, s in runs["h"].items() if name != "light"]
    area = sum(s["area"] for s in reflecting)
    mean = [sum(s["area"] * s["radiance"][c] for s in reflecting) / area for c in range(3)]
    for name, s in runs["u50"].items():
        for c in range(3):
            h, h2 = runs["h"][name]["radiance"][c], runs["h2"][name]["radiance"][c]
            u50, u100 = s["radiance"][c], runs["u100"][name]["radiance"][c]
            bound = 0.5 * math.sqrt(eps) * (h + mean[c]) + 2 * abs(h2 - h) + 2 * abs(u100 - u50)
            expect_close("radiance", h, u50, tol=bound,
                         where=f"of the Cornell box's {name}, {CHANNELS[c]}, --eps {eps}",
                         by="the uniform solve at --patch-size 50, within both solves' discretisation errors",
                         command=f"build/{CHAPTER} scenes/cornell.scene " + " ".join(map(str, common)) +
                         f" --eps {eps} --eps-spread 0")


def test_hierarchical_ball_carries_radiosity(ctx):
    """The diffuse emitting ball in the furnace (grade_03_radiosity's SPHERE_FURNACE):
    its leaves carry L = Le / (1 - rho s) like the walls', in the stats, the image,
    the probe under it and the PLY."""
    check_meshed_ball(ctx, CHAPTER, [*HIER, "--eps", 2e-2, "--levels", 5], "chapter 03c")


def test_hierarchical_smooth_shading_has_no_step_at_t_vertices(ctx):
    """Leaves split on one side of an edge only make T-vertices, as --adaptive does
    in chapter 3: the smooth-shaded radiance must be continuous there."""
    check_smooth_t_vertices(ctx, CHAPTER, [*HIER, "--eps", 2e-2, "--levels", 6])
