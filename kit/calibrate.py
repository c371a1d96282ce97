#!/usr/bin/python3
"""Measure the grader: false failures of the solution over many seeds, and power on mutants.

usage: kit/calibrate.py false-failures [--seeds A-B] [--jobs N] [--chapters "A B"]   (default seeds 1-100)
       kit/calibrate.py mutants [--jobs N] [NAME ...]             (default every tests/mutants/*.patch)

false-failures: the solution (this tree's build/, `make` first) graded by
  every statistical (compare) criterion with seeds A..B; writes
  out/calibration/false_failures.csv (seed, criterion, passed, p) and prints
  per criterion and overall how many gradings failed (--chapters: only
  those chapters' criteria, still at the rubric's alpha per criterion).
mutants: each tests/mutants/NAME.patch applied alone to a copy of this tree
  (its build/ copied, so only what the patch touches is recompiled); the
  criteria of the chapters the patch names ("# chapters: ...") are run as
  kit/grade.py runs them; writes out/calibration/mutants.csv and prints,
  per mutant, the criteria that failed (a survivor fails none).
"""
import csv
import glob
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


def false_failures(seeds, jobs, chapters=None):
    rub = rubric_module.load(ROOT)
    crit = [c for c in rub["criteria"] if c["kind"] == "compare" and (not chapters or c["chapter"] in chapters)]
    os.makedirs(OUT, exist_ok=True)
    failed_by = {c["name"]: 0 for c in crit}
    any_failed = 0
    with open(os.path.join(OUT, "false_failures.csv"), "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["seed", "chapter", "criterion", "passed", "p_value", "message"])
        for seed in seeds:
            bad = []
            for c in crit:
                try:
                    ok, p, message, _ = compare.run_compare(ROOT, "build", c, rub, seed, jobs, None)
                except compare.CriterionFailed as e:
                    ok, p, message = False, None, str(e)
                w.writerow([seed, c["chapter"], c["name"], ok, p, message])
                if not ok:
                    failed_by[c["name"]] += 1
                    bad.append(c["name"])
            f.flush()
            any_failed += bool(bad)
            print(f"seed {seed}: {'FAIL ' + ', '.join(bad) if bad else 'all pass'}", flush=True)
    n = len(seeds)
    for name, k in failed_by.items():
        print(f"  {name}: {k} of {n} gradings failed")
    print(f"false failures: {any_failed} of {n} gradings failed any statistical criterion "
          f"({100.0 * any_failed / n:.1f} %; family-wise alpha {rub['family_alpha']})")


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
    jobs, seeds, names, chapters = 2, list(range(1, 101)), [], None
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
        elif rest[i] == "--chapters" and i + 1 < len(rest):
            chapters = rest[i + 1].split()
            i += 2
        elif rest[i].startswith("-"):
            print(f"kit/calibrate.py: bad option {rest[i]} (see --help)", file=sys.stderr)
            sys.exit(2)
        else:
            names.append(rest[i])
            i += 1
    if mode == "false-failures":
        false_failures(seeds, jobs, chapters)
    elif mode == "mutants":
        mutants(names, jobs)
    else:
        print(f"kit/calibrate.py: unknown mode {mode} (see --help)", file=sys.stderr)
        sys.exit(2)


if __name__ == "__main__":
    main(sys.argv[1:])
