"""Tests of the student handout (kit/handout.py): it gives no answer away, says where the stubs are,
refuses bad input, and its documents point only at what it has.

"An answer" is an exercise's body as the solution writes it ([exercise N.M], kit/markers.py),
compared after normalising (comments gone, whitespace ignored, every name one token): a function of
any .c, .h or Markdown file of the handout that contains it (or, for a short body, is it; or has
most of its statements) gives it away.  The handouts are built from the tracked files (git ls-files),
about 3 s each; they do not depend on the build under test, so under the sanitizer build the tests
pass without running.
"""
import ast
import html
import importlib.util
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile

from lib import ROOT

sys.path.insert(0, os.path.join(ROOT, "kit"))
import markers  # noqa: E402
import rubric  # noqa: E402

PY = "/usr/bin/python3"
_SCRATCH = []


def scratch_dir():
    d = tempfile.mkdtemp(prefix="gi-handout-")
    _SCRATCH.append(d)
    return d


def tear_down():
    """The handouts made (tests/run.py calls it after the tests that made them)."""
    for d in _SCRATCH:
        shutil.rmtree(d, ignore_errors=True)
    _SCRATCH.clear()
    _HANDOUTS.clear()


_HANDOUTS = {}


def handout(chapters, root=ROOT):
    """(returncode, stderr, path) of kit/handout.py PATH CHAPTERS..., built once per run."""
    key = (root, chapters)
    if key not in _HANDOUTS:
        out = os.path.join(scratch_dir(), "handout")
        r = subprocess.run([PY, os.path.join(root, "kit", "handout.py"), out, *chapters.split()], cwd=root,
                           capture_output=True, text=True, timeout=300, stdin=subprocess.DEVNULL)
        _HANDOUTS[key] = (r.returncode, r.stderr, out)
    return _HANDOUTS[key]


def handout_files(tree):
    files = []
    for base, _, names in os.walk(tree):
        files += [os.path.relpath(os.path.join(base, n), tree) for n in names]
    return sorted(files)


def marked_chapters():
    names = markers.chapter_names(ROOT)
    return sorted({names[e.lecture] for e in markers.all_exercises(ROOT)})


def test_no_handout_contains_an_answer(ctx):
    """For each chapter with exercises, its handout: no function of any .c, .h or .md file contains
    the normalised body of one of the chapter's exercises.  The same comparison finds every exercise
    in the solution itself (so it can fail)."""
    if "asan" in ctx.build:
        return
    exercises = markers.all_exercises(ROOT)
    names = markers.chapter_names(ROOT)
    solution = markers.answers_in_tree(ROOT, exercises, sorted({e.file for e in exercises}))
    assert {e.id for _, e in solution} == {e.id for e in exercises}, \
        f"the comparison misses exercises in the solution itself: {sorted({e.id for e in exercises} - {e.id for _, e in solution})}"
    problems = []
    for chapter in marked_chapters():
        code, stderr, out = handout(chapter)
        if code != 0:
            problems.append(f"kit/handout.py {chapter}: exit {code}:\n{stderr.strip()}")
            continue
        mine = [e for e in exercises if names[e.lecture] == chapter]
        for fn, e in markers.answers_in_tree(out, mine, handout_files(out)):
            problems.append(f"{chapter} handout: {fn.file}:{fn.line}: {fn.name} holds the answer of exercise {e.id} "
                            f"({e.file} {e.name})")
    assert not problems, "\n".join(problems)


def copy_project(dst):
    """The tracked files of the project in dst, with a git index (kit/handout.py reads git ls-files)."""
    files = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout.decode()
    for rel in filter(None, files.split("\0")):
        if rel.startswith(("tests/mutants/", "docs/", "slides/")) or not os.path.isfile(os.path.join(ROOT, rel)):
            continue
        os.makedirs(os.path.dirname(os.path.join(dst, rel)) or dst, exist_ok=True)
        shutil.copy2(os.path.join(ROOT, rel), os.path.join(dst, rel))
    subprocess.run(["git", "init", "-q", dst], check=True)
    subprocess.run(["git", "add", "-A"], cwd=dst, check=True)
    return dst


def insert_after_includes(path, code):
    with open(path) as f:
        text = f.read()
    at = list(re.finditer(r"^#include .*$", text, re.M))[-1].end() + 1
    with open(path, "w") as f:
        f.write(text[:at] + code + text[at:])


def line_of(path, pattern):
    with open(path) as f:
        return next(i + 1 for i, ln in enumerate(f) if re.search(pattern, ln))


def refused(root, chapters):
    parent = scratch_dir()
    out = os.path.join(parent, "handout")
    r = subprocess.run([PY, os.path.join(root, "kit", "handout.py"), out, *chapters.split()], cwd=root,
                       capture_output=True, text=True, timeout=300, stdin=subprocess.DEVNULL)
    assert r.returncode == 2 and "Traceback" not in r.stderr, (chapters, r.returncode, r.stderr)
    assert not os.listdir(parent), f"a refused handout left {os.listdir(parent)}"
    return r.stderr


def test_handout_refuses_bad_input_and_writes_nothing(ctx):
    """kit/handout.py exits 2 naming file:line, and leaves no tree, for an unknown chapter, an
    [exercise] tag above something that is not a function, and answers left elsewhere: a short one
    as a whole function, a long one renamed inside a longer function, and a near copy (one
    guard dropped, as a header of common/ once had exercise 4.3)."""
    if "asan" in ctx.build:
        return
    assert "no chapter 99_nothing" in refused(ROOT, "99_nothing")
    by_id = {e.id: e for e in markers.all_exercises(ROOT)}

    stray = copy_project(ctx.path("stray"))
    insert_after_includes(os.path.join(stray, "chapters", "01_local.c"),
                          "\n/* a constant\n * [exercise 1.9] */\nstatic const double stray = 1.0;\n")
    line = line_of(os.path.join(stray, "chapters", "01_local.c"), r"\[exercise 1\.9\]")
    err = refused(stray, "01_local")
    assert err.startswith(f"chapters/01_local.c:{line}: [exercise 1.9]"), (line, err)

    copies = copy_project(ctx.path("copies"))
    short, long_, near = by_id["5.6"], by_id["1.3"], by_id["4.3"]
    renamed = re.sub(r"\bemitter\b", "source", re.sub(r"\bsamples\b", "count", long_.body))
    code = (f"\nstatic double copied_short(double a, int b, double c)\n{short.body}\n"
            f"static double copied_long(int extra)\n{{\n    if (extra) return 0.0;\n{renamed[1:-1]}\n    "
            f"return 1.0;\n}}\n")
    near_body = near.body
    guard = re.search(r"\n\s*if \(k < [^\n]*\n[^\n]*return true;", near_body)  # the rr_depth guard, if any
    near_body = near_body[:guard.start()] + near_body[guard.end():] if guard else near_body
    code += f"static bool copied_near(void)\n{near_body}\n"
    insert_after_includes(os.path.join(copies, "common", "render.c"), code)
    err = refused(copies, "01_local 04_pathtrace 05_photonmap")
    for name, ex in (("copied_short", short), ("copied_long", long_), ("copied_near", near)):
        at = line_of(os.path.join(copies, "common", "render.c"), rf"\b{name}\(")
        assert f"common/render.c:{at}: {name} holds the answer of exercise {ex.id}" in err, (name, err)


def assignment_rows(text):
    return re.findall(r"^\| (\d+[a-z]?\.\d+) \| `(\w+)` \| `([^`:]+):(\d+)` \|", text, re.M)


def test_assignment_points_at_the_stubs_and_computes_its_figures(ctx):
    """In the handout of every chapter, each ASSIGNMENT.md row's file:line is the line of its
    stub's definition in the handout; the false-failure figure is the one kit/handout.py computes
    from kit/rubric.json and tests/lib.py, and for all chapters it is the figure README.md states."""
    if "asan" in ctx.build:
        return
    sys.path.insert(0, os.path.join(ROOT, "kit"))
    import handout as handout_module
    code, stderr, out = handout(" ".join(marked_chapters()))
    assert code == 0, stderr
    rub = rubric.load(ROOT)
    for chapter in marked_chapters():
        with open(os.path.join(out, "assignments", chapter, "ASSIGNMENT.md")) as f:
            text = f.read()
        rows = assignment_rows(text)
        assert rows, f"{chapter}: no exercise rows in ASSIGNMENT.md"
        for ex_id, name, rel, line in rows:
            with open(os.path.join(out, rel)) as f:
                lines = f.read().split("\n")
            line = int(line)
            assert re.search(rf"\b{name}\(", lines[line - 1]), \
                f"{chapter} ASSIGNMENT.md: exercise {ex_id} at {rel}:{line}, which is: {lines[line - 1]!r}"
            following = "\n".join(lines[line:line + 6])
            assert f'TODO_ONCE("{name}")' in following, f"{rel}:{line}: {name} is not the stub"
        criteria = [c for c in rub["criteria"] if c["chapter"] == chapter]
        rate, _ = handout_module.false_failure_budget(ROOT, rub, criteria)
        stated = re.search(r"at most ([\d.]+) %", text)
        assert stated and stated.group(1) + " %" == handout_module.percent(rate), \
            f"{chapter}: ASSIGNMENT.md states {stated and stated.group(0)}, computed {handout_module.percent(rate)}"
        for c in criteria:
            if c["kind"] in ("compare", "surfaces"):
                row = next(ln for ln in text.split("\n") if ln.startswith(f"| {c['name']} |"))
                assert f"build/{chapter} {c['scene']}" in row and all(a in row for a in c.get("args", [])), row
    whole, _ = handout_module.false_failure_budget(ROOT, rub, rub["criteria"])
    with open(os.path.join(ROOT, "README.md")) as f:
        readme = f.read()
    stated = re.search(r"false-failure rate of a whole\s+grading: at most ([\d.]+) %", readme)
    assert stated and stated.group(1) + " %" == handout_module.percent(whole), \
        f"README.md states {stated and stated.group(0)!r}; kit/rubric.json and tests/lib.py give " \
        f"{handout_module.percent(whole)}"


# ---- the handout's documents ------------------------------------------------------------------------

LINK = re.compile(r"!?\[[^\]\n]*\]\(([^()\s]+)(?:\s+\"[^\"]*\")?\)")


def code_parts(text):
    """The code in Markdown: `spans`, fenced blocks and indented blocks (where commands are)."""
    parts = re.findall(r"^(```|~~~)[^\n]*\n(.*?)^\1", text, re.S | re.M)
    parts = [p[1] for p in parts]
    prose = re.sub(r"^(```|~~~)[^\n]*\n.*?^\1", "", text, flags=re.S | re.M)
    parts += re.findall(r"`([^`\n]+)`", prose)
    parts += re.findall(r"^(?: {4}|\t)(.*)$", prose, re.M)
    return parts


def make_targets(tree):
    """The targets of the tree's Makefile and the makefiles it includes."""
    targets = set()
    paths = [os.path.join(tree, "Makefile")]
    with open(paths[0]) as f:
        paths += [os.path.join(tree, p) for p in re.findall(r"^-?include\s+(\S+\.mk)\s*$", f.read(), re.M)]
    for path in paths:
        if not os.path.exists(path):
            continue
        with open(path) as f:
            for m in re.finditer(r"^([A-Za-z][\w.-]*(?:[ \t]+[A-Za-z][\w.-]*)*)[ \t]*:(?![=])", f.read(), re.M):
                targets.update(m.group(1).split())
    return targets


def test_handout_documents_have_no_dead_link_or_target(ctx):
    """The handout's README.md is the student's (kit/student/README.md: the assignments, build,
    run, the viewer's heat map, make grade, the student decks); in every Markdown file of the
    handout, relative links lead to a file of the handout and every `make TARGET` is a target of
    the handout's Makefile."""
    if "asan" in ctx.build:
        return
    chapters = " ".join(marked_chapters())
    code, stderr, out = handout(chapters)
    assert code == 0, stderr
    with open(os.path.join(out, "README.md")) as f:
        readme = f.read()
    for chapter in marked_chapters():
        assert f"(assignments/{chapter}/ASSIGNMENT.md)" in readme, f"README.md does not point at {chapter}'s assignment"
    for needed in ("make grade", "build/viewer", "heat map", "make slides", "make demo"):
        assert needed in readme, f"the student README does not say {needed!r}"
    assert "{{" not in readme, "a placeholder of kit/student/README.md is left"
    targets = make_targets(out)
    assert {"all", "grade", "demo", "slides"} <= targets, sorted(targets)
    problems = []
    for rel in handout_files(out):
        if not rel.endswith(".md"):
            continue
        with open(os.path.join(out, rel)) as f:
            text = f.read()
        for m in LINK.finditer(text):
            target = m.group(1).split("#")[0]
            if not target or re.match(r"[a-z]+:", target):
                continue
            # decks name images from the project's root (slides/build.py Deck.asset)
            base = out if rel.startswith("slides/") and m.group(0).startswith("!") else os.path.dirname(
                os.path.join(out, rel))
            if not os.path.exists(os.path.normpath(os.path.join(base, target))):
                problems.append(f"{rel}:{text.count(chr(10), 0, m.start()) + 1}: dead link {target}")
        for part in code_parts(text):
            for m in re.finditer(r"(?<![\w/.-])make((?:\s+[\w.-]+=\S*|\s+-\S+)*)\s+([a-z][\w.-]*)", part):
                if m.group(2) not in targets:
                    problems.append(f"{rel}: `make {m.group(2)}`: the handout's Makefile has no such target")
    assert not problems, "\n".join(sorted(set(problems)))


def load_slide_builder():
    spec = importlib.util.spec_from_file_location("slides_build", os.path.join(ROOT, "slides", "build.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_student_decks_show_exercise_signatures_only(ctx):
    """slides/build.py --student: every {{code}} slide of every deck, rendered as a student deck,
    holds no exercise's answer, and each exercise it quotes shows `/* exercise N.M: your code */`;
    rendered as the instructor's deck, some slides do hold answers (so the check can fail).
    (The slide code only: figures and Markdown need node and gnuplot, tests/grade_slides.py.)"""
    if "asan" in ctx.build:
        return
    builder = load_slide_builder()
    exercises = markers.all_exercises(ROOT)
    answers = [(e, markers.exercise_tokens(e)) for e in exercises]

    def shown(student):
        builder.STUDENT = builder.student_exercises() if student else None
        blocks = []
        for deck in sorted(glob_decks()):
            with open(deck) as f:
                for number, line in enumerate(f, 1):
                    for m in re.finditer(r"\{\{code ([^}]*)\}\}", line):
                        where = f"{os.path.relpath(deck, ROOT)}:{number}"
                        try:
                            block, _ = builder.code_block(where, m.group(1))
                        except builder.BuildError as e:
                            if not student:
                                continue  # the instructor's deck is tests/grade_slides.py's
                            raise AssertionError(str(e))
                        code = html.unescape(re.sub(r"<[^>]+>", "", re.search(r"<code>(.*)</code>", block,
                                                                              re.S).group(1)))
                        blocks.append((where, m.group(1), code))
        return blocks

    def leaks(blocks):
        found = []
        for where, spec, code in blocks:
            pieces = markers.functions(code, where) + [markers.Function(where, "excerpt", 1,
                                                                        markers.normalised(markers.tokens(code)))]
            for e, a in answers:
                if any(markers.gives_away(p, a) for p in pieces):
                    found.append(f"{where}: {{{{code {spec}}}}} shows the answer of exercise {e.id} ({e.name})")
        return sorted(set(found))

    instructor = shown(False)
    assert leaks(instructor), "the instructor's decks quote no exercise: the check below proves nothing"
    student = shown(True)
    problems = leaks(student)
    by_name = {(e.file, e.name): e for e in exercises}
    for where, spec, code in student:
        e = by_name.get(tuple(spec.split()[0].rsplit(":", 1)))
        if e and f"/* exercise {e.id}: your code */" not in code:
            problems.append(f"{where}: exercise {e.id} {e.name} is quoted without its stub line")
    assert not problems, "\n".join(problems)


def glob_decks():
    return [os.path.join(ROOT, "slides", p) for p in os.listdir(os.path.join(ROOT, "slides"))
            if re.fullmatch(r"\d\d[a-z]?_\w+\.md", p)]


# ---- chapters not handed out yet ----------------------------------------------------------------------
#
# A course hands its chapters out in order: the handout of a chapter stubs every later chapter's exercises
# as it stubs its own (kit/handout.py, with kit/grade.py's later_chapters) and keeps the earlier chapters'
# solutions (handed out already; the chosen chapters link them and their criteria run them).

def later_exercises(chapters):
    """The exercises of the chapters after every one of `chapters`."""
    names = markers.chapter_names(ROOT)
    last = max(chapters.split())
    return [e for e in markers.all_exercises(ROOT) if names[e.lecture] > last]


def tree_files(tree):
    """Every file under tree (any kind: sources, documents, scripts, data), without build/ and .git/."""
    files = []
    for base, dirs, names in os.walk(tree):
        dirs[:] = [d for d in dirs if d not in ("build", ".git", "__pycache__")]
        files += [os.path.relpath(os.path.join(base, n), tree) for n in names]
    return sorted(files)


def answer_text_in_tree(tree, exercises, files):
    """[(file, exercise id)] where a text file of any kind (not only .c, .h and .md, as kit/handout.py checks)
    holds an exercise's answer: a function of it gives the answer away (kit/markers.py gives_away), or its
    whole normalised text contains an answer long enough to mean something (markers.MIN_TOKENS_INSIDE)."""
    answers = [(e, markers.exercise_tokens(e)) for e in exercises]
    found = []
    for rel in files:
        try:
            with open(os.path.join(tree, rel), encoding="utf-8") as f:
                text = f.read()
        except (OSError, UnicodeDecodeError):  # binary: images, archives
            continue
        pieces = markers.markdown_code(text, rel) if rel.endswith(".md") else markers.functions(text, rel)
        whole = markers.normalised(markers.tokens(text))
        for e, a in answers:
            if any(markers.gives_away(p, a) for p in pieces) or (
                    len(a) >= markers.MIN_TOKENS_INSIDE and markers.contains(whole, a)):
                found.append((rel, e.id))
    return found


def later_chapters_given_away(tree, chapters):
    """What a tree made for `chapters` gives away of the later chapters: each file of the solution that
    holds a later exercise and is byte for byte the solution's in tree (or is missing: the chapter must
    still build), each later exercise whose function in tree is not its stub, and answer_text_in_tree.
    The same text search finds every later exercise in the solution's files (so it can fail)."""
    later = later_exercises(chapters)
    assert later, f"no chapter after {chapters}: nothing to check"
    problems = []
    for rel in sorted({e.file for e in later}):
        mine = os.path.join(tree, rel)
        if not os.path.isfile(mine):
            problems.append(f"{rel}: missing (a later chapter's file the build needs)")
            continue
        with open(mine, "rb") as a, open(os.path.join(ROOT, rel), "rb") as b:
            if a.read() == b.read():
                problems.append(f"{rel}: the solution's, byte for byte")
        stubs = {e.id: e for e in markers.parse_file(tree, rel)}
        for e in later:
            if e.file == rel and (e.id not in stubs or f'TODO_ONCE("{e.name}")' not in stubs[e.id].body):
                problems.append(f"{rel}: exercise {e.id} {e.name} is not a stub")
    problems += [f"{rel}: holds the answer of exercise {ex}" for rel, ex in answer_text_in_tree(tree, later,
                                                                                               tree_files(tree))]
    in_solution = {ex for _, ex in answer_text_in_tree(ROOT, later, sorted({e.file for e in later}))}
    assert in_solution == {e.id for e in later}, \
        f"the search misses exercises in the solution: {sorted({e.id for e in later} - in_solution)}"
    return problems


def test_handout_of_chapter_1_gives_no_later_chapter_away(ctx):
    """make handout CHAPTERS=01_local (week 1 of a course that hands its chapters out in order): every file
    that holds a later chapter's exercise differs from the solution's, each such exercise is its stub, and
    no file of the tree, of any kind, holds a later exercise's answer; the handout's handout.json and the student's
    README name the later chapters as stubbed."""
    if "asan" in ctx.build:
        return
    code, stderr, out = handout("01_local")
    assert code == 0, stderr
    problems = later_chapters_given_away(out, "01_local")
    assert not problems, "the chapter-1 handout gives later chapters away:\n" + "\n".join(problems)
    with open(os.path.join(out, "kit", "handout.json")) as f:
        record = json.load(f)
    later = sorted(set(markers.chapter_names(ROOT).values()) - {"01_local"})
    assert record["chapters"] == ["01_local"] and record["later_chapters"] == later, record
    with open(os.path.join(out, "README.md")) as f:
        readme = f.read()
    assert all(f"`{c}`" in readme for c in later) and "stubs too" in readme, readme[:1500]


def test_handout_of_chapter_2_keeps_chapter_1_and_stubs_the_later(ctx):
    """make handout CHAPTERS=02_whitted (week 2): chapter 1, handed out already and linked by chapter 2
    (its local model), is the solution's byte for byte; chapter 2's exercises and every later one's are
    stubs and no later answer is in the tree."""
    if "asan" in ctx.build:
        return
    code, stderr, out = handout("02_whitted")
    assert code == 0, stderr
    with open(os.path.join(out, "chapters", "01_local.c"), "rb") as a, \
            open(os.path.join(ROOT, "chapters", "01_local.c"), "rb") as b:
        assert a.read() == b.read(), "chapters/01_local.c: not the solution in the chapter-2 handout"
    with open(os.path.join(out, "chapters", "02_whitted.c")) as f:
        assert 'TODO_ONCE("trace")' in f.read()
    problems = later_chapters_given_away(out, "02_whitted")
    assert not problems, "the chapter-2 handout gives later chapters away:\n" + "\n".join(problems)


def test_handout_of_chapter_1_builds_and_later_stubs_run(ctx):
    """`make` in the chapter-1 handout builds every chapter, the viewer and the benchmark without a warning
    (the later chapters with their stubs, linked with each other's: chapter 7 links 4, 5 and 6), and
    chapter 7 and chapter 2 run on them (exit 0, finite pixels, each stub reached says TODO once, from
    its own file or one the chapter links).  About a minute on 2 cores."""
    if "asan" in ctx.build:
        return
    out = os.path.join(scratch_dir(), "handout")
    r = subprocess.run([PY, os.path.join(ROOT, "kit", "handout.py"), out, "01_local"], cwd=ROOT,
                       capture_output=True, text=True, timeout=300, stdin=subprocess.DEVNULL)
    assert r.returncode == 0, r.stderr
    r = subprocess.run(["make", "-j2", "--no-print-directory"], cwd=out, capture_output=True, text=True, timeout=900,
                       stdin=subprocess.DEVNULL)
    assert r.returncode == 0 and "warning" not in r.stderr, r.stderr[-3000:]
    import lib
    linked = {"02_whitted": ("chapters/01_local.c", "chapters/02_whitted.c", "common/optics.h"),
              "07_metropolis": ("chapters/04_pathtrace.c", "chapters/05_photonmap.c", "chapters/06_bidirectional.c",
                                "chapters/07_metropolis.c")}
    for chapter, args in (("02_whitted", []), ("07_metropolis", ["--method", "mmlt", "--bootstrap", "4096",
                                                                   "--chains", "64"])):
        pfm = ctx.path(f"{chapter}.pfm")
        r = subprocess.run([os.path.join(out, "build", chapter), "scenes/cornell-spheres.scene", "--quiet", "--size",
                            "8x8", "--spp", "2", *args, "--out", pfm], cwd=out, capture_output=True, text=True,
                           timeout=300, stdin=subprocess.DEVNULL)
        assert r.returncode == 0, f"{chapter}: exit {r.returncode}: {r.stderr[-2000:]}"
        todo = [ln for ln in r.stderr.splitlines() if "TODO" in ln]
        assert todo and len(todo) == len(set(todo)), f"{chapter}: {r.stderr}"
        own = [ln for ln in todo if re.match(r"(%s):\d+: TODO \w+ is not implemented$" % "|".join(linked[chapter]),
                                             ln)]
        assert own == todo, f"{chapter}: a TODO from a file it does not link: {sorted(set(todo) - set(own))}"
        assert lib.finite_image(lib.read_pfm(pfm)), f"{chapter}: NaN or infinite pixels from the stubs"


def _grade_module(name, cache):
    """{function name: (node, module)}, {constant name: str}, {alias: module} of tests/NAME.py (parsed once)."""
    if name not in cache:
        path = os.path.join(ROOT, "tests", name + ".py")
        with open(path) as f:
            tree = ast.parse(f.read(), path)
        functions = {n.name: (n, name) for n in tree.body if isinstance(n, ast.FunctionDef)}
        constants = {t.id: n.value.value for n in tree.body if isinstance(n, ast.Assign)
                     and isinstance(n.value, ast.Constant) and isinstance(n.value.value, str)
                     for t in n.targets if isinstance(t, ast.Name)}
        aliases, imported = {}, {}
        for n in tree.body:
            if isinstance(n, ast.Import):
                aliases.update({a.asname or a.name: a.name for a in n.names if a.name.startswith(("grade_", "lib"))})
            elif isinstance(n, ast.ImportFrom) and (n.module or "").startswith(("grade_", "lib")):
                imported.update({a.asname or a.name: (n.module, a.name) for a in n.names})
        cache[name] = (functions, constants, aliases, imported)
    return cache[name]


def chapters_a_test_runs(module, test, chapters, cache):
    """The chapters named by the strings (not the docstrings) that test (tests/MODULE.py) and every function it
    calls in the grade modules and tests/lib.py hold: what its criterion runs (ctx.render("04_pathtrace", ...))."""
    todo, seen, strings = [(module, test)], set(), set()
    while todo:
        where, name = todo.pop()
        functions, constants, aliases, imported = _grade_module(where, cache)
        if (where, name) in seen:
            continue
        seen.add((where, name))
        if name in imported:
            todo.append(imported[name])
            continue
        if name in constants:
            strings.add(constants[name])
            continue
        if name not in functions:
            continue
        docstrings = {id(n.value) for n in ast.walk(functions[name][0]) if isinstance(n, ast.Expr)}  # not run
        for node in ast.walk(functions[name][0]):
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docstrings:
                strings.add(node.value)
            elif isinstance(node, ast.Name) and node.id != name:
                todo.append((where, node.id))
            elif isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in aliases:
                todo.append((aliases[node.value.id], node.attr))
    return sorted(c for c in chapters if any(c in s for s in strings))


def test_no_criterion_runs_a_chapter_after_its_own(ctx):
    """A handout, and the Gradescope archive built from it, stubs the chapters after the last one handed
    out: a criterion that ran a later chapter would fail every correct submission there.  So no criterion
    of kit/rubric.json runs a chapter after its own (by the strings its test and the functions it calls
    hold); the same search finds chapter 4 in chapter 03c's comparison with path tracing, a test that is
    no criterion (so it can fail)."""
    if "asan" in ctx.build:
        return
    chapters = sorted(markers.chapter_names(ROOT).values())
    cache = {}
    assert "04_pathtrace" in chapters_a_test_runs("grade_03c_hierarchical",
                                                  "test_hierarchical_agrees_with_uniform_and_path_tracing", chapters,
                                                  cache), "the search does not see a chapter a test runs"
    problems = []
    for c in rubric.load(ROOT)["criteria"]:
        if c["kind"] != "grade":
            continue
        later = [x for x in chapters_a_test_runs(c["module"], c["test"], chapters, cache) if x > c["chapter"]]
        if later:
            problems.append(f"{c['chapter']} '{c['name']}' ({c['module']}.{c['test']}) runs {', '.join(later)}")
    assert not problems, "criteria that run a later chapter (stubbed in their handout):\n" + "\n".join(problems)
