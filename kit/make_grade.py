#!/usr/bin/python3
"""`make grade`: the make variables, read from the environment, as arguments of kit/grade.py or
kit/grade_class.py.

Make passes the variables of its command line to the recipe's environment; reading them here, never
through the shell, keeps them data: SUBMISSION='dir;rm -rf ~' is a directory name with a ';' in it,
a path with spaces or quotes is one path.

  SUBMISSION=DIR       one tree (default: this one)          REPORT=DIR     where the report goes
  SUBMISSIONS="A B"    a class (whitespace-separated; or @LIST.txt, one directory per line)
  CHAPTERS="01_local ..."   SEED=N   JOBS=N   SSHLOGINFILE=FILE   UNSAFE=1 (no sandbox: trusted code only)
  SANDBOX=user         the weaker sandbox where user namespaces are blocked (kit/grade.py --help)
"""
import os
import sys

KIT = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, KIT)


def arguments(env):
    """(script, argv) for the environment env."""
    def value(name):
        return env.get(name, "").strip()
    common = []
    if value("REPORT"):
        common += ["--report", env["REPORT"]]
    if value("CHAPTERS"):
        common += ["--chapters", value("CHAPTERS")]
    if value("SEED"):
        common += ["--seed", value("SEED")]
    if value("UNSAFE") not in ("", "0"):
        common += ["--unsafe"]
    if value("SANDBOX"):
        common += ["--sandbox", value("SANDBOX")]
    if value("SUBMISSIONS"):
        extra = (["--jobs", value("JOBS")] if value("JOBS") else []) + \
                (["--sshloginfile", env["SSHLOGINFILE"]] if value("SSHLOGINFILE") else [])
        return "grade_class", common + extra + value("SUBMISSIONS").split()
    return "grade", [env.get("SUBMISSION") or "."] + common


def main():
    script, argv = arguments(os.environ)
    module = __import__(script)
    module.main(argv)


if __name__ == "__main__":
    main()
