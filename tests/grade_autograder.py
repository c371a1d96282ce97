"""Tests of the platforms' glue (kit/autograder/): the Gradescope archive and the GitHub Classroom
self-check a handout carries.

The Gradescope test builds the archive with `make autograder`, unpacks it into a fake /autograder
in a scratch directory (AUTOGRADER_ROOT), runs setup.sh --dry-run (no apt-get) and run_autograder
on a chapter-1 handout with exercise 1.2 solved, and checks results.json against every field of
Gradescope's "Autograder Specifications" (gradescope-autograders.readthedocs.io/en/latest/specs/).
About 90 s on 2 cores (two gradings of chapter 1); under the sanitizer build they pass without
running (the kit builds its own binaries, whatever BUILD is).  The refusal where no sandbox starts is
checked here cheaply (setpriv drops CAP_SETUID); tests/cluster_gradescope.py runs the archive in a
Debian 12 root and in Docker, and the Classroom workflow's steps (make test-cluster).
"""
import json
import math
import os
import shutil
import stat
import subprocess
import sys
import tempfile
import zipfile

from lib import ROOT

sys.path.insert(0, os.path.join(ROOT, "kit"))
import markers  # noqa: E402
import rubric  # noqa: E402
from grade_handout import later_chapters_given_away  # noqa: E402

# The archive test checks that its runs leave no gi-autograder-* directory in /tmp, so no other
# grading may be under way beside it (tests/run.py -j).
RUN_ALONE = {"test_gradescope_archive_grades_a_submission_into_results_json"}

# What Gradescope's specification allows (results.json).
TOP_LEVEL = {"score": "number", "execution_time": "int", "output": "str", "output_format": "format",
             "test_output_format": "format", "test_name_format": "format", "visibility": "visibility",
             "stdout_visibility": "visibility", "extra_data": "dict", "tests": "list", "leaderboard": "list"}
PER_TEST = {"score": "number", "max_score": "number", "status": "status", "name": "str", "name_format": "format",
            "number": "str", "output": "str", "output_format": "format", "tags": "tags", "visibility": "visibility",
            "extra_data": "dict"}
VISIBILITIES = ("visible", "hidden", "after_due_date", "after_published")
FORMATS = ("text", "html", "simple_format", "md", "ansi")
SANDBOX_UID = 65534


def make(*args, cwd=ROOT, timeout=300):
    return subprocess.run(["make", "--no-print-directory", *args], cwd=cwd, capture_output=True, text=True,
                          timeout=timeout, stdin=subprocess.DEVNULL)


def build_packages():
    """The Makefile's BUILD_PACKAGES, as make expands it."""
    r = make("-s", "--eval", "print-build-packages: ; @echo $(BUILD_PACKAGES)", "print-build-packages")
    assert r.returncode == 0 and r.stdout.split(), r.stderr
    return r.stdout.split()


def chapter_1_autograder(ctx):
    """make autograder for chapter 1, unpacked into a fake /autograder root (returned)."""
    archive = ctx.path("autograder.zip")
    r = make("autograder", f"OUT={archive}", "CHAPTERS=01_local")
    assert r.returncode == 0, r.stderr
    root = ctx.path("autograder")
    unpack(archive, root)
    return root


def unpack(archive, root):
    """The archive into ROOT/source as Gradescope does (modes kept), run_autograder copied to ROOT."""
    source = os.path.join(root, "source")
    with zipfile.ZipFile(archive) as z:
        for info in z.infolist():
            path = z.extract(info, source)
            mode = info.external_attr >> 16
            if mode:
                os.chmod(path, stat.S_IMODE(mode))
    shutil.copy2(os.path.join(source, "run_autograder"), os.path.join(root, "run_autograder"))
    return source


def solve(tree, rel, name):
    """Put the solution's body of exercise `name` into the handout's stub."""
    solution = {e.name: e for e in markers.parse_file(ROOT, rel)}[name]
    stub = {e.name: e for e in markers.parse_file(tree, rel)}[name]
    with open(os.path.join(tree, rel)) as f:
        text = f.read()
    with open(os.path.join(tree, rel), "w") as f:
        f.write(text[:stub.body_start] + solution.body + text[stub.body_end:])


def run_autograder(root):
    env = dict(os.environ, AUTOGRADER_ROOT=root)
    return subprocess.run([os.path.join(root, "run_autograder")], cwd=root, env=env, capture_output=True,
                          text=True, timeout=1800, stdin=subprocess.DEVNULL)


def of_kind(value, kind):
    number = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    return {"number": number, "int": isinstance(value, int) and not isinstance(value, bool) and value >= 0,
            "str": isinstance(value, str), "dict": isinstance(value, dict), "list": isinstance(value, list),
            "format": value in FORMATS, "visibility": value in VISIBILITIES, "status": value in ("passed", "failed"),
            "tags": isinstance(value, list) and all(isinstance(t, str) for t in value)}[kind]


def check_results(path, criteria):
    """results.json against Gradescope's fields, and its tests against the rubric's rows `criteria`
    (names, order, points).  Returns the parsed results."""
    with open(path) as f:
        results = json.load(f)
    problems = [f"top level {k}: not Gradescope's" for k in results if k not in TOP_LEVEL]
    problems += [f"top level {k} = {v!r}: not a {TOP_LEVEL[k]}" for k, v in results.items()
                 if k in TOP_LEVEL and not of_kind(v, TOP_LEVEL[k])]
    for k in ("score", "execution_time", "output", "visibility", "stdout_visibility", "tests"):
        if k not in results:
            problems.append(f"no top-level {k}")
    tests = results.get("tests", [])
    for i, t in enumerate(tests):
        problems += [f"test {i} {k}: not Gradescope's" for k in t if k not in PER_TEST]
        problems += [f"test {i} {k} = {v!r}: not a {PER_TEST[k]}" for k, v in t.items()
                     if k in PER_TEST and not of_kind(v, PER_TEST[k])]
        for k in ("name", "score", "max_score", "output", "visibility", "status"):
            if k not in t:
                problems.append(f"test {i}: no {k}")
        if not problems and not 0 <= t["score"] <= t["max_score"]:
            problems.append(f"test {t['name']}: score {t['score']} outside 0..{t['max_score']}")
        if not problems and (t["status"] == "passed") != (t["score"] == t["max_score"] > 0):
            problems.append(f"test {t['name']}: status {t['status']} with {t['score']} / {t['max_score']}")
    assert not problems, "\n".join(problems)
    names = [t["name"] for t in tests]
    numbers = [t["number"] for t in tests if "number" in t]
    assert len(set(names)) == len(names) and len(set(numbers)) == len(numbers), "test names or numbers repeat"
    assert names == [f"{c['chapter']}: {c['name']}" for c in criteria], "the tests are not the rubric's criteria"
    assert [t["max_score"] for t in tests] == [c["points"] for c in criteria], "max_score is not the rubric's"
    assert results["score"] == sum(t["score"] for t in tests), "score is not the sum of the tests' scores"
    return results


def test_gradescope_archive_grades_a_submission_into_results_json(ctx):
    """make autograder for chapter 1: the zip has setup.sh and run_autograder at its top, the kit,
    and outside kit/ the chapter-1 handout, byte for byte (no solution the students lack); run_autograder in a fake /autograder grades a handout with exercise 1.2
    solved (zipped as a folder) into a results.json with every Gradescope field right, the
    rubric's names and points, exercise 1.2's criteria passed and the others failed; a forged
    results.json placed before is gone; results/ is root's and uid 65534 cannot write there."""
    if "asan" in ctx.build:
        return
    archive = ctx.path("autograder.zip")
    r = make("autograder", f"OUT={archive}", "CHAPTERS=01_local")
    assert r.returncode == 0, r.stderr
    with zipfile.ZipFile(archive) as z:
        infos = {i.filename: i for i in z.infolist()}
    for script in ("setup.sh", "run_autograder"):
        assert script in infos and (infos[script].external_attr >> 16) & 0o111, f"{script}: not at the top or not executable"
    for needed in ("autograder.json", "Makefile", "kit/grade.py", "kit/rubric.json", "tests/lib.py",
                   "tests/grade_01_local.py", "tests/test_common.c"):
        assert needed in infos, f"the archive has no {needed}"
    leaks = [n for n in infos if n.startswith(("tests/mutants/", "kit/autograder/", "kit/handout.json"))]
    assert not leaks, f"the archive carries what grading does not need: {leaks[:5]}"

    handout = ctx.path("handout")
    r = make("handout", f"OUT={handout}", "CHAPTERS=01_local")
    assert r.returncode == 0, r.stderr
    root = ctx.path("autograder")
    source = unpack(archive, root)
    # Outside kit/, the archive holds the students' handout: no more solution than they have.
    differ = [n for n in infos if not n.startswith("kit/") and n not in ("setup.sh", "run_autograder", "autograder.json")
              and not (os.path.isfile(os.path.join(handout, n)) and
                       open(os.path.join(handout, n), "rb").read() == open(os.path.join(source, n), "rb").read())]
    assert not differ, f"the archive's files are not the handout's: {differ[:5]}"
    r = subprocess.run(["bash", os.path.join(source, "setup.sh"), "--dry-run"], cwd=source, capture_output=True,
                       text=True, timeout=60, env=dict(os.environ, AUTOGRADER_ROOT=root))
    assert r.returncode == 0, r.stderr
    install = [ln for ln in r.stdout.splitlines() if "apt-get install" in ln]
    assert install and set(build_packages()) | {"bubblewrap"} <= set(install[0].split()), r.stdout
    assert stat.S_IMODE(os.stat(os.path.join(source, "kit")).st_mode) & 0o077 == 0, "kit/ is readable by others"

    solve(handout, "chapters/01_local.c", "point_lights")
    os.makedirs(os.path.join(root, "submission"))
    shutil.move(handout, os.path.join(root, "submission", "my-renderer"))  # a zip of the folder, unpacked
    os.makedirs(os.path.join(root, "results"))  # open to all, and a forged result in it: run_autograder locks it
    with open(os.path.join(root, "results", "results.json"), "w") as f:
        json.dump({"score": 999}, f)
    os.chown(os.path.join(root, "results"), SANDBOX_UID, SANDBOX_UID)
    os.chmod(os.path.join(root, "results"), 0o777)

    leftovers = set(os.listdir(tempfile.gettempdir()))
    r = run_autograder(root)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    criteria = [c for c in rubric.load(ROOT)["criteria"] if c["chapter"] == "01_local"]
    results = check_results(os.path.join(root, "results", "results.json"), criteria)
    assert sum(c["points"] for c in criteria) == 100 and 0 < results["score"] < 100, results["score"]
    wrong = [f"{t['name']} ({t['status']}; {t['tags']})" for t in results["tests"]
             if (t["status"] == "passed") != all(tag == "exercise 1.2" for tag in t["tags"])]
    assert not wrong, "passed iff it checks only exercise 1.2 (or nothing): " + "; ".join(wrong)
    assert "point_lights" not in results["output"] and "area_light" in results["output"], results["output"]

    results_dir = os.path.join(root, "results")
    for path in (results_dir, os.path.join(results_dir, "results.json")):
        st = os.stat(path)
        assert st.st_uid == 0 and st.st_mode & 0o022 == 0, f"{path}: mode {oct(st.st_mode)}, owner {st.st_uid}"
    probe = subprocess.run([sys.executable, "-c", "import sys; open(sys.argv[1], 'a')",
                            os.path.join(results_dir, "forged.json")], preexec_fn=lambda: os.setuid(SANDBOX_UID),
                           capture_output=True, text=True, timeout=30)
    assert probe.returncode != 0 and "PermissionError" in probe.stderr, "uid 65534 can write in results/"
    new = {n for n in set(os.listdir(tempfile.gettempdir())) - leftovers if n.startswith("gi-autograder-")}
    assert not new, f"left behind in {tempfile.gettempdir()}: {sorted(new)}"


def test_gradescope_single_files_are_graded_by_their_names(ctx):
    """Single files uploaded (no tree): without the file an exercise is in, results.json has every
    criterion at 0 with the reason, naming the file to submit; with the handout's stubbed
    01_local.c (and a stray file) it is graded as chapters/01_local.c: the unit tests of common/
    pass (10 points), every criterion of the stubs fails, and the stubs are named still to write."""
    if "asan" in ctx.build:
        return
    root = chapter_1_autograder(ctx)
    submission = os.path.join(root, "submission")
    os.makedirs(submission)
    with open(os.path.join(submission, "notes.txt"), "w") as f:
        f.write("my notes\n")
    r = run_autograder(root)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    criteria = [c for c in rubric.load(ROOT)["criteria"] if c["chapter"] == "01_local"]
    results = check_results(os.path.join(root, "results", "results.json"), criteria)
    assert results["score"] == 0 and "01_local.c" in results["output"], results["output"]
    assert all(t["output"].startswith("not graded: ") for t in results["tests"])

    handout = ctx.path("handout")
    r = make("handout", f"OUT={handout}", "CHAPTERS=01_local")
    assert r.returncode == 0, r.stderr
    shutil.copy2(os.path.join(handout, "chapters", "01_local.c"), os.path.join(submission, "01_local.c"))
    r = run_autograder(root)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    results = check_results(os.path.join(root, "results", "results.json"), criteria)
    passed = sorted(t["name"] for t in results["tests"] if t["status"] == "passed")
    assert results["score"] == 10 and passed == ["01_local: unit tests test_common",
                                                 "01_local: unit tests test_sampling_chi2"], passed
    assert all(name in results["output"] for name in ("reflected_fraction", "point_lights", "area_light"))


def test_gradescope_archive_of_chapter_1_gives_no_later_chapter_away(ctx):
    """make autograder CHAPTERS=01_local: the archive (kit/handout.py's tree with the instructor's kit) has
    every file of a later chapter's exercises, none of them the solution's byte for byte, each such
    exercise its stub, and no file of it, of any kind (the kit's included), holds a later exercise's
    answer (tests/grade_handout.py later_chapters_given_away)."""
    if "asan" in ctx.build:
        return
    archive = ctx.path("autograder.zip")
    r = make("autograder", f"OUT={archive}", "CHAPTERS=01_local")
    assert r.returncode == 0, r.stderr
    source = unpack(archive, ctx.path("autograder"))
    problems = later_chapters_given_away(source, "01_local")
    assert not problems, "the chapter-1 archive gives later chapters away:\n" + "\n".join(problems)


def test_handout_carries_the_classroom_self_check(ctx):
    """A handout has .github/workflows/classroom.yml (kit/autograder/classroom.yml): on push it
    installs the Makefile's BUILD_PACKAGES, runs make grade with UNSAFE=1 and keeps
    out/grade/ (report.html) as an artifact; the handout has no kit/autograder/."""
    if "asan" in ctx.build:
        return
    handout = ctx.path("handout")
    r = make("handout", f"OUT={handout}", "CHAPTERS=01_local")
    assert r.returncode == 0, r.stderr
    assert not os.path.exists(os.path.join(handout, "kit", "autograder")), "the handout carries the autograder"
    with open(os.path.join(handout, ".github", "workflows", "classroom.yml")) as f:
        workflow = f.read()
    with open(os.path.join(ROOT, "kit", "autograder", "classroom.yml")) as f:
        assert workflow == f.read()
    assert "\t" not in workflow, "a tab in YAML"
    assert "on:\n  push:" in workflow and "make grade UNSAFE=1" in workflow, workflow
    install = workflow[workflow.index("apt-get install"):].split("\n\n")[0].split()
    assert set(build_packages()) <= set(install), f"the workflow does not install {build_packages()}"
    assert "actions/upload-artifact@" in workflow and "path: out/grade/" in workflow


def test_gradescope_falls_back_to_a_separate_user_without_bubblewrap(ctx):
    """Where bubblewrap cannot start (here: no bwrap on PATH; on Gradescope: Docker blocks user
    namespaces), the archive's grader does not grade unconfined (as a handout's self-check would):
    it grades with kit/sandbox.py's fallback, a separate user, and says so."""
    if "asan" in ctx.build:
        return
    root = chapter_1_autograder(ctx)
    r = make("handout", f"OUT={os.path.join(root, 'submission')}", "CHAPTERS=01_local")
    assert r.returncode == 0, r.stderr
    env = dict(os.environ, AUTOGRADER_ROOT=root, PATH="/nonexistent")
    r = subprocess.run([sys.executable, os.path.join(root, "run_autograder")], cwd=root, env=env, capture_output=True,
                       text=True, timeout=300, stdin=subprocess.DEVNULL)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    criteria = [c for c in rubric.load(ROOT)["criteria"] if c["chapter"] == "01_local"]
    results = check_results(os.path.join(root, "results", "results.json"), criteria)
    assert "Sandbox: a separate user" in results["output"], results["output"]
    assert not any(t["output"].startswith("not graded: ") for t in results["tests"]), results["output"]
    units = sum(c["points"] for c in criteria if c["kind"] == "unit")
    assert results["score"] == units, f"the handout as it is scores its unit tests' {units}: {results['score']}"


def test_gradescope_refuses_where_no_sandbox_starts(ctx):
    """Where neither bubblewrap (here: no bwrap on PATH) nor the fallback can start (here: root without
    CAP_SETUID and CAP_SETGID, dropped from the bounding set by setpriv, as a container may withhold
    them), run_autograder runs none of the submission's code: it says so in its output and in
    results.json, every criterion 0 and not graded.  tests/cluster_gradescope.py shows it in Docker."""
    if "asan" in ctx.build:
        return
    if os.geteuid() != 0:
        raise AssertionError("as root: run_autograder runs as root on Gradescope")
    root = chapter_1_autograder(ctx)
    r = make("handout", f"OUT={os.path.join(root, 'submission')}", "CHAPTERS=01_local")
    assert r.returncode == 0, r.stderr
    env = dict(os.environ, AUTOGRADER_ROOT=root, PATH="/nonexistent")
    r = subprocess.run(["/usr/bin/setpriv", "--bounding-set", "-setuid,-setgid", sys.executable,
                        os.path.join(root, "run_autograder")], cwd=root, env=env, capture_output=True, text=True,
                       timeout=300, stdin=subprocess.DEVNULL)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert "REFUSED to grade" in r.stdout and "no CAP_SETUID" in r.stdout, r.stdout[-3000:]
    assert "grading: " not in r.stdout, f"it started kit/grade.py: {r.stdout[-3000:]}"
    criteria = [c for c in rubric.load(ROOT)["criteria"] if c["chapter"] == "01_local"]
    results = check_results(os.path.join(root, "results", "results.json"), criteria)
    assert results["score"] == 0 and "refuses to run the submission's code" in results["output"], results["output"]
    assert all(t["output"].startswith("not graded: no sandbox can start") for t in results["tests"])

