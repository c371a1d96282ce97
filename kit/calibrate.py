#!/usr/bin/python3
"""Measure the grader: false failures of the solution over many seeds, and power on mutants.

usage: kit/calibrate.py false-failures [--seeds A-B] [--jobs N] [--kinds K,K] [--chapters "A B"] [--out FILE]
       kit/calibrate.py seed-dependence
       kit/calibrate.py combine FILE FILE ...
       kit/calibrate.py mutants [--jobs N] [NAME ...]             (default every tests/mutants/*.patch)

false-failures: the solution (this tree's build/, `make` first) graded with
  seeds A..B (default 1-100) by every statistical criterion: the compare
  criteria, and the grade and surfaces criteria whose outputs depend on the
  seed (seed-dependence, below, run first); each as kit/grade.py --seed S runs
  it.  --kinds compare,grade,surfaces keeps only those kinds (to split a long
  measurement; `combine` joins the parts per seed); --chapters keeps only those
  chapters' criteria (each still at the rubric's alpha).  Writes FILE (default
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
"""
import csv
import glob
import hashlib
import importlib.util
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time

KIT = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(KIT)
sys.path.insert(0, KIT)
import compare  # noqa: E402
import grade  # noqa: E402
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


def false_failures(seeds, jobs, kinds, out_file, chapters=None):
    rub = rubric_module.load(ROOT)
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
                        ok, p, message, _ = compare.run_compare(ROOT, "build", c, rub, seed, jobs, None)
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
    opts = {"seed": 1, "jobs": jobs, "timeout": 120.0, "memory": 4096}  # 300 s in kit/grade.py
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
                        ok, message = False, "does not compile"
                    elif c["kind"] == "unit":
                        ok, message = grade.run_unit(src, c, opts)
                    else:
                        res = grade.run_criterion(src, c, opts, "")
                        ok, message = res["passed"], res["message"]
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


def main(argv):
    if not argv or argv[0] in ("-h", "--help"):
        print(__doc__.strip())
        sys.exit(0 if argv else 2)
    mode, rest = argv[0], argv[1:]
    jobs, seeds, names, kinds, out_file, chapters = 2, list(range(1, 101)), [], None, None, None
    i = 0
    while i < len(rest):
        if rest[i] == "--jobs" and i + 1 < len(rest) and rest[i + 1].isdigit():
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
        false_failures(seeds, jobs, kinds, out_file, chapters)
    elif mode == "seed-dependence":
        seed_dependence(rubric_module.load(ROOT))
    elif mode == "combine":
        if not names:
            print("kit/calibrate.py: combine needs the CSV files of false-failures runs", file=sys.stderr)
            sys.exit(2)
        combine(names)
    elif mode == "mutants":
        mutants(names, jobs)
    else:
        print(f"kit/calibrate.py: unknown mode {mode} (see --help)", file=sys.stderr)
        sys.exit(2)


if __name__ == "__main__":
    main(sys.argv[1:])
