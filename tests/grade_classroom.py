"""GitHub Classroom: a student's push may change only the exercise files (kit/autograder/classroom_guard.py).

The handout's workflow (.github/workflows/classroom.yml) runs the files of the pushed commit; the
organisation's push ruleset that classroom_guard.py writes for a handout, here enforced by the same
rule as a git pre-receive hook on a bare repository, keeps a push from changing the workflow or the
grader.  About 20 s (a handout and some twenty pushes); tests/cluster_gradescope.py runs the
workflow itself behind that hook.
"""
import json
import os
import subprocess

from lib import ROOT
from grade_autograder import make, solve


def git(*args, cwd, check=True):
    r = subprocess.run(["git", "-c", "user.name=test", "-c", "user.email=test@example.invalid",
                        "-c", "init.defaultBranch=main", *args], cwd=cwd, capture_output=True, text=True,
                       timeout=120, stdin=subprocess.DEVNULL)
    assert r.returncode == 0 or not check, f"git {' '.join(args)}: {r.stderr}"
    return r


def test_classroom_push_may_change_only_the_exercise_files(ctx):
    """kit/autograder/classroom_guard.py: the push ruleset of a chapter-1 handout restricts every file
    but chapters/01_local.c (and new top-level files); its pre-receive hook, on a bare repository
    holding the handout, accepts a push of the exercise file and refuses pushes that change the
    grader (kit/grade.py) or the workflow (each also on a new branch, and undone by a later commit), a
    second workflow, the Makefile (deleted), a grading test, a shared header of the chapter, or add a
    GNUmakefile or a module in kit/ named as a standard one (either would run instead of the grader's); a
    refused push moves no ref."""
    if "asan" in ctx.build:
        return
    handout = ctx.path("handout")
    r = make("handout", f"OUT={handout}", "CHAPTERS=01_local")
    assert r.returncode == 0, r.stderr
    guard = os.path.join(ROOT, "kit", "autograder", "classroom_guard.py")
    rules_path = ctx.path("ruleset.json")
    r = subprocess.run([guard, "ruleset", handout, "--repos", "ch1-*", "--out", rules_path], capture_output=True,
                       text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    with open(rules_path) as f:
        rules = json.load(f)
    assert rules["target"] == "push" and rules["conditions"]["repository_name"]["include"] == ["ch1-*"]
    (rule,) = rules["rules"]
    assert rule["type"] == "file_path_restriction", rule

    remote = ctx.path("ch1-student.git")
    git("init", "-q", "--bare", remote, cwd=ctx.scratch)
    git("init", "-q", cwd=handout)
    git("add", "-A", cwd=handout)
    git("commit", "-q", "-m", "the handout", cwd=handout)
    git("push", "-q", remote, "HEAD:main", cwd=handout)  # the instructor's template, before the rule
    hook = os.path.join(remote, "hooks", "pre-receive")
    with open(hook, "w") as f:
        f.write(f"#!/bin/sh\nexec {guard} hook {rules_path}\n")
    os.chmod(hook, 0o755)
    student = ctx.path("student")
    git("clone", "-q", remote, student, cwd=ctx.scratch)

    def head():
        return git("ls-remote", remote, "refs/heads/main", cwd=student).stdout.split()[0]

    def attempt(label, change, ref="main", undo=False):
        before = head()
        git("checkout", "-q", "-B", "work", "origin/main", cwd=student)
        paths = change()
        git("add", "-A", cwd=student)
        git("commit", "-q", "-m", label, cwd=student)
        if undo:  # the change undone by a second commit: the pushed tree is the honest one
            git("revert", "--no-edit", "HEAD", cwd=student)
        r = git("push", "origin", f"HEAD:refs/heads/{ref}", cwd=student, check=False)
        git("fetch", "-q", "origin", cwd=student)
        return r, before, paths

    def write(rel, text):
        path = os.path.join(student, rel)
        os.makedirs(os.path.dirname(path), exist_ok=True)
        with open(path, "w") as f:
            f.write(text)
        return [rel]

    r, before, _ = attempt("exercise 1.2", lambda: solve(student, "chapters/01_local.c", "point_lights"))
    assert r.returncode == 0, f"the exercise file was refused: {r.stderr}"
    assert head() != before
    forged = {  # each to main; the first two also to a new branch, and undone by a later commit
        "the grader": lambda: write("kit/grade.py", "print('100 points')\n"),
        "the workflow": lambda: write(".github/workflows/classroom.yml", "name: self-check\n"),
        "a second workflow": lambda: write(".github/workflows/more.yml", "name: more\n"),
        "the Makefile deleted": lambda: os.remove(os.path.join(student, "Makefile")),
        "a grading test": lambda: write("tests/grade_01_local.py", "\n"),
        "a GNUmakefile": lambda: write("GNUmakefile", "grade:\n\ttrue\n"),
        "a module before the standard library's": lambda: write("kit/json.py", "\n"),
        "chapter 1's shared header": lambda: write("chapters/local_model.h", "\n"),
    }
    for number, (label, change) in enumerate(forged.items()):
        for ref, undo in (("main", False), ("other-branch", False), ("main", True))[:3 if number < 2 else 1]:
            r, before, _ = attempt(label, change, ref, undo)
            assert r.returncode != 0, f"{label} (to {ref}{', undone' if undo else ''}): pushed"
            assert "refused" in r.stderr and "only the instructor may change" in r.stderr, r.stderr
            assert head() == before
            assert git("ls-remote", "--heads", remote, "other-branch", cwd=student).stdout == "", \
                f"{label}: a ref moved"
