"""Held-out grading data (issue 24 item 3): replaying the handout's public numbers fails.

The handout ships kit/reference/ (the solution's tile means of every compare criterion) so that a
student's `make grade` can check itself.  A submission could copy those numbers into its output
instead of rendering.  The instructor grades each compare criterion from a camera the handout does
not have (kit/heldout/, drawn by kit/grade.py --make-heldout), so such a replay passes the
student's self-check and fails the instructor's grading, while the solution passes both.
The gradings use a one-criterion rubric (chapter 1's "classic blinn vs reference": 16 renders of
16 x 16 pixels at one sample), each one build of chapter 1; they check the kit, not the C code,
so they run with the plain build only.
"""
import json
import os
import subprocess
import sys

import lib

ROOT = lib.ROOT
CRITERION = "classic blinn vs reference"
CHAPTER = "chapters/01_local.c"
sys.path.insert(0, os.path.join(ROOT, "kit"))
import compare  # noqa: E402


def criterion():
    with open(os.path.join(ROOT, "kit", "rubric.json")) as f:
        rub = json.load(f)
    return rub, next(c for c in rub["criteria"] if c["name"] == CRITERION)


def rubric_file(ctx):
    """kit/rubric.json with CRITERION's row only."""
    rub, c = criterion()
    return ctx.write("rubric.json", json.dumps(dict(rub, criteria=[c])))


def replaying_source(reference):
    """chapters/01_local.c of a student who copies numbers instead of rendering: the solution's file
    with a constructor (run before main) that, when the chapter is asked for a PFM, writes an image
    whose tiles hold the public reference's tile means (the mean over its batches, as numbers in
    the source) and exits, whatever the scene, camera or seed."""
    rows = reference["tile_means"]
    means = [sum(column) / len(column) for column in zip(*rows)]
    table = ", ".join(f"{v:.9g}f" for v in means)
    with open(os.path.join(ROOT, CHAPTER)) as f:
        solution = f.read()
    return solution + f"""
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
/* The public tile means of kit/reference/{compare.slug(criterion()[1])}.json, copied. */
static const float replayed[{len(means)}] = {{{table}}};
__attribute__((constructor)) static void replay(int argc, char **argv)
{{
    const char *out = NULL;
    int width = 0, height = 0;
    for (int i = 1; i + 1 < argc; i++) {{
        if (!strcmp(argv[i], "--out")) out = argv[i + 1];
        if (!strcmp(argv[i], "--size")) sscanf(argv[i + 1], "%dx%d", &width, &height);
    }}
    if (!out || !strstr(out, ".pfm") || width <= 0 || height <= 0) return;
    FILE *f = fopen(out, "wb");
    if (!f) exit(1);
    fprintf(f, "PF\\n%d %d\\n-1\\n", width, height);
    for (int y = height - 1; y >= 0; y--) /* PFM: bottom row first */
        for (int x = 0; x < width; x++)
            for (int ch = 0; ch < 3; ch++) {{
                int tile = (y * {reference["tiles_y"]} / height) * {reference["tiles_x"]} + x * {reference["tiles_x"]} / width;
                fwrite(&replayed[3 * tile + ch], sizeof(float), 1, f);
            }}
    fclose(f);
    exit(0);
}}
"""


def submission(ctx, name, text):
    top = ctx.path(name)
    os.makedirs(os.path.join(top, "chapters"))
    with open(os.path.join(top, CHAPTER), "w") as f:
        f.write(text)
    return top


def graded(ctx, kit_root, sub, name, *extra):
    """(passed, report row) of CRITERION for submission sub, graded by kit_root's kit/grade.py."""
    report = ctx.path("report-" + name)
    r = subprocess.run([sys.executable, os.path.join(kit_root, "kit", "grade.py"), sub, "--report", report,
                        "--chapters", "01_local", "--rubric", rubric_file(ctx), *extra], cwd=kit_root,
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, f"{name}: kit/grade.py exit {r.returncode}:\n{r.stderr[-2000:]}"
    with open(os.path.join(report, "report.json")) as f:
        row = next(c for c in json.load(f)["criteria"] if c["name"] == CRITERION)
    return row["passed"], row


def make_handout(ctx):
    out = ctx.path("handout")
    r = subprocess.run([sys.executable, os.path.join(ROOT, "kit", "handout.py"), out, "01_local"], cwd=ROOT,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, f"kit/handout.py: exit {r.returncode}:\n{r.stderr[-2000:]}"
    return out


def test_replaying_the_public_reference_fails_the_heldout_grading(ctx):
    """The replay passes the handout's self-check (its kit/grade.py, public references) and fails the
    instructor's (held-out camera); the solution passes both; the report says which was graded."""
    if "asan" in ctx.build:
        return
    rub, c = criterion()
    assert os.path.exists(compare.heldout_path(c)), \
        f"{os.path.relpath(compare.heldout_path(c), ROOT)} is missing: kit/grade.py --make-heldout"
    with open(compare.reference_path(c)) as f:
        public = json.load(f)
    handout = make_handout(ctx)
    shipped = os.listdir(os.path.join(handout, "kit", "heldout")) if os.path.isdir(
        os.path.join(handout, "kit", "heldout")) else []
    assert shipped in ([], ["README.md"]), f"the handout ships held-out data: kit/heldout/ holds {shipped}"
    replay = submission(ctx, "replay", replaying_source(public))
    with open(os.path.join(ROOT, CHAPTER)) as f:
        solution = submission(ctx, "solution", f.read())

    passed, row = graded(ctx, handout, replay, "replay-self-check", "--statistical-only")
    assert passed, f"the replay of the public numbers must pass the handout's self-check: {row['message']}"
    assert "public reference" in row.get("reference", ""), f"self-check: graded with {row.get('reference')}"
    passed, row = graded(ctx, ROOT, replay, "replay-instructor", "--statistical-only")
    assert not passed, f"the replay passed the instructor's held-out grading: {row['message']}"
    assert "held-out camera" in row.get("reference", ""), f"instructor: graded with {row.get('reference')}"
    assert "held-out camera" in row["message"], row["message"]
    shown = [m for m in row.get("measured", []) if m["quantity"] == "image mean" and m.get("expected") is not None]
    assert not shown and " vs " not in row["message"], \
        f"the held-out solution's image mean reached the report: {shown[:1] or row['message']}"

    passed, row = graded(ctx, handout, solution, "solution-self-check", "--statistical-only")
    assert passed, f"the solution fails the handout's self-check: {row['message']}"
    passed, row = graded(ctx, ROOT, solution, "solution-instructor")
    assert passed, f"the solution fails the instructor's held-out grading: {row['message']}"
    assert "held-out camera" in row["message"] and row.get("images"), (row["message"], row.get("images"))
    assert "held-out camera" in row.get("preview", {}).get("grid", ""), row.get("preview")


def test_heldout_files_are_the_instructors_only(ctx):
    """kit/heldout/ is tracked (so the instructor's grading and the Gradescope archive have it), left out of
    handouts (kit/handout.py INSTRUCTOR_ONLY) and graded instead of the public reference only where it
    matches the rubric row it was made for."""
    if "asan" in ctx.build:
        return
    tracked = subprocess.run(["git", "ls-files", "kit/heldout"], cwd=ROOT, capture_output=True, text=True).stdout
    rub = json.load(open(os.path.join(ROOT, "kit", "rubric.json")))
    expected = {f"kit/heldout/{compare.slug(c)}.json" for c in rub["criteria"] if c["kind"] in ("compare", "surfaces")}
    if os.path.isdir(os.path.join(ROOT, ".git")):
        assert expected <= set(tracked.split()), f"not tracked: {sorted(expected - set(tracked.split()))}"
    import handout
    assert "kit/heldout/" in handout.INSTRUCTOR_ONLY
    for c in rub["criteria"]:
        if c["kind"] in ("compare", "surfaces"):
            v = compare.graded_variant(c)
            assert v.get("heldout") and compare.public_criterion(v) == c, c["name"]
            assert compare.graded_variant(c, public=True) is c
    c = next(c for c in rub["criteria"] if c["kind"] == "compare")
    try:
        compare.graded_variant(dict(c, spp=c["spp"] + 1))
        raise AssertionError("a held-out file made for other options was used")
    except ValueError as e:
        assert "--make-heldout" in str(e), e


def test_the_solution_passes_every_surfaces_criterion_against_both_references(ctx):
    """Radiosity's per-surface numbers are exact up to the solver's tolerance (no Monte Carlo): the
    solution in this build must match kit/reference/ (the handout's self-check) and kit/heldout/ (the
    instructor's grading) within the rubric's surface tolerance.  A change to chapter 3's output that
    is not followed by `kit/grade.py --make-reference` fails here, not in a class's grading (the
    kernel-weighted form factors moved short_side2 by 2.3 % and the references stayed a day behind).
    Six radiosity solves, about 13 s; the compare criteria's Monte Carlo images cost too much to
    re-render here.  The kit grades plain builds: under the sanitizer build it passes without running."""
    if "asan" in ctx.build:
        return
    with open(os.path.join(ROOT, "kit", "rubric.json")) as f:
        rub = json.load(f)
    rows = [c for c in rub["criteria"] if c["kind"] == "surfaces"]
    assert rows, "kit/rubric.json has no surfaces criterion"
    for c in rows:
        for variant in (c, compare.graded_variant(c)):
            passed, _, message, _ = compare.run_surfaces(ROOT, ctx.build, variant, rub)
            which = "kit/heldout/ (the instructor's)" if variant.get("heldout") else "kit/reference/ (the handout's)"
            assert passed, f"{c['name']} against {which}: {message}  Refresh: kit/grade.py --make-reference"
