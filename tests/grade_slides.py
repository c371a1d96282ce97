"""Grading of the lecture decks: slides/*.md -> out/slides/*.html.

What is checked:
  - the decks build (slides/build.py --draft into build/slides/draft: every
    figure at an eighth of its samples, rendered by the chapters of the plain
    build, cached in build/slides/cache) and every figure on them is a render
    by the current executables (figures.json);
  - slides and code cannot drift: a deck naming a function that does not
    exist, code citing an equation the deck does not state, and a label that
    is not one the notes define each fail the build with deck:line;
  - every equation label is the lecture's: the rendering-equation deck states
    the first ten, and the labels a deck states are the ones docs/lecture-notes.md defines;
  - headless Chromium (Debian's chromium driven by playwright-core) opens
    every deck offline: no console or page errors, no request that is not
    file:, KaTeX present and no .katex-error, every image loaded, no slide
    taller or wider than the slide; screenshots of a title and an equation
    slide per deck go to build/slides/draft/screenshots/ for a person to look at.

The decks are built once, in the pass over the plain build; the pass over
build/asan reuses them (sanitizer builds would only make the renders slower).
Chromium, node and gnuplot are required: CI installs them (slides/slides.mk),
so their absence is a failure, not a skip.
"""
import glob
import json
import os
import re
import shutil
import subprocess
import sys

import lib
from lib import ROOT

GRADES_NOTHING = True  # no grading, no handout: may run beside the RUN_ALONE tests (tests/run.py)

PYTHON = sys.executable or "/usr/bin/python3"
WORK = os.path.join(ROOT, "build", "slides")
OUT = os.path.join(WORK, "draft")  # not out/slides: `make slides` builds those at full quality
DECKS = ["01_local", "02_whitted", "03a_rendering_equation", "03b_radiosity", "03c_hierarchical", "04_pathtrace", "05_photonmap",
         "06_bidirectional", "07_metropolis", "08_tradeoff"]
PLAIN = "build"
# build/slides is shared: the plain pass builds the decks, the sanitizer pass reuses them.
RUN_IN_SEQUENCE = True


def _tool(name):
    path = shutil.which(name)
    assert path, f"{name} is not installed (make deps installs the packages of slides/slides.mk)"
    return path


def _chromium():
    for name in ("chromium", "chromium-browser"):
        if shutil.which(name):
            return shutil.which(name)
    raise AssertionError("chromium is not installed: the slides test needs it (apt-get install chromium)")


def _build_decks(ctx):
    """Build the decks (HTML only) unless this is a sanitizer pass that can reuse them."""
    stamp = os.path.join(WORK, "test-built")
    reuse = ctx.build != PLAIN and os.path.exists(stamp) and all(
        os.path.exists(os.path.join(OUT, d + ".html")) for d in DECKS)
    if reuse:
        return
    chapters = PLAIN if os.path.exists(os.path.join(ROOT, PLAIN, "04_pathtrace")) else ctx.build
    result = subprocess.run([PYTHON, os.path.join(ROOT, "slides", "build.py"), "--build", chapters, "--no-pdf",
                             "--draft", "--out", OUT],
                            cwd=ROOT, capture_output=True, text=True, timeout=900, stdin=subprocess.DEVNULL)
    assert result.returncode == 0, f"slides/build.py failed:\n{result.stderr[-3000:]}"
    os.makedirs(WORK, exist_ok=True)
    with open(stamp, "w") as f:
        f.write(chapters + "\n")


def _deck_build(ctx, text, name="deck.md"):
    """Build one scratch deck into scratch; return the CompletedProcess."""
    path = ctx.write(name, text)
    return subprocess.run([PYTHON, os.path.join(ROOT, "slides", "build.py"), "--build", PLAIN, "--no-pdf",
                           "--deck", path, "--out", ctx.path("out")],
                          cwd=ROOT, capture_output=True, text=True, timeout=300, stdin=subprocess.DEVNULL)


def test_decks_build_with_rendered_figures(ctx):
    _tool("node"), _tool("gnuplot")
    _build_decks(ctx)
    for deck in DECKS:
        assert os.path.getsize(os.path.join(OUT, deck + ".html")) > 10000, f"{deck}.html is (almost) empty"
    with open(os.path.join(OUT, "figures.json")) as f:
        manifest = json.load(f)
    chapters = {r["chapter"] for r in manifest["renders"]}
    assert {"01_local", "02_whitted", "03_radiosity", "04_pathtrace"} <= chapters, \
        f"figures come from the chapters, found only {sorted(chapters)}"
    # the Neumann terms k:k from both radiosity and path tracing
    for chapter in ("03_radiosity", "04_pathtrace"):
        terms = {r["args"][r["args"].index("--bounces") + 1] for r in manifest["renders"]
                 if r["chapter"] == chapter and "--bounces" in r["args"]}
        assert {"0:0", "1:1", "2:2", "3:3"} <= terms, f"{chapter}: Neumann terms on the slides: {sorted(terms)}"
    # every figure was made by the executable now in the build directory
    import hashlib
    for r in manifest["renders"]:
        exe = os.path.join(ROOT, r["executable"])
        with open(exe, "rb") as f:
            digest = hashlib.sha256(f.read()).hexdigest()
        assert digest == r["executable_sha256"], f"{r['where']}: figure made by an older {r['executable']}"
    # the decks carry no code by hand: every code figure names its file and lines
    for deck in DECKS:
        html = open(os.path.join(OUT, deck + ".html")).read()
        assert re.search(r'<figure class="code"[^>]*><figcaption>(chapters|common)/\w+\.[ch]:\d+', html), \
            f"{deck}: no code pulled from the chapters"
        assert "\x00" not in html and "\ue000" not in html, f"{deck}: an unexpanded placeholder"


def test_markdown_by_markdown_it(ctx):
    """The Markdown is markdown-it's (slides/markdown_render.cjs); math, directives and notes are ours."""
    result = _deck_build(ctx, "# T *one*\n\n---\n\n## Two $x^2$\n\n- item `a $b$ c`\n  - nested, $y$\n\n"
                              "```\nliteral $z$ <tag>\n```\n\n| h |\n|---|\n| $w$ |\n\n"
                              "::: cols\n::: col\n- before math\n$$\nE = mc^2\n$$\n:::\n:::\n\n"
                              "Note: say *this*\n\n- a list in the notes\n")
    assert result.returncode == 0, result.stderr
    page = open(ctx.path("out/deck.html")).read()
    assert "<title>T one</title>" in page, "the title is the first slide's <h1> as text"
    assert page.count('class="katex"') == 4 and page.count('class="katex-display"') == 1, "math: $x^2$ $y$ $w$ $$E$$"
    assert "<code>a $b$ c</code>" in page, "no math inside code spans"
    assert '<pre class="plain"><code>literal $z$ &lt;tag&gt;</code></pre>' in page, "a ``` block stays literal"
    assert re.search(r"<li>item <code>.*?</code>\s*<ul>\s*<li>nested, <span class=\"katex\">", page, re.S), \
        "nested list"
    assert re.search(r'<div class="col">\s*<ul>\s*<li>before math</li>\s*</ul>\s*'
                     r'<div class="eq"><span class="katex-display">', page), \
        "$$ after a list item ends the list, inside the column"
    assert re.search(r'<aside class="notes"><p>say <em>this</em></p>\s*<ul>\s*<li>a list in the notes</li>', page), \
        "speaker notes are Markdown too"
    assert "\ue000" not in page and "\x00" not in page, "an unexpanded placeholder"


def test_missing_function_fails_with_deck_line(ctx):
    result = _deck_build(ctx, "# Title\n\n---\n\n## Code\n\n{{code chapters/01_local.c:no_such_function}}\n")
    assert result.returncode == 1, f"a deck naming a missing function must fail the build (exit {result.returncode})"
    assert re.search(r"deck\.md:7: chapters/01_local\.c: no function named 'no_such_function'", result.stderr), \
        f"message should name deck:line and the function:\n{result.stderr}"
    result = _deck_build(ctx, "# T\n\n{{code chapters/01_local.c:radiance from=\"no such text\"}}\n")
    assert result.returncode == 1 and "deck.md:3:" in result.stderr and "no such text" in result.stderr, result.stderr


def test_cited_labels_must_be_stated(ctx):
    # 01_local.c's radiance() cites (R1): a deck showing it must state (R1) ...
    result = _deck_build(ctx, "# T\n\n---\n\n{{code chapters/01_local.c:radiance}}\n")
    assert result.returncode == 1 and "(R1)" in result.stderr and "deck.md:5" in result.stderr, result.stderr
    # ... and then it builds
    result = _deck_build(ctx, "# T\n\n$$\nL_r = L_e + f \\frac{I}{r^2}\\cos\\theta_i \\tag{R1}\n$$\n\n"
                              "{{code chapters/01_local.c:radiance}}\n")
    assert result.returncode == 0, result.stderr
    # labels are the lecture's R1 .. R10 only
    result = _deck_build(ctx, "# T\n\n$$ x \\tag{R11} $$\n")
    assert result.returncode == 1 and "deck.md:3" in result.stderr and "R1 .. R10" in result.stderr, result.stderr
    # bad TeX is a build error with deck:line, not a red formula on a slide
    result = _deck_build(ctx, "# T\n\nText $\\frac{1}{$ more.\n")
    assert result.returncode == 1 and "deck.md:3: KaTeX" in result.stderr, result.stderr


def test_equation_labels_follow_the_lecture(ctx):
    stated = {}
    for deck in DECKS:
        text = open(os.path.join(ROOT, "slides", deck + ".md")).read()
        stated[deck] = set(re.findall(r"\\tag\{(R\d+)\}", text))
    assert stated["03a_rendering_equation"] >= {f"R{k}" for k in range(1, 11)}, \
        f"the rendering-equation deck states R1..R10, has {sorted(stated['03a_rendering_equation'])}"
    notes = os.path.join(ROOT, "docs", "lecture-notes.md")  # the course's own notes define every label
    defined = set(re.findall(r"^\*\*\((R\d+)\)\*\*", open(notes).read(), re.M))
    for deck, labels in stated.items():
        assert labels <= defined, f"{deck}: labels {sorted(labels - defined)} are not in docs/lecture-notes.md"
    # the same label always states the same equation: compare each with the main deck's (whitespace-free)
    def equations(deck):
        text = open(os.path.join(ROOT, "slides", deck + ".md")).read()
        return {m.group(2): re.sub(r"\s+", "", m.group(1)) for m in
                re.finditer(r"\$\$((?:(?!\$\$).)*?)\\tag\{(R\d+)\}\s*\$\$", text, re.S)}
    main = equations("03a_rendering_equation")
    for deck in DECKS:
        for label, tex in equations(deck).items():
            if label in main and label != "R4":  # the radiosity deck states (R4) per patch: L_i = ... i.e. L = E + KL
                assert tex == main[label], f"{deck}: ({label}) differs from the rendering-equation deck's"


def test_decks_in_headless_chromium(ctx):
    if lib.sanitizer_build(ctx):  # Chromium opens the same decks in both passes: nothing of ours runs
        return
    chromium = _chromium()
    node = _tool("node")
    _build_decks(ctx)
    shots = os.path.join(OUT, "screenshots")
    for old in glob.glob(os.path.join(shots, "*.png")):
        os.remove(old)
    result = subprocess.run([node, os.path.join(ROOT, "slides", "check.cjs"), os.path.join(WORK, "node_modules"),
                             chromium, OUT, shots], cwd=ROOT, capture_output=True, text=True, timeout=300,
                            stdin=subprocess.DEVNULL)
    assert result.returncode == 0, f"slides/check.cjs failed:\n{result.stderr[-3000:]}"
    report = json.loads(result.stdout)["decks"]
    assert sorted(report) == DECKS, f"decks opened: {sorted(report)}"
    problems = []
    for deck, r in report.items():
        for key in ("consoleErrors", "pageErrors", "failedRequests", "offlineViolations", "brokenImages",
                    "overflowing"):
            if r[key]:
                problems.append(f"{deck}: {key}: {r[key][:5]}")
        if r["katex"] == 0:
            problems.append(f"{deck}: no KaTeX math rendered")
        if r["katexErrors"]:
            problems.append(f"{deck}: {r['katexErrors']} .katex-error elements")
        if r["images"] == 0:
            problems.append(f"{deck}: no images")
        if len(r["screenshots"]) != 2:
            problems.append(f"{deck}: screenshots {r['screenshots']} (want a title and an equation slide)")
        for shot in r["screenshots"]:
            if not (os.path.exists(shot) and os.path.getsize(shot) > 5000):
                problems.append(f"{deck}: screenshot {shot} missing or blank")
    assert not problems, "\n".join(problems)
