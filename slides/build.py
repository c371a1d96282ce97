#!/usr/bin/python3
"""Build the lecture decks: slides/*.md -> out/slides/*.html (+ .pdf).

usage: slides/build.py [--build DIR] [--out DIR] [--work DIR] [--no-pdf] [--only DECK] [--student]

--student builds the decks students may have while the assignment is open:
every function marked [exercise N.M] (kit/markers.py) that a {{code}} slide
quotes shows its comment and signature only, its body one line
`/* exercise N.M: your code */` (nocomment, from= and to= are ignored for it:
an excerpt would be the answer).  In a student handout (kit/handout.json
exists) the decks are always student decks.

Standard-library Python plus node and gnuplot. The Markdown is CommonMark
with pipe tables and raw HTML, rendered by markdown-it (npm, pinned in
slides/package-lock.json) at build time, with the math by KaTeX (npm), both in
one run of slides/markdown_render.cjs for every slide of every deck. This file
keeps only what is the course's own: it turns the directives below into HTML
(and the math into placeholders, so Markdown never sees TeX), checks them with
deck:line, and hands each slide's Markdown to node.

What a deck may contain besides Markdown (headings, paragraphs, lists,
**bold**, *italic*, `code`, [links](..), ![images](path), pipe tables, raw HTML):

  $...$, $$...$$            KaTeX math, rendered at build time (\\tag{R4}: R1 .. R10 only)
  ---                       a line on its own: next slide
  ::: cols / ::: col / :::  <div class="..."> blocks (e.g. code left, figure right)
  Note: ...                 speaker notes (to the end of the slide)
  {{code FILE:FUNCTION [nocomment] [from=TEXT] [to=TEXT]}}
                            the C function FUNCTION cut out of FILE now, with its
                            comment and true line numbers; from/to keep only the
                            lines from the first one containing TEXT to the next
                            one containing TEXT.  A missing function or text
                            fails the build with deck:line.
  ```render [cols=N] [size=WxH]
  caption | CHAPTER ARGS...
  ```                       a grid of images rendered now by build/CHAPTER ARGS
  {{plot NAME}}             a plot made now by running the chapters (see PLOTS)
  {{fact NAME}}             in text: a number such a plot computed (see FACT_PLOTS)
  {{tradeoff}}              out/tradeoff*.png of `make tradeoff` when
                            out/tradeoff.csv exists, else a plot of our own sweep

Renders are cached in WORK/cache by a hash of the executable, the scene file
and the arguments, so a second build only re-renders what changed.

--draft renders every figure with an eighth of its samples (DRAFT_OPTIONS): the
decks, their checks and the browser's are the same, only the pictures noisier
and the plots' error axes off.  The tests build drafts (make test's time);
`make slides` never does.
"""
import argparse
import hashlib
import html
import json
import math
import os
import re
import shlex
import shutil
import subprocess
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "tests"))
import pfm  # noqa: E402  (tests/pfm.py: the one PFM reader of the Python tools)

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SLIDES = os.path.join(ROOT, "slides")
LABEL_RANGE = range(1, 11)  # the lecture's equations are R1 .. R10


DRAFT_OPTIONS = ("--spp", "--photons", "--time")  # the work a render does, divided by DRAFT_FACTOR
DRAFT_FACTOR = 8


def drafted(args):
    """ARGS with the samples of DRAFT_OPTIONS divided by DRAFT_FACTOR (at least one)."""
    out = list(args)
    for i in range(len(out) - 1):
        if out[i] in DRAFT_OPTIONS:
            value = float(out[i + 1]) / DRAFT_FACTOR
            out[i + 1] = f"{value:g}" if out[i] == "--time" else str(max(1, int(value)))
    return out


class BuildError(Exception):
    pass


def fail(where, message):
    raise BuildError(f"{where}: {message}")


def rel(path):
    """path relative to the repository when inside it (for messages), else absolute."""
    r = os.path.relpath(path, ROOT)
    return os.path.abspath(path) if r.startswith("..") else r


# ---- C source: functions by name, highlighting ------------------------------------------------

def c_code_mask(text):
    """A copy of text with comments, strings and char literals replaced by
    spaces (newlines kept), so braces can be counted safely."""
    out, i, n = [], 0, len(text)
    while i < n:
        c = text[i]
        if text.startswith("/*", i):
            j = text.find("*/", i + 2)
            j = n if j < 0 else j + 2
            out.append(re.sub(r"[^\n]", " ", text[i:j]))
            i = j
        elif text.startswith("//", i):
            j = text.find("\n", i)
            j = n if j < 0 else j
            out.append(" " * (j - i))
            i = j
        elif c in "\"'":
            j = i + 1
            while j < n and text[j] != c and text[j] != "\n":
                j += 2 if text[j] == "\\" else 1
            j = min(j + 1, n)
            out.append(" " * (j - i))
            i = j
        else:
            out.append(c)
            i += 1
    return "".join(out)


def find_function(path, name):
    """(first_line, last_line, comment_first_line) of the definition of C
    function `name` in path (1-based, inclusive), or None."""
    with open(path) as f:
        text = f.read()
    masked = c_code_mask(text)
    lines = text.split("\n")
    # A definition starts at column 0 (not a call, not a prototype): return type ... name(
    pattern = re.compile(r"^[A-Za-z_][\w \t\*]*?\b" + re.escape(name) + r"\s*\(", re.M)
    for m in pattern.finditer(masked):
        if re.match(r"(return|else|if|while|for|switch)\b", m.group(0)):
            continue
        # the parameter list, then '{' (definition) or ';' (prototype)
        depth, i = 0, m.end() - 1
        while i < len(masked):
            if masked[i] == "(":
                depth += 1
            elif masked[i] == ")":
                depth -= 1
                if depth == 0:
                    break
            i += 1
        rest = masked[i + 1:]
        k = len(rest) - len(rest.lstrip())
        if not rest[k:k + 1] == "{":
            continue
        start = i + 1 + k
        depth, j = 0, start
        while j < len(masked):
            if masked[j] == "{":
                depth += 1
            elif masked[j] == "}":
                depth -= 1
                if depth == 0:
                    break
            j += 1
        first = masked.count("\n", 0, m.start()) + 1
        last = masked.count("\n", 0, j) + 1
        # the comment block right above the definition
        c = first - 1
        while c >= 1 and lines[c - 1].strip() and (lines[c - 1].lstrip().startswith(("/*", "*", "//"))):
            c -= 1
        comment_first = c + 1 if c + 1 < first and lines[c].lstrip().startswith(("/*", "//")) else first
        return first, last, comment_first
    return None


C_KEYWORDS = set("""break case const continue default do else enum extern for goto if inline return
sizeof static struct switch typedef union while restrict""".split())
C_TYPES = set("""void bool char short int long float double unsigned signed size_t uint64_t uint32_t
int64_t vec3 ray hit rng scene material surface patch FILE""".split())
LABEL_RE = re.compile(r"\(R\d+(?:\s*(?:,|-|–|and)\s*R?\d+)*\)|\bR(?:10|[1-9])\b")


def labels_in(text):
    """The equation labels R1..R10 cited in text: (R9), (R7, R8), (R7-R9), R6."""
    found = set()
    for m in re.finditer(r"\((R\d+(?:\s*(?:,|-|–|and)\s*R?\d+)*)\)", text):
        parts = re.split(r"\s*(,|-|–|and)\s*", m.group(1))
        numbers, ops = [int(p.lstrip("R")) for p in parts[0::2]], parts[1::2]
        for k, num in enumerate(numbers):
            found.add(num)
            if k > 0 and ops[k - 1] in "-–":
                found.update(range(numbers[k - 1], num + 1))
    return {n for n in found if n in LABEL_RANGE}


def highlight_c(code):
    """Minimal C highlighting to HTML; equation labels in comments are marked."""
    token = re.compile(r"(/\*.*?\*/|//[^\n]*)|(\"(?:\\.|[^\"\\\n])*\"|'(?:\\.|[^'\\\n])*')|"
                       r"(^[ \t]*#[^\n]*)|(\b\d+(?:\.\d*)?(?:[eE][-+]?\d+)?[uUlLfF]*\b)|(\b[A-Za-z_]\w*\b)",
                       re.S | re.M)
    out, pos = [], 0
    for m in token.finditer(code):
        out.append(html.escape(code[pos:m.start()]))
        s = m.group(0)
        if m.group(1):
            body = html.escape(s)
            body = re.sub(r"\((R\d+(?:\s*(?:,|-|–|and)\s*R?\d+)*)\)",
                          lambda k: f'<span class="eqref">({k.group(1)})</span>', body)
            out.append(f'<span class="cm">{body}</span>')
        elif m.group(2):
            out.append(f'<span class="st">{html.escape(s)}</span>')
        elif m.group(3):
            out.append(f'<span class="pp">{html.escape(s)}</span>')
        elif m.group(4):
            out.append(f'<span class="nu">{html.escape(s)}</span>')
        elif s in C_KEYWORDS:
            out.append(f'<span class="kw">{s}</span>')
        elif s in C_TYPES:
            out.append(f'<span class="ty">{s}</span>')
        else:
            out.append(s)
        pos = m.end()
    out.append(html.escape(code[pos:]))
    return "".join(out)


def code_block(where, spec, narrow=False):
    """{{code FILE:FUNCTION options}} -> (html, labels cited in the shown code)."""
    try:
        words = shlex.split(spec)
    except ValueError as e:
        fail(where, f"bad code directive: {e}")
    if not words or ":" not in words[0]:
        fail(where, "code directive wants FILE:FUNCTION")
    file_name, function = words[0].rsplit(":", 1)
    options = {}
    for w in words[1:]:
        key, _, value = w.partition("=")
        if key not in ("nocomment", "from", "to", "height"):
            fail(where, f"unknown code option '{key}'")
        options[key] = value
    path = os.path.join(ROOT, file_name)
    if not os.path.isfile(path):
        fail(where, f"{file_name}: no such file")
    found = find_function(path, function)
    if not found:
        fail(where, f"{file_name}: no function named '{function}' (the slide shows it: "
                    f"rename it here or restore it there)")
    first, last, comment_first = found
    with open(path) as f:
        lines = f.read().split("\n")
    exercise = STUDENT.get((file_name, function)) if STUDENT is not None else None
    if exercise is not None:
        return student_code_block(file_name, function, exercise, lines, first, comment_first, narrow,
                                  options.get("height"), where)
    start = first if "nocomment" in options or "from" in options else comment_first
    end = last
    if "from" in options:
        hits = [k for k in range(first, last + 1) if options["from"] in lines[k - 1]]
        if not hits:
            fail(where, f"{file_name}:{first}: function '{function}' has no line containing "
                        f"'{options['from']}'")
        start = hits[0]
    if "to" in options:
        hits = [k for k in range(start, last + 1) if options["to"] in lines[k - 1]]
        if not hits:
            fail(where, f"{file_name}:{first}: function '{function}' has no line containing "
                        f"'{options['to']}' after line {start}")
        end = hits[0]
    shown = lines[start - 1:end]
    return figure_block(file_name, function, shown, start, end, first, last, narrow, options.get("height"), where)


# The exercises a student deck hides: {(file, function): exercise}, or None for the instructor's decks.
STUDENT = None


def student_exercises():
    """{(file, function): Exercise} of every [exercise N.M] marker (kit/markers.py)."""
    sys.path.insert(0, os.path.join(ROOT, "kit"))
    import markers
    try:
        return {(e.file, e.name): e for e in markers.all_exercises(ROOT)}
    except ValueError as e:
        raise BuildError(str(e))


def student_code_block(file_name, function, exercise, lines, first, comment_first, narrow, height, where):
    """An exercise function as a student deck shows it: comment, signature, no body."""
    k = first
    while k <= len(lines) and "{" not in lines[k - 1]:
        k += 1
    signature = lines[comment_first - 1:k]
    brace_line = signature.pop()
    head = brace_line[:brace_line.index("{")]
    if head.strip():
        signature.append(head.rstrip())
    shown = signature + ["{", f"    /* exercise {exercise.id}: your code */", "}"]
    end = comment_first + len(shown) - 1
    return figure_block(file_name, function, shown, comment_first, end, first, end, narrow, height, where,
                        numbers=list(range(comment_first, comment_first + len(signature))) + ["", "", ""],
                        note=f" (exercise {exercise.id}: the body is yours to write)")


def figure_block(file_name, function, shown, start, end, first, last, narrow, height, where, numbers=None,
                 note=""):
    indent = min((len(s) - len(s.lstrip()) for s in shown if s.strip()), default=0)
    shown = [s[indent:] for s in shown]
    code = "\n".join(shown)
    # as large as fits: 600 px of height for the lines, the slide's (or column's) width for the longest
    width = 590 if narrow else 1220
    longest = max((len(s.expandtabs(4)) for s in shown), default=1) + len(str(end)) + 3
    try:
        height = float(height or 600)
    except ValueError:
        fail(where, f"height={height}: wants pixels")
    font_px = max(10.0, min(19.0, height / (len(shown) * 1.36 + 2), width / (longest * 0.61)))
    numbers = "\n".join(str(k) for k in (numbers if numbers is not None else range(start, end + 1)))
    caption = f'{html.escape(file_name)}:{start}&ndash;{end} &nbsp;<b>{html.escape(function)}()</b>'
    if note:
        caption = f'{html.escape(file_name)}:{first} &nbsp;<b>{html.escape(function)}()</b>{html.escape(note)}'
    elif start > first or end < last:
        caption += " (excerpt)"
    block = (f'<figure class="code" style="font-size: {font_px:.1f}px"><figcaption>{caption}</figcaption>'
             f'<div class="code-scroll"><pre class="ln">{numbers}</pre>'
             f'<pre class="src"><code>{highlight_c(code)}</code></pre></div></figure>')
    return block, labels_in(code)


# ---- images -------------------------------------------------------------------------------------

def read_pfm(path):
    try:
        return pfm.read_pfm(path)
    except ValueError:
        raise BuildError(f"{rel(path)}: not a colour PFM")


def mean_luminance(path):
    _, _, f = read_pfm(path)
    n = len(f) // 3
    return sum(0.2126 * f[3 * i] + 0.7152 * f[3 * i + 1] + 0.0722 * f[3 * i + 2] for i in range(n)) / n


def rms_difference(path_a, path_b):
    wa, ha, a = read_pfm(path_a)
    wb, hb, b = read_pfm(path_b)
    if (wa, ha) != (wb, hb):
        raise BuildError(f"{rel(path_a)} and {rel(path_b)} differ in size")
    return math.sqrt(sum((x - y) ** 2 for x, y in zip(a, b)) / len(a))


class Renderer:
    """Runs the chapters; caches every render by what determines it."""

    def __init__(self, build, work, log, draft=False):
        self.build, self.cache, self.log, self.draft = build, os.path.join(work, "cache"), log, draft
        os.makedirs(self.cache, exist_ok=True)
        self.fresh = 0
        self.seconds = 0.0
        self.used = []  # every render a deck used, for out/slides/figures.json
        self._exe_hash = {}

    def _file_hash(self, path):
        if path not in self._exe_hash:
            with open(path, "rb") as f:
                self._exe_hash[path] = hashlib.sha256(f.read()).hexdigest()
        return self._exe_hash[path]

    def render(self, where, chapter, args):
        """Render build/CHAPTER ARGS; return {'png','pfm','json'} paths."""
        args = drafted(args) if self.draft else args
        exe = os.path.join(ROOT, self.build, chapter)
        if not re.fullmatch(r"\d\d[a-z]?_\w+", chapter):
            fail(where, f"'{chapter}' is not a chapter name (like 04_pathtrace)")
        if not os.access(exe, os.X_OK):
            fail(where, f"{rel(exe)} is not built (run make first)")
        h = hashlib.sha256()
        h.update(self._file_hash(exe).encode())
        for a in args:
            h.update(b"\0" + a.encode())
            if a.endswith(".scene") or a.endswith(".obj"):
                p = os.path.join(ROOT, a)
                if not os.path.isfile(p):
                    fail(where, f"{a}: no such file")
                h.update(self._file_hash(p).encode())
                if a.endswith(".scene"):
                    with open(p) as f:
                        for line in f:
                            w = line.split()
                            if len(w) >= 4 and w[0] == "mesh":
                                mesh = os.path.join(os.path.dirname(p), w[3])
                                if os.path.isfile(mesh):
                                    h.update(self._file_hash(mesh).encode())
        key = h.hexdigest()[:20]
        self.used.append({"where": where, "chapter": chapter, "args": args,
                          "executable": rel(exe), "executable_sha256": self._file_hash(exe), "key": key})
        base = os.path.join(self.cache, f"{chapter}-{key}")
        out = {k: f"{base}.{k}" for k in ("png", "pfm", "json")}
        if all(os.path.exists(p) for p in out.values()):
            return out
        command = [exe, *args, "--quiet", "--out", out["png"], "--out", out["pfm"], "--stats", out["json"]]
        start = time.time()
        result = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, stdin=subprocess.DEVNULL)
        self.seconds += time.time() - start
        self.fresh += 1
        if result.returncode != 0:
            fail(where, f"{chapter} {' '.join(args)} exited {result.returncode}: {result.stderr.strip()[-800:]}")
        self.log(f"  rendered {chapter} {' '.join(args)}  ({time.time() - start:.1f} s)")
        return out


# ---- plots (gnuplot) -----------------------------------------------------------------------------

GNUPLOT_HEAD = """set terminal svg size 720,430 fixed font 'DejaVu Sans,15' background '#ffffff'
set output '{out}'
set border lw 1.2
set grid lc rgb '#dddddd'
set key top right box opaque
"""


def gnuplot(where, script, out):
    os.makedirs(os.path.dirname(out), exist_ok=True)
    tmp = out + ".tmp"
    result = subprocess.run(["gnuplot"], input=GNUPLOT_HEAD.format(out=tmp) + script, text=True,
                            capture_output=True, cwd=ROOT)
    if result.returncode != 0 or not os.path.exists(tmp):
        fail(where, f"gnuplot failed: {result.stderr.strip()[-800:]}")
    os.replace(tmp, out)


def write_data(path, rows):
    with open(path, "w") as f:
        for row in rows:
            f.write(" ".join(str(v) for v in row) + "\n")


# Neumann-term renders shared by the figures and the plots (same arguments -> same cache entry).
NEUMANN_TERMS = 6
NEUMANN_SIZE = "128x128"
NEUMANN_PT_SPP = "64"


def neumann_args(chapter, k):
    bounces = f"{k}:{k}" if k is not None else "0:"
    # one stop brighter per bounce, so every term is visible (the plot reads the PFM, unaffected)
    args = ["scenes/cornell.scene", "--size", NEUMANN_SIZE, "--bounces", bounces, "--exposure", str(max(0, (k or 0) - 1))]
    if chapter == "04_pathtrace":
        args += ["--spp", NEUMANN_PT_SPP]
    return args


def plot_neumann(ctx, where, out):
    """Mean radiance of each Neumann term K^k E, radiosity vs path tracing."""
    rows = []
    for k in range(NEUMANN_TERMS):
        rad = ctx.renderer.render(where, "03_radiosity", neumann_args("03_radiosity", k))
        pt = ctx.renderer.render(where, "04_pathtrace", neumann_args("04_pathtrace", k))
        rows.append((k, mean_luminance(rad["pfm"]), mean_luminance(pt["pfm"])))
    rad_full = mean_luminance(ctx.renderer.render(where, "03_radiosity", neumann_args("03_radiosity", None))["pfm"])
    data = os.path.join(ctx.work, "neumann.dat")
    write_data(data, rows)
    ratio = rows[3][1] / rows[2][1] if rows[2][1] > 0 else 0
    ctx.facts["neumann_ratio"] = ratio
    ctx.facts["neumann_full"] = rad_full
    gnuplot(where, f"""
set logscale y
set xlabel 'k  (term K^k E of the Neumann series)'
set ylabel 'mean radiance of the term'
set xtics 1
set xrange [-0.3:{NEUMANN_TERMS - 1}.3]
plot '{data}' using 1:2 with linespoints lw 2 pt 7 ps 1.3 lc rgb '#1f77b4' title 'radiosity (03)', \\
     '{data}' using 1:3 with points pt 6 ps 2.2 lw 2 lc rgb '#d62728' title 'path tracing (04), {NEUMANN_PT_SPP} spp'
""", out)


def plot_residual(ctx, where, out):
    """Radiosity residual per iteration for the three iterative solvers."""
    series = []
    for solver in ("jacobi", "gauss-seidel", "shooting"):
        r = ctx.renderer.render(where, "03_radiosity", ["scenes/cornell.scene", "--size", "32x32", "--solver", solver,
                                                          "--tol", "1e-5", "--patch-size", "100"])
        stats = json.load(open(r["json"]))
        history = stats.get("residual_history")
        if not history:
            fail(where, f"03_radiosity --solver {solver}: no residual_history in its --stats")
        step = 1.0  # shooting records its residual every n shots: one "iteration" = the work of a Jacobi step
        data = os.path.join(ctx.work, f"residual-{solver}.dat")
        write_data(data, [((i + 1) * step, v) for i, v in enumerate(history) if v > 0])
        series.append((solver, data))
    colours = {"jacobi": "#1f77b4", "gauss-seidel": "#2ca02c", "shooting": "#ff7f0e"}
    plots = ", ".join(f"'{d}' using 1:2 with lines lw 2.5 lc rgb '{colours[s]}' title '{s}'" for s, d in series)
    gnuplot(where, f"""
set logscale y
set format y '10^{{%L}}'
set xlabel 'iterations (shooting: n shots = 1 iteration; 100 mm patches)'
set ylabel 'residual / source power'
set xrange [0:*]
plot {plots}
""", out)


CONVERGENCE_SPP = [1, 2, 4, 8, 16, 32, 64, 128, 256]


def plot_pt_convergence(ctx, where, out):
    """Path-tracing noise against samples per pixel, with the N^-1/2 line.
    The error of one image is estimated without a reference: two renders
    with different seeds differ by sqrt(2) times the noise of one."""
    rows = []
    for spp in CONVERGENCE_SPP:
        # --bounces 1: leaves out the lamp seen directly: its edge pixels are all-or-nothing (0 or 17)
        # at low spp and would dominate the RMS; the reflected light is what the estimator integrates.
        renders = [ctx.renderer.render(where, "04_pathtrace", ["scenes/cornell.scene", "--size", "48x48", "--spp",
                                                               str(spp), "--seed", str(seed), "--bounces", "1:",
                                                               "--probe-samples", "32"]) for seed in (1, 2)]
        rows.append((spp, rms_difference(renders[0]["pfm"], renders[1]["pfm"]) / math.sqrt(2)))
    data = os.path.join(ctx.work, "pt-convergence.dat")
    write_data(data, rows)
    # least-squares slope in log-log
    xs, ys = [math.log(r[0]) for r in rows], [math.log(r[1]) for r in rows]
    mx, my = sum(xs) / len(xs), sum(ys) / len(ys)
    slope = sum((x - mx) * (y - my) for x, y in zip(xs, ys)) / sum((x - mx) ** 2 for x in xs)
    ctx.facts["pt_slope"] = slope
    c = rows[0][1]
    gnuplot(where, f"""
set logscale xy
set xlabel 'samples per pixel N'
set ylabel 'RMS noise of the reflected light'
set format y '%g'
set key bottom left box opaque
plot '{data}' using 1:2 with linespoints lw 2 pt 7 ps 1.3 lc rgb '#d62728' title 'path tracing (04), fitted slope {slope:.2f}', \\
     {c}*x**-0.5 with lines dt 2 lw 2 lc rgb '#444444' title 'N^{{-1/2}}'
""", out)


def own_tradeoff(ctx, where, out):
    """Error against time, our own quick sweep (when `make tradeoff` has not run).
    Reference: path tracing with many samples (an independent, unbiased
    estimate); radiosity's error is its discretisation bias."""
    size = "32x32"
    # few probe walks: the probes are not what this plot is about, and they would dominate the time
    quick = ["--probe-samples", "32", "--bounces", "1:"]  # reflected light only, as in plot_pt_convergence
    ref = ctx.renderer.render(where, "04_pathtrace", ["scenes/cornell.scene", "--size", size, "--spp", "4096",
                                                      "--seed", "99"] + quick)
    rows_pt, rows_rad = [], []
    for spp in (1, 4, 16, 64, 256):
        r = ctx.renderer.render(where, "04_pathtrace", ["scenes/cornell.scene", "--size", size, "--spp", str(spp)]
                                + quick)
        t = json.load(open(r["json"]))["time_s"]
        rows_pt.append((t, rms_difference(r["pfm"], ref["pfm"]), spp))
    for patch in (200, 140, 100, 70, 50):
        # 16 spp: anti-aliased pixels like the path tracer's, so edges do not count as radiosity's error
        r = ctx.renderer.render(where, "03_radiosity", ["scenes/cornell.scene", "--size", size, "--patch-size",
                                                          str(patch), "--shading", "smooth", "--spp", "16",
                                                          "--bounces", "1:"])
        t = json.load(open(r["json"]))["time_s"]
        rows_rad.append((t, rms_difference(r["pfm"], ref["pfm"]), patch))
    d_pt, d_rad = os.path.join(ctx.work, "tradeoff-pt.dat"), os.path.join(ctx.work, "tradeoff-rad.dat")
    write_data(d_pt, rows_pt)
    write_data(d_rad, rows_rad)
    gnuplot(where, f"""
set logscale xy
set xlabel 'time (s, 2 cores, {size} pixels)'
set ylabel 'RMS error vs. 4096-spp reference'
set format y '%g'
set key top right box opaque
plot '{d_pt}' using 1:2 with linespoints lw 2 pt 7 ps 1.3 lc rgb '#d62728' title 'path tracing: 1 .. 256 spp', \\
     '{d_pt}' using 1:2:(sprintf('%d', $3)) with labels offset 0,1 notitle, \\
     '{d_rad}' using 1:2 with linespoints lw 2 pt 5 ps 1.3 lc rgb '#1f77b4' title 'radiosity (smooth): patch edge 200 .. 50 mm', \\
     '{d_rad}' using 1:2:(sprintf('%d', $3)) with labels offset 0,-1 notitle
""", out)


# numbers the text may quote with {{fact NAME}}, and the plot that computes each
FACT_PLOTS = {"neumann_ratio": "neumann", "neumann_full": "neumann", "pt_slope": "pt-convergence"}

PLOTS = {
    "neumann": plot_neumann,
    "residual": plot_residual,
    "pt-convergence": plot_pt_convergence,
}


# ---- Markdown -> HTML: our directives here, the Markdown itself by markdown-it -------------------

# Placeholders for what markdown-it must not see (math, figures, captions): private-use characters,
# which it passes through as ordinary text. The kind letter says what the number refers to.
PLACEHOLDER = re.compile("(?:<!--)?\ue000([DIBM])(\\d+)\ue001(?:-->)?")
INLINE_MATH = re.compile(r"(?<![\\$])\$(?=\S)([^$\n]+?)(?<=\S)\$(?!\d)")


class Markup:
    """Everything of all decks that node renders, collected for one run of
    slides/markdown_render.cjs: slides as Markdown (D), inline Markdown (I,
    captions) and TeX (M); plus the HTML made here (B), kept from Markdown."""

    def __init__(self):
        self.jobs = {"D": [], "I": [], "M": [], "B": []}
        self.where = []  # deck:line of each formula, for KaTeX's errors
        self.done = None

    def add(self, kind, value):
        self.jobs[kind].append(value)
        return f"\ue000{kind}{len(self.jobs[kind]) - 1}\ue001"

    def math(self, tex, display, where):
        self.where.append(where)
        return self.add("M", {"tex": tex, "display": display})

    def block(self, html_text):
        """HTML made here, as a line of its own that markdown-it keeps (an HTML comment)."""
        return f"<!--{self.add('B', html_text)}-->"

    def render(self, node, node_modules):
        script = os.path.join(SLIDES, "markdown_render.cjs")
        payload = json.dumps({"blocks": self.jobs["D"], "inline": self.jobs["I"], "math": self.jobs["M"]})
        result = subprocess.run([node, script, node_modules], input=payload, capture_output=True, text=True)
        if result.returncode != 0:
            raise BuildError(f"slides/markdown_render.cjs failed: {result.stderr.strip()[-1500:]}")
        out = json.loads(result.stdout)
        errors = [f"{self.where[i]}: KaTeX: {r['error']}" for i, r in enumerate(out["math"]) if "error" in r]
        if errors:
            raise BuildError("\n".join(errors))
        self.done = {"D": out["blocks"], "I": out["inline"], "M": [r["html"] for r in out["math"]],
                     "B": self.jobs["B"]}

    def expand(self, text, keep_math=False):
        """Placeholders -> their HTML (those inside included, until none is left)."""
        def one(m):
            if keep_math and m.group(1) == "M":
                return m.group(0)
            return self.done[m.group(1)][int(m.group(2))]
        while True:
            new = PLACEHOLDER.sub(one, text)
            if new == text:
                return text
            text = new


class Deck:
    def __init__(self, ctx, path):
        self.ctx, self.path = ctx, path
        self.name = os.path.splitext(os.path.basename(path))[0]
        self.tags = set()          # labels stated with \tag{Rn}
        self.code_labels = []      # (where, labels) of every code block
        self.title = self.name
        self.title_slide = ""      # placeholder of the first slide's HTML (set_title reads its <h1>)
        self.in_column = False

    def where(self, line):
        return f"{rel(self.path)}:{line}"

    def inline(self, text, line):
        """A line of Markdown with its math, {{fact}}s and image paths replaced (code spans untouched)."""
        spans = []
        text = re.sub(r"`[^`]+`", lambda m: spans.append(m.group(0)) or f"\ue002{len(spans) - 1}\ue003", text)
        text = re.sub(r"\{\{fact\s+(\w+)\}\}", lambda m: self.fact(m.group(1), line), text)
        text = INLINE_MATH.sub(lambda m: self.math(m.group(1), False, line), text)
        text = re.sub(r"!\[([^\]]*)\]\(([^)\s]+)\)", lambda m: f"![{m.group(1)}]({self.asset(m.group(2), line)})",
                      text)
        return re.sub("\ue002(\\d+)\ue003", lambda m: spans[int(m.group(1))], text)

    def math(self, tex, display, line):
        for m in re.finditer(r"\\tag\*?\{([^}]*)\}", tex):
            label = m.group(1)
            if not re.fullmatch(r"R(\d+)", label) or int(label[1:]) not in LABEL_RANGE:
                fail(self.where(line), f"\\tag{{{label}}}: equations are labelled R1 .. R10 as in the lecture")
            self.tags.add(int(label[1:]))
        return self.ctx.markup.math(tex, display, self.where(line))

    def asset(self, src, line):
        """An image path in the deck: copied next to the decks under fig/."""
        if re.match(r"[a-z]+:", src):
            fail(self.where(line), f"{src}: decks are offline, no URLs")
        path = os.path.join(ROOT, src)
        if not os.path.isfile(path):
            fail(self.where(line), f"{src}: no such file")
        return self.ctx.publish(path)

    def convert(self):
        """The deck's <section>s, with placeholders for what node renders (see Markup)."""
        with open(self.path) as f:
            lines = f.read().split("\n")
        slides, current, start = [], [], 1
        in_fence = False
        for number, text in enumerate(lines, 1):
            if text.startswith("```"):
                in_fence = not in_fence
            if text.strip() == "---" and not in_fence:
                slides.append((start, current))
                current, start = [], number + 1
            else:
                current.append((number, text))
        slides.append((start, current))
        sections = []
        for index, (start, body) in enumerate(slides):
            text, notes = self.markdown(body)
            content = self.ctx.markup.add("D", text)
            if index == 0:
                self.title_slide = content
            if notes is not None:
                content += '\n<aside class="notes">' + self.ctx.markup.add("D", notes) + "</aside>"
            classes = "title-slide" if index == 0 else ""
            sections.append(f'<section class="{classes}" data-source="{self.where(start)}">\n{content}\n</section>')
        # every label the shown code cites is stated on a slide of the deck
        for where, labels in self.code_labels:
            missing = sorted(labels - self.tags)
            if missing:
                fail(where, "the code shown cites " + ", ".join(f"(R{n})" for n in missing) +
                     f" but no slide of {os.path.basename(self.path)} states it (\\tag{{R{missing[0]}}})")
        return sections

    def set_title(self):
        """The deck's title: the first slide's <h1>, as text (once node has rendered it)."""
        m = re.search(r"<h1>(.*?)</h1>", self.ctx.markup.expand(self.title_slide, keep_math=True), re.S)
        if m:
            self.title = html.unescape(re.sub(r"<[^>]+>|\ue000M\d+\ue001", "", m.group(1))).strip()

    def markdown(self, body):
        """One slide's lines -> (its Markdown, the Markdown of its speaker notes or None). The
        directives, ``` render blocks, $$ math and ::: blocks become HTML here, each on lines of
        its own between blank lines, so Markdown ends a paragraph or list before them as before."""
        out, notes, div_stack = [], None, []
        target = out
        i = 0
        while i < len(body):
            number, text = body[i]
            stripped = text.strip()
            if stripped.startswith("```"):  # render grids here; literal code to markdown-it as it is
                j = i + 1
                while j < len(body) and not body[j][1].strip().startswith("```"):
                    j += 1
                if j >= len(body):
                    fail(self.where(number), "unclosed ``` block")
                if stripped[3:].split()[:1] == ["render"]:
                    target += ["", self.ctx.markup.block(self.render_grid(number, stripped[3:].strip(),
                                                                          body[i + 1:j])), ""]
                else:
                    target += [t for _, t in body[i:j + 1]]
                i = j + 1
                continue
            if stripped.startswith("$$"):
                tex, j = stripped[2:], i
                while not (tex.rstrip().endswith("$$") and (j > i or len(stripped) > 2)):
                    j += 1
                    if j >= len(body):
                        fail(self.where(number), "unclosed $$")
                    tex += "\n" + body[j][1]
                tex = tex.rstrip()[:-2]
                target += ["", f'<div class="eq">{self.math(tex.strip(), True, number)}</div>', ""]
                i = j + 1
                continue
            m = re.fullmatch(r"\{\{(\w+)\s*(.*?)\}\}", stripped)
            if m and m.group(1) != "fact":
                target += ["", self.ctx.markup.block(self.directive(number, m.group(1), m.group(2))), ""]
            elif stripped.startswith(":::"):
                classes = stripped[3:].strip()
                if classes:
                    target += ["", f'<div class="{html.escape(classes)}">', ""]
                    div_stack.append(classes.split())
                else:
                    if not div_stack:
                        fail(self.where(number), "::: closes nothing")
                    target += ["", "</div>", ""]
                    div_stack.pop()
                self.in_column = any("col" in c for c in div_stack)
            elif stripped.startswith("Note:"):
                notes = []
                target = notes
                target.append(self.inline(stripped[5:].strip(), number))
            else:
                target.append(self.inline(text, number))
            i += 1
        if div_stack:
            fail(self.where(body[-1][0] if body else 0), "a ::: block is not closed on this slide")
        return "\n".join(out), None if notes is None else "\n".join(notes)

    def directive(self, number, name, argument):
        where = self.where(number)
        if name == "code":
            block, labels = code_block(where, argument, narrow=self.in_column)
            self.code_labels.append((where, labels))
            return block
        if name == "plot":
            key = argument.strip()
            if key not in PLOTS:
                fail(where, f"unknown plot '{key}' (known: {', '.join(sorted(PLOTS))})")
            self.plot(where, key)
            return f'<figure class="plot r-stretch"><img src="fig/plot-{key}.svg" alt="plot {key}"></figure>'
        if name == "tradeoff":
            return self.tradeoff(where)
        fail(where, f"unknown directive {{{{{name}}}}}")

    def plot(self, where, key):
        if key not in self.ctx.plots_done:
            PLOTS[key](self.ctx, where, os.path.join(self.ctx.out, "fig", f"plot-{key}.svg"))
            self.ctx.plots_done.add(key)

    def fact(self, key, line):
        """{{fact NAME}} in text: a number a plot computed from the renders (e.g. neumann_ratio)."""
        if key not in self.ctx.facts and key in FACT_PLOTS:
            self.plot(self.where(line), FACT_PLOTS[key])
        if key not in self.ctx.facts:
            fail(self.where(line), f"no fact '{key}' (known: {', '.join(sorted(FACT_PLOTS))})")
        return f'<span class="fact">{self.ctx.facts[key]:.2f}</span>'

    def tradeoff(self, where):
        """The plots of `make tradeoff` when out/tradeoff.csv exists, else our own quick sweep."""
        out_dir = self.ctx.tradeoff_dir
        stems = []
        if os.path.exists(os.path.join(out_dir, "tradeoff.csv")):
            names = [p for p in os.listdir(out_dir) if re.fullmatch(r"tradeoff[-\w]*\.(png|svg)", p)]
            stems = sorted({os.path.splitext(p)[0] for p in names},
                           key=lambda t: ("radiosity" in t, t))  # error-time plots first, then radiosity's
        if stems:
            self.ctx.tradeoff_source = f"make tradeoff ({rel(out_dir)}/tradeoff.csv)"
            published = []
            for stem in stems:
                name = stem + (".svg" if os.path.exists(os.path.join(out_dir, stem + ".svg")) else ".png")
                published.append((name, self.ctx.publish(os.path.join(out_dir, name))))
            # the first error-against-time plot large; the others one click away
            others = ", ".join(f'<a href="{src}">{html.escape(name)}</a>' for name, src in published[1:])
            return (f'<figure class="plot big r-stretch"><img src="{published[0][1]}" alt="{published[0][0]}">'
                    f'<figcaption>from <code>make tradeoff</code> ({html.escape(rel(out_dir))}/tradeoff.csv, '
                    f'tradeoff.md): {html.escape(published[0][0])}' + (f"; also {others}" if others else "") +
                    '</figcaption></figure>')
        self.ctx.tradeoff_source = "own sweep (no out/tradeoff.csv)"
        out = os.path.join(self.ctx.out, "fig", "plot-tradeoff.svg")
        own_tradeoff(self.ctx, where, out)
        return ('<figure class="plot r-stretch"><img src="fig/plot-tradeoff.svg" alt="error against time">'
                '<figcaption>quick sweep by the slide build, 32&times;32 pixels (run <code>make tradeoff</code> '
                'for the full study)</figcaption></figure>')

    def stats_fields(self, where, caption, json_path):
        """%key% in a caption -> that number from the render's --stats (e.g. %time_s%, %patches%)."""
        if "%" not in caption:
            return caption
        stats = json.load(open(json_path))

        def field(m):
            value = stats.get(m.group(1))
            if not isinstance(value, (int, float)) or isinstance(value, bool):
                fail(where, f"caption field %{m.group(1)}%: no number of that name in the chapter's --stats")
            return f"{value:.2g}" if isinstance(value, float) and value < 10 else f"{value:.0f}" \
                if isinstance(value, float) else str(value)
        return re.sub(r"%(\w+)%", field, caption)

    def render_grid(self, number, info, block):
        where = self.where(number)
        options = dict(w.split("=", 1) for w in info.split()[1:] if "=" in w)
        unknown = set(options) - {"cols", "size"}
        if unknown:
            fail(where, f"unknown render option(s) {', '.join(sorted(unknown))}")
        size = options.get("size", "160x160")
        cells = []
        for line_number, text in block:
            if not text.strip() or text.strip().startswith("#"):
                continue
            if "|" not in text:
                fail(self.where(line_number), "render line wants: caption | CHAPTER ARGS")
            caption, command = text.rsplit("|", 1)
            words = shlex.split(command)
            if not words:
                fail(self.where(line_number), "render line without a chapter")
            if words[0] == "neumann":  # shorthand for the shared Neumann-term renders: neumann CHAPTER K|all
                if len(words) != 3 or words[1] not in ("03_radiosity", "04_pathtrace") or \
                        not (words[2] == "all" or words[2].isdigit()):
                    fail(self.where(line_number), "neumann wants: neumann 03_radiosity|04_pathtrace K|all")
                words, args = [words[1]], neumann_args(words[1], None if words[2] == "all" else int(words[2]))
            else:
                args = words[1:]
                if "--size" not in args:
                    args += ["--size", size]
            result = self.ctx.renderer.render(self.where(line_number), words[0], args)
            src = self.ctx.publish(result["png"])
            caption = self.stats_fields(self.where(line_number), caption, result["json"])
            caption = self.ctx.markup.add("I", self.inline(caption.strip(), line_number))  # Markdown, by node
            cells.append(f'<figure><img src="{src}" alt="{html.escape(" ".join(words + args))}">'
                         f'<figcaption>{caption}</figcaption></figure>')
        cols = int(options.get("cols", min(len(cells), 4)))
        rows = -(-len(cells) // cols)
        # As large as the slide allows (1280 x 800 with a title and a line of
        # text: about 1200 x 440 for the grid), at most 1.5 times the render's
        # size (more is blur); the slide test catches a slide that overflows.
        fit = min((1200 - 16 * (cols - 1)) // cols, 440 // rows - 36)
        rendered = int(size.split("x")[0]) if re.fullmatch(r"\d+x\d+", size) else 260
        shown = max(120, min(fit, int(1.5 * rendered)))
        return (f'<div class="grid" style="grid-template-columns: repeat({cols}, 1fr); --img-max: {shown}px">'
                f'{"".join(cells)}</div>')


# ---- the build -----------------------------------------------------------------------------------

TEMPLATE = """<!doctype html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>{title}</title>
<link rel="stylesheet" href="lib/reveal/reset.css">
<link rel="stylesheet" href="lib/reveal/reveal.css">
<link rel="stylesheet" href="lib/reveal/theme/white.css">
<link rel="stylesheet" href="lib/katex/katex.min.css">
<link rel="stylesheet" href="lib/slides.css">
</head>
<body>
<div class="reveal"><div class="slides">
{sections}
</div></div>
<script src="lib/reveal/reveal.js"></script>
<script>
Reveal.initialize({{ hash: true, slideNumber: 'c/t', width: 1280, height: 800, margin: 0.04,
  center: false, transition: 'none', pdfSeparateFragments: false }});
</script>
</body>
</html>
"""

INDEX = """<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>Global illumination: the decks</title>
<link rel="stylesheet" href="lib/slides.css"></head>
<body class="index"><h1>Global illumination &mdash; lecture decks</h1>
<p>Built {when} from <code>slides/*.md</code>; figures rendered by the chapters in <code>{build}/</code>.</p>
<ul>
{items}
</ul></body></html>
"""


class Context:
    def __init__(self, args):
        self.build = args.build
        self.out = os.path.abspath(args.out)
        self.work = os.path.abspath(args.work)
        self.markup = Markup()
        self.renderer = Renderer(args.build, self.work, self.log, draft=args.draft)
        self.published = {}
        self.plots_done = set()
        self.facts = {}
        self.tradeoff_source = None
        self.tradeoff_dir = os.path.abspath(args.tradeoff_dir)

    @staticmethod
    def log(message):
        print(message, file=sys.stderr, flush=True)

    def publish(self, path):
        """Copy a figure next to the decks (out/slides/fig/); return its relative URL."""
        if path not in self.published:
            with open(path, "rb") as f:
                digest = hashlib.sha256(f.read()).hexdigest()[:16]
            name = f"{digest}{os.path.splitext(path)[1]}"
            os.makedirs(os.path.join(self.out, "fig"), exist_ok=True)
            target = os.path.join(self.out, "fig", name)
            if not os.path.exists(target):
                shutil.copyfile(path, target)
            self.published[path] = f"fig/{name}"
        return self.published[path]


def ensure_node_modules(work):
    """npm ci of slides/package-lock.json into WORK (only when it changed)."""
    lock = os.path.join(SLIDES, "package-lock.json")
    installed = os.path.join(work, "package-lock.json")
    modules = os.path.join(work, "node_modules")
    if os.path.isdir(modules) and os.path.exists(installed) and open(lock).read() == open(installed).read():
        return modules
    npm = shutil.which("npm")
    if not npm:
        raise BuildError("npm not found: install the Debian packages of slides/slides.mk (make deps)")
    os.makedirs(work, exist_ok=True)
    shutil.copyfile(os.path.join(SLIDES, "package.json"), os.path.join(work, "package.json"))
    shutil.copyfile(lock, installed)
    result = subprocess.run([npm, "ci", "--ignore-scripts", "--no-audit", "--no-fund", "--loglevel=error"],
                            cwd=work, capture_output=True, text=True)
    if result.returncode != 0:
        os.remove(installed)
        raise BuildError(f"npm ci in {rel(work)} failed:\n{result.stderr.strip()[-2000:]}")
    return modules


def copy_libraries(modules, out):
    lib = os.path.join(out, "lib")
    reveal, katex = os.path.join(modules, "reveal.js", "dist"), os.path.join(modules, "katex", "dist")
    os.makedirs(os.path.join(lib, "reveal", "theme"), exist_ok=True)
    for name in ("reset.css", "reveal.css", "reveal.js"):
        shutil.copyfile(os.path.join(reveal, name), os.path.join(lib, "reveal", name))
    shutil.copyfile(os.path.join(reveal, "theme", "white.css"), os.path.join(lib, "reveal", "theme", "white.css"))
    # the white theme @imports its web fonts from the theme's fonts/ folder
    fonts = os.path.join(reveal, "theme", "fonts")
    if os.path.isdir(fonts):
        shutil.copytree(fonts, os.path.join(lib, "reveal", "theme", "fonts"), dirs_exist_ok=True)
    os.makedirs(os.path.join(lib, "katex"), exist_ok=True)
    shutil.copyfile(os.path.join(katex, "katex.min.css"), os.path.join(lib, "katex", "katex.min.css"))
    shutil.copytree(os.path.join(katex, "fonts"), os.path.join(lib, "katex", "fonts"), dirs_exist_ok=True)
    shutil.copyfile(os.path.join(SLIDES, "slides.css"), os.path.join(lib, "slides.css"))
    for name, path in (("reveal.js", reveal), ("katex", katex)):
        lic = os.path.join(os.path.dirname(path), "LICENSE")
        if os.path.exists(lic):
            shutil.copyfile(lic, os.path.join(lib, f"LICENSE.{name}"))


def find_chromium():
    for name in ("chromium", "chromium-browser", "google-chrome"):
        p = shutil.which(name)
        if p:
            return p
    return None


def print_pdfs(ctx, modules, node, decks):
    """out/slides/DECK.pdf for every deck, when chromium is installed (slides/print_pdf.cjs)."""
    chromium = find_chromium()
    if not chromium:
        ctx.log("slides: no chromium, no PDFs (apt-get install chromium)")
        return
    pairs = []
    for deck in decks:
        pairs += [os.path.join(ctx.out, deck + ".html"), os.path.join(ctx.out, deck + ".pdf.tmp")]
    result = subprocess.run([node, os.path.join(SLIDES, "print_pdf.cjs"), modules, chromium, *pairs],
                            capture_output=True, text=True, timeout=600, stdin=subprocess.DEVNULL)
    if result.returncode != 0:
        raise BuildError(f"slides/print_pdf.cjs failed: {result.stderr.strip()[-1500:]}")
    for deck in decks:
        os.replace(os.path.join(ctx.out, deck + ".pdf.tmp"), os.path.join(ctx.out, deck + ".pdf"))
    ctx.log(f"  wrote {len(decks)} PDFs in {rel(ctx.out)}/")


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--build", default="build", help="where the chapter executables are (default build)")
    parser.add_argument("--out", default=os.path.join(ROOT, "out", "slides"))
    parser.add_argument("--work", default=os.path.join(ROOT, "build", "slides"))
    parser.add_argument("--no-pdf", action="store_true", help="HTML only")
    parser.add_argument("--draft", action="store_true",
                        help=f"figures at 1/{DRAFT_FACTOR} of their samples (the tests' quick build)")
    parser.add_argument("--tradeoff-dir", default=os.path.join(ROOT, "out"),
                        help="where `make tradeoff` wrote tradeoff.csv and its plots (default out)")
    parser.add_argument("--only", help="build only the deck whose name contains this")
    parser.add_argument("--deck", action="append", help="build this Markdown file instead of slides/NN[a]_*.md "
                                                         "(may be repeated; the tests use it)")
    parser.add_argument("--student", action="store_true",
                        help="student decks: exercise functions show their signature and comment only")
    args = parser.parse_args()
    start = time.time()
    global STUDENT
    if args.student or os.path.exists(os.path.join(ROOT, "kit", "handout.json")):
        try:
            STUDENT = student_exercises()
        except BuildError as e:
            print(f"{e}", file=sys.stderr)
            sys.exit(1)
    ctx = Context(args)
    try:
        node = shutil.which("node") or shutil.which("nodejs")
        if not node:
            raise BuildError("node not found: install the Debian packages of slides/slides.mk (make deps)")
        if not shutil.which("gnuplot"):
            raise BuildError("gnuplot not found: install gnuplot-nox (make deps)")
        modules = ensure_node_modules(ctx.work)
        os.makedirs(ctx.out, exist_ok=True)
        if args.deck:
            deck_paths = [os.path.abspath(p) for p in args.deck]
        else:
            deck_paths = sorted(os.path.join(SLIDES, p) for p in os.listdir(SLIDES) if re.fullmatch(r"\d\d[a-z]?_\w+\.md", p))
        if args.only:
            deck_paths = [p for p in deck_paths if args.only in os.path.basename(p)]
        decks = []
        for path in deck_paths:
            if not os.path.isfile(path):
                raise BuildError(f"{path}: no such deck")
            deck = Deck(ctx, path)
            ctx.log(f"slides: {rel(path)}")
            decks.append((deck, deck.convert()))
        ctx.markup.render(node, modules)  # the Markdown and math of every deck in one node run
        copy_libraries(modules, ctx.out)
        for deck, sections in decks:
            deck.set_title()
            page = TEMPLATE.format(title=html.escape(deck.title), sections="\n".join(sections))
            page = ctx.markup.expand(page)
            target = os.path.join(ctx.out, deck.name + ".html")
            with open(target + ".tmp", "w") as f:
                f.write(page)
            os.replace(target + ".tmp", target)
        with open(os.path.join(ctx.out, "figures.json"), "w") as f:
            json.dump({"build": args.build, "renders": ctx.renderer.used, "tradeoff": ctx.tradeoff_source}, f, indent=1)
        if not args.only and not args.deck:
            # figures no deck uses any more (renders of older executables) go
            keep = {os.path.basename(u) for u in ctx.published.values()} | {f"plot-{k}.svg" for k in ctx.plots_done}
            if ctx.tradeoff_source and ctx.tradeoff_source.startswith("own"):
                keep.add("plot-tradeoff.svg")
            for name in os.listdir(os.path.join(ctx.out, "fig")):
                if name not in keep:
                    os.remove(os.path.join(ctx.out, "fig", name))
            items = "\n".join(f'<li><a href="{d.name}.html">{html.escape(d.title)}</a>'
                              + (f' (<a href="{d.name}.pdf">PDF</a>)' if not args.no_pdf and find_chromium() else "")
                              + "</li>" for d, _ in decks)
            with open(os.path.join(ctx.out, "index.html"), "w") as f:
                f.write(INDEX.format(when=time.strftime("%Y-%m-%d %H:%M"), build=html.escape(args.build),
                                     items=items))
        ctx.log(f"slides: {len(decks)} decks in {rel(ctx.out)}/, {len(ctx.markup.jobs['M'])} formulas, "
                f"{ctx.renderer.fresh} fresh renders ({ctx.renderer.seconds:.1f} s)"
                + (f", trade-off plot: {ctx.tradeoff_source}" if ctx.tradeoff_source else ""))
        if not args.no_pdf:
            print_pdfs(ctx, modules, node, [d.name for d, _ in decks])
        ctx.log(f"slides: done in {time.time() - start:.1f} s")
    except BuildError as e:
        print(f"{e}", file=sys.stderr)
        sys.exit(1)


if __name__ == "__main__":
    main()
