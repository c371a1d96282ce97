"""Everything the course's texts name exists in the tree.

A student reads the README, the lecture notes, the slides and the comments
next to the code; a name in them that the code no longer has sends the
student looking for something that is not there.  This test reads

  - the Markdown texts: docs/*.md, README.md, kit/README.md,
    kit/CALIBRATION.md, viewer/README.md, slides/*.md;
  - the comments of every tracked C file, and the comments and docstrings
    of the tracked Python files of kit/, tests/, bench/ and tradeoff/;

and fails on

  - a function, `name()` (in backticks or not), that no C source, Python or
    JavaScript file of the tree defines; "`name()` in `FILE`" and the
    summary table's "`FILE`: `a()`, `b()`" must name a function of FILE;
  - a file path (chapters/x.c, common/render.[ch], tests/grade_*.py, a bare
    01_local.c or cornell.scene) that is not a tracked file or directory;
  - an option `--name` that no chapter's --help prints and no program of the
    tree (viewer, kit/, tests/, bench/, tradeoff/, slides/) compares against;
    on a command line of a chapter, `build/04_pathtrace ... --spp 4`, an
    option that chapter's --help does not print;
  - `make TARGET` (in backticks or a code block) that is not a target of the
    Makefile and the files it includes (make -pn);
  - an equation label (Rn) that docs/lecture-notes.md does not define, and a
    range "R1-Rn" next to the notes' name that is not all of the notes' labels;
  - in anything a student gets (every tracked file that kit/handout.py puts
    into a handout): the project's own planning documents, which students do
    not have (the design and lecture plans at the repository's top, named by
    NAMES_STUDENTS_LACK below), and tracker numbers ("issue" and a number).

Names that belong to other projects are not ours to define: a name qualified
by another project ("pbrt's LiRandomWalk()", "os.replace()") is skipped by
rule, and EXTERNAL_FUNCTIONS lists the few library functions the texts cite
bare (the C library, OpenMP, OpenGL).

Needs the chapters built (their --help); run time about 1 s.
"""
import ast
import glob
import io
import os
import re
import subprocess
import sys
import tokenize

from lib import ROOT

sys.path.insert(0, os.path.join(ROOT, "kit"))
import handout  # noqa: E402  (kit/handout.py: INSTRUCTOR_ONLY, what a handout leaves out)

MARKDOWN = ["docs/*.md", "README.md", "kit/README.md", "kit/CALIBRATION.md", "viewer/README.md", "slides/*.md",
            "assignments/*/ASSIGNMENT.md"]
PYTHON_DIRS = ("kit/", "tests/", "bench/", "tradeoff/")
NOTES = "docs/lecture-notes.md"

# Functions of other code that the texts cite by bare name: the C library, POSIX, OpenMP, OpenGL.
# (Names qualified by their project or module, "pbrt's X()", "os.replace()", are skipped by rule.)
EXTERNAL_FUNCTIONS = {
    # C library and POSIX
    "sqrt", "exp", "log", "pow", "fabs", "floor", "ceil", "sin", "cos", "atan2", "acos", "asin", "atan", "erf",
    "malloc", "calloc", "realloc", "free", "qsort", "strtod", "strtol", "strcmp", "printf", "fprintf", "snprintf",
    "fopen", "fclose", "fread", "fwrite", "fflush", "rename", "fsync", "abort", "exit", "signal", "sigaction",
    "isfinite", "isnan", "clock_gettime", "memcpy", "memset", "assert", "dlopen", "dlsym", "setjmp", "longjmp",
    "kill", "setpgid", "getrusage", "setrlimit",
    # OpenMP
    "omp_get_thread_num", "omp_get_num_threads", "omp_get_max_threads", "omp_get_wtime",
    # OpenGL, GLFW, EGL, OSMesa (the viewer's backends)
    "glReadPixels", "glViewport", "glfwPollEvents", "glfwSwapBuffers", "eglGetDisplay", "OSMesaMakeCurrent",
}

# The libraries' own prefixes: OpenGL, GLFW, EGL, OSMesa, OpenMP, the dynamic loader.
EXTERNAL_PREFIX = re.compile(r"(?:gl|glfw|egl|OSMesa)[A-Z]|omp_|dl(?:open|sym|close|error)$")

# Tracker numbers and the planning documents students do not have (written so that this file does not
# match itself).
NAMES_STUDENTS_LACK = re.compile(r"\b(?:DES" r"IGN|LEC" r"TURE)\.md\b")
TRACKER_NUMBER = re.compile(r"\biss" r"ues?\s+#?[0-9]+")


# ---- the tree -------------------------------------------------------------------------------------


def tracked_files(root):
    """The files of a tree: git's list in the project, every file in a handout (which has no .git)."""
    if not os.path.exists(os.path.join(root, ".git")):
        return sorted(os.path.relpath(os.path.join(d, f), root) for d, _, names in os.walk(root) for f in names)
    out = subprocess.run(["git", "ls-files", "-z"], cwd=root, capture_output=True, check=True).stdout
    return sorted(f for f in out.decode().split("\0") if f and os.path.isfile(os.path.join(root, f)))


def read(rel, root=ROOT):
    with open(os.path.join(root, rel), encoding="utf-8", errors="replace") as f:
        return f.read()


class Tree:
    """What the tree has: files, directories, functions per file, options, make targets, labels."""

    def __init__(self, build, root=ROOT):
        self.root = root
        self.files = tracked_files(root)
        self.file_set = set(self.files)
        self.dirs = set()
        for f in self.files:
            parts = f.split("/")[:-1]
            for i in range(1, len(parts) + 1):
                self.dirs.add("/".join(parts[:i]))
        self.basenames = {os.path.basename(f) for f in self.files}
        # (the project's stems: a handout lacks kit/CALIBRATION.md, but CALIBRATION is still no placeholder)
        self.stems = {os.path.basename(f).split(".")[0] for f in tracked_files(ROOT)}
        self.functions = {f: defined_functions(f, read(f, root)) for f in self.files
                          if f.endswith((".c", ".h", ".py", ".cjs")) and not f.startswith("tests/mutants/")}
        self.all_functions = set().union(*self.functions.values())
        self.python_modules = {os.path.basename(f)[:-3]: f for f in self.files if f.endswith(".py")}
        self.chapter_options = chapter_options(build)
        self.program_options = program_options(self.files, root)
        self.all_options = set().union(*self.chapter_options.values(), *self.program_options.values())
        self.code_words = code_words(self.files, root)
        self.targets = make_targets(build, root)
        self.labels = defined_labels(read(NOTES, root))

    def matching(self, pattern):
        """Tracked files (or directories) a path or glob names: chapters/NN_*.c, common/render.[ch]."""
        pattern = pattern.rstrip("/")
        if pattern in self.file_set or pattern in self.dirs:
            return [pattern]
        regex = glob_regex(pattern)
        found = [f for f in self.files if regex.fullmatch(f)]
        return found or [d for d in self.dirs if regex.fullmatch(d)]

    def functions_of(self, path):
        """The functions defined in the files a path names (a bare file name: in any directory)."""
        files = self.matching(path) if "/" in path else [f for f in self.files if glob_regex(path).fullmatch(
            os.path.basename(f))]
        return set().union(*(self.functions.get(f, set()) for f in files)) if files else None


def glob_regex(pattern):
    """A glob with the texts' own placeholders: *, [ch], NN (two digits)."""
    out = ""
    i = 0
    while i < len(pattern):
        c = pattern[i]
        if c == "*":
            out += "[^/]*"
        elif c == "[":
            j = pattern.index("]", i)
            out += "[" + re.escape(pattern[i + 1:j]) + "]"
            i = j
        elif pattern.startswith("NN", i):
            out += "[0-9][0-9][a-z]?"
            i += 1
        else:
            out += re.escape(c)
        i += 1
    return re.compile(out)


C_DEFINITION = re.compile(r"^(?:[A-Za-z_][\w\s\*]*?[\s\*])?([A-Za-z_]\w*)\s*\(", re.M)
C_MACRO = re.compile(r"^\s*#\s*define\s+([A-Za-z_]\w*)\(", re.M)
C_KEYWORDS = {"if", "for", "while", "switch", "return", "sizeof", "do", "else"}


def defined_functions(path, text):
    if path.endswith(".py"):
        return set(re.findall(r"^\s*(?:async\s+)?(?:def|class)\s+(\w+)", text, re.M))
    if path.endswith(".cjs"):
        return set(re.findall(r"\bfunction\s+(\w+)", text)) | set(re.findall(r"\b(?:const|let)\s+(\w+)\s*=\s*(?:async\s*)?\(", text))
    names = {m.group(1) for m in C_DEFINITION.finditer(text)} | set(C_MACRO.findall(text))
    return names - C_KEYWORDS


def code_words(files, root):
    """Every word of the tree's code, comments and docstrings left out (so that a comment cannot vouch
    for itself), and the stems of the file names (`grade_docs`, `bench_03_radiosity`)."""
    words = set()
    for f in files:
        if f.startswith("tests/mutants/"):
            continue
        words.update(re.split(r"[/.]", f))
        if f.endswith((".c", ".h")):
            words.update(re.findall(r"\w+", re.sub(r"/\*.*?\*/|//[^\n]*", " ", read(f, root), flags=re.S)))
        elif f.endswith(".py"):
            words.update(python_code_words(read(f, root)))
        elif f.endswith((".cjs", ".mk", ".json", ".scene", ".sh", ".gp")) or f == "Makefile":
            words.update(re.findall(r"\w+", read(f, root)))
    return words


def python_code_words(text):
    """The names and the words of the strings of a Python file, without comments and docstrings."""
    words, previous = set(), tokenize.NEWLINE
    try:
        for tok in tokenize.generate_tokens(io.StringIO(text).readline):
            if tok.type == tokenize.NAME:
                words.add(tok.string)
            elif tok.type == tokenize.STRING and previous not in (tokenize.NEWLINE, tokenize.INDENT,
                                                                  tokenize.DEDENT, tokenize.NL):
                words.update(re.findall(r"\w+", tok.string))
            if tok.type != tokenize.COMMENT:
                previous = tok.type
    except (SyntaxError, tokenize.TokenError):
        words.update(re.findall(r"\w+", text))
    return words


def chapter_options(build):
    """{"04_pathtrace": {"--spp", ...}} from every built chapter's --help."""
    options = {}
    for exe in sorted(glob.glob(os.path.join(ROOT, build, "0*_*"))):
        if not os.access(exe, os.X_OK) or exe.endswith(".d"):
            continue
        text = subprocess.run([exe, "--help"], capture_output=True, text=True, timeout=60).stdout
        options[os.path.basename(exe)] = set(re.findall(r"^  (--[a-z0-9-]+)", text, re.M))
    return options


def program_options(files, root):
    """{"kit/grade.py": {"--report", ...}}: the "--name" strings the other programs compare against
    (the viewer's option table, the Python scripts' argument loops)."""
    options = {}
    for f in files:
        if f.endswith((".c", ".py", ".cjs", ".sh", ".mk")) and not f.startswith(("chapters/", "tests/mutants/")):
            found = set(re.findall(r"[\"'](--[a-z][a-z0-9-]*)", read(f, root)))
            if found:
                options[f] = found
    return options


def make_targets(build, root):
    """Every target the Makefile and its included *.mk files define (make's own database)."""
    r = subprocess.run(["make", "-pnq", f"BUILD={build}", "--no-print-directory"], cwd=root, capture_output=True,
                       text=True, timeout=60)
    targets, not_a_target = set(), False
    for line in r.stdout.splitlines():
        if line.startswith("# Not a target"):
            not_a_target = True
            continue
        m = re.match(r"^([A-Za-z0-9_.-]+):(?!=)", line)
        if m and not not_a_target:
            targets.add(m.group(1))
        not_a_target = False
    return targets


def defined_labels(text):
    """Labels the notes define (the rule of tests/grade_notes.py): **(Rn)** at a line's start, or in a heading."""
    defined = set()
    for line in text.splitlines():
        m = re.match(r"\s*\*\*\((R[0-9]+)\)\*\*", line)
        if m:
            defined.add(m.group(1))
        elif line.startswith("#"):
            defined.update(re.findall(r"\((R[0-9]+)\)", line))
    return defined


# ---- the texts ------------------------------------------------------------------------------------


def c_comments(text):
    """[(line, comment text)] of a C file, string and character literals skipped."""
    out, i, line, n = [], 0, 1, len(text)
    while i < n:
        c = text[i]
        if c == "\n":
            line += 1
        elif c in "\"'":
            j = i + 1
            while j < n and text[j] != c and text[j] != "\n":
                j += 2 if text[j] == "\\" else 1
            line += text.count("\n", i, j)
            i = j
        elif text.startswith("//", i):
            j = text.find("\n", i)
            j = n if j < 0 else j
            out.append((line, text[i + 2:j]))
            i = j - 1
        elif text.startswith("/*", i):
            j = text.find("*/", i + 2)
            j = n if j < 0 else j
            out.append((line, text[i + 2:j]))
            line += text.count("\n", i, j)
            i = j + 1
        i += 1
    return out


def python_comments(text):
    """[(line, text)] of a Python file's comments and docstrings."""
    out = []
    try:
        for tok in tokenize.generate_tokens(io.StringIO(text).readline):
            if tok.type == tokenize.COMMENT:
                out.append((tok.start[0], tok.string[1:]))
        tree = ast.parse(text)
    except (SyntaxError, tokenize.TokenError):
        return out
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant) and \
                    isinstance(first.value.value, str):
                out.append((first.lineno, first.value.value))
    return out


def texts(tree):
    """[(file, first line, text, kind)]: kind "md" for Markdown, "comment" for code comments."""
    out = []
    for pattern in MARKDOWN:
        for f in sorted(glob.glob(os.path.join(tree.root, pattern))):
            rel = os.path.relpath(f, tree.root)
            if rel in tree.file_set:
                out.append((rel, 1, read(rel, tree.root), "md"))
    for f in tree.files:
        if f.startswith("tests/mutants/") or f == "tests/grade_names.py":
            continue
        if f.endswith((".c", ".h")):
            out += [(f, line, text, "comment") for line, text in c_comments(read(f, tree.root))]
        elif f.endswith(".py") and f.startswith(PYTHON_DIRS):
            out += [(f, line, text, "comment") for line, text in python_comments(read(f, tree.root))]
    return out


# ---- the checks -----------------------------------------------------------------------------------

# `name()` or name() (a word followed by empty parentheses), and `name(args)` in backticks.
CALL = re.compile(r"(?<![\w.>])([A-Za-z_]\w*)\(\)")
CALL_IN_BACKTICKS = re.compile(r"`([A-Za-z_]\w*)\([^`()]+\)`")
# a name qualified by something else: os.replace(), pbrt's LiRandomWalk(), std::sort()
QUALIFIED = re.compile(r"(?:\b\w+'s\s+|\.|::|->)$")
# "`a()`, `b()` and `c()` in `FILE`"
CALLS_IN_FILE = re.compile(r"((?:`[A-Za-z_]\w*\(\)`(?:\s*(?:,|and|or|/)\s*)*)+)\s+in\s+`([\w./*\[\]-]+\.(?:c|h|\[ch\]|py))`")
# "`FILE`: `a()`, `b()`; ..." in the notes' summary table
FILE_COLON = re.compile(r"`([\w./*\[\]-]+\.(?:c|h|\[ch\]|py))`:\s*([^;|]*)")
# directories that runs create and fill: make fuzz's crashing inputs
WRITTEN_BY_RUNS = ("tests/fuzz/findings", "kit/handout.json")  # the latter: in every handout (kit/handout.py)
TOP_DIRS = ("chapters", "common", "kit", "docs", "tests", "slides", "viewer", "bench", "tradeoff", "scenes")
PATH = re.compile(r"(?<![\w/.-])((?:%s)/(?:[\w./*<>-]|\[ch\])*(?:[\w*/]|\[ch\]))" % "|".join(TOP_DIRS))
BARE_FILE = re.compile(r"(?<![\w/.<+-])([\w*-]+\.(?:c|h|\[ch\]|py|scene|mk|cjs|sh))(?![/\w])")
# a file of another project: "Chen's `room.c` and `draw.c`" (a possessive earlier in the sentence)
OTHER_PROJECTS_FILES = re.compile(r"\b[A-Z]\w*'s\s")
# the stems of files a reader is to write: example.scene, x.scene
PLACEHOLDER_STEMS = {"x", "example", "my", "name", "file", "foo"}
OPTION = re.compile(r"(?<![\w-])(--[a-z][a-z0-9-]*)")
CHAPTER_COMMAND = re.compile(r"\bbuild/(0[0-9]_[a-z]+)\b([^`\n]*)")
MAKE = re.compile(r"\bmake\s+((?:[A-Z_]+=\S*\s+|-\S+\s+)*)([a-z][\w-]*)")
LABEL = re.compile(r"\bR([1-9][0-9]*)\b")
LABEL_RANGE = re.compile(r"\bR1\s*(?:-|–|\.\.)\s*R([1-9][0-9]*)\b")


def line_of(first, text, pos):
    return first + text.count("\n", 0, pos)


def placeholder(path, tree):
    """Paths that stand for what the reader picks: DIR, FILE.json, <name>, NN_name, x.scene (a word in
    capitals that is no file's stem, as README is)."""
    stem = os.path.basename(path).split(".")[0]
    capitals = set(re.findall(r"\b[A-Z]{2,}\b", path.replace("NN", ""))) - tree.stems
    return bool(capitals or re.search(r"<|(?:\b|_)name\b", path)) or stem in PLACEHOLDER_STEMS


def check_functions(tree, f, first, text, problems):
    spans = []
    for m in CALL.finditer(text):
        spans.append((m.start(), m.group(1)))
    for m in CALL_IN_BACKTICKS.finditer(text):
        spans.append((m.start() + 1, m.group(1)))
    for pos, name in spans:
        if QUALIFIED.search(text[max(0, pos - 40):pos]) or name in EXTERNAL_FUNCTIONS or EXTERNAL_PREFIX.match(name):
            continue
        if name not in tree.all_functions:
            problems.append(f"{f}:{line_of(first, text, pos)}: function {name}() is defined nowhere in the tree")
    for m in CALLS_IN_FILE.finditer(text):
        where = tree.functions_of(m.group(2))
        for name in re.findall(r"`(\w+)\(\)`", m.group(1)):
            if where is not None and name not in where and name in tree.all_functions:
                problems.append(f"{f}:{line_of(first, text, m.start())}: {name}() is not in {m.group(2)}")
    for m in FILE_COLON.finditer(text):
        where = tree.functions_of(m.group(1))
        for n in re.finditer(r"(via\s+)?`(\w+)\(\)`", m.group(2)):
            if where is not None and not n.group(1) and n.group(2) not in where and n.group(2) in tree.all_functions:
                problems.append(f"{f}:{line_of(first, text, m.start())}: {n.group(2)}() is not in {m.group(1)}")


def check_identifiers(tree, f, first, text, problems):
    """A name with an underscore in backticks (`sample_bsdf`, `truncated_paths`) is a word of the code."""
    for m in re.finditer(r"`([^`\n]+)`", text):
        for word in re.findall(r"(?<![\w.-])([A-Za-z]\w*_\w+)\b(?!\()", m.group(1)):
            if word not in tree.code_words and not placeholder(word, tree) and not EXTERNAL_PREFIX.match(word):
                problems.append(f"{f}:{line_of(first, text, m.start())}: `{word}` is not a name in the tree's code")


def check_paths(tree, f, first, text, problems):
    for m in PATH.finditer(text):
        path = m.group(1).rstrip(".")
        if not placeholder(path, tree) and not tree.matching(path) and not os.path.exists(os.path.join(tree.root, path)) \
                and not path.startswith(WRITTEN_BY_RUNS):
            problems.append(f"{f}:{line_of(first, text, m.start())}: no file or directory {path}")
    for m in BARE_FILE.finditer(text):
        name = m.group(1)
        sentence = re.split(r"[.!?:;]\s", text[:m.start()])[-1]
        if placeholder(name, tree) or OTHER_PROJECTS_FILES.search(sentence):
            continue
        if not any(glob_regex(name).fullmatch(b) for b in tree.basenames):
            problems.append(f"{f}:{line_of(first, text, m.start())}: no file named {name} in the tree")


def check_options(tree, f, first, text, problems):
    for m in OPTION.finditer(text):
        if m.group(1) not in tree.all_options:
            problems.append(f"{f}:{line_of(first, text, m.start())}: option {m.group(1)} is not an option of "
                            "any chapter or program of the tree")
    for m in CHAPTER_COMMAND.finditer(text):
        chapter, rest = m.group(1), m.group(2)
        own = tree.chapter_options.get(chapter)
        if own is None:
            problems.append(f"{f}:{line_of(first, text, m.start())}: no chapter {chapter}")
            continue
        for o in OPTION.findall(rest):
            if o not in own and o in tree.all_options:
                problems.append(f"{f}:{line_of(first, text, m.start())}: {chapter} has no option {o}")


def code_spans(text, kind):
    """[(offset, code)]: backticked spans, and in Markdown the lines of code blocks."""
    spans = [(m.start(1), m.group(1)) for m in re.finditer(r"`([^`\n]+)`", text)]
    if kind == "md":
        fenced = False
        offset = 0
        for line in text.splitlines(keepends=True):
            if line.startswith("```"):
                fenced = not fenced
            elif fenced or line.startswith("    "):
                spans.append((offset, line))
            offset += len(line)
    else:
        # a comment's own command lines: "make test", indented or at a line's start
        spans += [(m.start(1), m.group(1)) for m in re.finditer(r"^[\s*#]*(make\s[^\n]*)", text, re.M)]
    return spans


def check_make(tree, f, first, text, kind, problems):
    for offset, code in code_spans(text, kind):
        for m in MAKE.finditer(code):
            if not code[:m.start()].strip() or code[:m.start()].rstrip().endswith(("#", ";", "&&", "$")) or \
                    m.start() == 0:
                if m.group(2) not in tree.targets:
                    problems.append(f"{f}:{line_of(first, text, offset)}: make {m.group(2)}: no such target")


def check_labels(tree, f, first, text, problems):
    for m in LABEL.finditer(text):
        if f"R{m.group(1)}" not in tree.labels:
            problems.append(f"{f}:{line_of(first, text, m.start())}: label R{m.group(1)} is not defined in {NOTES}")
    highest = max(int(label[1:]) for label in tree.labels)
    for m in LABEL_RANGE.finditer(text):
        near = text[max(0, m.start() - 200):m.end() + 200]
        if int(m.group(1)) != highest and re.search(r"lecture-notes\.md|[Nn]otes\b", near):
            problems.append(f"{f}:{line_of(first, text, m.start())}: R1-R{m.group(1)} next to the notes, which "
                            f"define R1-R{highest}")


def check_student_visible(tree, problems):
    student = [f for f in tree.files if not f.startswith(handout.INSTRUCTOR_ONLY)
               and not f.endswith((".png", ".pfm", ".json", ".patch", ".lock", ".pyc")) and "/bad/" not in f]
    for f in student:
        try:
            text = read(f, tree.root)
        except OSError:
            continue
        for pattern in (NAMES_STUDENTS_LACK, TRACKER_NUMBER):
            for m in pattern.finditer(text):
                problems.append(f"{f}:{text.count(chr(10), 0, m.start()) + 1}: \"{m.group(0)}\": a student "
                                "does not have it (a handout gets this file)")


def problems_of(build, root=ROOT):
    """["file:line: what is missing"] for the project (root) or a handout written from it."""
    tree = Tree(build, root)
    problems = []
    for f, first, text, kind in texts(tree):
        check_functions(tree, f, first, text, problems)
        check_paths(tree, f, first, text, problems)
        check_identifiers(tree, f, first, text, problems)
        check_options(tree, f, first, text, problems)
        check_make(tree, f, first, text, kind, problems)
        check_labels(tree, f, first, text, problems)
    check_student_visible(tree, problems)
    return problems


def test_every_name_in_the_texts_exists(ctx):
    problems = problems_of(ctx.build)
    assert not problems, f"{len(problems)} names in the texts that the tree does not have:\n" + "\n".join(problems)


def test_every_name_in_a_handout_exists(ctx):
    """A handout (every chapter stubbed) names only what the handout has: no link to the instructor's
    files, no target or option it lacks."""
    out = os.path.join(ctx.scratch, "handout")
    r = subprocess.run([sys.executable, os.path.join(ROOT, "kit", "handout.py"), out], cwd=ROOT,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, f"kit/handout.py failed: {r.stderr}"
    problems = problems_of(ctx.build, out)
    assert not problems, f"{len(problems)} names in the handout's texts that the handout does not have:\n" + \
        "\n".join(problems)


if __name__ == "__main__":
    # tests/grade_names.py [BUILD [ROOT]]: the problems, one a line (ROOT: a handout's directory)
    for p in problems_of(*(sys.argv[1:3] or ["build"])):
        print(p)
