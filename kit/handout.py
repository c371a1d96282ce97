#!/usr/bin/python3
"""Write a student handout: this project without the solutions of the chosen chapters.

usage: kit/handout.py OUT_DIR [CHAPTER ...]        (make handout OUT=DIR CHAPTERS="03_radiosity ...")

  OUT_DIR   a directory that does not exist yet or is empty
  CHAPTER   e.g. 03_radiosity (default: every chapter with [exercise N.M] markers)

The tree is the project's tracked files (git ls-files) minus what only the
instructor may see (INSTRUCTOR_ONLY below: the kit's own tests and mutants,
its calibration and this script).  In the chosen chapters every function
marked [exercise N.M] gets a stub body (kit/markers.py): it prints
"file:line: TODO name is not implemented" once and returns zero, so the
handout compiles without warnings and runs, with black or partial images.
The chapters after the last chosen one have their exercises stubbed the same
way (kit/grade.py later_chapters, as a grading stubs them): a course hands its
chapters out in order, so a handout gives away no chapter not yet handed out.
The chapters before it keep the solution: they are handed out already, the
chosen chapters link them (chapter 2 shades with chapter 1's model, chapter 5
with chapter 4's, chapter 7 with 4, 5 and 6) and their criteria run them
(chapter 4's compare with chapter 3), so a correct answer must find them right.
assignments/NN_name/ASSIGNMENT.md says what to write and how it is graded
(from the markers of the stubbed text and kit/rubric.json); README.md is the
student's (kit/student/README.md); `make grade` in the handout grades it, and
.github/workflows/classroom.yml (kit/autograder/classroom.yml) runs that
self-check on every push to the student's GitHub repository.
The slides go as their Markdown and builder: `make slides` in the handout
builds student decks (slides/build.py --student) from the handout's own code.

The tree is written next to OUT_DIR under a temporary name and renamed at the
end: on any refusal (exit 2, "file:line: message") nothing is left.  It refuses
an unknown chapter, an [exercise] tag that is not just above a function, and a
handout in which a function of any file still holds one of the stubbed
exercises' answers, the later chapters' included (kit/markers.py
answers_in_tree: chapter 5 once carried copies of chapter 4's scattering in
common/).
"""
import ast
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import grade  # noqa: E402  (later_chapters: what a grading stubs, a handout stubs too)
import markers  # noqa: E402
import rubric as rubric_module  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
INSTRUCTOR_ONLY = ("tests/mutants/", "tests/grade_kit.py", "tests/grade_handout.py", "kit/handout.py",
                   "kit/calibrate.py", "kit/README.md", "kit/CALIBRATION.md", "kit/student/", ".ci/",
                   "kit/autograder/", "tests/grade_autograder.py", "tests/grade_matrix.py",
                   "tests/grade_sandbox.py", "tests/grade_classroom.py", "kit/heldout/", "tests/grade_heldout.py", "tests/cluster_")
# The student's self-check on push (GitHub Classroom): kept in the kit, so that it runs in the
# handout's repository only, not in the instructor's.
CLASSROOM_WORKFLOW = (os.path.join("kit", "autograder", "classroom.yml"), os.path.join(".github", "workflows",
                                                                                       "classroom.yml"))
STUDENT_README = os.path.join("kit", "student", "README.md")
HELDOUT_README = """# Held-out references (the instructor's)

In the instructor's copy of the course this folder holds, for every criterion *vs reference*,
a variant nobody sees in a handout (another camera, another patch size) with the solution's
reference for it, and the instructor's grading grades that variant. A handout has none, so
`make grade` here grades against the public references in `kit/reference/`: a check of your
own, not your grade. Code that is right passes both; copying the public numbers passes only here.
"""


class Refused(Exception):
    pass


def fail(message):
    """Exit 2 with message; lines that start with file:line: stand as they are."""
    lines = [ln if re.match(r"[\w./-]+:\d+: ", ln) else f"kit/handout.py: {ln}" for ln in message.splitlines()]
    print("\n".join(lines), file=sys.stderr)
    sys.exit(2)


def tracked_files(root):
    try:
        out = subprocess.run(["git", "ls-files", "-z"], cwd=root, capture_output=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError) as e:
        raise Refused(f"git ls-files failed in {root}: {e}")
    files = [f for f in out.decode().split("\0") if f]
    return [f for f in files if not f.startswith(INSTRUCTOR_ONLY) and os.path.isfile(os.path.join(root, f))]


# ---- the numbers ASSIGNMENT.md states, computed from their sources ----------------------------------

def criterion_alpha(root):
    """CRITERION_ALPHA of tests/lib.py, read as a literal (importing lib is not needed for one number)."""
    path = os.path.join(root, "tests", "lib.py")
    with open(path) as f:
        tree = ast.parse(f.read(), path)
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == "CRITERION_ALPHA" for t in node.targets):
            return float(ast.literal_eval(node.value))
    raise Refused(f"{path}: no CRITERION_ALPHA")


def _budget_names(function):
    """True when a test function takes a false-alarm budget of CRITERION_ALPHA: it calls t_bound with
    the default alpha, or names CRITERION_ALPHA outside an alpha= argument.  A test that passes its
    own alpha= asks for a difference to be present (a power requirement such as chapter 5's "bias
    falls"): it has no false-alarm rate of CRITERION_ALPHA."""
    own_alpha = set()
    for node in ast.walk(function):
        if isinstance(node, ast.Call) and any(k.arg == "alpha" for k in node.keywords):
            own_alpha.update(id(x) for x in ast.walk(node.func))
            for k in node.keywords:
                own_alpha.update(id(x) for x in ast.walk(k.value))
    names = set()
    for node in ast.walk(function):
        if id(node) in own_alpha:
            continue
        if isinstance(node, ast.Name):
            names.add(node.id)
        elif isinstance(node, ast.Attribute):
            names.add(node.attr)
    return names


def _test_functions(path):
    """The module's functions, and those it imports from another grade module (`from grade_06_bidirectional
    import expect_tiles_agree`: chapter 7 compares tiles by chapter 6's rule)."""
    with open(path) as f:
        tree = ast.parse(f.read(), path)
    found = {}
    for n in tree.body:
        if isinstance(n, ast.ImportFrom) and (n.module or "").startswith("grade_"):
            other = _test_functions(os.path.join(os.path.dirname(path), n.module + ".py"))
            found.update({a.name: other[a.name] for a in n.names if a.name in other})
    found.update({n.name: n for n in tree.body if isinstance(n, ast.FunctionDef)})
    return found


def grade_criteria_with_budget(root, criteria):
    """The grade criteria whose test (or a helper of its module or tests/lib.py it calls) has a Monte
    Carlo tolerance at CRITERION_ALPHA (tests/lib.py t_bound)."""
    lib = _test_functions(os.path.join(root, "tests", "lib.py"))
    found = []
    for c in criteria:
        if c["kind"] != "grade":
            continue
        pool = {**lib, **_test_functions(os.path.join(root, "tests", c["module"] + ".py"))}
        todo, seen = [c["test"]], set()
        while todo:
            name = todo.pop()
            if name in seen or name not in pool:
                continue
            seen.add(name)
            names = _budget_names(pool[name])
            if names & {"t_bound", "CRITERION_ALPHA"} and name != "t_bound":
                found.append(c)
                break
            todo += sorted(names & set(pool))
    return found


def false_failure_budget(root, rub, criteria):
    """(rate, text): the designed chance that grading `criteria` fails a correct solution, by the union
    bound: each compare criterion family_alpha / (compare criteria of the rubric) (kit/rubric.json,
    Bonferroni), each grade criterion with a tolerance CRITERION_ALPHA (tests/lib.py)."""
    all_compare = [c for c in rub["criteria"] if rubric_module.statistical(c)]
    compare = [c for c in criteria if rubric_module.statistical(c)]
    graded = grade_criteria_with_budget(root, criteria)
    alpha = criterion_alpha(root)
    rate = rub["family_alpha"] * len(compare) / max(1, len(all_compare)) + alpha * len(graded)
    text = (f"{len(compare)} criteria *vs reference* at {rub['family_alpha']} / {len(all_compare)} each "
            f"(`family_alpha` of kit/rubric.json over its {len(all_compare)} such criteria) and "
            f"{len(graded)} criteria with a Monte Carlo tolerance at {alpha} each (`CRITERION_ALPHA`, "
            f"tests/lib.py)")
    return rate, text


def percent(rate):
    return f"{100 * rate:.3g} %"


def criterion_command(root, c):
    """What a criterion runs, as the commands a student can type (rubric.criterion_commands when the
    kit has it, else derived from the rubric row here)."""
    if hasattr(rubric_module, "criterion_commands"):
        commands = rubric_module.criterion_commands(root, c)
        if commands or c["kind"] == "grade":
            return [x["text"] if isinstance(x, dict) else x for x in commands]
    # without it, the row's own fields (as kit/compare.py passes them, minus --out, --seed and the like)
    if c["kind"] == "compare":
        return [" ".join([f"build/{c['chapter']}", c["scene"], "--size", c.get("size", "32x32"),
                          "--spp", str(c.get("spp", 1)), *c.get("args", [])])]
    if c["kind"] == "surfaces":
        return [" ".join([f"build/{c['chapter']}", c["scene"], "--patch-size", str(c.get("patch_size", 50)),
                          "--tol", str(c.get("tol", 1e-6)), *c.get("args", [])])]
    if c["kind"] == "unit":
        return [f"build/tests/{c['test']}"]
    return []


# ---- ASSIGNMENT.md ----------------------------------------------------------------------------------

def command_cell(root, c):
    commands = criterion_command(root, c)
    if commands:
        return "<br>".join(f"`{x}`" for x in commands)
    return f"`{c['test']}` in `tests/{c['module']}.py`"


def assignment_text(root, chapter, exercises, criteria, rub):
    """exercises: as parsed from the stubbed text (their lines are the handout's)."""
    lines = [f"# Assignment: {chapter}", "",
             "Write the bodies of the functions below.  In this handout each one is a stub that prints",
             "`file:line: TODO name is not implemented` once and returns zero, so the chapter builds and",
             "runs from the start (its images are black or partial until you fill them in).", "",
             "    make                       # build every chapter into build/",
             f"    build/{chapter} --help",
             "    make demo                  # render the Cornell box with every chapter",
             "    make grade                 # grade this tree: out/grade/report.html and report.json", "",
             "## What to write", "",
             "| exercise | function | where | equations |", "|---|---|---|---|"]
    for e in exercises:
        lines.append(f"| {e.id} | `{e.name}` | `{e.file}:{e.line}` | {' '.join(e.labels) or '—'} |")
    for e in exercises:
        lines += ["", f"### Exercise {e.id}: `{e.name}`", "", f"`{e.signature}` in `{e.file}:{e.line}`", ""]
        lines += ["> " + ln if ln else ">" for ln in e.comment.splitlines()]
    total = sum(c["points"] for c in criteria)
    lines += ["", f"## How it is graded ({total} points)", "",
              "Each criterion is all or nothing.  Run `make grade` to see your score before you hand in.",
              "The last column is what the criterion runs: the chapter, scene and options (build the unit",
              "tests with `make tests`; a criterion *vs reference* runs its command with many seeds).", "",
              "| criterion | points | exercises | what is checked | runs |", "|---|---|---|---|---|"]
    for c in criteria:
        lines.append(f"| {c['name']} | {c['points']} | {', '.join(c['exercises']) or '—'} | {c['what']} | "
                     f"{command_cell(root, c)} |")
    rate, how = false_failure_budget(root, rub, criteria)
    lines += ["", "Criteria marked *vs reference* compare your image with the solution's, rendered with other",
              "seeds: the mean of each tile of "
              f"{rub['tile']}x{rub['tile']} pixels and each colour channel, over {rub['batches']} renders with",
              f"different seeds, against {rub['reference_batches']} of the solution, by Welch's t-test (both",
              "variances counted) with Holm's correction over the tiles and channels.  Other criteria compare",
              "with closed forms or other methods within a Monte Carlo tolerance.  By design, the grading of",
              f"this chapter fails a correct solution with probability at most {percent(rate)}: {how}.",
              "A compile error gives 0 for the chapter; a crash, a time-out, a NaN pixel or a missing output",
              "fails the criterion with a message.",
              "Your instructor grades each criterion *vs reference* on a held-out variant (another camera, or",
              "for radiosity another patch size) whose reference this handout does not have; `make grade`",
              "here uses the public references in `kit/reference/` (kit/heldout/README.md).", ""]
    return "\n".join(lines)


# ---- README.md --------------------------------------------------------------------------------------

def student_readme(root, chosen, names, stubbed, later=()):
    with open(os.path.join(root, STUDENT_README)) as f:
        template = f.read()
    rows = []
    for chapter in chosen:
        files = sorted({e.file for e in stubbed if names[e.lecture] == chapter})
        rows.append(f"| `{chapter}` | [assignments/{chapter}/ASSIGNMENT.md](assignments/{chapter}/ASSIGNMENT.md) "
                    f"| {', '.join(f'`{x}`' for x in files)} | `make grade CHAPTERS={chapter}` |")
    others = sorted(set(names.values()) - set(chosen) - set(later))
    held_back = (f" The chapters after yours ({', '.join(f'`{c}`' for c in later)}) are stubs too, as yours are: "
                 "each comes with its own assignment later." if later else "")
    return (template.replace("{{assignments}}", "\n".join(rows))
            .replace("{{chapters}}", " ".join(chosen))
            .replace("{{first_chapter}}", chosen[0])
            .replace("{{other_chapters}}", ", ".join(f"`{c}`" for c in others) or "none")
            .replace("{{later_chapters}}", held_back))


# ---- the tree ---------------------------------------------------------------------------------------

def write_tree(out, files, stubbed):
    by_file = {}
    for e in stubbed:
        by_file.setdefault(e.file, []).append(e)
    for rel in files:
        dst = os.path.join(out, rel)
        os.makedirs(os.path.dirname(dst), exist_ok=True)
        if rel in by_file:
            with open(os.path.join(ROOT, rel)) as f:
                text = f.read()
            with open(dst, "w") as f:
                f.write(markers.stub_file(text, by_file[rel]))
        else:
            shutil.copy2(os.path.join(ROOT, rel), dst)
    if "common/todo.h" not in files:
        shutil.copy2(os.path.join(ROOT, "common", "todo.h"), os.path.join(out, "common", "todo.h"))


def stubbed_markers(tree, stubbed):
    """The stubbed exercises as the handout's text has them (its line numbers)."""
    ids = {e.id for e in stubbed}
    found = []
    for rel in sorted({e.file for e in stubbed}):
        found += [e for e in markers.parse_file(tree, rel) if e.id in ids]
    missing = ids - {e.id for e in found}
    if missing:
        raise Refused(f"the stubbed text lost the markers of {', '.join(sorted(missing))}")
    return sorted(found, key=lambda e: e.order)


def check_no_answers(tree, stubbed):
    """Refuse when a function of the handout still holds an answer of a stubbed exercise."""
    files = []
    for base, _, names in os.walk(tree):
        files += [os.path.relpath(os.path.join(base, n), tree) for n in names]
    found = markers.answers_in_tree(tree, stubbed, sorted(files))
    if found:
        lines = [f"{fn.file}:{fn.line}: {fn.name} holds the answer of exercise {ex.id} ({ex.file} {ex.name}): "
                 f"write it once, where the exercise is" for fn, ex in found]
        raise Refused("\n".join(lines))


def build(out, chosen_args):
    names = markers.chapter_names(ROOT)
    try:
        exercises = markers.all_exercises(ROOT)
        rub = rubric_module.load(ROOT)
    except ValueError as e:
        raise Refused(str(e))
    marked = sorted({names[e.lecture] for e in exercises if e.lecture in names})
    chosen = chosen_args or marked
    for c in chosen:
        if c not in names.values():
            raise Refused(f"CHAPTERS: no chapter {c} (chapters: {' '.join(sorted(names.values()))})")
        if c not in marked:
            raise Refused(f"chapters/{c}.c:1: chapter {c} has no [exercise N.M] markers")
    chosen = [c for c in names.values() if c in chosen]
    stubbed = [e for e in exercises if names.get(e.lecture) in chosen]
    # Not yet handed out: stubbed as the chosen ones are, and no answer of theirs left anywhere either.
    later = [c for c in grade.later_chapters(chosen) if c in marked]
    held_back = [e for e in exercises if names.get(e.lecture) in later]
    files = tracked_files(ROOT)

    parent = os.path.dirname(out)
    os.makedirs(parent, exist_ok=True)
    tmp = tempfile.mkdtemp(prefix=f".{os.path.basename(out)}.partial-", dir=parent)
    try:
        write_tree(tmp, files, stubbed + held_back)
        if os.path.isfile(os.path.join(ROOT, CLASSROOM_WORKFLOW[0])):  # (a copy of the tree may lack the kit's)
            os.makedirs(os.path.join(tmp, os.path.dirname(CLASSROOM_WORKFLOW[1])), exist_ok=True)
            shutil.copy2(os.path.join(ROOT, CLASSROOM_WORKFLOW[0]), os.path.join(tmp, CLASSROOM_WORKFLOW[1]))
        os.makedirs(os.path.join(tmp, "kit", "heldout"), exist_ok=True)  # the instructor's are left out: say so
        with open(os.path.join(tmp, "kit", "heldout", "README.md"), "w") as f:
            f.write(HELDOUT_README)
        check_no_answers(tmp, stubbed + held_back)
        in_handout = stubbed_markers(tmp, stubbed)
        for chapter in chosen:
            ex = [e for e in in_handout if names[e.lecture] == chapter]
            crit = [c for c in rub["criteria"] if c["chapter"] == chapter]
            os.makedirs(os.path.join(tmp, "assignments", chapter), exist_ok=True)
            with open(os.path.join(tmp, "assignments", chapter, "ASSIGNMENT.md"), "w") as f:
                f.write(assignment_text(ROOT, chapter, ex, crit, rub))
        with open(os.path.join(tmp, "README.md"), "w") as f:
            f.write(student_readme(ROOT, chosen, names, stubbed, later))
        with open(os.path.join(tmp, "kit", "handout.json"), "w") as f:
            json.dump({"chapters": chosen, "stubbed": [f"{e.id} {e.file}:{e.name}" for e in stubbed],
                       "later_chapters": later, "later_stubbed": [f"{e.id} {e.file}:{e.name}" for e in held_back]},
                      f, indent=1)
        if os.path.isdir(out):
            os.rmdir(out)  # empty (checked in main)
        os.rename(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return files, stubbed, chosen, held_back


def main(argv):
    if not argv or argv[0] in ("-h", "--help"):
        print(__doc__.strip())
        sys.exit(0 if argv else 2)
    out, chosen = os.path.abspath(argv[0]), argv[1:]
    if os.path.exists(out) and (not os.path.isdir(out) or os.listdir(out)):
        fail(f"{argv[0]}: exists and is not an empty directory")
    if out == ROOT or out.startswith(ROOT + os.sep) and not out.startswith(os.path.join(ROOT, "out") + os.sep):
        fail(f"{argv[0]}: inside the project (use a directory outside it, or under out/)")
    try:
        files, stubbed, chosen, held_back = build(out, chosen)
    except Refused as e:
        fail(str(e))
    later = f"; the {len(held_back)} of the later chapters too" if held_back else ""
    print(f"handout in {out}: {len(files)} files, {len(stubbed)} functions stubbed in {' '.join(chosen)}{later}")


if __name__ == "__main__":
    main(sys.argv[1:])
