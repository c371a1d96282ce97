#!/usr/bin/python3
"""Grade a class: many submissions in parallel with GNU parallel, then a summary (CSV and HTML).

usage: kit/grade_class.py [--report DIR] [--jobs N] [--sshloginfile FILE | --slurm] [--chapters "A B"] [--seed N]
                          [--rubric FILE] SUBMISSION... | @LIST.txt

  SUBMISSION   a student's directory; @LIST.txt: one directory per line (# comments)
  --report DIR class reports (default out/class): DIR/<student>/report.{json,html}, DIR/summary.{csv,html},
               DIR/criteria.csv, DIR/joblog.tsv (GNU parallel's log: exit status and time of every grading)
  --jobs N     gradings at once (default: the number of cores); each grading uses one core
  --sshloginfile FILE   spread the gradings over the machines in FILE (GNU parallel's format, e.g.
               "4/user@host"); every machine must see this project and the submissions at the same
               paths (a shared file system) and have the build packages installed
  --chapters, --seed, --rubric   passed to kit/grade.py (--rubric FILE: another rubric than kit/rubric.json)
  --slurm      grade on a Slurm cluster instead: one job array, a task per submission, a task that ends
               without a report (node lost, killed) submitted once more; summary.csv's column "retried" names
               them (kit/slurm_engine.py; --jobs N: at most N tasks at once)

A grading that fails (crash of the grader, a killed machine) leaves a row
"not graded" with its exit status; the other students' reports are kept.

summary.csv: one row per student: total, points per chapter, points per criterion (columns
"chapter: criterion"), the grading seed, the date, and the sha256 of the submission's files (so a
regrade or an appeal can show it graded the same code).  criteria.csv: one row per student and
criterion, with its measured value (the report's sentence) and p-value.
"""
import csv
import html
import json
import os
import shlex
import shutil
import subprocess
import sys

KIT = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(KIT)


def fail(message):
    print(f"kit/grade_class.py: {message}", file=sys.stderr)
    sys.exit(2)


def points_by_criterion(r):
    return {f"{c['chapter']}: {c['name']}": c for c in r["criteria"]}


def first_measured(c):
    """The sentence of the criterion's first failed comparison, else its first one ("" if none)."""
    measured = c.get("measured") or []
    failed = [m for m in measured if not m.get("passed")]
    return (failed or measured or [{"text": ""}])[0].get("text", "")


def write_csv(report, rows, chapter_names, criterion_names):
    with open(os.path.join(report, "summary.csv"), "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["student", "directory", "total", "max", *chapter_names, *criterion_names, "seed", "date",
                    "submission_sha256", "seconds", "status"])
        for r in rows:
            by = points_by_criterion(r)
            w.writerow([r["student"], r["directory"], r["total"], r["max"],
                        *[r["chapters"].get(c, ("", ""))[0] for c in chapter_names],
                        *[by[k]["points"] if k in by else "" for k in criterion_names],
                        r["seed"], r["date"], r["sha256"], r["seconds"], r["status"]])
    with open(os.path.join(report, "criteria.csv"), "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["student", "chapter", "criterion", "points", "max", "passed", "p_value", "measured", "message",
                    "seed", "date", "submission_sha256"])
        for r in rows:
            for c in r["criteria"]:
                w.writerow([r["student"], c["chapter"], c["name"], c["points"], c["max"], c["passed"],
                            "" if c.get("p_value") is None else c["p_value"], first_measured(c),
                            c["message"][:500], r["seed"], r["date"], r["sha256"]])


def criteria_table(rows, criterion_names):
    """How the class did on each criterion: how many passed (for the instructor: a criterion most
    fail may be a hard exercise, or a lecture that did not land)."""
    h = html.escape
    graded = [r for r in rows if r["status"] == "graded"]
    if not graded:
        return []
    out = ["<h2>Per criterion</h2><table><tr><th>criterion</th><th>passed</th></tr>"]
    for k in criterion_names:
        passed = sum(1 for r in graded if points_by_criterion(r).get(k, {}).get("passed"))
        out.append(f"<tr><td>{h(k)}</td><td>{passed} of {len(graded)}</td></tr>")
    out.append("</table>")
    return out


def refusal(log):
    """The one line kit/grade.py wrote when it refused a submission ("kit/grade.py: not graded: ..."),
    or None."""
    try:
        with open(log, errors="replace") as f:
            lines = [ln.strip() for ln in f.read(1 << 20).splitlines()]
    except OSError:
        return None
    found = [ln.split("not graded: ", 1)[1] for ln in lines if "kit/grade.py: not graded: " in ln]
    return found[-1][:300] if found else None


def main(argv):
    report, jobs, login, extra, dirs = os.path.join(ROOT, "out", "class"), os.cpu_count() or 1, None, [], []
    slurm, slurm_jobs = False, None
    i = 0
    while i < len(argv):
        a = argv[i]
        if a in ("-h", "--help"):
            print(__doc__.strip())
            return
        if a == "--slurm":
            slurm, i = True, i + 1
            continue
        if a in ("--report", "--jobs", "--sshloginfile", "--chapters", "--seed", "--rubric"):
            if i + 1 >= len(argv):
                fail(f"{a} needs a value")
            v = argv[i + 1]
            if a == "--report":
                report = os.path.abspath(v)
            elif a == "--jobs":
                if not v.isdigit() or int(v) < 1:
                    fail(f"--jobs {v}: not a positive integer")
                jobs = slurm_jobs = int(v)
            elif a == "--sshloginfile":
                login = v
            else:
                extra += [a, v]
            i += 2
            continue
        if a.startswith("-"):
            fail(f"unknown option {a}")
        if a.startswith("@"):
            try:
                with open(a[1:]) as f:
                    dirs += [ln.strip() for ln in f if ln.strip() and not ln.lstrip().startswith("#")]
            except OSError as e:
                fail(f"{a}: {e.strerror}")
        else:
            dirs.append(a)
        i += 1
    if not dirs:
        fail("no submissions given")
    if slurm and login:
        fail("--slurm and --sshloginfile: one or the other")
    if not slurm and not shutil.which("parallel"):
        fail("GNU parallel is missing: sudo apt-get install -y parallel")
    # One report directory per student, named after the directory (numbered when two share a name).
    names, seen = [], {}
    for d in dirs:
        base = os.path.basename(os.path.abspath(d)) or "submission"  # "." is named after the directory
        seen[base] = seen.get(base, 0) + 1
        names.append(base if seen[base] == 1 else f"{base}-{seen[base]}")
    os.makedirs(report, exist_ok=True)
    table = os.path.join(report, "submissions.tsv")
    with open(table, "w") as f:
        for d, n in zip(dirs, names):
            f.write(f"{os.path.abspath(d)}\t{n}\n")
    cmd = ["parallel", "--colsep", "\t", "--jobs", str(jobs), "--joblog", os.path.join(report, "joblog.tsv"),
           "--halt", "never", "--tag"]
    if login:
        cmd += ["--sshloginfile", login]
    # GNU parallel joins the command's words with spaces for the shell (here or on the remote machine
    # over ssh), so every word we give is quoted; {1} and {2} are quoted by parallel itself.  The
    # interpreter is Debian's, which every machine of the class has (this one may run another).
    python = "/usr/bin/python3" if os.path.exists("/usr/bin/python3") else sys.executable
    words = [python, os.path.join(KIT, "grade.py")]
    words = [shlex.quote(w) for w in words] + ["{1}", "--report", shlex.quote(report) + "/{2}", "--name", "{2}",
                                               "--jobs", "1", *map(shlex.quote, extra)]
    cmd += words + [">", shlex.quote(report) + "/{2}.log", "2>&1", "::::", table]
    if slurm:
        import slurm_engine
        slurm_engine.grade_class(report, [python, os.path.join(KIT, "grade.py")], extra, slurm_jobs)
    else:
        subprocess.run(cmd)
    status = {}
    try:
        with open(os.path.join(report, "joblog.tsv")) as f:
            for row in list(csv.reader(f, delimiter="\t"))[1:]:
                words = shlex.split(row[-1])
                if "--name" in words:
                    status[words[words.index("--name") + 1]] = (row[6].strip(), row[3].strip())
    except OSError:
        pass
    rows = []
    for d, n in zip(dirs, names):
        path = os.path.join(report, n, "report.json")
        try:
            with open(path) as f:
                r = json.load(f)
            chapters = {}
            for c in r["criteria"]:
                got, top = chapters.get(c["chapter"], (0, 0))
                chapters[c["chapter"]] = (got + c["points"], top + c["max"])
            rows.append({"student": n, "directory": os.path.abspath(d), "total": r["total"], "max": r["max"],
                         "chapters": chapters, "seconds": r.get("seconds"), "status": "graded",
                         "criteria": r["criteria"], "seed": r.get("seed", ""), "date": r.get("date", ""),
                         "sha256": r.get("submission_sha256", "")})
        except (OSError, ValueError, KeyError):
            code, seconds = status.get(n, ("?", "?"))
            reason = refusal(os.path.join(report, n + ".log"))
            rows.append({"student": n, "directory": os.path.abspath(d), "total": "", "max": "", "chapters": {},
                         "seconds": seconds, "status": f"not graded: {reason}" if reason else
                         f"not graded (exit status {code}; see {n}.log)",
                         "criteria": [], "seed": "", "date": "", "sha256": ""})
    chapter_names = sorted({c for r in rows for c in r["chapters"]})
    criterion_names = []  # "chapter: name", in rubric order as the reports list them
    for r in rows:
        for c in r["criteria"]:
            key = f"{c['chapter']}: {c['name']}"
            if key not in criterion_names:
                criterion_names.append(key)
    write_csv(report, rows, chapter_names, criterion_names)
    h = html.escape
    out = ["<!doctype html><meta charset=utf-8><title>class summary</title><style>body{font-family:sans-serif}"
           "table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:4px 8px}</style>",
           f"<h1>Class summary ({len(rows)} submissions)</h1><table><tr><th>student</th><th>total</th>" +
           "".join(f"<th>{h(c)}</th>" for c in chapter_names) +
           "<th>seed</th><th>date</th><th>sha256</th><th>seconds</th><th>status</th></tr>"]
    for r in rows:
        link = f"<a href='{h(r['student'])}/report.html'>{h(r['student'])}</a>" if r["status"] == "graded" \
            else h(r["student"])
        cells = "".join(f"<td>{r['chapters'][c][0]} / {r['chapters'][c][1]}</td>" if c in r["chapters"]
                        else "<td></td>" for c in chapter_names)
        out.append(f"<tr><td>{link}</td><td>{r['total']} / {r['max']}</td>{cells}<td>{h(str(r['seed']))}</td>"
                   f"<td>{h(r['date'])}</td><td title='{h(r['sha256'])}'><code>{h(r['sha256'][:12])}</code></td>"
                   f"<td>{r['seconds']}</td><td>{h(r['status'])}</td></tr>")
    out.append("</table>")
    out += criteria_table(rows, criterion_names)
    with open(os.path.join(report, "summary.html"), "w") as f:
        f.write("\n".join(out) + "\n")
    if slurm:
        slurm_engine.note_retries(report)
    graded = sum(1 for r in rows if r["status"] == "graded")
    print(f"{graded} of {len(rows)} submissions graded; summary: {os.path.join(report, 'summary.html')}")


if __name__ == "__main__":
    main(sys.argv[1:])
