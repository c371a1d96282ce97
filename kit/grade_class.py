#!/usr/bin/python3
"""Grade a class: many submissions in parallel with GNU parallel, then a summary (CSV and HTML).

usage: kit/grade_class.py [--report DIR] [--jobs N] [--sshloginfile FILE [--ssh CMD] [--remote-root DIR] | --slurm]
                          [--retries N] [--chapters "A B"] [--seed N] [kit/grade.py options]
                          SUBMISSION... | @LIST.txt

  SUBMISSION   a student's directory; @LIST.txt: one directory per line (# comments)
  --report DIR class reports (default out/class): DIR/<student>/report.{json,html}, DIR/<student>.log,
               DIR/summary.{csv,html} with its plots DIR/scores.svg and DIR/criteria.svg, DIR/criteria.csv,
               DIR/joblog.tsv (GNU parallel's log: exit status, time and machine of each grading's last
               attempt), DIR/.attempts/ (a record and log of every attempt: which machine, when, how it ended).  A class
               graded again into the same DIR replaces its students' reports.
  --jobs N     gradings at once (default: as many as this machine's cores and free memory hold, each grading
               one core and its memory cap: kit/grade.py --gradings-that-fit).  With
               --sshloginfile: gradings at once on each machine (default: its number in the login file,
               "4/user@host", else its number of cores)
  --sshloginfile FILE   spread the gradings over the machines in FILE (GNU parallel's format, e.g.
               "4/user@host"; ":" is this machine); every machine must see the submissions and DIR at
               the same paths (a shared file system), the project (this one, or --remote-root) and have
               the build packages installed
  --ssh CMD    the ssh command GNU parallel runs (default: ssh in batch mode whose keep-alives give up on
               a machine that stopped answering after about a minute)
  --remote-root DIR   where the machines of the login file have their copy of this project (default: at
               this project's path)
  --retries N  a grading that fails (its machine lost, ssh failing, a grader that crashed) is tried again,
               on another machine where there is one, up to N times in all (default 3 with
               --sshloginfile, else 1); then a last pass (GNU parallel's --resume-failed) regrades what
               still failed once more, on the machines that answer over ssh then (DIR/last-pass-logins)
  --chapters, --seed, --rubric, --timeout, --memory, --sandbox, --unsafe, --public   as kit/grade.py's
  --slurm      grade on a Slurm cluster instead: one job array, a task per submission (several arrays where the
               class is larger than the cluster's MaxArraySize), a task that ends without a report (node lost,
               killed) submitted once more; summary.csv's column "retried" names them (kit/slurm_engine.py;
               --jobs N: at most N tasks at once, each array then waiting for the one before it)

A grading that fails leaves a row "not graded" with its exit status; a submission the kit refuses a row
"not graded: <reason>"; the other students' reports are kept.  Every grading runs kit/grade_job.py,
which grades into an attempt directory and moves it to DIR/<student> only when its report is
complete: a student has one report or none, however many machines tried.

summary.csv: one row per student: total, points per chapter, points per criterion (columns
"chapter: criterion"), the grading seed, the date, and the sha256 of the submission's files (so a
regrade or an appeal can show it graded the same code), the seconds the grading took, the machine that
graded it and the attempts (the machines that tried, in order, "+" between them: more than one is a
retry), the limits its runs hit, its status.  criteria.csv: one row per student and criterion, with
its measured value (the report's sentence) and p-value.  summary.html: the table, the scores'
histogram, each criterion's pass rate, the slowest gradings, the submissions that hit a limit (a
time-out, the memory, CPU time or process cap, the file size cap) and the retried ones.
"""
import concurrent.futures
import csv
import html
import json
import os
import re
import shlex
import shutil
import signal
import subprocess
import sys

KIT = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(KIT)
sys.path.insert(0, KIT)
import sandbox  # noqa: E402
# grade.py's options a class passes through to every grading: with a value, and without
GRADE_OPTIONS = ("--chapters", "--seed", "--rubric", "--timeout", "--memory", "--sandbox")
GRADE_FLAGS = ("--unsafe", "--public")
# ssh that gives up on a machine that stopped answering (keep-alives), and never asks for a password
DEFAULT_SSH = "ssh -o BatchMode=yes -o ConnectTimeout=30 -o ServerAliveInterval=15 -o ServerAliveCountMax=4"


def fail(message):
    say(message)
    sys.exit(2)


def say(message):
    print(f"kit/grade_class.py: {message}", file=sys.stderr, flush=True)


# ---- options and the students ---------------------------------------------------------------------

def parse_args(argv):
    opts = {"report": os.path.join(ROOT, "out", "class"), "jobs": None, "sshloginfile": None,
            "ssh": None, "remote_root": None, "retries": None, "grade": [], "dirs": [], "slurm": False}
    i = 0
    while i < len(argv):
        a = argv[i]
        if a in ("-h", "--help"):
            print(__doc__.strip())
            sys.exit(0)
        if a == "--slurm":
            opts["slurm"] = True
            i += 1
            continue
        if a in GRADE_FLAGS:
            opts["grade"].append(a)
            i += 1
            continue
        if a in ("--report", "--jobs", "--sshloginfile", "--ssh", "--remote-root", "--retries") + GRADE_OPTIONS:
            if i + 1 >= len(argv):
                fail(f"{a} needs a value")
            v = argv[i + 1]
            if a in ("--jobs", "--retries"):
                if not v.isdigit() or int(v) < 1:
                    fail(f"{a} {v}: not a positive integer")
                opts[a[2:]] = int(v)
            elif a in ("--report", "--remote-root"):
                opts[a[2:].replace("-", "_")] = os.path.abspath(v)
            elif a == "--sshloginfile":
                if not os.path.isfile(v):
                    fail(f"--sshloginfile {v}: no such file")
                opts["sshloginfile"] = os.path.abspath(v)
            elif a == "--ssh":
                opts["ssh"] = v
            else:
                opts["grade"] += [a, v]
            i += 2
            continue
        if a.startswith("-"):
            fail(f"unknown option {a}")
        if a.startswith("@"):
            try:
                with open(a[1:]) as f:
                    opts["dirs"] += [ln.strip() for ln in f if ln.strip() and not ln.lstrip().startswith("#")]
            except OSError as e:
                fail(f"{a}: {e.strerror}")
        else:
            opts["dirs"].append(a)
        i += 1
    if not opts["dirs"]:
        fail("no submissions given")
    if opts["slurm"] and opts["sshloginfile"]:
        fail("--slurm and --sshloginfile: one or the other")
    if (opts["ssh"] or opts["remote_root"]) and not opts["sshloginfile"]:
        fail("--ssh and --remote-root need --sshloginfile")
    opts["jobs_given"] = opts["jobs"] is not None
    if opts["jobs"] is None:  # GNU parallel's --jobs is per machine: 100 % of each one's cores (or its number)
        memory = opts["grade"][opts["grade"].index("--memory") + 1] if "--memory" in opts["grade"] else None
        cap = int(memory) if memory and memory.isdigit() else sandbox.Limits().memory_mib
        opts["jobs"] = "100%" if opts["sshloginfile"] else sandbox.gradings_that_fit(cap)  # a core and its cap each
    if opts["retries"] is None:
        opts["retries"] = 3 if opts["sshloginfile"] else 1
    return opts


def students(dirs):
    """[(absolute directory, name)]: one report directory per student, named after the directory
    (numbered when two share a name; never hidden)."""
    out, seen = [], {}
    for d in dirs:
        base = os.path.basename(os.path.abspath(d)).lstrip(".") or "submission"  # "." is named after its dir
        seen[base] = seen.get(base, 0) + 1
        out.append((os.path.abspath(d), base if seen[base] == 1 else f"{base}-{seen[base]}"))
    return out


def job_command(opts):
    """The command of one grading as argv words, with {1} for the submission's directory and {2} for
    the student's name (an engine substitutes them): kit/grade_job.py of this project, or of the
    machines' copy (--remote-root).  The interpreter is Debian's, which every machine of the class has."""
    root = opts["remote_root"] or ROOT
    python = "/usr/bin/python3" if os.path.exists("/usr/bin/python3") or opts["remote_root"] else sys.executable
    return [python, os.path.join(root, "kit", "grade_job.py"), opts["report"], "{2}", "{1}", "--jobs", "1",
            *opts["grade"]]


def clear_reports(report, table):
    """What an earlier grading of these students left in report (their reports, logs, attempts); never
    a submission (a report directory that holds the submissions under their own names)."""
    submitted = [os.path.realpath(d) for d, _ in table]
    for _, n in table:
        target = os.path.realpath(os.path.join(report, n))
        if any(d == target or d.startswith(target + os.sep) for d in submitted):
            fail(f"--report {report}: {n}/ there is a submission, not a report: another --report DIR")
    for _, n in table:
        for path in (os.path.join(report, n), os.path.join(report, ".attempts", n)):
            if os.path.isdir(path) and not os.path.islink(path):
                shutil.rmtree(path)
        if os.path.lexists(os.path.join(report, n + ".log")):
            os.unlink(os.path.join(report, n + ".log"))


# ---- the engine: GNU parallel (here, or over ssh) -------------------------------------------------

def read_joblog(path):
    """{student: {"exit", "signal", "seconds", "host"}} from GNU parallel's joblog (its last row for a
    student: a --resume-failed pass appends)."""
    status = {}
    try:
        with open(path) as f:
            for row in list(csv.reader(f, delimiter="\t"))[1:]:
                words = shlex.split(row[-1])
                if len(words) >= 4 and words[1].endswith("grade_job.py"):
                    status[words[3]] = {"exit": row[6].strip(), "signal": row[7].strip(),
                                        "seconds": row[3].strip(), "host": row[1].strip()}
    except OSError:
        pass
    return status


def run_parallel(table, opts):
    """Grade the students of `table` (a file of "directory<TAB>name" lines) with GNU parallel;
    {student: {"exit", "signal", "seconds", "host"}} as the engine saw each one's last attempt."""
    if not shutil.which("parallel"):
        fail("GNU parallel is missing: sudo apt-get install -y parallel")
    joblog = os.path.join(opts["report"], "joblog.tsv")
    cmd = ["parallel", "--colsep", "\t", "--jobs", str(opts["jobs"]), "--joblog", joblog, "--halt", "never",
           "--tag", "--retries", str(opts["retries"])]
    if opts["sshloginfile"]:
        cmd += ["--sshloginfile", opts["sshloginfile"], "--ssh", opts["ssh"] or DEFAULT_SSH]
    # GNU parallel joins the command's words with spaces for the shell (here or on the remote machine
    # over ssh), so every word we give is quoted; {1} and {2} are quoted by parallel itself.
    words = [w if w in ("{1}", "{2}") else shlex.quote(w) for w in job_command(opts)]
    if os.path.exists(joblog):
        os.unlink(joblog)
    subprocess.run(cmd + words + ["::::", table], stdin=subprocess.DEVNULL)
    status = read_joblog(joblog)
    if any(s["exit"] != "0" for s in status.values()) or len(status) < sum(1 for _ in open(table)):
        # what failed (a machine lost with all its retries, a grader that crashed) or never ran, once more,
        # on the machines that still answer
        if opts["sshloginfile"]:
            logins = reachable_logins(opts["sshloginfile"], opts["ssh"] or DEFAULT_SSH,
                                      os.path.join(opts["report"], "last-pass-logins"))
            if logins is None:
                say("no machine of the login file answers over ssh: no last pass")
                return status
            cmd[cmd.index("--sshloginfile") + 1] = logins
        subprocess.run(cmd + ["--resume-failed"] + words + ["::::", table], stdin=subprocess.DEVNULL)
        status = read_joblog(joblog)
    return status


PROBE_SECONDS = 90  # an ssh that has not logged in and run `true` by then: the machine is lost


def reachable_logins(path, ssh, out):
    """A copy of the login file `path` at `out` without the machines that do not answer `ssh MACHINE true`
    now (asked all at once, at most PROBE_SECONDS): GNU parallel sends work to every machine of its
    file, a lost one too, and with --retries 1 a last pass's grading sent there would fail again.
    None if no machine answers.  Lines GNU parallel reads but this does not (a login that is an ssh
    command of its own) are kept."""
    lines = []
    try:
        with open(path) as f:
            lines = [ln.strip() for ln in f if ln.strip() and not ln.lstrip().startswith("#")]
    except OSError:
        return path  # GNU parallel's own names (.., -): left to it
    logins = [ln.split("/", 1)[1] if re.match(r"\d+/", ln) else ln for ln in lines]

    def answers(login):
        if login == ":" or not re.fullmatch(r"[\w.@:%+-]+", login):
            return True
        try:
            return subprocess.run(shlex.split(ssh) + [login, "true"], stdin=subprocess.DEVNULL,
                                  capture_output=True, timeout=PROBE_SECONDS).returncode == 0
        except subprocess.TimeoutExpired:
            return False
    with concurrent.futures.ThreadPoolExecutor(max_workers=min(32, len(logins) or 1)) as pool:
        alive = list(pool.map(answers, logins))
    for login, ok in zip(logins, alive):
        if not ok:
            say(f"{login} does not answer over ssh: left out of the last pass")
    kept = [ln for ln, ok in zip(lines, alive) if ok]
    if not kept:
        return None
    with open(out, "w") as f:
        f.write("\n".join(kept) + "\n")
    return out


# ---- the engine: Slurm (kit/slurm_engine.py) -------------------------------------------------------

def run_slurm(table, opts):
    """Grade the students of `table` as a Slurm job array (kit/slurm_engine.py); {student: {"exit",
    "signal", "seconds", "host"}} from the joblog it writes in GNU parallel's format (kit/grade.py's
    command words, the student after --name)."""
    import slurm_engine
    python = "/usr/bin/python3" if os.path.exists("/usr/bin/python3") else sys.executable
    jobs = opts["jobs"] if opts["jobs_given"] else None
    opts["slurm_retried"] = slurm_engine.grade_class(opts["report"], [python, os.path.join(KIT, "grade.py")],
                                                     opts["grade"], jobs)
    status = {}
    try:
        with open(os.path.join(opts["report"], "joblog.tsv")) as f:
            for row in list(csv.reader(f, delimiter="\t"))[1:]:
                words = shlex.split(row[-1])
                if "--name" in words:
                    status[words[words.index("--name") + 1]] = {"exit": row[6].strip(), "signal": row[7].strip(),
                                                                "seconds": row[3].strip(), "host": row[1].strip()}
    except OSError:
        pass
    return status


ENGINES = {"parallel": run_parallel, "slurm": run_slurm}


# ---- what each grading left: the summary (whatever engine graded) ------------------------------

def attempts_of(report, name):
    """The attempt records of a student (kit/grade_job.py), in the order they started."""
    top = os.path.join(report, ".attempts", name)
    records = []
    try:
        for f in os.listdir(top):
            if f.endswith(".json"):
                try:
                    with open(os.path.join(top, f)) as fh:
                        records.append(json.load(fh))
                except (OSError, ValueError):
                    continue
    except OSError:
        pass
    return sorted(records, key=lambda r: r.get("started") or 0)


def remove_unfinished_attempts(report, names):
    """The directories of attempts that never ended (their machine was lost): nothing of theirs counts."""
    for n in names:
        top = os.path.join(report, ".attempts", n)
        if os.path.isdir(top):
            for f in os.listdir(top):
                path = os.path.join(top, f)
                if os.path.isdir(path) and not os.path.islink(path):
                    shutil.rmtree(path, ignore_errors=True)


# What a criterion's message says when a run hit one of the grader's limits (kit/sandbox.py's and
# kit/grade.py's own words).  The message holds the end of the run's stderr too, which a submission
# writes: a submission could make itself look limited in this table (not in its points).
LIMITS = [("time", re.compile(r"timed out after|time-out after")),
          ("memory", re.compile(r"memory cap of \d+")),
          ("CPU time", re.compile(r"CPU time cap of")),
          ("processes", re.compile(r"processes outlived the run|Resource temporarily unavailable")),
          ("file size", re.compile(r"SIGXFSZ|File too large|exited -%d\b" % signal.SIGXFSZ))]


def limits_hit(r):
    """[(criterion, limit)] for the report r's criteria whose runs hit a limit: the grader's own record
    (criterion["limit"]: "memory", "time" or "output", written by kit/grade.py from the sandbox's log of the
    runs it stopped) where it names one; else read from the message (older reports, and the caps the record
    does not tell apart: CPU time, processes, a run that wrote on past the file size cap)."""
    found = []
    for c in r["criteria"]:
        if c.get("limit"):
            found.append((c["name"], {"output": "file size"}.get(c["limit"], c["limit"])))
            continue
        for limit, pattern in LIMITS:
            if pattern.search(c.get("message", "")):
                found.append((c["name"], limit))
    return found


def points_by_criterion(r):
    return {f"{c['chapter']}: {c['name']}": c for c in r["criteria"]}


def first_measured(c):
    """The sentence of the criterion's first failed comparison, else its first one ("" if none)."""
    measured = c.get("measured") or []
    failed = [m for m in measured if not m.get("passed")]
    return (failed or measured or [{"text": ""}])[0].get("text", "")


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


def collect(report, table, engine):
    """One row per student from what the gradings left in report: its report.json, its attempts,
    the engine's status (engine: {student: {"exit", "seconds", "host", ...}}, possibly empty)."""
    rows = []
    for d, n in table:
        attempts = attempts_of(report, n)
        placed = [a for a in attempts if a.get("placed")]
        base = {"student": n, "directory": d, "attempts": [a.get("host", "?") for a in attempts],
                "lost": sum(1 for a in attempts if a.get("ended") is None)}
        try:
            with open(os.path.join(report, n, "report.json")) as f:
                r = json.load(f)
            chapters = {}
            for c in r["criteria"]:
                got, top = chapters.get(c["chapter"], (0, 0))
                chapters[c["chapter"]] = (got + c["points"], top + c["max"])
            rows.append(dict(base, total=r["total"], max=r["max"], chapters=chapters, seconds=r.get("seconds"),
                             status="graded", criteria=r["criteria"], seed=r.get("seed", ""), date=r.get("date", ""),
                             sha256=r.get("submission_sha256", ""), limits=limits_hit(r),
                             host=placed[-1].get("host", "?") if placed else engine.get(n, {}).get("host", "")))
        except (OSError, ValueError, KeyError, TypeError):
            s = engine.get(n, {})
            code, seconds = s.get("exit", "?"), s.get("seconds", "?")
            reason = refusal(os.path.join(report, n + ".log"))
            ended = [a for a in attempts if a.get("ended") is not None]
            rows.append(dict(base, total="", max="", chapters={}, seconds=seconds, criteria=[], seed="", date="",
                             sha256="", limits=[], host=ended[-1].get("host", "") if ended else s.get("host", ""),
                             status=f"not graded: {reason}" if reason else
                             f"not graded (exit status {code}; see {n}.log)"))
    return rows


def write_csv(report, rows, chapter_names, criterion_names):
    with open(os.path.join(report, "summary.csv"), "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["student", "directory", "total", "max", *chapter_names, *criterion_names, "seed", "date",
                    "submission_sha256", "seconds", "host", "attempts", "limits", "status"])
        for r in rows:
            by = points_by_criterion(r)
            w.writerow([r["student"], r["directory"], r["total"], r["max"],
                        *[r["chapters"].get(c, ("", ""))[0] for c in chapter_names],
                        *[by[k]["points"] if k in by else "" for k in criterion_names],
                        r["seed"], r["date"], r["sha256"], r["seconds"], r["host"], "+".join(r["attempts"]),
                        "; ".join(f"{c}: {lim}" for c, lim in r["limits"]), r["status"]])
    with open(os.path.join(report, "criteria.csv"), "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["student", "chapter", "criterion", "points", "max", "passed", "p_value", "measured", "message",
                    "seed", "date", "submission_sha256"])
        for r in rows:
            for c in r["criteria"]:
                w.writerow([r["student"], c["chapter"], c["name"], c["points"], c["max"], c["passed"],
                            "" if c.get("p_value") is None else c["p_value"], first_measured(c),
                            c["message"][:500], r["seed"], r["date"], r["sha256"]])


# ---- plots: SVG written here, no plotting library ----------------------------------------------

def histogram_bins(rows, bins=10):
    """[(low, high, count)]: the graded students' totals in `bins` equal bins over 0..max (the last
    bin holds max itself); [] when nothing was graded."""
    graded = [r for r in rows if r["status"] == "graded"]
    if not graded:
        return []
    top = max(r["max"] for r in graded) or 1
    edges = [top * k / bins for k in range(bins + 1)]
    counts = [0] * bins
    for r in graded:
        counts[min(bins - 1, int(r["total"] * bins / top))] += 1
    return [(edges[k], edges[k + 1], counts[k]) for k in range(bins)]


def fmt(x):
    return f"{x:g}"


def svg_histogram(bins):
    """A bar chart of the scores: one <rect class='bar' data-count=N> per bin, height proportional to N."""
    width, height, left, bottom, top = 520, 240, 40, 40, 20
    most = max((c for _, _, c in bins), default=0) or 1
    bar_w = (width - left - 10) / max(len(bins), 1)
    scale = (height - top - bottom) / most
    out = [f"<svg xmlns='http://www.w3.org/2000/svg' width='{width}' height='{height}' font-family='sans-serif' "
           f"font-size='11'><title>scores of the graded submissions</title>",
           f"<line x1='{left}' y1='{height - bottom}' x2='{width - 10}' y2='{height - bottom}' stroke='black'/>"]
    for k, (low, high, count) in enumerate(bins):
        x, h = left + k * bar_w, count * scale
        out.append(f"<rect class='bar' data-low='{fmt(low)}' data-high='{fmt(high)}' data-count='{count}' "
                   f"x='{x + 2:.1f}' y='{height - bottom - h:.2f}' width='{bar_w - 4:.1f}' height='{h:.2f}' "
                   f"fill='#4a7ab5'><title>{fmt(low)}-{fmt(high)} points: {count}</title></rect>")
        if count:
            out.append(f"<text x='{x + bar_w / 2:.1f}' y='{height - bottom - h - 3:.1f}' "
                       f"text-anchor='middle'>{count}</text>")
        out.append(f"<text x='{x + bar_w / 2:.1f}' y='{height - bottom + 14}' text-anchor='middle'>"
                   f"{fmt(round(low, 1))}</text>")
    out.append(f"<text x='{(width + left) / 2}' y='{height - 8}' text-anchor='middle'>points (bins of "
               f"{fmt(round(bins[0][1] - bins[0][0], 2)) if bins else 0}; the last holds the maximum)</text>")
    out.append(f"<text x='12' y='{(height - bottom + top) / 2}' transform='rotate(-90 12 "
               f"{(height - bottom + top) / 2})' text-anchor='middle'>students</text></svg>")
    return "\n".join(out)


def pass_rates(rows, criterion_names):
    """[(criterion, passed, graded)] over the graded students."""
    graded = [r for r in rows if r["status"] == "graded"]
    return [(k, sum(1 for r in graded if points_by_criterion(r).get(k, {}).get("passed")), len(graded))
            for k in criterion_names]


def svg_pass_rates(rates):
    """One horizontal <rect class='bar' data-passed=P data-graded=N> per criterion, its length P/N."""
    label_w, bar_max, row_h = 330, 260, 20
    height = row_h * len(rates) + 30
    out = [f"<svg xmlns='http://www.w3.org/2000/svg' width='{label_w + bar_max + 90}' height='{height}' "
           f"font-family='sans-serif' font-size='11'><title>pass rate of each criterion</title>"]
    for k, (name, passed, graded) in enumerate(rates):
        y = 10 + k * row_h
        w = bar_max * passed / graded if graded else 0
        out.append(f"<text x='{label_w - 6}' y='{y + 13}' text-anchor='end'>{html.escape(name)}</text>")
        out.append(f"<rect x='{label_w}' y='{y + 2}' width='{bar_max}' height='{row_h - 6}' fill='#eee'/>")
        out.append(f"<rect class='bar' data-passed='{passed}' data-graded='{graded}' x='{label_w}' y='{y + 2}' "
                   f"width='{w:.2f}' height='{row_h - 6}' fill='#3a9a5a'><title>{html.escape(name)}: {passed} "
                   f"of {graded}</title></rect>")
        out.append(f"<text x='{label_w + bar_max + 6}' y='{y + 13}'>{passed} of {graded}</text>")
    out.append("</svg>")
    return "\n".join(out)


# ---- the HTML summary ----------------------------------------------------------------------------

def write_html(report, rows, chapter_names, criterion_names):
    h = html.escape
    graded = [r for r in rows if r["status"] == "graded"]
    with open(os.path.join(report, "scores.svg"), "w") as f:
        f.write(svg_histogram(histogram_bins(rows)) + "\n")
    with open(os.path.join(report, "criteria.svg"), "w") as f:
        f.write(svg_pass_rates(pass_rates(rows, criterion_names)) + "\n")
    hosts = sorted({r["host"] for r in graded if r["host"]})
    out = ["<!doctype html><meta charset=utf-8><title>class summary</title><style>body{font-family:sans-serif}"
           "table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:4px 8px}.fail{color:#b00}</style>",
           f"<h1>Class summary ({len(rows)} submissions)</h1>",
           f"<p>{len(graded)} graded, {len(rows) - len(graded)} not graded"
           + (f"; on {len(hosts)} machine{'s' if len(hosts) > 1 else ''}: "
              + ", ".join(f"{h(x)} ({sum(1 for r in graded if r['host'] == x)})" for x in hosts) if hosts else "")
           + ".</p>"]
    if graded:
        out += ["<h2>Scores</h2><img src='scores.svg' alt='histogram of the scores'>",
                "<h2>Per criterion</h2><p>How many of the graded submissions passed each criterion (a criterion "
                "most fail may be a hard exercise, or a lecture that did not land).</p>"
                "<img src='criteria.svg' alt='pass rate of each criterion'>"]
        slow = sorted(graded, key=lambda r: -(r["seconds"] or 0))[:5]
        out.append("<h2>Slowest gradings</h2><table><tr><th>student</th><th>seconds</th><th>machine</th>"
                   "<th>total</th></tr>" + "".join(
                       f"<tr><td>{h(r['student'])}</td><td>{r['seconds']}</td><td>{h(r['host'])}</td>"
                       f"<td>{r['total']} / {r['max']}</td></tr>" for r in slow) + "</table>")
    limited = [r for r in rows if r["limits"]]
    out.append("<h2>Submissions that hit a limit</h2>" + (
        "<table><tr><th>student</th><th>criterion: limit</th></tr>" + "".join(
            f"<tr><td>{h(r['student'])}</td><td>{h('; '.join(f'{c}: {lim}' for c, lim in r['limits']))}</td></tr>"
            for r in limited) + "</table>" if limited else "<p>none</p>"))
    retried = [r for r in rows if len(r["attempts"]) > 1]
    out.append("<h2>Retried gradings</h2><p>A grading tried on more than one machine, or more than once (its "
               "machine lost, or its grader failed); only the last that ended with a report counts.</p>" + (
                   "<table><tr><th>student</th><th>attempts (machines in order)</th><th>lost</th><th>graded by"
                   "</th></tr>" + "".join(
                       f"<tr><td>{h(r['student'])}</td><td>{h(' + '.join(r['attempts']))}</td><td>{r['lost']}</td>"
                       f"<td>{h(r['host'])}</td></tr>" for r in retried) + "</table>" if retried else "<p>none</p>"))
    out.append("<h2>Students</h2><table><tr><th>student</th><th>total</th>" +
               "".join(f"<th>{h(c)}</th>" for c in chapter_names) +
               "<th>seed</th><th>date</th><th>sha256</th><th>seconds</th><th>machine</th><th>status</th></tr>")
    for r in rows:
        link = f"<a href='{h(r['student'])}/report.html'>{h(r['student'])}</a>" if r["status"] == "graded" \
            else h(r["student"])
        cells = "".join(f"<td>{r['chapters'][c][0]} / {r['chapters'][c][1]}</td>" if c in r["chapters"]
                        else "<td></td>" for c in chapter_names)
        machine = h(r["host"]) + (f" (after {h(' + '.join(r['attempts'][:-1]))})" if len(r["attempts"]) > 1 else "")
        out.append(f"<tr><td>{link}</td><td>{r['total']} / {r['max']}</td>{cells}<td>{h(str(r['seed']))}</td>"
                   f"<td>{h(r['date'])}</td><td title='{h(r['sha256'])}'><code>{h(r['sha256'][:12])}</code></td>"
                   f"<td>{r['seconds']}</td><td>{machine}</td><td>{h(r['status'])}</td></tr>")
    out.append("</table>")
    with open(os.path.join(report, "summary.html"), "w") as f:
        f.write("\n".join(out) + "\n")


def summarize(report, table, engine):
    """summary.csv, criteria.csv, summary.html and its plots from what the gradings left; the rows."""
    rows = collect(report, table, engine)
    chapter_names = sorted({c for r in rows for c in r["chapters"]})
    criterion_names = []  # "chapter: name", in rubric order as the reports list them
    for r in rows:
        for c in r["criteria"]:
            key = f"{c['chapter']}: {c['name']}"
            if key not in criterion_names:
                criterion_names.append(key)
    write_csv(report, rows, chapter_names, criterion_names)
    write_html(report, rows, chapter_names, criterion_names)
    return rows


def main(argv, engine="parallel"):
    opts = parse_args(argv)
    table = students(opts["dirs"])
    report = opts["report"]
    try:
        os.makedirs(report, exist_ok=True)
        clear_reports(report, table)
    except OSError as e:
        fail(f"--report {report}: {e.strerror}")
    path = os.path.join(report, "submissions.tsv")
    with open(path, "w") as f:
        for d, n in table:
            f.write(f"{d}\t{n}\n")
    engine = "slurm" if opts["slurm"] else engine
    status = ENGINES[engine](path, opts)
    remove_unfinished_attempts(report, [n for _, n in table])
    rows = summarize(report, table, status)
    retried = sum(1 for r in rows if len(r["attempts"]) > 1)
    if engine == "slurm":
        import slurm_engine
        slurm_engine.note_retries(report)
        retried = len(opts["slurm_retried"] or {})
    graded = sum(1 for r in rows if r["status"] == "graded")
    print(f"{graded} of {len(rows)} submissions graded ({retried} retried); summary: "
          f"{os.path.join(report, 'summary.html')}")


if __name__ == "__main__":
    main(sys.argv[1:])
