"""The rubric's exercise lists are measured, not written by hand (kit/exercise-matrix.json).

kit/calibrate.py exercises stubs each exercise alone in the solution and records which criteria
then fail; kit/rubric.json's "exercises" lists must be exactly those (a student whose criterion
fails is sent to the exercises that can make it fail).  So that the matrix cannot go stale
unnoticed, each run re-measures one exercise (chosen by the commit, so successive commits walk
through all of them) and compares it with the file.  A rubric row naming an exercise or a test
that does not exist makes the kit refuse to grade.

Times (2 cores): the agreement test under a second, the bad-rubric one a few seconds; the
re-measurement under a minute: copying and rebuilding what the stub changes, then as many of
the criteria the stub reaches as fit in BUDGET_S by the times the matrix recorded (all of them for
most exercises; an exercise of chapter 4 reaches chapter 5's criteria too, and successive commits
take turns through them).  Under the sanitizer build it passes without running.
"""
import hashlib
import json
import os
import shutil
import subprocess
import sys

from lib import ROOT

sys.path.insert(0, os.path.join(ROOT, "kit"))
import calibrate  # noqa: E402
import markers  # noqa: E402
import rubric  # noqa: E402

PY = "/usr/bin/python3"
REMEASURE = "kit/calibrate.py exercises --only {} (then kit/calibrate.py sync-rubric)"


def measured_matrix():
    matrix = rubric.load_matrix(ROOT)
    assert matrix is not None, "no kit/exercise-matrix.json: run kit/calibrate.py exercises"
    return matrix


def test_rubric_lists_are_the_measured_matrix(ctx):
    """kit/rubric.json's exercise lists equal the matrix's, the matrix covers exactly the exercises
    marked in the tree, and it says which criteria no single stub fails."""
    matrix = measured_matrix()
    differ = calibrate.rubric_disagreements(rubric.load(ROOT), matrix)
    assert not differ, "the rubric's exercise lists are not the measured ones " \
                       "(kit/calibrate.py sync-rubric):\n" + "\n".join(differ)
    marked = [e.id for e in markers.all_exercises(ROOT)]
    new = [x for x in marked if x not in matrix["measured"]]
    gone = [x for x in matrix["measured"] if x not in marked]
    assert not new, f"exercises marked but never measured: {new}: " + REMEASURE.format(" ".join(new))
    assert not gone, f"the matrix measured exercises no longer marked: {gone}: kit/calibrate.py exercises"
    rows = matrix["criteria"]
    assert matrix["no_single_stub_fails"] == [rubric.key(r) for r in rows if not r["exercises"]]
    assert not matrix["solution_fails"], f"the solution failed when the matrix was measured: " \
                                         f"{matrix['solution_fails']}"
    for key in ("date", "commit", "seed"):
        assert matrix.get(key), f"kit/exercise-matrix.json has no {key}"


# Seconds of grading per run, by the times the matrix recorded for the stub: half the exercises reach more than
# 60 s of criteria, which successive commits take turns through, so a smaller share per run only makes the walk
# longer (30 s, not 60: make test's budget).
BUDGET_S = 30


def turn_of_the_commit():
    """(a number from HEAD's hash, HEAD's short hash): each commit takes another turn."""
    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    return int(hashlib.sha256(head.encode()).hexdigest(), 16), head[:10]


def within_budget(keys, seconds, turn):
    """The criteria of `keys` to grade this run: starting at a place the commit chooses, in rubric
    order and round, as many as fit in BUDGET_S (at least one); all of them when they fit.  An
    exercise of chapter 4 reaches chapter 5's criteria too (minutes in all): over successive
    commits every one is graded."""
    if not keys:
        return []
    start = turn % len(keys)
    chosen, used = [], 0.0
    for key in keys[start:] + keys[:start]:
        cost = seconds.get(key, 30.0)
        if chosen and used + cost > BUDGET_S:
            continue
        chosen.append(key)
        used += cost
    return chosen


def test_one_exercise_remeasured_agrees_with_the_matrix(ctx):
    """Stub one exercise (this commit's turn) in a copy of the tree and grade the criteria that run
    what it changes: the criteria that fail are the ones the matrix lists for it."""
    if "asan" in ctx.build:
        return
    matrix = measured_matrix()
    exercises = markers.all_exercises(ROOT)
    turn, head = turn_of_the_commit()
    ex = exercises[turn % len(exercises)]
    print(f"\n     re-measuring exercise {ex.id} ({ex.file}: {ex.name}), the turn of commit {head}", flush=True)
    assert ex.id in matrix["exercises"], f"exercise {ex.id} was never measured: " + REMEASURE.format(ex.id)
    stub_seconds = matrix["exercises"][ex.id].get("criterion_seconds", {})
    rub = rubric.load(ROOT)
    rows = {rubric.key(r): r for r in matrix["criteria"]}
    # rows added since the matrix was measured: test_rubric_lists_are_the_measured_matrix says so
    rub = dict(rub, criteria=[c for c in rub["criteria"] if rubric.key(c) in rows])
    opts = {"seed": matrix["seed"], "jobs": 2, "timeout": 300.0, "memory": 4096, "unsafe": True}  # our own code
    work = ctx.path("exercises")
    base, chapters, units = calibrate.prepare_base(work, rub, opts, build_from=os.path.join(ROOT, ctx.build))
    targets = calibrate.target_names(chapters, units)
    programs = [t for t in targets if "/tests/" not in t]
    programs_of = {k: calibrate.criterion_programs(c, rows[k]["commands"], programs)
                   for c in rub["criteria"] for k in [rubric.key(c)]}
    timeouts = {k: min(300.0, max(60.0, 5 * r["seconds"])) for k, r in rows.items()}
    reached = []

    def choose(keys):
        reached.extend(keys)
        return within_budget(keys, stub_seconds, turn // len(exercises))

    got = calibrate.measure_exercise(base, work, ex, rub, programs_of, targets, opts, timeouts, log=lambda s: None,
                                     choose=choose)
    shutil.rmtree(work, ignore_errors=True)
    measured_then = set(matrix["exercises"][ex.id]["ran"])
    assert set(reached) == measured_then, (
        f"exercise {ex.id}'s stub now reaches other criteria than when measured: new "
        f"{sorted(set(reached) - measured_then)}, gone {sorted(measured_then - set(reached))}: "
        + REMEASURE.format(ex.id))
    expected = sorted(k for k in got["ran"] if ex.id in rows[k]["exercises"])
    now = sorted(got["failed"])
    assert now == expected, (
        f"exercise {ex.id} ({ex.name}): of the {len(got['ran'])} criteria graded, its stub alone now fails "
        f"{len(now)}, the matrix says {len(expected)}.\n  newly failing: "
        f"{[k + ': ' + got['messages'][k] for k in now if k not in expected]}"
        f"\n  no longer failing: {[k for k in expected if k not in now]}\n  re-measure: " + REMEASURE.format(ex.id))
    print(f"     exercise {ex.id}: graded {len(got['ran'])} of the {len(reached)} criteria it reaches "
          f"({', '.join(got['ran'])}); {len(now)} fail, as measured ({got['seconds']:.0f} s)", flush=True)


def copy_kit_tree(dst):
    """The tracked files the kit needs to start grading (not slides/, docs/)."""
    files = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True).stdout.split()
    for rel in files:
        if rel.startswith(("slides/", "docs/", "tests/mutants/")) or not os.path.isfile(os.path.join(ROOT, rel)):
            continue
        os.makedirs(os.path.dirname(os.path.join(dst, rel)) or dst, exist_ok=True)
        shutil.copy2(os.path.join(ROOT, rel), os.path.join(dst, rel))
    return dst


def test_rubric_row_naming_unknown_exercise_or_test_refuses_to_grade(ctx):
    """A row naming an exercise not marked in the tree, a test module or function that does not
    exist, or a missing unit test: kit/grade.py and kit/handout.py exit 2 naming the row, and
    nothing is graded or written."""
    tree = copy_kit_tree(ctx.path("tree"))
    path = os.path.join(tree, "kit", "rubric.json")
    with open(path) as f:
        good = json.load(f)
    first_grade = next(i for i, c in enumerate(good["criteria"]) if c["kind"] == "grade")
    first_unit = next(i for i, c in enumerate(good["criteria"]) if c["kind"] == "unit")
    cases = [(first_grade, "exercises", ["1.1", "9.9"], "exercise 9.9 is not marked"),
             (first_grade, "module", "grade_nothing", "tests/grade_nothing.py does not exist"),
             (first_grade, "test", "test_nothing", "has no function test_nothing"),
             (first_unit, "test", "test_nothing", "tests/test_nothing.c does not exist")]
    for index, field, value, says in cases:
        bad = json.loads(json.dumps(good))
        bad["criteria"][index][field] = value
        with open(path, "w") as f:
            json.dump(bad, f, indent=1)
        row = f"kit/rubric.json: criterion {index + 1} '{bad['criteria'][index]['name']}'"
        report = ctx.path(f"report-{field}")
        for args in (["kit/grade.py", tree, "--chapters", bad["criteria"][index]["chapter"], "--report", report],
                     ["kit/handout.py", ctx.path(f"handout-{field}")]):
            r = subprocess.run([PY, *args], cwd=tree, capture_output=True, text=True, timeout=60,
                               stdin=subprocess.DEVNULL)
            assert r.returncode == 2 and row in r.stderr and says in r.stderr and "Traceback" not in r.stderr, \
                f"{field} = {value!r}: {args[0]} exit {r.returncode}: {r.stderr.strip()}"
        assert not os.path.exists(os.path.join(report, "report.json")), "a report was written"
        assert not os.path.exists(ctx.path(f"handout-{field}")), "a handout was written"
    with open(path, "w") as f:
        json.dump(good, f, indent=1)
    assert rubric.load(tree)["criteria"] == good["criteria"]
