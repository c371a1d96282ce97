"""Helpers shared by the grading tests: run a chapter, read its outputs.

Standard library only (Debian's /usr/bin/python3), so `make test` needs no
Python packages.
"""
import json
import math
import os
import re
import subprocess
import shutil
import tempfile

import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "tests"))
import pfm  # noqa: E402  (tests/pfm.py: the one PFM reader of the Python tools)

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "kit"))
import stats as kit_stats  # noqa: E402  (kit/stats.py: Student's t, F, Welch; standard library only)

# The chance that one statistical grading test (one criterion of kit/rubric.json) fails a correct
# solution: at most CRITERION_ALPHA, Bonferroni over the comparisons in it.  Every grade criterion
# with such a tolerance adds CRITERION_ALPHA to the chance that a correct solution fails a whole
# grading, the compare criteria add their family_alpha (kit/rubric.json): the designed rate that
# README.md states and ASSIGNMENT.md computes, kept below the 1 % the kit promises (the
# instructor's calibration measures it).
CRITERION_ALPHA = 0.0002
# Probes' and surfaces' standard errors come from 32 batch means (common/render.h PROBE_BATCHES,
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


# ---- What a test measured and ran, for the grading report ------------------------------------------
# kit/criterion.py empties these lists before a criterion's test and returns them with its result, so
# the report shows a passed criterion's measured values too, the commands to rerun it, and the stubs
# ("TODO name is not implemented", common/todo.h) its runs reached.
COMMANDS = []   # "build/04_pathtrace scenes/cornell.scene --estimator mis --spp 16", in the order run
MEASURED = []   # one dict per comparison of expect_close / expect_between / expect (see measurement())
TODOS = []      # {"name", "file", "line"} of every stub a run reported, once each
CHANNELS = ("red", "green", "blue")

# Options that only say where the output goes or how fast it comes: left out of a recorded command.
PLUMBING = {"--quiet": 0, "--out": 1, "--stats": 1, "--threads": 1}
TODO_LINE = re.compile(r"^(?P<file>[^\s:]+):(?P<line>\d+): TODO (?P<name>\S+) is not implemented\s*$")


# How a chapter program is started: here directly; kit/criterion.py replaces it with a runner that
# starts it inside the grader's sandbox (kit/sandbox.py), where a submission's code reaches nothing of
# the grader's.  Same arguments and result as subprocess.run(capture_output=True, text=True).
def run_program(argv, cwd, timeout):
    return subprocess.run(argv, cwd=cwd, capture_output=True, text=True, timeout=timeout, stdin=subprocess.DEVNULL,
                          errors="replace")


RUN_PROGRAM = [run_program]  # a list, so that the runner can be swapped in every importer at once


def reset_record():
    """Forget what earlier tests recorded (kit/criterion.py calls it before each criterion)."""
    del COMMANDS[:], MEASURED[:], TODOS[:]


def command_text(chapter, argv, scratch=None):
    """The command a student types to rerun this: "build/CHAPTER ARG ...", without the plumbing
    options (PLUMBING) and with a test's scratch files written "scratch/NAME" (the test function,
    named in the report, writes them)."""
    words, i = [f"build/{chapter}"], 0
    while i < len(argv):
        if argv[i] in PLUMBING:
            i += 1 + PLUMBING[argv[i]]
            continue
        word = argv[i]
        if scratch and word.startswith(scratch + os.sep):
            word = "scratch/" + word[len(scratch) + 1:]
        words.append(word)
        i += 1
    return " ".join(words)


def record_command(chapter, argv, scratch=None):
    text = command_text(chapter, argv, scratch)
    if text not in COMMANDS:
        COMMANDS.append(text)
    record_command.last = text


record_command.last = None


def record_todos(stderr):
    """Note the stubs a run reported on stderr ("file:line: TODO name is not implemented")."""
    for line in (stderr or "").splitlines():
        m = TODO_LINE.match(line.strip())
        if m:
            todo = {"name": m["name"], "file": m["file"], "line": int(m["line"])}
            if todo not in TODOS:
                TODOS.append(todo)


def as_number(x):
    """A measured value as a float: None (a stats file's null, written for NaN or infinity) is NaN."""
    return math.nan if x is None else x


def number(x):
    """A value as a student reads it: 5 significant digits, no float noise."""
    if isinstance(x, float) and not math.isfinite(x):
        return str(x)
    return f"{x:.5g}"


def percent(fraction):
    p = abs(fraction) * 100
    return f"{p:.2g} %" if p < 10 else f"{p:.0f} %"


BRIGHT_WORDS = ("radiance", "irradiance", "pixel", "image", "brightness", "light", "emission", "power", "flux")


def direction_words(quantity, words=None):
    """("too bright", "too dark") for light, else ("too large", "too small")."""
    if words:
        return words
    q = quantity.lower()
    if any(w in q for w in BRIGHT_WORDS):
        return ("too bright", "too dark")
    return ("too large", "too small")


def deviation(quantity, measured, expected, words=None):
    """"too bright by 49 %" (or "too dark by 100 %: it is 0, as a stub returns"); "" when equal."""
    high, low = direction_words(quantity, words)
    if not math.isfinite(measured):
        return f"not a number ({measured})"
    d = measured - expected
    if d == 0:
        return ""
    side = high if d > 0 else low
    if expected == 0:
        return f"{side} by {number(abs(d))} (expected exactly 0)"
    text = f"{side} by {percent(d / abs(expected))}" if abs(d / expected) < 100 else \
        f"{side} by {number(abs(d))} ({abs(d / expected):.3g} times the expected value)"
    if measured == 0:
        text += " (0: what a stub returns)"
    return text


def measurement(quantity, measured, expected, passed, allowed, where="", se=None, by="", command=None, words=None,
                limit=None, bound=None):
    """Record one comparison in MEASURED and return its sentence, e.g.
    "irradiance at probe centre, red: measured 0.7412 ± 0.0021 (standard error), expected 0.75227
    (Lambert's polygon formula), allowed ± 0.0086 (4.1 standard errors): too dark by 1.5 %;
    ran build/01_local scratch/area.scene --probe-samples 262144"."""
    command = command if command is not None else record_command.last
    what = quantity + (f" {where}" if where else "")
    text = f"{what[:1].upper()}{what[1:]}: measured {number(measured)}"
    if se is not None:
        text += f" ± {se:.2g} (standard error)"
    if bound:  # a one-sided bound (expect_at_least, expect_at_most): how far beyond it, not a percentage
        text += f", expected {bound} {number(expected)}" + (f" ({by})" if by else "")
        high, low = direction_words(quantity, words)
        beyond = f"{high if measured > expected else low} by {number(abs(measured - expected))} beyond the bound" \
            if math.isfinite(measured) else f"not a number ({measured})"
        text += ": agrees" if passed else ": " + beyond
    else:
        text += f", expected {number(expected)}" + (f" ({by})" if by else "")
        if allowed:
            text += f", allowed {allowed}"
        off = deviation(quantity, measured, expected, words)
        text += (": " + off if off and not passed else ": agrees" + (f" ({off})" if off else ""))
    if command:
        text += f"; ran {command}"
    MEASURED.append({"quantity": quantity, "where": where, "measured": measured, "expected": expected,
                     "standard_error": se, "allowed": allowed, "limit": limit, "passed": passed,
                     "command": command, "text": text})
    return text


def expect_close(quantity, measured, expected, *, rel=None, tol=None, se=None, bound=None, where="", by="",
                 command=None, words=None):
    """Check |measured - expected| <= the largest of rel * |expected|, tol, and bound * se (se: the
    standard error of `measured`, bound: how many of them, e.g. t_bound(...)); record it, and raise
    AssertionError with a sentence a student can act on when it fails.
    quantity: what was measured ("centre pixel radiance"); where: which one ("at probe up, red");
    by: where the expected value comes from ("I cos/r^2"); command: the run that measured it
    (default: the last one run).  Returns the sentence."""
    limits, parts = [], []
    if rel is not None:
        limits.append(rel * abs(expected))
        parts.append(f"{rel:.2g} relative")
    if tol is not None:
        limits.append(tol)
        parts.append(f"± {number(tol)}")
    if se is not None and bound is not None:
        limits.append(bound * se)
        parts.append(f"± {number(bound * se)} ({bound:.2f} standard errors)")
    allowed = max(limits) if limits else 0.0
    measured = as_number(measured)
    ok = math.isfinite(measured) and abs(measured - expected) <= allowed
    text = measurement(quantity, measured, expected, ok, " or ".join(parts) if parts else "no difference",
                       where, se, by, command, words, allowed)
    if not ok:
        raise AssertionError(text)
    return text


def expect_estimate(quantity, measured, expected, se, bound, max_se, *, where="", by="", positive=False,
                    command=None, words=None):
    """A Monte Carlo estimate `measured` with standard error `se`: within bound * se of expected
    (expect_close), and se below max_se (and above 0 when positive) so the tolerance cannot grow to
    hide an error.  The value is checked first: its sentence says which way it is off."""
    se = as_number(se)
    text = expect_close(quantity, measured, expected, se=se, bound=bound, where=where, by=by, command=command,
                        words=words)
    expect(se < max_se and (se > 0 or not positive),
           f"standard error of the {quantity}{' ' + where if where else ''}: {se:.3g}, expected "
           f"{'positive and ' if positive else ''}below {max_se:.3g} so the tolerance stays tight"
           f"{': too noisy' if se >= max_se else ''}", measured=se, expected=max_se, command=command)
    return text


def expect_between(quantity, measured, low, high, *, expected=None, where="", by="", command=None, words=None):
    """Check low <= measured <= high (expected: the value the band is around, for the sentence)."""
    measured = as_number(measured)
    ok = math.isfinite(measured) and low <= measured <= high
    centre = expected if expected is not None else (low + high) / 2
    text = measurement(quantity, measured, centre, ok, f"between {number(low)} and {number(high)}", where,
                       None, by, command, words, max(high - centre, centre - low))
    if not ok:
        raise AssertionError(text)
    return text


def expect_at_least(quantity, measured, low, *, where="", by="", command=None, words=None):
    """Check measured >= low (a one-sided bound): "expected at least low"; when it fails the sentence
    says how far below the bound it is ("too small by 40 %")."""
    measured = as_number(measured)
    ok = math.isfinite(measured) and measured >= low
    text = measurement(quantity, measured, low, ok, f"at least {number(low)}", where, None, by, command, words,
                       None, bound="at least")
    if not ok:
        raise AssertionError(text)
    return text


def expect_at_most(quantity, measured, high, *, where="", by="", command=None, words=None):
    """Check measured <= high (a one-sided bound), as expect_at_least."""
    measured = as_number(measured)
    ok = math.isfinite(measured) and measured <= high
    text = measurement(quantity, measured, high, ok, f"at most {number(high)}", where, None, by, command, words,
                       None, bound="at most")
    if not ok:
        raise AssertionError(text)
    return text


def expect_each(quantity, cases, *, rel=None, tol=None, by="", command=None, words=None):
    """Many comparisons of one kind: cases are (where, measured, expected); each must be within the
    larger of rel * |expected| and tol.  The one farthest off for its allowance goes through
    expect_close, so one sentence names it (a passed check records the closest call)."""
    worst, worst_share = None, -1.0
    for where, got, e in cases:
        got = as_number(got)
        allowed = max(rel * abs(e) if rel is not None else 0.0, tol or 0.0)
        share = abs(got - e) / allowed if allowed > 0 else (0.0 if got == e else math.inf)
        share = share if math.isfinite(got) else math.inf
        if share > worst_share:
            worst, worst_share = (where, got, e), share
    if worst is None:
        return ""
    return expect_close(quantity, worst[1], worst[2], rel=rel, tol=tol, where=worst[0], by=by, command=command,
                        words=words)


def expect_image(quantity, image, expected_at, *, rel=None, tol=None, pixels=None, where="", by="", command=None,
                 words=None):
    """Every pixel channel of `image` against expected_at(x, y, channel) (None: not checked), each
    within the larger of rel * |expected| and tol: the pixel channel farthest off for its allowance
    goes through expect_close, so one sentence names it ("radiance at pixel (3, 5), red ...: too dark
    by 8 %") and a passed check records the closest call.  pixels: the (x, y) to check (default all)."""
    worst, worst_share = None, -1.0
    for x, y in pixels if pixels is not None else ((x, y) for y in range(image.height) for x in range(image.width)):
        for c in range(3):
            e = expected_at(x, y, c)
            if e is None:
                continue
            got = as_number(image.at(x, y)[c])
            allowed = max(rel * abs(e) if rel is not None else 0.0, tol or 0.0)
            share = abs(got - e) / allowed if allowed > 0 else (0.0 if got == e else math.inf)
            if not math.isfinite(got):
                share = math.inf
            if share > worst_share:
                worst, worst_share = (x, y, c, got, e), share
    if worst is None:
        return ""
    x, y, c, got, e = worst
    return expect_close(quantity, got, e, rel=rel, tol=tol, where=f"at pixel ({x}, {y}), {CHANNELS[c]}" +
                        (f" {where}" if where else ""), by=by,
                        command=command if command is not None else getattr(image, "command", None), words=words)


def expect(condition, sentence, *, measured=None, expected=None, command=None):
    """A check that is not a comparison of two numbers: record the sentence (what was expected and
    what was seen) and raise AssertionError with it when condition is false."""
    command = command if command is not None else record_command.last
    text = sentence[:1].upper() + sentence[1:] + (f"; ran {command}" if command else "")
    MEASURED.append({"quantity": sentence, "where": "", "measured": measured, "expected": expected,
                     "standard_error": None, "allowed": None, "limit": None, "passed": bool(condition),
                     "command": command, "text": text})
    if not condition:
        raise AssertionError(text)
    return text


class Context:
    """What a test needs: the build directory under test and a scratch dir.

    seed: the grading seed (kit/grade.py --seed, via kit/criterion.py).  None or 1 runs every
    chapter exactly as the test says (the fixed seeds of `make test`); any other value shifts
    the seed of every chapter run by shifted_seed: an explicit `--seed X` becomes
    shifted_seed(X, seed), and a run without --seed, which the chapter would give its default
    seed 1, gets `--seed shifted_seed(1, seed)` appended.  So each grading seed reruns every
    Monte Carlo test with fresh random numbers, and the instructor's calibration can measure how often a
    correct solution fails.  Runs with --help, and values of --seed that are not a seed the
    chapters accept (bad-input tests), are left alone."""

    def __init__(self, build, seed=None):
        self.build = build
        self.seed = seed
        self._scratch = None

    @property
    def scratch(self):
        """The test's scratch directory, made when first asked for (a Context that only seeds
        arguments leaves no empty directory behind); whoever made the Context removes it (close)."""
        if self._scratch is None:
            self._scratch = tempfile.mkdtemp(prefix="gi-test-")
        return self._scratch

    @property
    def made_scratch(self):
        """The scratch directory if one was made, else None."""
        return self._scratch

    def close(self):
        """Remove the scratch directory, if one was made."""
        if self._scratch is not None:
            shutil.rmtree(self._scratch, ignore_errors=True)
            self._scratch = None

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
        """A file of the test's (a scene) in scratch: written anew, never through a link a run left."""
        p = self.path(name)
        if os.path.lexists(p):
            os.unlink(p)
        with os.fdopen(os.open(p, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o644), "w") as f:
            f.write(text)
        return p

    def run(self, chapter, *args, timeout=600):
        """Run build/<chapter> with args from the repo root; return the CompletedProcess.
        The command goes into COMMANDS, the stubs it reports into TODOS (see record_run)."""
        exe = os.path.join(ROOT, self.build, chapter)
        argv = self.seeded([str(a) for a in args])
        record_command(chapter, argv, self.scratch)
        result = RUN_PROGRAM[0]([exe, *argv], cwd=ROOT, timeout=timeout)
        record_todos(result.stderr)
        return result

    def render(self, chapter, scene, *args, name="render", timeout=600):
        """Render to PFM + stats in scratch; return (image, stats). Fails loudly on a non-zero exit."""
        pfm, stats = self.path(name + ".pfm"), self.path(name + ".json")
        result = self.run(chapter, scene, "--quiet", "--out", pfm, "--stats", stats, *args, timeout=timeout)
        assert result.returncode == 0, f"{chapter} {scene} {' '.join(map(str, args))} exited " \
                                       f"{result.returncode}: {result.stderr.strip()}"
        image = read_pfm(pfm)
        image.command = record_command.last  # for expect_close(..., command=image.command)
        return image, read_json(stats)


class Image:
    def __init__(self, width, height, pixels):
        self.width, self.height, self.pixels = width, height, pixels  # pixels: list of (r,g,b), top row first
        self.command = None  # the chapter command that rendered it (Context.render), for the report

    def at(self, x, y):
        return self.pixels[y * self.width + x]


def read_pfm(path):
    width, height, floats = pfm.read_pfm(path)
    return Image(width, height, pfm.pixels_top_first(width, height, floats))


def read_json(path):
    """A program's JSON output, read as data: a regular file (not a link), at most pfm.OUTPUT_LIMIT bytes."""
    return json.loads(pfm.read_output(path))


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
            where = f"at probe {name}, {CHANNELS[c]}" + (f" ({label.strip()})" if label.strip() else "")
            expect_close("irradiance", got["irradiance"][c], expected, se=se, bound=bound, where=where,
                         by="Lambert's polygon formula")
            expect(0 < se < max_relative_se * expected,
                   f"standard error of the irradiance {where}: {number(se)}, expected positive (a Monte Carlo "
                   f"estimate) and below {max_relative_se:.1%} of {number(expected)} so the tolerance stays tight",
                   measured=se, expected=max_relative_se * expected)


def radiosity_surfaces(ctx, scene, patch_sizes=None):
    """{patch size: {surface name: its entry of build/03_radiosity's "surfaces"}},
    converged (--tol 1e-7): the reference other chapters' surface means are
    compared with, with its discretisation error from two patch sizes, h and h / 2:
    50 and 25 mm, and under the sanitizers 100 and 50 (a sixteenth of the work; the
    same bound for that pair, looser: there the test checks memory, not accuracy)."""
    import os as _os
    assert _os.path.exists(_os.path.join(ROOT, ctx.build, "03_radiosity")), \
        "build/03_radiosity is missing (chapter 3 reports the 'surfaces' key)"
    found = {}
    for h in patch_sizes or ((100, 50) if sanitizer_build(ctx) else (50, 25)):
        _, stats = ctx.render("03_radiosity", scene, "--size", "8x8", "--patch-size", h, "--tol", "1e-7",
                              "--iterations", 10000, name=f"radiosity{h}")
        found[h] = {s["name"]: s for s in stats["surfaces"]}
    return found


def expect_surfaces_match_radiosity(estimated, radiosity, method, how):
    """Each surface's mean radiance (a chapter's "surfaces", with standard errors from 32 batch
    means) against radiosity_surfaces(): within 2 |L_h - L_h/2| (radiosity's discretisation
    error at h/2, for convergence of order >= 0.585) plus t_bound standard errors, and each
    standard error below 2 %.  method names the estimate, how says where its mean comes from."""
    coarse, fine = max(radiosity), min(radiosity)
    expect(set(estimated) == set(radiosity[fine]) == set(radiosity[coarse]),
           f"surfaces of the Cornell box: {method} {sorted(estimated)}, radiosity {sorted(radiosity[fine])}; "
           "expected the same names")
    t = t_bound(BATCH_DF, 3 * len(estimated))
    for name, s in estimated.items():
        r_fine, r_coarse = radiosity[fine][name], radiosity[coarse][name]
        expect_close("area", s["area"], r_fine["area"], rel=1e-6, where=f"of the Cornell box's {name}",
                     by="build/03_radiosity's")
        for c in range(3):
            bound = 2 * abs(r_coarse["radiance"][c] - r_fine["radiance"][c]) + t * s["standard_error"][c]
            expect_close("radiance", s["radiance"][c], r_fine["radiance"][c], tol=bound, se=s["standard_error"][c],
                         where=f"of the Cornell box's {name}, {CHANNELS[c]} ({how})",
                         by=f"radiosity at {fine:g} mm patches ({coarse:g} mm: {r_coarse['radiance'][c]:.5g}), within "
                            f"twice their difference + {t:.2f} standard errors")
            expect_at_most("standard error of the radiance", s["standard_error"][c], 0.02 * s["radiance"][c] + 1e-4,
                           where=f"of the Cornell box's {name}, {CHANNELS[c]}", by="2 % of the radiance + 1e-4",
                           words=("too noisy", "less noisy"))


def furnace_scene(ctx, rho, emission=1.0, name="furnace"):
    """scenes/furnace-pt.scene (a 2 x 2 x 2 cube seen from its centre) with its wall material
    replaced by `emitter E E E diffuse rho rho rho`: L = E / (1 - rho) everywhere."""
    with open(os.path.join(ROOT, "scenes", "furnace-pt.scene")) as f:
        lines = f.read().splitlines()
    text = [f"material wall emitter {emission} {emission} {emission}  diffuse {rho} {rho} {rho}"
            if line.startswith("material wall") else line for line in lines]
    return ctx.write(f"{name}.scene", "\n".join(text) + "\n")


def sanitizer_build(ctx):
    """Whether ctx runs the AddressSanitizer build.  A test that measures statistics at sample counts
    the sanitizers make slow returns early there, naming the test that runs its code under them."""
    return "asan" in ctx.build
