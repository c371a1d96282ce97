"""The course's own notes cover what the code cites (docs/lecture-notes.md,
docs/scene-format.md), so a student who clones the repository can follow
a `(R9)` in a comment and look up every statement a scene may use.

  - every equation label cited in chapters/, common/ and the slide decks is
    defined in docs/lecture-notes.md, on a line that starts with
    **(Rn)** or in a heading containing (Rn), and defined only once;
  - every statement keyword the parser accepts (the strcmp keywords of
    parse_statement in common/scene*.c) has a section in
    docs/scene-format.md (a heading naming it), and every material kind
    and light kind the parser accepts has its usage line there
    (`material NAME KIND ...`).

No binaries needed: the build directory argument of tests/run.py is unused.
"""
import glob
import os
import re

from lib import ROOT

GRADES_NOTHING = True  # no grading, no handout: may run beside the RUN_ALONE tests (tests/run.py)

NOTES = os.path.join(ROOT, "docs", "lecture-notes.md")
SCENE_FORMAT = os.path.join(ROOT, "docs", "scene-format.md")

# A label is R followed by a number from 1 on, as a word of its own:
# (R9), (R7, R8), (R1, the term KE), "area form R9", \tag{R6}, R1–R10.
# R0 is not a label (Schlick's R0 in common/optics.h is a reflectance).
LABEL = re.compile(r"\bR([1-9][0-9]*)\b")
# A range of labels cites every label in it: R1–R10, (R7-R9), R1..R10.
LABEL_RANGE = re.compile(r"\bR([1-9][0-9]*)\s*(?:-|–|\.\.)\s*R?([1-9][0-9]*)\b")


def read(path):
    with open(path, encoding="utf-8", errors="replace") as f:
        return f.read()


def cited_files():
    patterns = ["chapters/*.c", "chapters/*.h", "common/*", "slides/*.md"]
    return sorted(p for pattern in patterns for p in glob.glob(os.path.join(ROOT, pattern)) if os.path.isfile(p))


def cited_labels():
    """{"R9": ["chapters/04_pathtrace.c:295", ...]} for every label cited."""
    cited = {}
    for path in cited_files():
        rel = os.path.relpath(path, ROOT)
        for number, line in enumerate(read(path).splitlines(), 1):
            found = {int(m.group(1)) for m in LABEL.finditer(line)}
            for m in LABEL_RANGE.finditer(line):
                lo, hi = int(m.group(1)), int(m.group(2))
                if lo <= hi <= lo + 20:
                    found.update(range(lo, hi + 1))
            for n in found:
                cited.setdefault(f"R{n}", []).append(f"{rel}:{number}")
    return cited


def defined_labels(text):
    """Labels defined in the notes: a line starting with **(Rn)**, or a heading containing (Rn)."""
    defined = []
    for line in text.splitlines():
        m = re.match(r"\s*\*\*\((R[0-9]+)\)\*\*", line)
        if m:
            defined.append(m.group(1))
        elif line.startswith("#"):
            defined.extend(re.findall(r"\((R[0-9]+)\)", line))
    return defined


def test_every_cited_label_is_defined_in_the_notes(ctx):
    assert os.path.exists(NOTES), "docs/lecture-notes.md is missing"
    cited = cited_labels()
    assert cited, "no equation labels found in chapters/, common/, slides/ (has the citation style changed?)"
    defined = defined_labels(read(NOTES))
    missing = sorted(set(cited) - set(defined), key=lambda l: int(l[1:]))
    assert not missing, "labels cited but not defined in docs/lecture-notes.md (a line starting with **(Rn)**): " + \
        "; ".join(f"{label} (cited at {', '.join(cited[label][:3])})" for label in missing)
    twice = sorted({label for label in defined if defined.count(label) > 1})
    assert not twice, f"labels defined more than once in docs/lecture-notes.md: {twice}"


def function_body(text, name):
    """The text of C function `name` from its signature to the closing brace at column 0."""
    m = re.search(r"^[^\n;]*\b%s\s*\([^;{]*\)\s*\{" % re.escape(name), text, re.M)
    if not m:
        return None
    end = re.search(r"^\}", text[m.end():], re.M)
    return text[m.start():m.end() + (end.start() if end else len(text))]


def parser_keywords():
    """(statements, material kinds, light kinds) the parser compares against, from common/scene*.c."""
    statements, materials, lights = set(), set(), set()
    sources = sorted(glob.glob(os.path.join(ROOT, "common", "scene*.c")))
    for path in sources:
        text = read(path)
        for name, into in (("parse_statement", statements), ("parse_material", materials),
                           ("parse_light", lights)):
            body = function_body(text, name)
            if body:
                # strcmp(x, "word") == 0 (or !strcmp / expect_keyword): the words the parser accepts
                into.update(re.findall(r"strcmp\s*\(\s*[^,()]+(?:\([^()]*\))?[^,()]*,\s*\"([A-Za-z_][\w-]*)\"\s*\)",
                                       body))
    return statements, materials, lights


def test_every_scene_statement_has_a_section(ctx):
    assert os.path.exists(SCENE_FORMAT), "docs/scene-format.md is missing"
    statements, materials, lights = parser_keywords()
    assert len(statements) >= 5, f"found only {sorted(statements)} in parse_statement (has the parser changed shape?)"
    assert materials, "no material kinds found in parse_material"
    text = read(SCENE_FORMAT)
    headings = [line.lstrip("#").strip() for line in text.splitlines() if re.match(r"#{2,4} ", line)]
    missing = sorted(k for k in statements
                     if not any(re.search(r"(^|[\s`])%s($|[\s`])" % re.escape(k), h) for h in headings))
    assert not missing, "statements the parser accepts without a section (### KEYWORD) in " \
                        f"docs/scene-format.md: {missing}"
    # each kind with its usage line: `material NAME KIND ...` and `light NAME KIND ...`
    usages = [" ".join(item.split()) for item in re.findall(r"`([^`]+)`", text)] + \
             [" ".join(line.split()) for line in text.splitlines() if line.startswith("    ")]
    missing_kinds = sorted(f"{statement} {kind}" for statement, kinds in (("material", materials), ("light", lights))
                           for kind in kinds
                           if not any(u.startswith(f"{statement} NAME {kind}") for u in usages))
    assert not missing_kinds, "kinds the parser accepts without a usage line (`material NAME KIND ...`, " \
                              f"`light NAME KIND ...`) in docs/scene-format.md: {missing_kinds}"
