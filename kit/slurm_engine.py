#!/usr/bin/python3
"""Grade a class on a Slurm cluster (kit/grade_class.py --slurm): one array task per submission.

kit/grade_class.py writes DIR/submissions.tsv (directory, student) and calls grade_class(); this module
  1. submits the class as a job array (sbatch --array=0-N, --no-requeue): task i grades line i with
     kit/grade.py (--name STUDENT --jobs 1 and the class's --chapters/--seed), as GNU parallel's path does;
     a class larger than the cluster's MaxArraySize goes as several arrays, and with --jobs N (each array's
     %N) each waits for the one before it (--dependency=afterany), so that N caps the class;
  2. waits for the array by polling squeue (a task Slurm holds after a failed launch is cancelled, so
     that it counts as failed rather than waiting for ever);
  3. submits once more, as a second array, every submission whose task left no report: a node lost mid-class
     (NODE_FAIL), a task killed or timed out, a grader that crashed.  A refused submission (kit/grade.py's
     exit status 2: a missing directory, a device file, too large) is not retried: it would be refused again;
  4. writes DIR/joblog.tsv in GNU parallel's format (one row per student, its last attempt), so the class
     summary reads it as it reads parallel's, and DIR/.slurm/retried.json; note_retries() then adds the
     column "retried" to summary.csv and a list to summary.html.

Exactly one report per student.  A task grades into DIR/.slurm/attempts/<job>_<task>/ and, when kit/grade.py
wrote a report there, renames that directory to DIR/<student>: a rename is atomic and fails when
DIR/<student> is already there, so of two attempts of one student (a task on a node that was declared lost
but still ran, and its retry) the first to finish is the report and the other is discarded, never mixed.
Reports of an earlier grading of the class into the same DIR are moved to DIR/.slurm/replaced/ first.

Every node must see this project, the submissions and DIR at the same paths (a shared file system), and have
the build packages and bubblewrap; tasks run as the submitting user (kit/grade.py needs root for the
sandbox's cgroups).  sbatch's own options come from the environment: SBATCH_PARTITION, SBATCH_ACCOUNT,
SBATCH_TIMELIMIT, SBATCH_MEM_PER_CPU, ... (see `man sbatch`, "INPUT ENVIRONMENT VARIABLES").

usage (by sbatch, not by hand): kit/slurm_engine.py task DIR LIST   grade the submission on line
        $SLURM_ARRAY_TASK_ID of DIR/.slurm/LIST (an index into DIR/submissions.tsv)
"""
import csv
import json
import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
import time

KIT = os.path.dirname(os.path.abspath(__file__))
POLL_SECONDS = 5.0           # between two squeue calls
UNREACHABLE_SECONDS = 600.0  # squeue failing this long (the controller gone): stop waiting
COMMAND_TIMEOUT = 120        # one sbatch, squeue, scontrol or scancel call
REFUSED = 2                  # kit/grade.py's exit status for a refused submission (or bad arguments)


def fail(message):
    print(f"kit/grade_class.py --slurm: {message}", file=sys.stderr)
    sys.exit(2)


def say(message):
    print(f"kit/grade_class.py --slurm: {message}", flush=True)


def slurm(*argv, check=True):
    """Run a Slurm command; its CompletedProcess (stdout, stderr as text)."""
    try:
        r = subprocess.run(list(argv), capture_output=True, text=True, timeout=COMMAND_TIMEOUT,
                           stdin=subprocess.DEVNULL)
    except subprocess.TimeoutExpired:
        r = subprocess.CompletedProcess(argv, 124, "", f"{argv[0]}: no answer in {COMMAND_TIMEOUT} s")
    if check and r.returncode != 0:
        raise SlurmError(f"{' '.join(argv[:2])} ...: {(r.stderr or r.stdout).strip()[:500]}")
    return r


class SlurmError(Exception):
    pass


class Stop(Exception):
    """SIGTERM (or SIGINT): cancel the class's jobs and stop."""


def state_dir(report):
    return os.path.join(report, ".slurm")


def read_table(report):
    """[(directory, student)] of DIR/submissions.tsv, in order."""
    with open(os.path.join(report, "submissions.tsv")) as f:
        return [tuple(line.rstrip("\n").split("\t", 1)) for line in f if line.strip()]


def max_array_size():
    """The cluster's MaxArraySize (an array's indices must be below it); 1001, Slurm's default, if unknown."""
    r = slurm("scontrol", "show", "config", check=False)
    m = re.search(r"^MaxArraySize\s*=\s*(\d+)", r.stdout, re.M)
    return int(m.group(1)) if m else 1001


def prepare(report, command, extra):
    """DIR/.slurm anew (the earlier grading's kept reports moved to .slurm/replaced), the task's script."""
    top = state_dir(report)
    shutil.rmtree(top, ignore_errors=True)
    for sub in ("attempts", "logs", "replaced"):
        os.makedirs(os.path.join(top, sub))
    for _, student in read_table(report):
        if student == ".slurm":
            fail("a submission directory named .slurm: its report would be the engine's state (rename it)")
        old = os.path.join(report, student)
        if os.path.lexists(old):
            os.rename(old, os.path.join(top, "replaced", student))
    with open(os.path.join(top, "command.json"), "w") as f:
        json.dump({"command": command, "extra": extra}, f)
    python = command[0]
    script = os.path.join(top, "grade-task.sh")
    with open(script, "w") as f:
        f.write("#!/bin/sh\n# one array task of kit/grade_class.py --slurm: grade one submission\n"
                f"exec {shlex.quote(python)} {shlex.quote(os.path.abspath(__file__))} task {shlex.quote(report)} "
                '"$1"\n')
    os.chmod(script, 0o755)
    return script


def submit(report, script, indices, round_number, jobs, array_limit):
    """Submit the table lines `indices` as job arrays (more than one when the class is larger than the
    cluster's MaxArraySize); [(job id, list file)].  An array's %N caps only its own tasks, so with a cap
    each array waits for the one before it (afterany: however its tasks ended): the class never runs more
    than `jobs` gradings at once."""
    top = state_dir(report)
    submitted = []
    chunk = max(1, array_limit - 1)
    for start in range(0, len(indices), chunk):
        part = indices[start:start + chunk]
        listing = f"round{round_number}-{start // chunk}.txt"
        with open(os.path.join(top, listing), "w") as f:
            f.write("".join(f"{i}\n" for i in part))
        array = f"0-{len(part) - 1}" + (f"%{jobs}" if jobs else "")
        after = [f"--dependency=afterany:{submitted[-1][0]}"] if jobs and submitted else []
        r = slurm("sbatch", "--parsable", f"--array={array}", *after, "--no-requeue", "--job-name=grade-class",
                  f"--output={os.path.join(top, 'logs', '%A_%a.out')}", script, listing)
        job = r.stdout.strip().split(";")[0]
        if not job.isdigit():
            raise SlurmError(f"sbatch printed {r.stdout.strip()!r}, not a job id")
        submitted.append((job, listing))
    return submitted


def wait(jobs, poll=POLL_SECONDS):
    """Until no task of the job arrays `jobs` is pending or running.  A task Slurm holds after its launch
    failed ("launch failed requeued held", JobHeldAdmin) is cancelled: it counts as failed and is retried."""
    unreachable_since = None
    while True:
        left = 0
        for job in jobs:
            r = slurm("squeue", "-h", "-j", job, "-o", "%i|%T|%r", check=False)
            if r.returncode != 0:
                if "Invalid job id" in r.stderr:  # finished and already forgotten
                    continue
                unreachable_since = unreachable_since or time.time()
                if time.time() - unreachable_since > UNREACHABLE_SECONDS:
                    say(f"squeue has failed for {UNREACHABLE_SECONDS:.0f} s ({r.stderr.strip()[:200]}); "
                        "stopped waiting: the summary shows what is graded so far")
                    return
                left += 1
                continue
            unreachable_since = None
            for line in r.stdout.splitlines():
                task, state, reason = (line.split("|") + ["", ""])[:3]
                if state == "PENDING" and ("launch failed" in reason or reason == "JobHeldAdmin"):
                    say(f"task {task} is held ({reason}): cancelled, to be retried")
                    slurm("scancel", task, check=False)
                left += 1
        if not left:
            return
        time.sleep(poll)


def slurm_states(job):
    """{array task index: {"state", "node", "exit"}} of a job array as Slurm remembers it (scontrol while the
    controller keeps finished jobs (MinJobAge), else sacct where accounting is on); {} if neither knows."""
    found = {}
    r = slurm("scontrol", "-o", "show", "job", job, check=False)
    for line in r.stdout.splitlines():
        fields = dict(re.findall(r"(\w+)=(\S*)", line))
        if fields.get("ArrayJobId") == job and fields.get("ArrayTaskId", "").isdigit():
            found[int(fields["ArrayTaskId"])] = {"state": fields.get("JobState", "?"),
                                                 "node": fields.get("NodeList", "?"),
                                                 "exit": fields.get("ExitCode", "?")}
    if found:
        return found
    r = slurm("sacct", "-n", "-P", "-X", "-j", job, "-o", "JobID,State,NodeList,ExitCode", check=False)
    for line in r.stdout.splitlines():
        parts = line.split("|")
        if len(parts) == 4 and re.fullmatch(rf"{job}_\d+", parts[0]):
            found[int(parts[0].split("_")[1])] = {"state": parts[1].split()[0], "node": parts[2], "exit": parts[3]}
    return found


def attempts_of(report, job, listing):
    """One dict per array task of `job`: table index, student, node, start, seconds, exit status, installed,
    from the task's record (written at its start and end) and Slurm's state."""
    top = state_dir(report)
    table = read_table(report)
    with open(os.path.join(top, listing)) as f:
        indices = [int(x) for x in f.read().split()]
    states = slurm_states(job)
    out = []
    for task, index in enumerate(indices):
        record = {}
        try:
            with open(os.path.join(top, "attempts", f"{job}_{task}.json")) as f:
                record = json.load(f)
        except (OSError, ValueError):
            pass
        state = states.get(task, {})
        out.append({"task": f"{job}_{task}", "index": index, "student": table[index][1],
                    "directory": table[index][0], "node": record.get("node") or state.get("node", "?"),
                    "start": record.get("start"), "seconds": record.get("seconds"), "exit": record.get("exit"),
                    "installed": record.get("installed", False), "state": state.get("state", "?")})
    return out


def describe(a):
    """"5_3 on n2: NODE_FAIL" / "5_3 on n2: exit status 1" / "9_0 on n1: graded"."""
    what = "graded" if a["installed"] else f"exit status {a['exit']}" if a["exit"] is not None else \
        f"{a['state']} (no report)"
    return f"task {a['task']} on {a['node']}: {what}"


def lost_log(report, a):
    """DIR/<student>.log for an attempt that left none (its node lost, killed): what Slurm said."""
    path = os.path.join(report, a["student"] + ".log")
    with open(path + ".tmp", "w") as f:
        f.write(f"kit/slurm_engine.py: {describe(a)}; Slurm's state {a['state']}: the grading was killed "
                "or its node lost before it wrote a report\n")
    os.replace(path + ".tmp", path)


def write_joblog(report, final, command, extra):
    """DIR/joblog.tsv in GNU parallel's format: one row per student, its last attempt."""
    with open(os.path.join(report, "joblog.tsv"), "w", newline="") as f:
        w = csv.writer(f, delimiter="\t", lineterminator="\n")
        w.writerow(["Seq", "Host", "Starttime", "JobRuntime", "Send", "Receive", "Exitval", "Signal", "Command"])
        for seq, a in enumerate(final, 1):
            words = [*command, a["directory"], "--report", os.path.join(report, a["student"]), "--name",
                     a["student"], "--jobs", "1", *extra]
            w.writerow([seq, a["node"], f"{a['start']:.3f}" if a["start"] else "0",
                        f"{a['seconds']:.3f}" if a["seconds"] is not None else "0", 0, 0,
                        a["exit"] if a["exit"] is not None else -1, 0, shlex.join(words)])


def grade_class(report, command, extra, jobs=None, poll=POLL_SECONDS, retries=1):
    """Grade DIR/submissions.tsv on Slurm (see the module).  command: the interpreter and kit/grade.py;
    extra: the class's --chapters/--seed words; jobs: at most this many tasks at once (the array's %N),
    None for as many as Slurm gives.  Returns {student: [sentences of its attempts]} of those retried."""
    for tool in ("sbatch", "squeue", "scontrol", "scancel"):
        if not shutil.which(tool):
            fail(f"{tool} is missing: run it where Slurm's commands are (Debian: slurm-client)")
    r = slurm("squeue", "-h", "-j", "0", check=False)
    if r.returncode != 0 and "Invalid job id" not in r.stderr:
        fail(f"Slurm does not answer: {(r.stderr or r.stdout).strip()[:300]}")
    script = prepare(report, command, extra)
    table = read_table(report)
    array_limit = max_array_size()
    history = {i: [] for i in range(len(table))}
    pending, submitted = list(range(len(table))), []

    def stop(signum, frame):
        raise Stop()

    old = {s: signal.signal(s, stop) for s in (signal.SIGTERM, signal.SIGINT)}
    try:
        for round_number in range(retries + 1):
            if not pending:
                break
            arrays = submit(report, script, pending, round_number, jobs, array_limit)
            submitted += [job for job, _ in arrays]
            say(("submitted " if round_number == 0 else "resubmitted ") + f"{len(pending)} submissions as job "
                f"array{'s' if len(arrays) > 1 else ''} {', '.join(job for job, _ in arrays)}")
            wait([job for job, _ in arrays], poll)
            for job, listing in arrays:
                for a in attempts_of(report, job, listing):
                    history[a["index"]].append(a)
            pending = [i for i in pending if not reported(report, table[i][1]) and
                       history[i][-1]["exit"] != REFUSED]
        for i in pending:  # retried and still no report: the log says why
            a = history[i][-1]
            if a["exit"] is None:
                lost_log(report, a)
    except Stop:
        say(f"stopped: cancelling job{'s' if len(submitted) > 1 else ''} {', '.join(submitted) or '(none)'}")
        for job in submitted:
            slurm("scancel", job, check=False)
        sys.exit(130)
    except SlurmError as e:
        for job in submitted:
            slurm("scancel", job, check=False)
        fail(str(e))
    finally:
        for s, handler in old.items():
            signal.signal(s, handler)
    write_joblog(report, [history[i][-1] for i in range(len(table))], command, extra)
    retried = {table[i][1]: [describe(a) for a in history[i]] for i in range(len(table)) if len(history[i]) > 1}
    with open(os.path.join(state_dir(report), "retried.json"), "w") as f:
        json.dump(retried, f, indent=1)
    with open(os.path.join(state_dir(report), "attempts.json"), "w") as f:
        json.dump([a for i in range(len(table)) for a in history[i]], f, indent=1)
    return retried


def reported(report, student):
    return os.path.isfile(os.path.join(report, student, "report.json"))


def note_retries(report):
    """After the class summary is written: summary.csv gets the column "retried" (the attempts of a
    student graded more than once: which task, which node, what became of it), summary.html a list."""
    try:
        with open(os.path.join(state_dir(report), "retried.json")) as f:
            retried = json.load(f)
    except (OSError, ValueError):
        return
    path = os.path.join(report, "summary.csv")
    try:
        with open(path, newline="") as f:
            rows = list(csv.reader(f))
    except OSError:
        rows = []
    if rows and "student" in rows[0] and "retried" not in rows[0]:
        at = rows[0].index("student")
        rows = [rows[0] + ["retried"]] + [row + ["; ".join(retried.get(row[at], []))] for row in rows[1:]]
        with open(path + ".tmp", "w", newline="") as f:
            csv.writer(f).writerows(rows)
        os.replace(path + ".tmp", path)
    import html
    items = "".join(f"<li>{html.escape(s)}: {html.escape('; '.join(how))}</li>" for s, how in sorted(retried.items()))
    text = (f"<h2>Retried on Slurm ({len(retried)})</h2><p>A task that ended without a report (its node lost, "
            f"killed, a crash of the grader) was submitted once more.</p><ul>{items}</ul>\n") if retried else \
        "<p>Slurm: no submission needed a second task.</p>\n"
    with open(os.path.join(report, "summary.html"), "a") as f:
        f.write(text)
    if retried:
        say(f"retried {len(retried)}: " + ", ".join(sorted(retried)))


# ---- the array task ----------------------------------------------------------------------------------------

def write_record(path, record):
    with open(path + ".tmp", "w") as f:
        json.dump(record, f)
    os.replace(path + ".tmp", path)


def task_main(report, listing):
    """One array task: grade line $SLURM_ARRAY_TASK_ID of the list into an attempt directory, then install it
    as DIR/<student> unless another attempt did first (see the module)."""
    top = state_dir(report)
    job, task = os.environ.get("SLURM_ARRAY_JOB_ID"), os.environ.get("SLURM_ARRAY_TASK_ID")
    if not (job and task and task.isdigit()):
        fail("task: SLURM_ARRAY_JOB_ID and SLURM_ARRAY_TASK_ID are not set (sbatch runs this)")
    with open(os.path.join(top, listing)) as f:
        index = int(f.read().split()[int(task)])
    directory, student = read_table(report)[index]
    with open(os.path.join(top, "command.json")) as f:
        spec = json.load(f)
    name = f"{job}_{task}"
    attempt, log = os.path.join(top, "attempts", name), os.path.join(top, "attempts", name + ".log")
    record_path = os.path.join(top, "attempts", name + ".json")
    record = {"student": student, "index": index, "node": os.environ.get("SLURMD_NODENAME", os.uname().nodename),
              "start": time.time(), "seconds": None, "exit": None, "installed": False}
    write_record(record_path, record)
    argv = [*spec["command"], directory, "--report", attempt, "--name", student, "--jobs", "1", *spec["extra"]]
    with open(log, "w") as out:
        code = subprocess.run(argv, stdin=subprocess.DEVNULL, stdout=out, stderr=subprocess.STDOUT).returncode
    record.update(seconds=round(time.time() - record["start"], 3), exit=code)
    final = os.path.join(report, student)
    if code == 0 and os.path.isfile(os.path.join(attempt, "report.json")):
        try:
            os.rename(attempt, final)  # atomic; fails when an earlier attempt installed its report
            record["installed"] = True
        except OSError:
            record["duplicate"] = f"{final} was there already: this attempt's report is discarded"
            shutil.rmtree(attempt, ignore_errors=True)
    if record["installed"] or not reported(report, student):  # DIR/<student>.log, naming where the report is
        with open(log, errors="replace") as f:
            text = f.read(1 << 22).replace(attempt, final)
        with open(os.path.join(report, student + ".log.tmp"), "w") as f:
            f.write(text)
        os.replace(os.path.join(report, student + ".log.tmp"), os.path.join(report, student + ".log"))
    write_record(record_path, record)
    print(f"{student}: kit/grade.py exit status {code}" + (", report installed" if record["installed"] else ""))
    return 0


if __name__ == "__main__":
    if len(sys.argv) == 4 and sys.argv[1] == "task":
        sys.exit(task_main(os.path.abspath(sys.argv[2]), sys.argv[3]))
    print(__doc__.strip(), file=sys.stderr)
    sys.exit(2)
