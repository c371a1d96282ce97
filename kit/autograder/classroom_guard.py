#!/usr/bin/python3
"""Keep a student's push away from the Classroom workflow and the grader it runs.

usage: kit/autograder/classroom_guard.py ruleset HANDOUT_DIR --repos PATTERN [--name NAME] --out FILE
       kit/autograder/classroom_guard.py hook RULESET          (a git pre-receive hook; stdin as git gives it)

The handout's .github/workflows/classroom.yml runs on every push to a student's repository, and it
runs the files of the pushed commit: a push that changed the workflow, kit/grade.py, the Makefile
or tests/ would change the self-check with it.  So a push may change only the exercise files.

ruleset: writes FILE, a GitHub *push ruleset* (REST API "Create an organization repository
  ruleset", POST /orgs/ORG/rulesets; rule `file_path_restriction`) that refuses every push
  with a commit changing a file of HANDOUT_DIR other than its exercise files (kit/handout.json:
  the files of the stubbed exercises), or adding a top-level file (a GNUmakefile would win over
  the Makefile).  PATTERN names the assignment's repositories (GitHub Classroom names them
  ASSIGNMENT-USERNAME: e.g. 'ch1-*').  Organisation admins (the instructor) may bypass it.
  Send it to POST /orgs/ORG/rulesets (`gh api` can send FILE as the request body).  Push rulesets apply to
  every branch and tag, so a branch with its own workflow is refused too.
hook: the same rule for a git server of your own (and the tests): install as
  hooks/pre-receive (`exec kit/autograder/classroom_guard.py hook RULESET`).  Every commit a push
  brings that the repository does not have yet is compared with each of its parents (a root
  commit with the empty tree); one restricted path refuses the whole push, naming the commit and
  the file, with exit status 1 (git then updates no ref).

The patterns are fnmatch's with whole-path matching: `*` stops at '/', `**` does not.  What this
does not stop: the student's code itself, which the self-check runs without a sandbox (it is the
student's own check: kit/README.md, "GitHub Classroom"), and a student given admin rights on the
repository, who could rename it out of PATTERN (Classroom's default role is write).  Exit status 2 on bad input.
"""
import json
import os
import re
import subprocess
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
import grade  # noqa: E402  (project_files: a handout's files, as grading lists them)

EMPTY_TREE = "4b825dc642cb6eb9a5e52e3a46e6b2b1d5e4f3cb"  # git's well-known empty tree: a root commit's parent
# Org admins (the instructor) may push anything: GitHub's actor for the organisation admin role.
INSTRUCTOR_BYPASS = [{"actor_id": 1, "actor_type": "OrganizationAdmin", "bypass_mode": "always"}]


def fail(message, status=2):
    print(f"classroom_guard.py: {message}", file=sys.stderr)
    sys.exit(status)


def exercise_files(handout):
    """The files of the handout's stubbed exercises (kit/handout.json: "1.2 chapters/01_local.c:name")."""
    path = os.path.join(handout, "kit", "handout.json")
    try:
        with open(path) as f:
            stubbed = json.load(f)["stubbed"]
    except (OSError, ValueError, KeyError) as e:
        fail(f"{path}:1: not a handout's record of its exercises ({e})")
    return sorted({entry.split(" ", 1)[1].rsplit(":", 1)[0] for entry in stubbed})


def restricted_paths(handout):
    """Every path a push may not touch: each top-level directory without an exercise file as a whole
    (new files in it included), each other file by name, any new top-level file."""
    open_files = set(exercise_files(handout))
    open_dirs = {f.split("/")[0] for f in open_files if "/" in f}
    patterns = {"*", ".*"}  # top-level files, old and new (fnmatch's `*` skips a leading dot on GitHub)
    for f in grade.project_files(handout):
        top = f.split("/")[0]
        if f in open_files or "/" not in f:
            continue  # (top-level files: `*` and `.*`)
        patterns.add(f if top in open_dirs else f"{top}/**")
    return sorted(patterns)


def ruleset(handout, repos, name):
    return {"name": name, "target": "push", "enforcement": "active", "bypass_actors": INSTRUCTOR_BYPASS,
            "conditions": {"repository_name": {"include": [repos], "exclude": []}},
            "rules": [{"type": "file_path_restriction",
                       "parameters": {"restricted_file_paths": restricted_paths(handout)}}]}


def pattern_regex(pattern):
    """fnmatch over whole paths: `**` any characters, `*` and `?` none of them '/'."""
    parts = re.split(r"(\*\*|\*|\?)", pattern)
    table = {"**": ".*", "*": "[^/]*", "?": "[^/]"}
    return re.compile("".join(table.get(p, re.escape(p)) for p in parts) + r"\Z")


def restricted_by(rules):
    patterns = [p for r in rules["rules"] if r["type"] == "file_path_restriction"
                for p in r["parameters"]["restricted_file_paths"]]
    regexes = [(p, pattern_regex(p)) for p in patterns]
    return lambda path: next((p for p, rx in regexes if rx.match(path)), None)


def git(*args):
    r = subprocess.run(["git", *args], capture_output=True, text=True)
    if r.returncode != 0:
        fail(f"git {' '.join(args)}: {r.stderr.strip()}", 1)
    return r.stdout


def changed_paths(commit):
    """The paths a commit changes against each of its parents (a root commit: all of its files)."""
    parents = git("rev-list", "--parents", "-n", "1", commit).split()[1:] or [EMPTY_TREE]
    paths = set()
    for parent in parents:
        paths.update(git("diff-tree", "-r", "--no-renames", "--name-only", "-z", parent, commit).split("\0"))
    return sorted(p for p in paths if p)


def hook(ruleset_path):
    try:
        with open(ruleset_path) as f:
            restricted = restricted_by(json.load(f))
    except (OSError, ValueError, KeyError, TypeError) as e:
        fail(f"{ruleset_path}:1: not a push ruleset ({e})", 1)  # refuse the push: no rule read, no push
    for line in sys.stdin:
        old, new, ref = line.split()
        if set(new) == {"0"}:
            continue  # a deletion brings no commit (GitHub's push rules check what is pushed)
        for commit in git("rev-list", new, "--not", "--all").split():
            for path in changed_paths(commit):
                pattern = restricted(path)
                if pattern:
                    fail(f"push to {ref} refused: commit {commit[:12]} changes {path}, which only the "
                         f"instructor may change (restricted: {pattern}); change only your exercise files", 1)
    return 0


def main(argv):
    if len(argv) == 2 and argv[0] == "hook":
        return hook(argv[1])
    if len(argv) >= 2 and argv[0] == "ruleset" and not argv[1].startswith("-"):
        opts, rest = {"--name": "gi-course: only exercise files"}, argv[2:]
        while rest:
            if rest[0] not in ("--repos", "--name", "--out") or len(rest) < 2:
                fail(f"unknown or incomplete option {rest[0]!r}\n{__doc__}")
            opts[rest[0]], rest = rest[1], rest[2:]
        if "--repos" not in opts or "--out" not in opts:
            fail(f"ruleset needs --repos PATTERN and --out FILE\n{__doc__}")
        rules = ruleset(argv[1], opts["--repos"], opts["--name"])
        with open(opts["--out"] + ".partial", "w") as f:
            json.dump(rules, f, indent=1)
        os.replace(opts["--out"] + ".partial", opts["--out"])
        return 0
    fail(f"usage:\n{__doc__}")


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
