"""Memory at class scale: a grading's memory cap (kit/grade.py --memory) holds all its programs together.

A submission whose renders touch 1.5 GiB each, two side by side, graded whole through kit/grade.py
with a 2 GiB cap: a build of chapter 1 and a compare criterion (about 40-55 s), so here and not in
`make test`, whose sandbox tests check the same cap on two sandboxes directly (and the report's
"limit" with a fork-bomb submission).  Allocates at most 2 GiB at a time (3 GiB if the cap did not
hold).
"""
import json
import os
import subprocess
import sys

import lib

RUN_ALONE = True  # 2 GiB at a time: nothing beside it
GRADE = [sys.executable, os.path.join(lib.ROOT, "kit", "grade.py")]
CHAPTER = "chapters/01_local.c"


def submission(ctx, name, constructor):
    """A submission directory: chapter 1's solution with `constructor` (C statements, given argc and
    argv) run before its main."""
    top = ctx.path(name)
    os.makedirs(os.path.join(top, "chapters"))
    with open(os.path.join(lib.ROOT, CHAPTER)) as f:
        text = f.read()
    text += ("\n#include <stdio.h>\n#include <stdlib.h>\n#include <string.h>\n#include <unistd.h>\n"
             "__attribute__((constructor)) static void memory_probe(int argc, char **argv)\n{\n" + constructor + "}\n")
    with open(os.path.join(top, CHAPTER), "w") as f:
        f.write(text)
    return top


def test_parallel_runs_of_a_submission_share_the_gradings_memory_cap(ctx):
    """A submission whose first two renders each touch 1.5 GiB, side by side (--jobs 2), graded with
    --memory 2048: stopped by the grading's cap, its criterion fails saying memory, the report
    records the limit met ("limit": "memory") and the grading's peak within the cap (the renders run in
    the grading's Session, whose cgroup is a child of the grading's)."""
    if "asan" in ctx.build:
        return
    with open(os.path.join(lib.ROOT, "kit", "rubric.json")) as f:
        rub = json.load(f)
    rub["criteria"] = [c for c in rub["criteria"] if c["name"] == "classic blinn vs reference"]
    rubric = ctx.write("rubric-blinn.json", json.dumps(rub))
    sub = submission(ctx, "memory", """
    int first_two = 0; /* the criterion's first two renders (seeds 1000 and 1001), which run side by side */
    for (int i = 1; i + 1 < argc; i++)
        first_two |= !strcmp(argv[i], "--seed") && (!strcmp(argv[i + 1], "1000") || !strcmp(argv[i + 1], "1001"));
    size_t n = first_two ? 1536UL << 20 : 0;
    volatile char *m = n ? malloc(n) : NULL; /* volatile: the stores are not optimised away */
    for (size_t j = 0; m && j < n; j += 4096)
        m[j] = 1;
    if (n)
        sleep(2), fprintf(stderr, "HELD 1.5 GiB\\n");
""")
    report_dir = ctx.path("memory-report")
    r = subprocess.run(GRADE + [sub, "--report", report_dir, "--chapters", "01_local", "--rubric", rubric,
                                "--memory", "2048", "--jobs", "2"], cwd=lib.ROOT, capture_output=True, text=True,
                       timeout=900)
    assert r.returncode == 0, f"grading: exit {r.returncode}: {r.stderr[-800:]}"
    with open(os.path.join(report_dir, "report.json")) as f:
        report = json.load(f)
    row = report["criteria"][0]
    assert not row["passed"] and row["limit"] == "memory", f"the memory cap must stop it and be recorded: {row}"
    assert "memory" in row["message"].splitlines()[0], f"the message must say memory: {row['message'][:600]!r}"
    assert report["memory"]["cap_mib"] == 2048 and report["memory"]["peak_mib"] <= 2048, report["memory"]
