"""Helpers shared by the grading tests: run a chapter, read its outputs.

Standard library only (Debian's /usr/bin/python3), so `make test` needs no
Python packages.
"""
import json
import math
import os
import subprocess
import tempfile

import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "tests"))
import pfm  # noqa: E402  (tests/pfm.py: the one PFM reader of the Python tools)

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "kit"))
import stats as kit_stats  # noqa: E402  (kit/stats.py: Student's t, F, Welch; standard library only)

# The chance that one statistical grading test (one criterion of kit/rubric.json) fails a correct
# solution: at most CRITERION_ALPHA, Bonferroni over the comparisons in it.  Thirteen grade criteria
# have such a tolerance (8 of chapters 1-4, found by kit/calibrate.py seed-dependence, and 5 of
# chapter 5), 0.0026 together, plus the compare criteria's 0.002 (kit/rubric.json family_alpha):
# a correct solution fails a whole grading with probability at most 0.46 % by design, so that
# the measured rate stays below the 1 % the kit promises (kit/CALIBRATION.md).
CRITERION_ALPHA = 0.0002
# Probes' and surfaces' standard errors come from 32 batch means (common/walk_stats.h WALK_BATCHES,
# chapters/01_local.c): 31 degrees of freedom.
BATCH_DF = 31


def t_bound(df, comparisons=1, alpha=CRITERION_ALPHA):
    """How many estimated standard errors (with df degrees of freedom) a difference of zero
    expectation may be off in one of `comparisons` comparisons: the two-sided Student's t quantile
    at alpha / comparisons.  A flat 4 standard errors is this only for many degrees of freedom
    (P(|t| > 4) is 7e-5 for df = 1000 but 4e-4 for the 31 of 32 batch means, 5e-3 for 7)."""
    return kit_stats.t_quantile(alpha / comparisons, df)


SEED_LIMIT = 2 ** 31  # the chapters take --seed N with 0 <= N <= INT_MAX (common/render.c)
SEED_STRIDE = 0x2545F491  # odd: grading seed s moves every chapter seed by (s - 1) * SEED_STRIDE


def shifted_seed(chapter_seed, grading_seed):
    """The chapter seed a test's `--seed chapter_seed` becomes under grading seed `grading_seed`:
    chapter_seed + (grading_seed - 1) * SEED_STRIDE modulo 2^31.  Grading seed 1 (and None) is
    the identity; for any other it is a bijection of [0, 2^31), so two runs that share a seed in
    a test still share one, and two that differ still differ."""
    if grading_seed is None:
        return chapter_seed
    return (chapter_seed + (grading_seed - 1) * SEED_STRIDE) % SEED_LIMIT


class Context:
    """What a test needs: the build directory under test and a scratch dir.

    seed: the grading seed (kit/grade.py --seed, via kit/criterion.py).  None or 1 runs every
    chapter exactly as the test says (the fixed seeds of `make test`); any other value shifts
    the seed of every chapter run by shifted_seed: an explicit `--seed X` becomes
    shifted_seed(X, seed), and a run without --seed, which the chapter would give its default
    seed 1, gets `--seed shifted_seed(1, seed)` appended.  So each grading seed reruns every
    Monte Carlo test with fresh random numbers, and kit/calibrate.py can measure how often a
    correct solution fails.  Runs with --help, and values of --seed that are not a seed the
    chapters accept (bad-input tests), are left alone."""

    def __init__(self, build, seed=None):
        self.build = build
        self.seed = seed
        self.scratch = tempfile.mkdtemp(prefix="gi-test-")

    def seeded(self, args):
        """The argument list `args` (strings) with the context's seed applied (see the class)."""
        if self.seed is None or self.seed == 1 or "--help" in args or "-h" in args:
            return list(args)
        out = list(args)
        for i in range(len(out) - 1):
            if out[i] == "--seed" and out[i + 1].isdigit() and int(out[i + 1]) < SEED_LIMIT:
                out[i + 1] = str(shifted_seed(int(out[i + 1]), self.seed))
        if "--seed" not in out:
            out += ["--seed", str(shifted_seed(1, self.seed))]
        return out

    def path(self, name):
        return os.path.join(self.scratch, name)

    def write(self, name, text):
        p = self.path(name)
        with open(p, "w") as f:
            f.write(text)
        return p

    def run(self, chapter, *args, timeout=600):
        """Run build/<chapter> with args from the repo root; return the CompletedProcess."""
        exe = os.path.join(ROOT, self.build, chapter)
        return subprocess.run([exe, *self.seeded([str(a) for a in args])], cwd=ROOT, capture_output=True, text=True,
                              timeout=timeout, stdin=subprocess.DEVNULL)

    def render(self, chapter, scene, *args, name="render", timeout=600):
        """Render to PFM + stats in scratch; return (image, stats). Fails loudly on a non-zero exit."""
        pfm, stats = self.path(name + ".pfm"), self.path(name + ".json")
        result = self.run(chapter, scene, "--quiet", "--out", pfm, "--stats", stats, *args, timeout=timeout)
        assert result.returncode == 0, f"{chapter} {scene} {' '.join(map(str, args))} exited " \
                                       f"{result.returncode}: {result.stderr.strip()}"
        return read_pfm(pfm), read_json(stats)


class Image:
    def __init__(self, width, height, pixels):
        self.width, self.height, self.pixels = width, height, pixels  # pixels: list of (r,g,b), top row first

    def at(self, x, y):
        return self.pixels[y * self.width + x]


def read_pfm(path):
    width, height, floats = pfm.read_pfm(path)
    return Image(width, height, pfm.pixels_top_first(width, height, floats))


def read_json(path):
    with open(path) as f:
        return json.load(f)


def probe(stats, name):
    for p in stats["probes"]:
        if p["name"] == name:
            return p
    raise AssertionError(f"no probe {name} in stats")


def lambert_polygon_irradiance(radiance, polygon, point, normal):
    """Irradiance at `point` (unit `normal`) from a Lambertian polygon of
    constant radiance, by Lambert's contour formula:
        E = L/2 * sum_i beta_i * (n . (r_i x r_{i+1}) / |r_i x r_{i+1}|)
    where r_i are the unit vectors to the vertices and beta_i the angle
    between consecutive ones (the polygon must be fully above the plane and
    its vertices ordered so the sum is positive)."""
    def sub(a, b): return [a[k] - b[k] for k in range(3)]
    def dot(a, b): return sum(a[k] * b[k] for k in range(3))
    def cross(a, b): return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    def unit(a):
        length = math.sqrt(dot(a, a))
        return [c / length for c in a]
    rs = [unit(sub(v, point)) for v in polygon]
    total = 0.0
    for i in range(len(rs)):
        a, b = rs[i], rs[(i + 1) % len(rs)]
        c = cross(a, b)
        # atan2(|a x b|, a.b), not acos(a.b): accurate for the tiny angles a
        # small or distant polygon subtends, where the terms nearly cancel.
        beta = math.atan2(math.sqrt(dot(c, c)), dot(a, b))
        total += beta * dot(normal, unit(c))
    return abs(total) / 2.0 * radiance


def finite_image(img):
    return all(math.isfinite(c) for px in img.pixels for c in px)


def check_bad_input(ctx, chapter, args, expected_prefix="argv:"):
    """The chapter must exit 2 with one line starting expected_prefix and create no output."""
    out = ctx.path("should-not-exist.png")
    r = ctx.run(chapter, *args, "--out", out)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2, f"{chapter} {args}: exit {r.returncode}, expected 2 ({r.stderr.strip()})"
    assert len(lines) == 1 and lines[0].startswith(expected_prefix), \
        f"{chapter} {args}: stderr should be one line starting '{expected_prefix}', got {r.stderr!r}"
    assert not os.path.exists(out), f"{chapter} {args}: an output file was created"


def check_thread_independence(ctx, chapter, scene, *args):
    """1 and 2 threads must give byte-identical PFM files (per-sample random streams)."""
    outputs = []
    for threads in (1, 2):
        pfm = ctx.path(f"threads{threads}.pfm")
        r = ctx.run(chapter, scene, "--quiet", *args, "--threads", threads, "--out", pfm)
        assert r.returncode == 0, r.stderr
        with open(pfm, "rb") as f:
            outputs.append(f.read())
    assert outputs[0] == outputs[1], f"{chapter}: 1 and 2 threads gave different images"


def check_probes_match_lambert(stats, polygon, radiance, probes, max_relative_se, label="", comparisons=None):
    """Each probe's irradiance equals Lambert's polygon formula for the
    emitter `polygon` of RGB `radiance`, within t_bound(BATCH_DF, comparisons)
    of the standard errors the chapter reports (32 batch means; comparisons:
    the probe channels of the whole criterion, default those of this call),
    and each standard error is positive and below max_relative_se of the
    answer, so the tolerance cannot silently grow."""
    bound = t_bound(BATCH_DF, comparisons or 3 * len(probes))
    for name, (p, n) in probes.items():
        length = math.sqrt(sum(c * c for c in n))
        n = tuple(c / length for c in n)
        got = probe(stats, name)
        for c in range(3):
            expected = lambert_polygon_irradiance(radiance[c], polygon, p, n)
            se = got["standard_error"][c]
            assert 0 < se < max_relative_se * expected, \
                f"{label} probe {name}: standard error {se} not in (0, {max_relative_se:.1%} of {expected})"
            assert abs(got["irradiance"][c] - expected) <= bound * se, \
                f"{label} probe {name} channel {c}: {got['irradiance'][c]:.6f} vs Lambert {expected:.6f} " \
                f"({bound:.2f} standard errors = {bound * se:.2g})"


def radiosity_surfaces(ctx, scene, patch_sizes=(50, 25)):
    """{patch size: {surface name: its entry of build/03_radiosity's "surfaces"}},
    converged (--tol 1e-7): the reference other chapters' surface means are
    compared with, with its discretisation error from two patch sizes."""
    import os as _os
    assert _os.path.exists(_os.path.join(ROOT, ctx.build, "03_radiosity")), \
        "build/03_radiosity is missing (chapter 3 reports the 'surfaces' key)"
    found = {}
    for h in patch_sizes:
        _, stats = ctx.render("03_radiosity", scene, "--size", "8x8", "--patch-size", h, "--tol", "1e-7",
                              "--iterations", 10000, name=f"radiosity{h}")
        found[h] = {s["name"]: s for s in stats["surfaces"]}
    return found
