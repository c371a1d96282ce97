"""kit/rubric.json: the one place where criteria and their points are defined.

load() refuses a rubric the kit could not grade by: a row that names an exercise no function of the
tree is marked with, or a test that does not exist (tests/<module>.py without def <test>, or a unit
test tests/<test>.c that is missing).  The error names the row: kit/rubric.json: criterion N 'name'.

criterion_commands() says what a criterion runs (chapter, scene, options), for ASSIGNMENT.md and
the grading report: compare and surfaces rows from the row itself, grade rows from the commands
the instructor's calibration recorded into the exercise matrix.
"""
import json
import os
import re

KINDS = ("grade", "unit", "compare", "surfaces")
RUBRIC = os.path.join("kit", "rubric.json")
MATRIX = os.path.join("kit", "exercise-matrix.json")


def load(root, path=None):
    """The rubric (kit/rubric.json of root, or the file path: a test's own rubric), checked."""
    path = path or os.path.join(root, RUBRIC)
    try:
        with open(path) as f:
            rub = json.load(f)
    except (OSError, ValueError) as e:
        raise ValueError(f"{RUBRIC}: {e}")
    marked = marked_exercises(root)
    seen = set()
    for i, c in enumerate(rub.get("criteria", [])):
        where = f"{RUBRIC}: criterion {i + 1}" + (f" '{c['name']}'" if isinstance(c.get("name"), str) else "")
        for key in ("chapter", "name", "kind", "points", "exercises", "what"):
            if key not in c:
                raise ValueError(f"{where}: no '{key}'")
        if c["kind"] not in KINDS:
            raise ValueError(f"{where}: kind '{c['kind']}' is not one of {', '.join(KINDS)}")
        if (c["chapter"], c["name"]) in seen:
            raise ValueError(f"{where}: '{c['name']}' twice in {c['chapter']}")
        seen.add((c["chapter"], c["name"]))
        unknown = [x for x in c["exercises"] if x not in marked]
        if unknown:
            raise ValueError(f"{where}: exercise {', '.join(map(str, unknown))} is not marked in the tree "
                             f"(marked: {', '.join(sorted(marked, key=exercise_order)) or 'none'})")
        problem = missing_test(root, c)
        if problem:
            raise ValueError(f"{where}: {problem}")
    return rub


def exercise_order(exercise_id):
    lecture, number = exercise_id.split(".")
    digits = lecture.rstrip("abcdefghijklmnopqrstuvwxyz")
    return int(digits), lecture[len(digits):], int(number)


def marked_exercises(root):
    """The ids N.M of the [exercise N.M] markers in the tree's sources (kit/markers.py)."""
    import sys
    kit = os.path.dirname(os.path.abspath(__file__))
    if kit not in sys.path:
        sys.path.insert(0, kit)
    import markers  # kit/markers.py, beside this file
    return {e.id for e in markers.all_exercises(root)}


def missing_test(root, c):
    """Why the test a row names cannot run ("" if it can): read, not imported."""
    if c["kind"] == "unit":
        if not os.path.isfile(os.path.join(root, "tests", f"{c.get('test')}.c")):
            return f"unit test tests/{c.get('test')}.c does not exist"
    elif c["kind"] == "grade":
        module = os.path.join(root, "tests", f"{c.get('module')}.py")
        try:
            with open(module) as f:
                source = f.read()
        except OSError:
            return f"tests/{c.get('module')}.py does not exist"
        if not re.search(rf"^def {re.escape(str(c.get('test')))}\(", source, re.M):
            return f"tests/{c.get('module')}.py has no function {c.get('test')}"
    return ""


def statistical(c):
    return c["kind"] == "compare"


def key(c):
    """How kit/exercise-matrix.json names a criterion."""
    return f"{c['chapter']}: {c['name']}"


# ---- what a criterion runs ------------------------------------------------------------------------

def parse_command(text):
    """{"chapter", "scene", "options", "text"} of a command "build/CHAPTER [SCENE] OPTION ..."."""
    words = text.split()
    chapter = words[0].split("/")[-1]
    scene = words[1] if len(words) > 1 and not words[1].startswith("-") else None
    return {"chapter": chapter, "scene": scene, "options": words[2 if scene else 1:], "text": text}


def row_command(c):
    """The command a compare or surfaces row runs, from the row (kit/compare.py render, surfaces_of)."""
    if c["kind"] == "compare":
        options = ["--size", c.get("size", "32x32"), "--spp", str(c.get("spp", 1)), *c.get("args", [])]
    else:
        options = ["--size", "8x8", "--spp", "1", "--patch-size", str(c.get("patch_size", 50)),
                   "--tol", str(c.get("tol", 1e-6)), "--iterations", str(c.get("iterations", 500)),
                   *c.get("args", [])]
    return " ".join([f"build/{c['chapter']}", c["scene"], *options])


def load_matrix(root):
    """kit/exercise-matrix.json, or None when the tree has none."""
    try:
        with open(os.path.join(root, MATRIX)) as f:
            return json.load(f)
    except OSError:
        return None


def criterion_commands(root, c, matrix=None):
    """What criterion c (a row of kit/rubric.json) runs: a list of {"chapter", "scene" (None when the
    run has no scene), "options" (a list of words), "text" (the command line, "build/CHAPTER SCENE
    OPTION ...")}, without the options that only say where output goes (--out, --stats, --quiet,
    --threads).  A compare row renders its command `batches` times with seeds S * 1000 + b (grading
    seed S); a unit row runs build/tests/<test>; a grade row the commands its test ran when
    the instructor's calibration measured the solution (the exercise matrix), files the test
    writes shown as scratch/NAME.  [] when a grade row has not been measured yet."""
    if c["kind"] in ("compare", "surfaces"):
        return [parse_command(row_command(c))]
    if c["kind"] == "unit":
        return [{"chapter": None, "scene": None, "options": [], "text": f"build/tests/{c['test']}"}]
    matrix = matrix if matrix is not None else load_matrix(root)
    for row in (matrix or {}).get("criteria", []):
        if row["chapter"] == c["chapter"] and row["name"] == c["name"]:
            return [parse_command(text) for text in row.get("commands", [])]
    return []
