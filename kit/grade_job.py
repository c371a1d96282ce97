#!/usr/bin/python3
"""One grading of a class (kit/grade_class.py starts it, on this machine or another): an attempt.

usage: kit/grade_job.py REPORT NAME SUBMISSION [kit/grade.py options ...]

Runs this kit's grade.py on SUBMISSION into an attempt directory of its own,
REPORT/.attempts/NAME/HOST-PID/, and only when the grading ends with a report moves that directory to
REPORT/NAME (replacing an earlier one): a grading killed half-way (its machine lost) leaves no report
at REPORT/NAME, so a student has one complete report or none, whichever machine graded and however
often.  Each attempt leaves a record REPORT/.attempts/NAME/HOST-PID.json ({"host": this machine's
name, "pid", "started", "ended", "exit", "placed"}; "ended" is null while it runs, and stays null
for an attempt whose machine was lost); the log of the last attempt that ended is REPORT/NAME.log.

Exit status 0 when the submission was graded or refused by the kit (its reason is then the log's
"kit/grade.py: not graded: ..." line: that is a verdict, not a failure to retry); otherwise
grade.py's (a crash of the grader, no sandbox on this machine): the engine may retry elsewhere.
"""
import json
import os
import shutil
import socket
import subprocess
import sys
import time

KIT = os.path.dirname(os.path.abspath(__file__))
REFUSED = "kit/grade.py: not graded: "


def write_record(path, record):
    with open(path + ".part", "w") as f:
        json.dump(record, f)
    os.replace(path + ".part", path)


def place(attempt, target, attempts):
    """attempt's directory becomes target; an earlier target is moved aside and removed."""
    old = None
    if os.path.lexists(target):
        old = os.path.join(attempts, f".replaced-{os.getpid()}-{time.time_ns()}")
        os.rename(target, old)
    os.rename(attempt, target)
    if old:
        shutil.rmtree(old, ignore_errors=True)


def main(argv):
    if len(argv) < 3 or argv[0] in ("-h", "--help"):
        print(__doc__.strip(), file=sys.stderr if len(argv) < 3 else sys.stdout)
        sys.exit(0 if argv and argv[0] in ("-h", "--help") else 2)
    report, name, submission, options = os.path.abspath(argv[0]), argv[1], argv[2], argv[3:]
    if not name or name.startswith(".") or "/" in name:
        print(f"kit/grade_job.py: bad student name {name!r}", file=sys.stderr)
        sys.exit(2)
    host = socket.gethostname()
    attempts = os.path.join(report, ".attempts", name)
    os.makedirs(attempts, exist_ok=True)
    me = f"{host}-{os.getpid()}"
    attempt, record_path = os.path.join(attempts, me), os.path.join(attempts, me + ".json")
    record = {"host": host, "pid": os.getpid(), "started": time.time(), "ended": None, "exit": None,
              "placed": False}
    write_record(record_path, record)
    log = attempt + ".log"
    with open(log, "w") as out:
        code = subprocess.run([sys.executable, os.path.join(KIT, "grade.py"), submission, "--report", attempt,
                               "--name", name, *options], stdin=subprocess.DEVNULL, stdout=out,
                              stderr=subprocess.STDOUT).returncode
    with open(log, errors="replace") as f:
        refused = any(line.startswith(REFUSED) for line in f)
    graded = code == 0 and os.path.exists(os.path.join(attempt, "report.json"))
    if graded:
        place(attempt, os.path.join(report, name), attempts)
    shutil.copyfile(log, os.path.join(report, name + ".log.part"))
    os.replace(os.path.join(report, name + ".log.part"), os.path.join(report, name + ".log"))
    record.update(ended=time.time(), exit=code, placed=graded)
    write_record(record_path, record)
    shutil.rmtree(attempt, ignore_errors=True)  # a grading that ended without a report
    print(f"{name}: {'graded' if graded else 'refused' if refused else f'exit status {code}'} on {host}")
    sys.exit(0 if graded or (code == 2 and refused) else code or 1)


if __name__ == "__main__":
    main(sys.argv[1:])
