"""Tests of the instructor kit (kit/): markers, handouts, the grader and its statistics.

They build and grade copies of this tree in scratch directories (about a
minute on 2 cores), once: under the sanitizer build they pass without
running (the kit builds its own binaries, whatever BUILD is).
"""
import csv
import json
import os
import re
import shutil
import subprocess
import sys

from lib import ROOT

sys.path.insert(0, os.path.join(ROOT, "kit"))
import markers  # noqa: E402
import rubric  # noqa: E402
import stats  # noqa: E402

PY = "/usr/bin/python3"


def kit(*args, cwd=ROOT, timeout=900):
    return subprocess.run([PY, *args], cwd=cwd, capture_output=True, text=True, timeout=timeout,
                          stdin=subprocess.DEVNULL)


def make_handout(ctx, name, chapters):
    """`make handout` of these chapters into the scratch directory `name`; returns its path."""
    out = ctx.path(name)
    r = subprocess.run(["make", "--no-print-directory", "handout", f"OUT={out}", f"CHAPTERS={chapters}"], cwd=ROOT,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    return out


# The chapters whose objects a chapter links (the Makefile's model objects, chapters/local_model.h and the like).
LINKS = {"02_whitted": ["01_local"], "03c_hierarchical": ["03_radiosity"], "05_photonmap": ["04_pathtrace"],
         "06_bidirectional": ["04_pathtrace", "05_photonmap"],
         "07_metropolis": ["04_pathtrace", "05_photonmap", "06_bidirectional"]}


def check_stub_run(r, chapter, pfm, what):
    """A stubbed chapter's run `r`: exit 0, no sanitizer report, each stub it reached said
    `chapters/<file>.c:N: TODO name is not implemented` once (its own file's, or an earlier chapter's
    it links: chapter 03c's calls chapter 3's), and the image `pfm` is finite."""
    import lib
    assert r.returncode == 0 and "Sanitizer" not in r.stderr and "runtime error" not in r.stderr, \
        f"{what}: exit {r.returncode}: {r.stderr[-2000:]}"
    todo = [ln for ln in r.stderr.splitlines() if "TODO" in ln]
    own = re.compile(r"chapters/(%s|%s)\.c:\d+: TODO \w+ is not implemented$" % (chapter, "|".join(LINKS.get(chapter, []))))
    assert todo and all(own.match(ln) for ln in todo), f"{what}: {r.stderr}"
    assert len(todo) == len(set(todo)), f"{what}: a stub spoke more than once: {todo}"
    assert lib.finite_image(lib.read_pfm(pfm)), f"{what}: NaN or infinite pixels from the stubs"


def copy_tree(dst):
    files = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True).stdout.split()
    for rel in files:
        if rel.startswith(("slides/", "docs/", "tests/mutants/")):
            continue
        os.makedirs(os.path.dirname(os.path.join(dst, rel)) or dst, exist_ok=True)
        shutil.copy2(os.path.join(ROOT, rel), os.path.join(dst, rel))
    return dst


def test_markers_and_rubric_agree(ctx):
    """Every [exercise N.M] is checked by some criterion of its chapter, every exercise a criterion
    names is marked, and the markers parse into functions whose stubs have a neutral return."""
    exercises = markers.all_exercises(ROOT)
    names = markers.chapter_names(ROOT)
    rub = rubric.load(ROOT)
    marked = {e.id: e for e in exercises}
    checked = {x for c in rub["criteria"] for x in c["exercises"]}
    assert set(marked) <= checked, f"exercises no criterion checks: {sorted(set(marked) - checked)}"
    assert checked <= set(marked), f"criteria name unmarked exercises: {sorted(checked - set(marked))}"
    for c in rub["criteria"]:
        for x in c["exercises"]:
            # its own chapter's, or an earlier chapter's that it links or compares with (measured: the matrix)
            own = markers.lecture_order(markers.lecture_of(c["chapter"]))
            assert markers.lecture_order(x.split(".")[0]) <= own, f"{c['name']}: exercise {x} is of a later chapter"
    assert markers.neutral_value("static vec3") == "(vec3){0}" and markers.neutral_value("static bool") == "false"
    assert markers.neutral_value("static void") is None and markers.neutral_value("static inline double") == "0.0"
    for c in rub["criteria"]:
        if c["kind"] in ("compare", "surfaces"):
            import compare
            assert os.path.exists(compare.reference_path(c)), f"no reference for {c['name']}: --make-reference"


def test_statistics(ctx):
    """Welch's t and Holm's correction against tabled values and a computation by hand."""
    assert abs(stats.t_two_sided(2.228138852, 10) - 0.05) < 1e-8  # Student's table, 95 %, 10 df
    assert abs(stats.t_two_sided(12.7062047, 1) - 0.05) < 1e-7
    assert abs(stats.f_upper(4.9646027, 1, 10) - 0.05) < 1e-6  # F table = t^2: 2.228138852^2
    # a = 1..4, b = 2, 4, .., 10: means 2.5 and 6, variances of the means 5/12 and 2
    t, df, p, d, se = stats.welch([1, 2, 3, 4], [2, 4, 6, 8, 10])
    assert abs(se - (5 / 12 + 2) ** 0.5) < 1e-12 and abs(t + 3.5 / se) < 1e-12
    assert abs(df - (5 / 12 + 2) ** 2 / ((5 / 12) ** 2 / 3 + 4 / 4)) < 1e-9
    assert stats.holm([0.01, 0.04, 0.03]) == [0.03, 0.06, 0.06]
    assert abs(stats.t_quantile(0.05, 10) - 2.228138852) < 1e-8 and abs(stats.t_quantile(0.05, 1) - 12.7062047) < 1e-6
    assert abs(stats.f_quantile(0.05, 1, 10) - 4.9646027) < 1e-6


def test_grading_seed_shifts_every_chapter_seed(ctx):
    """lib.Context(build, seed): None and 1 leave a test's arguments alone; another grading seed
    maps an explicit --seed X to shifted_seed(X, seed), one to one (equal seeds stay equal, different
    ones different), gives a run without --seed what --seed 1 gets, and leaves --help and values that
    are no seed alone; kit/criterion.py hands its SEED to the grade criteria's Context."""
    import lib
    args = ["scenes/cornell.scene", "--spp", "4", "--seed", "11"]
    for seed in (None, 1):
        assert lib.Context(ctx.build, seed=seed).seeded(args) == args
        assert lib.Context(ctx.build, seed=seed).seeded(args[:3]) == args[:3]
    c = lib.Context(ctx.build, seed=7)
    assert c.seeded(args) == args[:4] + [str(lib.shifted_seed(11, 7))] and lib.shifted_seed(11, 7) != 11
    assert c.seeded(args[:3]) == args[:3] + ["--seed", str(lib.shifted_seed(1, 7))]
    for unchanged in (["--help"], ["x", "-h"], ["x", "--seed"], ["x", "--seed", "-1"], ["x", "--seed", str(2 ** 31)]):
        assert c.seeded(unchanged) == unchanged, unchanged
    chapter_seeds = list(range(2000)) + [2 ** 31 - 1]
    for grading_seed in (2, 3, 200, 10 ** 6):
        shifted = [lib.shifted_seed(x, grading_seed) for x in chapter_seeds]
        assert len(set(shifted)) == len(shifted) and all(0 <= x < 2 ** 31 for x in shifted)
        assert not set(shifted) & set(chapter_seeds[:200]), "grading seeds should not reuse the tests' own seeds"
    images = []
    for extra in ([], ["--seed", 1], ["--seed", 2]):
        img, stats = c.render("04_pathtrace", "scenes/cornell.scene", "--size", "8x8", "--spp", 2, "--probe-samples",
                              32, *extra, name="seeded")
        images.append(img.pixels)
        assert stats["seed"] == lib.shifted_seed(extra[1] if extra else 1, 7)
    c.close()
    assert images[0] == images[1] != images[2]
    # kit/criterion.py with SEED 5: the grade test (this kit's own, never the submission's) sees
    # Context(build, seed=5): its run without --seed gets --seed shifted_seed(1, 5).
    rub = json.load(open(os.path.join(ROOT, "kit", "rubric.json")))
    criterion = json.dumps(next(c for c in rub["criteria"] if c["name"] == "point light pixel is R1"))
    for seed in ("5", "1"):
        r = kit("kit/criterion.py", ROOT, ctx.build, criterion, seed, "1", "", timeout=120)
        result = json.loads(r.stdout[r.stdout.rfind("@@RESULT@@ ") + len("@@RESULT@@ "):])
        shifted = f"--seed {lib.shifted_seed(1, 5)}"
        assert result["passed"] and (shifted in " ".join(result["commands"])) == (seed == "5"), (seed, result)


def test_handout_builds_runs_and_grades(ctx):
    """make handout for chapter 1: the tree compiles without a warning, a stubbed chapter runs
    (exit 0, one TODO line per stub reached, black direct light), and make grade in it grades it."""
    if "asan" in ctx.build:
        return
    out = make_handout(ctx, "handout", "01_local")
    assert os.path.exists(os.path.join(out, "assignments", "01_local", "ASSIGNMENT.md"))
    assert not os.path.exists(os.path.join(out, "tests", "mutants")) and not os.path.exists(
        os.path.join(out, "kit", "handout.py"))
    with open(os.path.join(out, "chapters", "01_local.c")) as f:
        assert 'TODO_ONCE("area_light")' in f.read()
    r = subprocess.run(["make", "-j2", "build/01_local", "build/02_whitted"], cwd=out, capture_output=True,
                       text=True, timeout=600)
    assert r.returncode == 0 and "warning" not in r.stderr, r.stderr[-3000:]
    pfm = ctx.path("stub.pfm")
    r = subprocess.run([os.path.join(out, "build", "01_local"), "scenes/cornell.scene", "--quiet", "--size", "8x8",
                        "--bounces", "1:1", "--out", pfm], cwd=out, capture_output=True, text=True, timeout=60)
    check_stub_run(r, "01_local", pfm, "01_local --bounces 1:1")
    import lib
    assert all(p == (0.0, 0.0, 0.0) for p in lib.read_pfm(pfm).pixels), "the stubbed direct light is not black"
    r = subprocess.run(["make", "--no-print-directory", "grade"], cwd=out, capture_output=True, text=True,
                       timeout=900)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    report = lib.read_json(os.path.join(out, "out", "grade", "report.json"))
    assert report["chapters"] == ["01_local"] and report["max"] == 100 and report["total"] < 50, report["total"]
    assert os.path.exists(os.path.join(out, "out", "grade", "report.html"))


def test_handout_of_chapter_5_stubs_run_and_say_so(ctx):
    """make handout for chapter 5: ASSIGNMENT.md lists its marked functions with their equations and
    the chapter's criteria with their points; the stubbed chapter compiles without a warning and runs
    with every --maps choice and final gathering (exit 0, finite pixels), each stub it reaches saying
    TODO once."""
    if "asan" in ctx.build:
        return
    out = make_handout(ctx, "handout5", "05_photonmap")
    with open(os.path.join(out, "assignments", "05_photonmap", "ASSIGNMENT.md")) as f:
        text = f.read()
    marked = [e for e in markers.all_exercises(ROOT) if e.lecture == "5"]
    assert len(marked) >= 5, [e.id for e in marked]
    for e in marked:
        assert f"| {e.id} | `{e.name}` |" in text, f"exercise {e.id} {e.name} not in ASSIGNMENT.md"
    assert "(R11)" in text and "(R12)" in text, "the assignment cites no equation of the lecture"
    criteria = [c for c in rubric.load(ROOT)["criteria"] if c["chapter"] == "05_photonmap"]
    assert criteria and all(f"| {c['name']} | {c['points']} |" in text for c in criteria)
    with open(os.path.join(out, "chapters", "05_photonmap.c")) as f:
        source = f.read()
    assert all(f'TODO_ONCE("{e.name}")' in source for e in marked)
    r = subprocess.run(["make", "-j2", "build/05_photonmap"], cwd=out, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0 and "warning" not in r.stderr, r.stderr[-3000:]
    for maps in ("global", "caustic", "both"):
        pfm = ctx.path(f"stub5-{maps}.pfm")
        r = subprocess.run([os.path.join(out, "build", "05_photonmap"), "scenes/cornell-spheres.scene", "--quiet",
                            "--size", "8x8", "--spp", "3", "--photons", "2000", "--maps", maps, "--gather", "2",
                            "--probe-photons", "32", "--out", pfm], cwd=out, capture_output=True, text=True,
                           timeout=60)
        check_stub_run(r, "05_photonmap", pfm, f"--maps {maps}")


def test_handout_stubs_run_every_method_under_the_sanitizers(ctx):
    """make handout for chapters 2-4, 03c, 6 and 7 (1 and 5 have their own tests above), built with
    AddressSanitizer and UndefinedBehaviorSanitizer (SANITIZE=1): every method of each chapter
    runs on the spheres or the Cornell box with its stubs (exit 0, finite pixels, no sanitizer
    report), and each stub it reaches says TODO once.  A stub returns zero: this checks that the
    chapters survive the zeros (a stub does not write its pointer outputs)."""
    if "asan" in ctx.build:
        return
    out = make_handout(ctx, "handout234", "02_whitted 03_radiosity 03c_hierarchical 04_pathtrace 06_bidirectional "
                       "07_metropolis")
    r = subprocess.run(["make", "-j2", "--no-print-directory", "all", "BUILD=build/asan", "SANITIZE=1"], cwd=out,
                       capture_output=True, text=True, timeout=900)
    assert r.returncode == 0 and "warning" not in r.stderr, r.stderr[-3000:]
    spheres, box = "scenes/cornell-spheres.scene", "scenes/cornell.scene"
    runs = [("02_whitted", spheres, [])]
    runs += [("03_radiosity", box, ["--solver", s, "--patch-size", 150])
             for s in ("jacobi", "gauss-seidel", "shooting", "direct")]
    runs += [("03c_hierarchical", box, [])]
    runs += [("04_pathtrace", spheres, ["--spp", 4, "--estimator", e]) for e in ("hemisphere", "cosine", "light", "mis")]
    runs += [("06_bidirectional", spheres, ["--spp", 2, "--method", m]) for m in ("light", "bdpt", "vcm")]
    runs += [("07_metropolis", spheres, ["--spp", 2, "--method", m, "--bootstrap", 4096, "--chains", 64])
             for m in ("pssmlt", "mmlt")]
    for chapter, scene, args in runs:
        pfm = ctx.path("stub.pfm")
        r = subprocess.run([os.path.join(out, "build", "asan", chapter), scene, "--quiet", "--size", "12x12",
                            *map(str, args), "--out", pfm], cwd=out, capture_output=True, text=True, timeout=300)
        check_stub_run(r, chapter, pfm, f"{chapter} {' '.join(map(str, args))}")


def test_solution_scores_full_marks_on_chapter_1(ctx):
    if "asan" in ctx.build:
        return
    r = kit("kit/grade.py", ".", "--chapters", "01_local", "--report", ctx.path("report"))
    assert r.returncode == 0, r.stderr
    report = json.load(open(ctx.path("report/report.json")))
    failed = [c["name"] + ": " + c["message"] for c in report["criteria"] if not c["passed"]]
    assert report["total"] == report["max"] == 100 and not failed, failed
    assert any(c["p_value"] is not None for c in report["criteria"]), "no statistical criterion reported a p-value"
    for c in report["criteria"]:
        for name in c.get("images", {}).values():
            with open(ctx.path("report/" + name), "rb") as f:
                assert f.read(8) == b"\x89PNG\r\n\x1a\n"


def test_broken_submissions_are_reported_not_fatal(ctx):
    """Chapter 1 segfaults in area_light, chapter 4 does not compile, chapter 2 is missing:
    grading still ends with exit 0 and a report that says why each criterion failed."""
    if "asan" in ctx.build:
        return
    sub = copy_tree(ctx.path("broken"))
    path = os.path.join(sub, "chapters", "01_local.c")
    text = open(path).read()
    text = text.replace("const surface *emitter = &s->surfaces[emitter_surface];",
                        "const surface *emitter = &s->surfaces[emitter_surface];\n"
                        "    if (samples > 0) *(volatile int *)0 = 0;", 1)
    open(path, "w").write(text)
    with open(os.path.join(sub, "chapters", "04_pathtrace.c"), "a") as f:
        f.write("\nthis is not C;\n")
    os.remove(os.path.join(sub, "chapters", "02_whitted.c"))
    r = kit("kit/grade.py", sub, "--chapters", "01_local 02_whitted 04_pathtrace", "--report", ctx.path("r"),
            "--timeout", "120")
    assert r.returncode == 0, r.stderr
    report = json.load(open(ctx.path("r/report.json")))
    by = {}
    for c in report["criteria"]:
        by.setdefault(c["chapter"], []).append(c)
    assert all(not c["passed"] and "does not compile" in c["message"] for c in by["04_pathtrace"])
    assert "error" in report["build_errors"]["04_pathtrace"], report["build_errors"]
    assert all(not c["passed"] and "not in the submission" in c["message"] for c in by["02_whitted"])
    area = [c for c in by["01_local"] if c["name"] == "cornell area light vs reference"][0]
    assert not area["passed"] and ("SIGSEGV" in area["message"] or "exit status" in area["message"]), area
    assert any(c["passed"] for c in by["01_local"]), "criteria without area lights should still pass"


def test_bad_arguments_exit_2(ctx):
    for args in (["kit/grade.py", ctx.path("no-such-dir")], ["kit/grade.py", os.path.join(ROOT, "README.md")],
                 ["kit/grade.py", ".", "--chapters", "99_nothing"], ["kit/grade.py", ".", "--seed", "x"],
                 ["kit/grade.py"], ["kit/handout.py", ctx.path("h"), "99_nothing"],
                 ["kit/grade_class.py"], ["kit/grade_class.py", ".", "--retries", "0"],
                 ["kit/grade_class.py", ".", "--remote-root", "/x"],
                 ["kit/grade_class.py", ".", "--sshloginfile", ctx.path("none")]):
        r = kit(*args, timeout=60)
        assert r.returncode == 2 and r.stderr.strip() and "Traceback" not in r.stderr, (args, r.returncode, r.stderr)


def test_class_grading_quotes_chapters_paths_and_uses_sshlogins(ctx):
    """kit/grade_class.py through GNU parallel: two chapters in one --chapters word, a student
    directory with a space, one that does not exist (a row "not graded", the others stand), and
    an --sshloginfile (":" is GNU parallel's name for this machine, so no ssh server is needed)."""
    if "asan" in ctx.build:
        return
    empty = ctx.path("a student")
    os.makedirs(empty)
    logins = ctx.write("logins", "2/:\n")
    r = kit("kit/grade_class.py", ".", empty, ctx.path("gone"), "--report", ctx.path("class"),
            "--sshloginfile", logins, "--chapters", "01_local 02_whitted")
    assert r.returncode == 0, r.stderr
    with open(ctx.path("class/summary.csv")) as f:
        rows = {row["student"]: row for row in csv.DictReader(f)}
    solution, student, gone = rows[os.path.basename(ROOT)], rows["a student"], rows["gone"]
    assert solution["status"] == "graded" and solution["01_local"] == "100" and solution["02_whitted"] == "100", rows
    assert student["status"] == "graded" and student["total"] == "0", student
    assert gone["status"] == f"not graded: {ctx.path('gone')}: missing", gone


def test_class_summary_plots_limits_and_retries(ctx):
    """kit/grade_class.py's summary on reports made by hand (no grading): the histogram's bars hold the
    totals (one bar per tenth of the maximum, heights proportional), the criteria's bars their pass
    counts, the slowest gradings, the submissions that hit a limit, the machine that graded each and
    the retried ones (an attempt lost on one machine, the report from another); a student without a
    report is "not graded" with the engine's exit status."""
    import grade_class
    report = ctx.path("class")
    totals = {"a": 0, "b": 10, "c": 10, "d": 45, "e": 44, "f": 45, "g": 5}
    table = []
    for k, (name, total) in enumerate(sorted(totals.items())):
        criteria = [{"chapter": "01_local", "name": "first", "points": 10 if total >= 10 else 0, "max": 10,
                     "passed": total >= 10, "p_value": None, "message": "ok" if total >= 10 else "wrong"},
                    {"chapter": "01_local", "name": "second", "points": total - (10 if total >= 10 else 0), "max": 35,
                     "passed": total == 45, "p_value": None,
                     "message": "ok" if total == 45 else "stopped by the grader's sandbox: the sandbox's memory cap "
                     "of 1024 MiB" if name == "g" else "timed out after 40 s (its programs killed)" if name == "a"
                     else "off"}]
        os.makedirs(os.path.join(report, name))
        with open(os.path.join(report, name, "report.json"), "w") as f:
            json.dump({"total": total, "max": 45, "criteria": criteria, "seed": 1, "date": "2026-01-01",
                       "submission_sha256": "0" * 64, "seconds": 10 + k}, f)
        os.makedirs(os.path.join(report, ".attempts", name))
        records = [{"host": "h2", "started": 5, "ended": 9, "exit": 0, "placed": True}]
        if name == "c":  # lost with its machine h1, graded by h2
            records.insert(0, {"host": "h1", "started": 1, "ended": None, "exit": None, "placed": False})
        for i, rec in enumerate(records):
            with open(os.path.join(report, ".attempts", name, f"{rec['host']}-{i}.json"), "w") as f:
                json.dump(rec, f)
        table.append((ctx.path(name), name))
    table.append((ctx.path("z"), "z"))  # no report: its grading failed
    rows = {r["student"]: r for r in grade_class.summarize(report, table, {"z": {"exit": "255", "seconds": "3",
                                                                                  "host": "h1"}})}
    assert rows["c"]["attempts"] == ["h1", "h2"] and rows["c"]["host"] == "h2" and rows["c"]["lost"] == 1
    assert rows["z"]["status"] == "not graded (exit status 255; see z.log)", rows["z"]
    assert rows["a"]["limits"] == [("second", "time")] and rows["g"]["limits"] == [("second", "memory")]
    assert not rows["d"]["limits"]
    with open(os.path.join(report, "scores.svg")) as f:
        bars = re.findall(r"data-count='(\d+)' x='[^']*' y='[^']*' width='[^']*' height='([^']*)'", f.read())
    # bins of 4.5 points: 0 in the first, 5 in the second, 10 and 10 in the third, 44, 45, 45 in the last
    assert [int(c) for c, _ in bars] == [1, 1, 2, 0, 0, 0, 0, 0, 0, 3], bars
    heights = [float(h) for _, h in bars]
    assert heights[9] == max(heights) and abs(heights[2] - 2 * heights[0]) < 0.02 and heights[3] == 0, heights
    with open(os.path.join(report, "criteria.svg")) as f:
        rates = re.findall(r"data-passed='(\d+)' data-graded='(\d+)'", f.read())
    assert rates == [("5", "7"), ("2", "7")], rates
    with open(os.path.join(report, "summary.csv")) as f:
        csv_rows = {row["student"]: row for row in csv.DictReader(f)}
    assert csv_rows["c"]["attempts"] == "h1+h2" and csv_rows["g"]["limits"] == "second: memory"
    with open(os.path.join(report, "summary.html")) as f:
        page = f.read()
    assert "<td>c</td><td>h1 + h2</td><td>1</td><td>h2</td>" in page, "the retried grading is not listed"
    slowest = page.split("Slowest gradings")[1].split("</table>")[0]
    assert re.findall(r"<tr><td>(\w)</td>", slowest) == ["g", "f", "e", "d", "c"], slowest
    assert "<img src='scores.svg'" in page and "<img src='criteria.svg'" in page
    # a class graded again into the same directory replaces its reports, never a submission kept there
    inside = ctx.path("class/h")
    os.makedirs(os.path.join(inside, "chapters"))
    r = kit("kit/grade_class.py", "--report", report, inside, timeout=60)
    assert r.returncode == 2 and "is a submission" in r.stderr and os.path.isdir(inside), r.stderr
    # a grading that fails (here: a rubric that is not there, so grade.py stops at once) is not a
    # verdict: GNU parallel's --resume-failed pass tries it once more, and the summary says so
    r = kit("kit/grade_class.py", "--report", ctx.path("failing"), "--jobs", "1", "--rubric", ctx.path("none.json"),
            ctx.path("class/h"), timeout=120)
    assert r.returncode == 0, r.stderr
    with open(ctx.path("failing/summary.csv")) as f:
        row = next(csv.DictReader(f))
    assert row["status"] == "not graded (exit status 2; see h.log)" and len(row["attempts"].split("+")) == 2, row


def test_the_kit_leaves_no_temporary_files(ctx):
    """A compare criterion's renders, its preview and a surfaces criterion's run are read into memory and
    their temporary directories removed: a calibration of 60 seeds once left 1,000 directories of
    PFMs in /tmp.  (A grading's own temporaries are inside its scratch: grade_sandbox's leftovers.)"""
    import tempfile
    import compare
    rub = rubric.load(ROOT)
    pick = {c["name"]: c for c in rub["criteria"]}
    os.makedirs(ctx.path("tmp"))
    before, tempfile.tempdir = tempfile.tempdir, ctx.path("tmp")
    try:
        images = compare.batch_renders(ROOT, ctx.build, pick["classic blinn vs reference"], [1, 2], 2)
        assert len(images) == 2 and images[0][:2] == (16, 16)
        w, h, _ = compare.render_preview(ROOT, ctx.build, pick["classic blinn vs reference"], 1)
        surfaces = compare.surfaces_of(ROOT, ctx.build, pick["jacobi surfaces vs reference"])
        assert w * h > 0 and surfaces
        left = os.listdir(tempfile.tempdir)
    finally:
        tempfile.tempdir = before
    assert not left, f"the kit left {left} in the temporary directory"


def test_the_last_pass_leaves_out_machines_that_do_not_answer(ctx):
    """kit/grade_class.py reachable_logins: the login file of the last pass keeps this machine (":"),
    the machines whose `SSH MACHINE true` succeeds and the lines it cannot read as one machine, and
    drops those whose ssh fails; None when no machine answers.  (Over real sshd hosts, one of them
    lost: tests/cluster_ssh.py, make test-cluster.)"""
    sys.path.insert(0, os.path.join(ROOT, "kit"))
    import grade_class
    fake_ssh = ctx.write("ssh", "#!/bin/sh\ncase \"$1\" in up*) exit 0;; *) exit 255;; esac\n")
    os.chmod(fake_ssh, 0o755)
    logins = ctx.write("logins", "# the class's machines\n2/:\n1/up-host\n1/lost-host\n\n"
                                 "4/ssh -p 2222 someone@elsewhere\nroot@up2\n")
    kept = grade_class.reachable_logins(logins, fake_ssh, ctx.path("kept"))
    with open(kept) as f:
        text = f.read()
    assert text == "2/:\n1/up-host\n4/ssh -p 2222 someone@elsewhere\n", text
    only_lost = ctx.write("lost", "1/lost-host\nlost-too\n")
    assert grade_class.reachable_logins(only_lost, fake_ssh, ctx.path("none")) is None
    assert not os.path.exists(ctx.path("none"))
