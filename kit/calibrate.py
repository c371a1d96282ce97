#!/usr/bin/python3
"""Measure the grader: false failures of the solution over many seeds, and power on mutants.

usage: kit/calibrate.py false-failures [--seeds A-B] [--jobs N] [--kinds K,K] [--chapters "A B"] [--out FILE]
                                      [--public] [--build DIR]
       kit/calibrate.py seed-dependence
       kit/calibrate.py combine FILE FILE ...
       kit/calibrate.py mutants [--jobs N] [NAME ...]             (default every tests/mutants/*.patch)

false-failures: the solution (this tree's build/, `make` first) graded with
  seeds A..B (default 1-100) by every statistical criterion: the compare
  criteria, and the grade and surfaces criteria whose outputs depend on the
  seed (seed-dependence, below, run first); each as kit/grade.py --seed S runs
  it.  --kinds compare,grade,surfaces keeps only those kinds (to split a long
  measurement; `combine` joins the parts per seed); --chapters keeps only those
  chapters' criteria (each still at the rubric's alpha).  The compare and
  surfaces criteria are graded as kit/grade.py grades them: their held-out
  variants where kit/heldout/ has them, the public references with --public.
  --build DIR grades the solution built in DIR instead of build/ (--kinds
  compare only: the other kinds run through kit/grade.py's judge, on build/).
  Writes FILE (default
  out/calibration/false_failures.csv: seed, chapter, kind, criterion, passed,
  p, message) and prints per criterion and overall how many gradings failed.
seed-dependence: every grade and surfaces criterion of the rubric run twice,
  with grading seeds 1 and 2, recording every chapter run (its arguments but
  the seed, exit status, stdout, stderr, and its output image and stats
  without the seed, thread count and timings).  A criterion whose runs are
  identical for the two seeds is deterministic: its result cannot depend on
  the seed, and it is graded once.  Writes out/calibration/seed_dependence.csv.
combine: the per-criterion and overall counts over the seeds that every
  FILE (written by false-failures) covers.
mutants: each tests/mutants/NAME.patch applied alone to a copy of this tree
  (its build/ copied, so only what the patch touches is recompiled); the
  criteria of the chapters the patch names ("# chapters: ...") are run as
  kit/grade.py runs them; writes out/calibration/mutants.csv and prints,
  per mutant, the criteria that failed (a survivor fails none).
exercises [--only 4.5 ...] [--commit REV] [--build DIR] [--jobs N] [--out FILE]:
  which criteria each exercise's stub alone fails.  A copy of the tree (the
  working tree's tracked files, or REV's with --commit) is built (from DIR,
  a build directory of this tree, when given: only what differs compiles)
  and graded unstubbed, recording what each criterion runs; then each
  exercise marked in it is stubbed alone (kit/markers.py stub_file), the
  programs that changes are found with make -n (chapter 2 links chapter 1's
  object, common/optics.h is in chapters 2, 4 and 5) and rebuilt, and
  every criterion that runs one of them is graded as kit/grade.py grades
  (seed 1).  Writes kit/exercise-matrix.json (or FILE): per criterion the
  exercises whose stub alone fails it and the commands it ran, the criteria
  no single stub fails, the date, commit and seed.  --only re-measures those
  exercises and merges them into the existing file (keeping what it recorded
  of the solution's runs).  About 30 s per
  exercise outside chapters 4 and 5, minutes inside (chapter 5 links 4).
sync-rubric: kit/rubric.json's "exercises" lists set to the matrix's
  (tests/grade_matrix.py fails while they differ).
grading-time [--chapters "A B"] [--rounds N] [--jobs N] [--out FILE]: what the
  sandbox costs.  A submission of this tree's solution files for the chapters
  (default 01_local 02_whitted) is graded N times (default 3) sandboxed and N
  times with --unsafe, alternately (so both see the same load), each as
  `kit/grade.py SUBMISSION --chapters ...` grades; prints each grading's
  seconds (the report's) and the ratio of the medians, and writes FILE
  (default out/calibration/grading_time.csv).
"""
import csv
import glob
import hashlib
import importlib.util
import json
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

KIT = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(KIT)
sys.path.insert(0, KIT)
import compare  # noqa: E402
import grade  # noqa: E402
import markers  # noqa: E402
import rubric as rubric_module  # noqa: E402

OUT = os.path.join(ROOT, "out", "calibration")


VOLATILE_STATS = ("seed", "threads")  # and every key ending in _s (seconds)


def rounded(value):
    """JSON numbers to 9 significant digits: parallel sums (03_radiosity's reciprocity_error) differ
    from run to run in the last bits, whatever the seed."""
    if isinstance(value, float):
        return float(f"{value:.9g}")
    if isinstance(value, list):
        return [rounded(v) for v in value]
    if isinstance(value, dict):
        return {k: rounded(v) for k, v in value.items()}
    return value


def digest_run(args, result, scratch):
    """What one chapter run produced (its arguments but the seed, exit status, stdout, stderr and
    every file in the test's scratch directory it names, its stats without the seed, thread count
    and timings), without what the scratch directory's name changes."""
    h = hashlib.sha256()
    shown = [a.replace(scratch, "SCRATCH") for i, a in enumerate(args)
             if a != "--seed" and not (i > 0 and args[i - 1] == "--seed")]
    h.update(repr((shown, result.returncode, result.stdout.replace(scratch, "SCRATCH"),
                   result.stderr.replace(scratch, "SCRATCH"))).encode())
    for path in args:
        if not (path.startswith(scratch) and os.path.isfile(path)):
            continue
        if path.endswith(".json"):
            try:
                with open(path) as f:
                    data = json.load(f)
                data = {k: rounded(v) for k, v in data.items() if k not in VOLATILE_STATS and not k.endswith("_s")}
                h.update(json.dumps(data, sort_keys=True).replace(scratch, "SCRATCH").encode())
                continue
            except ValueError:
                pass
        with open(path, "rb") as f:
            h.update(f.read())
    return h.hexdigest()


def run_recorded(c, seed):
    """Run grade criterion c in this process with grading seed `seed`; (passed, message, [digest of each run])."""
    tests = os.path.join(ROOT, "tests")
    if tests not in sys.path:
        sys.path.insert(0, tests)
    import lib
    spec = importlib.util.spec_from_file_location(c["module"], os.path.join(tests, c["module"] + ".py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    runs = []

    class Recording(lib.Context):
        def run(self, chapter, *args, timeout=600):
            result = super().run(chapter, *args, timeout=timeout)
            runs.append(digest_run([chapter] + self.seeded([str(a) for a in args]), result, self.scratch))
            return result

    try:
        getattr(module, c["test"])(Recording("build", seed=seed))
        return True, "passed", runs
    except AssertionError as e:
        return False, str(e)[:300], runs


def seed_dependence(rub):
    """{criterion name: True if its chapter runs differ between grading seeds 1 and 2}; writes a CSV."""
    os.makedirs(OUT, exist_ok=True)
    found = {}
    with open(os.path.join(OUT, "seed_dependence.csv"), "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["chapter", "kind", "criterion", "runs", "runs_that_differ", "seed_dependent"])
        for c in rub["criteria"]:
            if c["kind"] == "surfaces":
                # compare.surfaces_of runs 03_radiosity without --seed: no grading seed reaches it.
                found[c["name"]] = False
                w.writerow([c["chapter"], c["kind"], c["name"], 1, 0, False])
                continue
            if c["kind"] != "grade":
                continue
            ok1, m1, a = run_recorded(c, 1)
            ok2, m2, b = run_recorded(c, 2)
            differ = sum(x != y for x, y in zip(a, b)) + abs(len(a) - len(b))
            found[c["name"]] = differ > 0
            w.writerow([c["chapter"], c["kind"], c["name"], len(a), differ, differ > 0])
            print(f"  {c['chapter']}: {c['name']}: {len(a)} runs, {differ} differ between seeds 1 and 2 -> "
                  f"{'seed-dependent' if differ else 'deterministic'}"
                  f"{'' if ok1 and ok2 else ' (FAILED: ' + (m1 if not ok1 else m2) + ')'}", flush=True)
    return found


def summarise_rows(rows, source=""):
    """rows: dicts of a false_failures CSV; prints the table over the seeds all criteria have."""
    criteria, seeds_of = [], {}
    for r in rows:
        key = (r["chapter"], r["kind"], r["criterion"])
        if key not in seeds_of:
            criteria.append(key)
            seeds_of[key] = {}
        seeds_of[key][int(r["seed"])] = r["passed"] == "True"
    seeds = sorted(set.intersection(*(set(v) for v in seeds_of.values()))) if seeds_of else []
    n = len(seeds)
    print(f"over {n} seeds ({seeds[0]}-{seeds[-1]}){source}:" if n else "no seeds in common")
    failing_seeds = set()
    for key in criteria:
        bad = [s for s in seeds if not seeds_of[key][s]]
        failing_seeds |= set(bad)
        print(f"  {key[0]}: {key[2]} ({key[1]}): {len(bad)} of {n} gradings failed"
              + (f" (seeds {' '.join(map(str, bad))})" if bad else ""))
    for kind in sorted({k[1] for k in criteria}):
        k_bad = {s for key in criteria if key[1] == kind for s in seeds if not seeds_of[key][s]}
        print(f"  kind {kind}: {len(k_bad)} of {n} gradings failed some {kind} criterion")
    if n:
        print(f"false failures: {len(failing_seeds)} of {n} gradings failed any statistical criterion "
              f"({100.0 * len(failing_seeds) / n:.1f} %)"
              + (f"; seeds {' '.join(map(str, sorted(failing_seeds)))}" if failing_seeds else ""))


def false_failures(seeds, jobs, kinds, out_file, chapters=None, public=False, build_dir="build"):
    rub = rubric_module.load(ROOT)
    rub = dict(rub, criteria=[compare.graded_variant(c, public) for c in rub["criteria"]])
    whole = rub  # compare's alpha per criterion is the whole rubric's, as kit/criterion.py grades (not --chapters')
    heldout = [c["name"] for c in rub["criteria"] if c.get("heldout")]
    print(f"{len(heldout)} criteria graded by their held-out variants (kit/heldout/)" if heldout else
          "the public references (kit/reference/)", flush=True)
    if chapters:
        rub = dict(rub, criteria=[c for c in rub["criteria"] if c["chapter"] in chapters])
    kinds = kinds or ["compare", "grade", "surfaces"]
    crit = [c for c in rub["criteria"] if c["kind"] == "compare" and "compare" in kinds]
    once = []
    if "grade" in kinds or "surfaces" in kinds:
        print("seed dependence of the grade and surfaces criteria (grading seeds 1 and 2):", flush=True)
        dependent = seed_dependence(rub)
        for c in rub["criteria"]:
            if c["kind"] in ("grade", "surfaces") and c["kind"] in kinds:
                (crit if dependent[c["name"]] else once).append(c)
    opts = {"seed": 1, "jobs": jobs, "timeout": 300.0, "memory": 4096}
    for c in once:  # deterministic: the same result for every seed
        res = grade.run_criterion(ROOT, c, opts, "")
        print(f"deterministic, graded once: {c['chapter']}: {c['name']}: "
              f"{'pass' if res['passed'] else 'FAIL ' + res['message'][:200]}", flush=True)
    os.makedirs(OUT, exist_ok=True)
    path = out_file or os.path.join(OUT, "false_failures.csv")
    rows = []
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["seed", "chapter", "kind", "criterion", "passed", "p_value", "message", "seconds"])
        for seed in seeds:
            bad = []
            start = time.time()
            for c in crit:
                t0 = time.time()
                if c["kind"] == "compare":
                    try:
                        ok, p, message, _ = compare.run_compare(ROOT, build_dir, c, whole, seed, jobs, None)
                    except compare.CriterionFailed as e:
                        ok, p, message = False, None, str(e)
                else:
                    res = grade.run_criterion(ROOT, c, dict(opts, seed=seed), "")
                    ok, p, message = res["passed"], res["p_value"], res["message"]
                row = [seed, c["chapter"], c["kind"], c["name"], ok, p, message, round(time.time() - t0, 2)]
                w.writerow(row)
                rows.append(dict(zip(["seed", "chapter", "kind", "criterion", "passed"], map(str, row))))
                if not ok:
                    bad.append(c["name"])
            f.flush()
            print(f"seed {seed}: {'FAIL ' + ', '.join(bad) if bad else 'all pass'} ({time.time() - start:.0f} s)",
                  flush=True)
    print(f"{len(crit)} statistical criteria (kinds {','.join(kinds)}); {len(once)} deterministic ones graded once; "
          f"family-wise alpha of the compare criteria {rub['family_alpha']}")
    summarise_rows(rows, f"; {os.path.relpath(path, ROOT)}")


def combine(files):
    rows = []
    for path in files:
        with open(path, newline="") as f:
            rows += list(csv.DictReader(f))
    summarise_rows(rows, "; " + " + ".join(files))


def mutants(names, jobs):
    rub = rubric_module.load(ROOT)
    patches = sorted(glob.glob(os.path.join(ROOT, "tests", "mutants", "*.patch")))
    if names:
        patches = [p for p in patches if any(n in os.path.basename(p) for n in names)]
    os.makedirs(OUT, exist_ok=True)
    files = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True).stdout.split()
    opts = {"seed": 1, "jobs": jobs, "timeout": 120.0, "memory": 4096, "unsafe": True}  # 300 s in kit/grade.py
    killed = 0
    with open(os.path.join(OUT, "mutants.csv"), "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["mutant", "description", "chapters", "points_lost", "failed_criteria"])
        for patch in patches:
            name = os.path.basename(patch)[:-6]
            with open(patch) as pf:
                head = [ln[2:].strip() for ln in pf if ln.startswith("# ")]
            chapters = next((h.split(":", 1)[1].split() for h in head if h.startswith("chapters:")), [])
            description = next((h for h in head if not h.startswith("chapters:")), "")
            work = tempfile.mkdtemp(prefix="gi-mutant-")
            src = os.path.join(work, "src")
            start = time.time()
            try:
                for rel in files:
                    if rel.startswith(("slides/", "docs/")):
                        continue
                    os.makedirs(os.path.dirname(os.path.join(src, rel)) or src, exist_ok=True)
                    shutil.copy2(os.path.join(ROOT, rel), os.path.join(src, rel))
                shutil.copytree(os.path.join(ROOT, "build"), os.path.join(src, "build"), symlinks=True,
                                ignore=shutil.ignore_patterns("asan", "dev", "slides", "viewer*", "glad"))
                r = subprocess.run(["patch", "-p1", "-s", "-i", patch], cwd=src, capture_output=True, text=True)
                if r.returncode != 0:
                    print(f"{name}: patch does not apply: {r.stdout}{r.stderr}", flush=True)
                    w.writerow([name, description, " ".join(chapters), "", "PATCH DOES NOT APPLY"])
                    continue
                now = time.time() + 1  # newer than the copied objects
                with open(patch) as pf:
                    touched = [ln[6:].split("\t")[0].strip() for ln in pf if ln.startswith("+++ b/")]
                for rel in touched:
                    os.utime(os.path.join(src, rel), (now, now))
                crit = [c for c in rub["criteria"] if c["chapter"] in chapters]
                units = sorted({c["test"] for c in crit if c["kind"] == "unit"})
                built = grade.build(src, sorted(set(chapters) | {"03_radiosity"}), units, opts)
                failed, lost = [], 0
                for c in crit:
                    error = built.get(f"build/{c['chapter']}")
                    if error:
                        ok = False  # does not compile
                    elif c["kind"] == "unit":
                        ok = grade.run_unit(src, c, opts)[0]
                    else:
                        ok = grade.run_criterion(src, c, opts, "")["passed"]
                    if not ok:
                        failed.append(f"{c['chapter']}: {c['name']}")
                        lost += c["points"]
                killed += bool(failed)
                w.writerow([name, description, " ".join(chapters), lost, " | ".join(failed)])
                f.flush()
                print(f"{name}: {'SURVIVED' if not failed else f'-{lost} points'} ({time.time() - start:.0f} s)"
                      f"{': ' + '; '.join(failed) if failed else ''}", flush=True)
            finally:
                shutil.rmtree(work, ignore_errors=True)
    print(f"mutants killed: {killed} of {len(patches)} ({100.0 * killed / max(1, len(patches)):.0f} %)")


# ---- exercises: which criteria each exercise's stub alone fails --------------------------------------

MATRIX = os.path.join(KIT, "exercise-matrix.json")
UNIT_TARGET = "build/tests/{}"


def copy_tracked_tree(dst, commit=None):
    """The project's tracked files into dst: as committed at `commit`, else as they are in the working
    tree (mtimes kept, so a copied build directory stays up to date)."""
    os.makedirs(dst, exist_ok=True)
    if commit:
        archive = subprocess.run(["git", "archive", commit], cwd=ROOT, capture_output=True, check=True).stdout
        subprocess.run(["tar", "-x", "-C", dst], input=archive, check=True)
        return
    files = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    for rel in (f for f in files.decode().split("\0") if f):
        if not os.path.isfile(os.path.join(ROOT, rel)):
            continue  # deleted in the working tree, not yet in git
        os.makedirs(os.path.dirname(os.path.join(dst, rel)) or dst, exist_ok=True)
        shutil.copy2(os.path.join(ROOT, rel), os.path.join(dst, rel))


def tree_state(commit=None):
    """(commit hash, tracked files that differ from it in the working tree; [] for --commit)."""
    head = subprocess.run(["git", "rev-parse", commit or "HEAD"], cwd=ROOT, capture_output=True,
                          text=True).stdout.strip()
    if commit:
        return head, []
    status = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=ROOT,
                            capture_output=True, text=True).stdout
    return head, sorted(line[3:] for line in status.splitlines() if line.strip())


def build_targets(src, rub):
    """(chapters, unit tests): every chapter program of the tree and every unit test the rubric runs."""
    chapters = sorted(os.path.splitext(f)[0] for f in os.listdir(os.path.join(src, "chapters"))
                      if f.endswith(".c") and f[:2].isdigit())
    units = sorted({c["test"] for c in rub["criteria"] if c["kind"] == "unit"})
    return chapters, units


def target_names(chapters, units):
    return [f"build/{c}" for c in chapters] + [UNIT_TARGET.format(u) for u in units]


def forget_objects_using(src, rel):
    """Make every object in src/build whose dependency file lists `rel` out of date (its time set to
    1970; deleting it would not do: the Makefile's .SECONDARY lets make skip a missing object).
    Make knows this already for a build of this Makefile (the chapter models' dependency files
    name the object itself, -MT); a build tree from before 9ff467e compiled them as
    ...model.o.tmp.o and renamed them, with their headers recorded for the temporary name only:
    without this, chapter 5 would keep chapter 4's object with the old common/optics.h."""
    for top, _, files in os.walk(os.path.join(src, "build")):
        for name in files:
            if not name.endswith(".d"):
                continue
            with open(os.path.join(top, name)) as f:
                text = f.read().replace("\\\n", " ")
            for line in text.splitlines():
                target, colon, prerequisites = line.partition(":")
                if not colon or rel not in prerequisites.split():
                    continue
                for obj in (target.strip(), target.strip().replace(".tmp.o", "")):
                    if obj.startswith("build/") and os.path.isfile(os.path.join(src, obj)):
                        os.utime(os.path.join(src, obj), (0, 0))


def changed_targets(src, targets):
    """The programs make would build in src (make -n: from the Makefile and the compiler's
    dependency files, so chapter 2 linking chapter 1's object, or a header in common/ used by three
    chapters, is found without being written down here)."""
    r = subprocess.run(["make", "-n", "BUILD=build", *targets], cwd=src, capture_output=True, text=True,
                       env=dict(os.environ, MAKEFLAGS=""))
    if r.returncode != 0:
        raise RuntimeError(f"make -n failed in {src}: {r.stderr.strip()[-500:]}")
    words = r.stdout.split()
    outputs = {words[i + 1] for i, w in enumerate(words[:-1]) if w == "-o"}
    return sorted(t for t in targets if t in outputs)


def command_programs(commands):
    """The programs ("build/04_pathtrace") that recorded commands ("build/04_pathtrace scene ...") ran."""
    return {text.split()[0] for text in commands if text.strip()}


def criterion_programs(c, commands, all_programs):
    """The programs criterion c depends on: the unit test it runs, or its chapter's and every chapter
    a grade test ran (grade tests of chapter 5 run chapters 3 and 4).  A grade criterion whose runs
    were not recorded depends on every program (it is always rerun)."""
    if c["kind"] == "unit":
        return {UNIT_TARGET.format(c["test"])}
    if c["kind"] == "grade" and not commands:
        return set(all_programs)
    return {f"build/{c['chapter']}"} | command_programs(commands)


def grade_one(src, c, built, opts):
    """(passed, message, commands, seconds) of criterion c in the built tree src, as kit/grade.py
    grades it (a chapter that does not compile fails all its criteria)."""
    start = time.time()
    error = built.get(f"build/{c['chapter']}")
    if error:
        return False, f"{c['chapter']} does not compile: {error[:300]}", [], time.time() - start
    if c["kind"] == "unit":
        error = built.get(UNIT_TARGET.format(c["test"]))
        if error:
            return False, f"tests/{c['test']}.c does not compile: {error[:300]}", [], time.time() - start
        result = grade.run_unit(src, c, opts)
        return result[0], result[1], [], time.time() - start
    res = grade.run_criterion(src, c, opts, "")
    commands = res.get("commands") or []
    if c["kind"] in ("compare", "surfaces"):
        commands = [rubric_module.row_command(c)]
    return res["passed"], res["message"], commands, time.time() - start


def prepare_base(work, rub, opts, commit=None, build_from=None):
    """A copy of the tree in work/base, built (chapters and the rubric's unit tests): the solution every
    exercise's stub is applied to.  build_from: a build directory of this tree to start from (only
    what differs is recompiled)."""
    base = os.path.join(work, "base")
    copy_tracked_tree(base, commit)
    if build_from:
        shutil.copytree(build_from, os.path.join(base, "build"), symlinks=True,
                        ignore=shutil.ignore_patterns("asan", "dev", "slides", "viewer*", "glad", "fuzz"))
        name = os.path.relpath(build_from, ROOT)
        if name != "build":  # the dependency files name their targets under the old directory
            for top, _, files in os.walk(os.path.join(base, "build")):
                for f in files:
                    if f.endswith(".d"):
                        path = os.path.join(top, f)
                        with open(path) as fh:
                            text = fh.read()
                        with open(path, "w") as fh:
                            fh.write(text.replace(name + "/", "build/"))
    chapters, units = build_targets(base, rub)
    built = grade.build(base, chapters, units, opts)
    broken = {t: e for t, e in built.items() if e}
    if broken:
        raise RuntimeError("the solution does not build: " + "; ".join(f"{t}: {e[:300]}" for t, e in broken.items()))
    return base, chapters, units


def stubbed_copy(base, work, ex):
    """work/stub-N.M: the base tree (its build directory too) with exercise ex alone stubbed."""
    src = os.path.join(work, f"stub-{ex.id}")
    shutil.copytree(base, src, symlinks=True)
    path = os.path.join(src, ex.file)
    with open(path) as f:
        text = f.read()
    with open(path, "w") as f:
        f.write(markers.stub_file(text, [ex]))
    later = max(os.path.getmtime(path), time.time()) + 1  # newer than every copied object
    os.utime(path, (later, later))
    return src


def first_line(message):
    """The line of a message that says what failed (a traceback's last line, not its first)."""
    lines = [ln.strip() for ln in (message or "").splitlines() if ln.strip()]
    if not lines:
        return ""
    return (lines[-1] if lines[0].startswith("Traceback") else lines[0])[:300]


def measure_exercise(base, work, ex, rub, programs_of, targets, opts, timeouts=None, log=print, choose=None):
    """Stub exercise ex alone in a copy of base, build what that changes and grade every criterion
    that runs a changed program (choose: a function that keeps some of their keys, to grade fewer).
    Returns {"file", "function", "affects", "ran", "failed", "messages", "criterion_seconds",
    "seconds"}; failed and ran are criterion keys ("chapter: name")."""
    start = time.time()
    src = stubbed_copy(base, work, ex)
    try:
        forget_objects_using(src, ex.file)
        affected = changed_targets(src, targets)
        chapters = [t[len("build/"):] for t in affected if not t.startswith("build/tests/")]
        units = [t[len("build/tests/"):] for t in affected if t.startswith("build/tests/")]
        built = grade.build(src, chapters, units, opts) if affected else {}
        ran, failed, messages, times = [], [], {}, {}
        # kit/grade.py fails every criterion of a chapter that does not compile
        reached = [rubric_module.key(c) for c in rub["criteria"] if programs_of[rubric_module.key(c)] & set(affected)
                   or built.get(f"build/{c['chapter']}")]
        chosen = set(choose(reached) if choose else reached)
        for c in rub["criteria"]:
            key = rubric_module.key(c)
            if key not in chosen:
                continue
            timeout = (timeouts or {}).get(key, opts["timeout"])
            passed, message, _, seconds = grade_one(src, c, built, dict(opts, timeout=timeout))
            ran.append(key)
            times[key] = round(seconds, 1)
            if not passed:
                failed.append(key)
                messages[key] = first_line(message)
            log(f"  {ex.id}: {'FAIL' if not passed else 'pass'} {key} ({seconds:.0f} s)"
                + (f": {messages[key][:150]}" if not passed else ""))
    finally:
        shutil.rmtree(src, ignore_errors=True)
    return {"file": ex.file, "function": ex.name, "affects": affected, "ran": ran, "failed": failed,
            "messages": messages, "criterion_seconds": times, "seconds": round(time.time() - start, 1)}


def load_tests_lib(src):
    """src's tests/lib.py as the module `lib` the grade tests import."""
    spec = importlib.util.spec_from_file_location("lib", os.path.join(src, "tests", "lib.py"))
    lib = importlib.util.module_from_spec(spec)
    sys.modules["lib"] = lib
    spec.loader.exec_module(lib)
    return lib


def shown_command(chapter, argv, scratch):
    """A chapter run as the report shows it: "build/CHAPTER ARG ...", without the options that only
    say where output goes, the test's scratch files as scratch/NAME (tests/lib.py command_text)."""
    plumbing = {"--quiet": 0, "--out": 1, "--stats": 1, "--threads": 1}
    words, i = [f"build/{chapter}"], 0
    while i < len(argv):
        if argv[i] in plumbing:
            i += 1 + plumbing[argv[i]]
            continue
        words.append(argv[i].replace(scratch + os.sep, "scratch/"))
        i += 1
    return " ".join(words)


def grade_recorded(src, c, lib, seed):
    """(passed, message, commands, seconds): grade criterion c of the solution tree src in this
    process (as kit/criterion.py does), recording every chapter command its test runs."""
    start = time.time()
    commands = []

    class Recording(lib.Context):
        def run(self, chapter, *args, timeout=600):
            text = shown_command(chapter, self.seeded([str(a) for a in args]), self.scratch)
            if text not in commands:
                commands.append(text)
            return super().run(chapter, *args, timeout=timeout)

    spec = importlib.util.spec_from_file_location(c["module"], os.path.join(src, "tests", c["module"] + ".py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    ctx = Recording("build", seed=seed)
    try:
        getattr(module, c["test"])(ctx)
        passed, message = True, "passed"
    except AssertionError as e:
        passed, message = False, str(e) or "assertion failed"
    except Exception as e:  # the solution should not get here: say where
        passed, message = False, f"{type(e).__name__}: {e}"
    finally:
        shutil.rmtree(ctx.scratch, ignore_errors=True)
    return passed, message, commands, time.time() - start


def baseline(base, rub, chapters, units, opts, log=print):
    """Every criterion on the unstubbed solution: {key: {"passed", "message", "commands", "seconds"}}.
    Grade criteria run in this process, so that their chapter commands are recorded."""
    built = {t: None for t in target_names(chapters, units)}
    found = {}
    lib = load_tests_lib(base)
    os.environ["OMP_NUM_THREADS"] = str(opts["jobs"])  # as kit/grade.py runs a criterion
    for c in rub["criteria"]:
        if c["kind"] == "grade":
            passed, message, commands, seconds = grade_recorded(base, c, lib, opts["seed"])
        else:
            passed, message, commands, seconds = grade_one(base, c, built, opts)
        found[rubric_module.key(c)] = {"passed": passed, "message": first_line(message),
                                       "commands": commands, "seconds": round(seconds, 1)}
        log(f"  solution: {'pass' if passed else 'FAIL'} {rubric_module.key(c)} ({seconds:.0f} s)")
    return found


def matrix_rows(rub, base_results, per_exercise, order):
    rows = []
    for c in rub["criteria"]:
        key = rubric_module.key(c)
        b = base_results[key]
        rows.append({"chapter": c["chapter"], "name": c["name"], "kind": c["kind"],
                     "exercises": [x for x in order if key in per_exercise.get(x, {}).get("failed", [])],
                     "commands": b["commands"], "solution_passed": b["passed"], "seconds": b["seconds"]})
    return rows


def write_matrix(path, matrix):
    with open(path + ".tmp", "w") as f:
        json.dump(matrix, f, indent=1)
        f.write("\n")
    os.replace(path + ".tmp", path)


MATRIX_ABOUT = ("Measured by kit/calibrate.py exercises: each exercise marked in the solution stubbed alone "
                "(kit/markers.py stub_file), the programs that changes (make -n) rebuilt, and every criterion "
                "that runs one of them graded with the grading seed below. criteria[].exercises: the exercises "
                "whose stub alone fails that criterion (kit/rubric.json's lists must equal them: "
                "tests/grade_matrix.py); commands: what the criterion ran on the solution; no_single_stub_fails: "
                "criteria that no single stub fails (they fail only for a wrong answer, or for two stubs "
                "together); exercises: per exercise the programs its stub rebuilt and the criteria it failed.")


def exercises(only, jobs, commit=None, build_from=None, out_path=MATRIX):
    """kit/calibrate.py exercises: measure the matrix (all exercises, or --only some, merged into the
    existing file) and write it.  The criteria are the copied tree's (kit/rubric.json as copied)."""
    rub = rubric_module.load(ROOT)
    # unsafe: the solution with one stub is this project's own code, run without kit/sandbox.py
    opts = {"seed": 1, "jobs": jobs, "timeout": 300.0, "memory": 4096, "unsafe": True}
    head, dirty = tree_state(commit)
    old = None
    if only and os.path.exists(out_path):
        with open(out_path) as f:
            old = json.load(f)
    work = tempfile.mkdtemp(prefix="gi-exercises-")
    start = time.time()
    try:
        base, chapters, units = prepare_base(work, rub, opts, commit, build_from)
        try:
            rub = rubric_module.load(base)
        except ValueError as e:
            print(f"kit/calibrate.py: the copied tree: {e}", file=sys.stderr)
            sys.exit(2)
        marked = markers.all_exercises(base)
        order = [e.id for e in marked]
        unknown = [x for x in only if x not in order]
        if unknown:
            print(f"kit/calibrate.py: no exercise {', '.join(unknown)} is marked (marked: {' '.join(order)})",
                  file=sys.stderr)
            sys.exit(2)
        chosen = [e for e in marked if not only or e.id in only]
        targets = target_names(chapters, units)
        if old is None:
            print(f"the solution, every criterion (seed {opts['seed']}):", flush=True)
            base_results = baseline(base, rub, chapters, units, opts, log=lambda s: print(s, flush=True))
        else:
            base_results = {rubric_module.key(r): {"passed": r["solution_passed"], "commands": r["commands"],
                                                   "seconds": r["seconds"], "message": ""}
                            for r in old["criteria"]}
            missing = [rubric_module.key(c) for c in rub["criteria"] if rubric_module.key(c) not in base_results]
            if missing:
                print(f"kit/calibrate.py: criteria not in the matrix yet (measure all): {'; '.join(missing)}",
                      file=sys.stderr)
                sys.exit(2)
        programs_of = {rubric_module.key(c): criterion_programs(c, base_results[rubric_module.key(c)]["commands"],
                                                                [t for t in targets if "/tests/" not in t])
                       for c in rub["criteria"]}
        timeouts = {k: min(opts["timeout"], max(60.0, 5 * v["seconds"])) for k, v in base_results.items()}
        per_exercise = dict(old["exercises"]) if old else {}
        for ex in chosen:
            print(f"exercise {ex.id} ({ex.file}: {ex.name}):", flush=True)
            per_exercise[ex.id] = measure_exercise(base, work, ex, rub, programs_of, targets, opts, timeouts,
                                                   log=lambda s: print(s, flush=True))
            m = per_exercise[ex.id]
            m["commit"] = head
            os.makedirs(OUT, exist_ok=True)  # what is measured so far, in case the run is cut short
            write_matrix(os.path.join(OUT, "exercise-matrix.partial.json"), per_exercise)
            print(f"exercise {ex.id}: rebuilt {' '.join(m['affects']) or 'nothing'}; fails {len(m['failed'])} of "
                  f"{len(m['ran'])} criteria run ({m['seconds']:.0f} s)", flush=True)
        per_exercise = {x: per_exercise[x] for x in order if x in per_exercise}
        rows = matrix_rows(rub, base_results, per_exercise, order)
        matrix = {"_about": MATRIX_ABOUT,
                  "date": time.strftime("%Y-%m-%d %H:%M:%S %z"),
                  "commit": head, "uncommitted_changes": dirty, "seed": opts["seed"],
                  "command": "kit/calibrate.py exercises" + (f" --commit {commit}" if commit else "")
                             + (f" --only {' '.join(only)}" if only else ""),
                  "measured": sorted(set(old["measured"] if old else []) | {e.id for e in chosen},
                                     key=rubric_module.exercise_order),
                  "seconds": round(time.time() - start),
                  "criteria": rows,
                  "no_single_stub_fails": [rubric_module.key(r) for r in rows if not r["exercises"]],
                  "solution_fails": [rubric_module.key(r) for r in rows if not r["solution_passed"]],
                  "exercises": per_exercise}
        write_matrix(out_path, matrix)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    print(f"wrote {os.path.relpath(out_path, ROOT)} in {time.time() - start:.0f} s")
    if matrix["solution_fails"]:
        print("the solution itself fails (every exercise then seems to fail them): "
              + "; ".join(matrix["solution_fails"]))
    print("no single stub fails: " + ("; ".join(matrix["no_single_stub_fails"]) or "none"))
    differ = rubric_disagreements(rub, matrix)
    print("kit/rubric.json agrees with the matrix" if not differ else
          "kit/rubric.json disagrees (kit/calibrate.py sync-rubric writes the measured lists):\n  " + "\n  ".join(differ))


def rubric_disagreements(rub, matrix):
    """Sentences: where kit/rubric.json's exercises lists differ from the matrix."""
    measured = {rubric_module.key(r): r["exercises"] for r in matrix["criteria"]}
    out = []
    for i, c in enumerate(rub["criteria"]):
        key = rubric_module.key(c)
        if key not in measured:
            out.append(f"kit/rubric.json: criterion {i + 1} '{c['name']}' ({c['chapter']}): not in the matrix")
        elif sorted(c["exercises"], key=rubric_module.exercise_order) != measured[key]:
            out.append(f"kit/rubric.json: criterion {i + 1} '{c['name']}' ({c['chapter']}): exercises "
                       f"{c['exercises']}, measured {measured[key]}")
    in_rubric = {rubric_module.key(c) for c in rub["criteria"]}
    out += [f"{os.path.relpath(MATRIX, ROOT)}: '{k}' is not a criterion of kit/rubric.json"
            for k in measured if k not in in_rubric]
    return out


def sync_rubric():
    """Write the matrix's measured exercise lists into kit/rubric.json: only each row's "exercises"
    list changes (a small edit of the text, so rows others add meanwhile are kept)."""
    path = os.path.join(KIT, "rubric.json")
    matrix = rubric_module.load_matrix(ROOT)
    if matrix is None:
        print("kit/calibrate.py: no kit/exercise-matrix.json (kit/calibrate.py exercises first)", file=sys.stderr)
        sys.exit(2)
    measured = {rubric_module.key(r): r["exercises"] for r in matrix["criteria"]}
    with open(path) as f:
        text = f.read()
    rows = json.loads(text)["criteria"]
    changed, unmeasured = 0, []
    row_starts = [m.start() for m in re.finditer(r'^  \{\s*$', text, re.M)]
    if len(row_starts) != len(rows):
        print(f"kit/calibrate.py: kit/rubric.json: expected one row per '  {{' line ({len(rows)} rows, "
              f"{len(row_starts)} lines)", file=sys.stderr)
        sys.exit(2)
    for i in reversed(range(len(rows))):
        key = rubric_module.key(rows[i])
        if key not in measured:
            unmeasured.append(key)
            continue
        if rows[i]["exercises"] == measured[key]:
            continue
        end = row_starts[i + 1] if i + 1 < len(rows) else len(text)
        block = text[row_starts[i]:end]
        m = re.search(r'^(\s*)"exercises": \[[^\]]*\]', block, re.M)
        indent = m.group(1)
        items = "".join(f'\n{indent} "{x}",' for x in measured[key]).rstrip(",")
        new = f'{indent}"exercises": [' + (items + f"\n{indent}]" if items else "]")
        text = text[:row_starts[i]] + block[:m.start()] + new + block[m.end():] + text[end:]
        changed += 1
    json.loads(text)  # still JSON
    with open(path, "w") as f:
        f.write(text)
    print(f"kit/rubric.json: {changed} exercise lists changed to the measured ones"
          + (f"; not measured yet: {'; '.join(unmeasured)}" if unmeasured else ""))


def grading_time(chapters, rounds, jobs, out_file):
    """Sandboxed against --unsafe grading time of the solution, alternately (see the module)."""
    chapters = chapters or ["01_local", "02_whitted"]
    work = tempfile.mkdtemp(prefix="gi-kit-timing-")
    rows = []
    try:
        sub = os.path.join(work, "submission")
        for rel in grade.submitted_files(chapters):
            os.makedirs(os.path.dirname(os.path.join(sub, rel)), exist_ok=True)
            shutil.copyfile(os.path.join(ROOT, rel), os.path.join(sub, rel))
        for r in range(rounds):
            for mode in ("sandbox", "unsafe"):
                report = os.path.join(work, f"report-{mode}-{r}")
                cmd = [sys.executable, os.path.join(KIT, "grade.py"), sub, "--chapters", " ".join(chapters),
                       "--report", report, "--jobs", str(jobs)] + (["--unsafe"] if mode == "unsafe" else [])
                done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
                if done.returncode != 0:
                    print(f"kit/calibrate.py: {' '.join(cmd)}: exit {done.returncode}: {done.stderr[-500:]}",
                          file=sys.stderr)
                    sys.exit(1)
                with open(os.path.join(report, "report.json")) as f:
                    got = json.load(f)
                rows.append({"round": r, "mode": mode, "seconds": got["seconds"],
                             "points": f"{got['total']}/{got['max']}"})
                print(f"round {r} {mode}: {got['seconds']} s, {got['total']}/{got['max']} points", flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    median = {m: statistics.median(r["seconds"] for r in rows if r["mode"] == m) for m in ("sandbox", "unsafe")}
    print(f"median: sandboxed {median['sandbox']:.1f} s, unsafe {median['unsafe']:.1f} s; "
          f"ratio {median['sandbox'] / median['unsafe']:.3f} ({' '.join(chapters)}, {rounds} rounds, jobs {jobs})")
    out_file = out_file or os.path.join(ROOT, "out", "calibration", "grading_time.csv")
    os.makedirs(os.path.dirname(out_file), exist_ok=True)
    with open(out_file, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=["round", "mode", "seconds", "points"])
        w.writeheader()
        w.writerows(rows)


def main(argv):
    if not argv or argv[0] in ("-h", "--help"):
        print(__doc__.strip())
        sys.exit(0 if argv else 2)
    mode, rest = argv[0], argv[1:]
    try:
        rubric_module.load(ROOT)
    except ValueError as e:  # a row naming an unknown exercise or test: nothing is measured
        print(f"kit/calibrate.py: {e}", file=sys.stderr)
        sys.exit(2)
    jobs, seeds, names, kinds, out_file, chapters = 2, list(range(1, 101)), [], None, None, None
    rounds = 3
    public = False
    only, commit, build_from = [], None, None
    i = 0
    while i < len(rest):
        if rest[i] == "--only":
            i += 1
            while i < len(rest) and not rest[i].startswith("-"):
                only.append(rest[i])
                i += 1
            if not only:
                print("kit/calibrate.py: --only needs exercise ids (e.g. --only 4.5 4.7)", file=sys.stderr)
                sys.exit(2)
        elif rest[i] == "--commit" and i + 1 < len(rest):
            commit = rest[i + 1]
            i += 2
        elif rest[i] == "--build" and i + 1 < len(rest):
            build_from = os.path.abspath(rest[i + 1])
            if not os.path.isdir(build_from):
                print(f"kit/calibrate.py: --build {rest[i + 1]}: not a directory", file=sys.stderr)
                sys.exit(2)
            i += 2
        elif rest[i] == "--jobs" and i + 1 < len(rest) and rest[i + 1].isdigit():
            jobs = int(rest[i + 1])
            i += 2
        elif rest[i] == "--seeds" and i + 1 < len(rest) and "-" in rest[i + 1]:
            a, b = rest[i + 1].split("-", 1)
            if not (a.isdigit() and b.isdigit()):
                break
            seeds = list(range(int(a), int(b) + 1))
            i += 2
        elif rest[i] == "--kinds" and i + 1 < len(rest):
            kinds = rest[i + 1].split(",")
            if not set(kinds) <= {"compare", "grade", "surfaces"}:
                print(f"kit/calibrate.py: --kinds {rest[i + 1]}: not compare, grade, surfaces", file=sys.stderr)
                sys.exit(2)
            i += 2
        elif rest[i] == "--rounds" and i + 1 < len(rest) and rest[i + 1].isdigit() and int(rest[i + 1]) > 0:
            rounds = int(rest[i + 1])
            i += 2
        elif rest[i] == "--public":
            public = True
            i += 1
        elif rest[i] == "--chapters" and i + 1 < len(rest):
            chapters = rest[i + 1].split()
            i += 2
        elif rest[i] == "--out" and i + 1 < len(rest):
            out_file = os.path.abspath(rest[i + 1])
            i += 2
        elif rest[i].startswith("-"):
            print(f"kit/calibrate.py: bad option {rest[i]} (see --help)", file=sys.stderr)
            sys.exit(2)
        else:
            names.append(rest[i])
            i += 1
    if mode == "false-failures":
        if build_from and kinds != ["compare"]:
            print("kit/calibrate.py: false-failures --build needs --kinds compare", file=sys.stderr)
            sys.exit(2)
        try:
            false_failures(seeds, jobs, kinds, out_file, chapters, public,
                           os.path.relpath(build_from, ROOT) if build_from else "build")
        except ValueError as e:  # a held-out file made for other options than the rubric's
            print(f"kit/calibrate.py: {e}", file=sys.stderr)
            sys.exit(2)
    elif mode == "seed-dependence":
        seed_dependence(rubric_module.load(ROOT))
    elif mode == "combine":
        if not names:
            print("kit/calibrate.py: combine needs the CSV files of false-failures runs", file=sys.stderr)
            sys.exit(2)
        combine(names)
    elif mode == "mutants":
        mutants(names, jobs)
    elif mode == "exercises":
        if names:
            print(f"kit/calibrate.py: exercises takes no argument {names[0]} (--only {names[0]}?)", file=sys.stderr)
            sys.exit(2)
        if commit and subprocess.run(["git", "rev-parse", "--verify", "--quiet", commit + "^{commit}"], cwd=ROOT,
                                     capture_output=True).returncode != 0:
            print(f"kit/calibrate.py: --commit {commit}: not a commit", file=sys.stderr)
            sys.exit(2)
        exercises(only, jobs, commit, build_from, out_file or MATRIX)
    elif mode == "sync-rubric":
        sync_rubric()
    elif mode == "grading-time":
        grading_time(chapters, rounds, jobs, out_file)
    else:
        print(f"kit/calibrate.py: unknown mode {mode} (see --help)", file=sys.stderr)
        sys.exit(2)


if __name__ == "__main__":
    main(sys.argv[1:])
