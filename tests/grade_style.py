"""One written code style across the tree: .clang-format at the root.

Every C file of the project (chapters, common, viewer, tests, bench) must be
what clang-format makes of it; `make format` rewrites them.  Lines stay
within 120 columns, which clang-format checks for code but not for comments
and strings, so that is checked here too.
"""
import glob
import os
import shutil
import subprocess

from lib import ROOT

GRADES_NOTHING = True  # no grading, no handout: may run beside the RUN_ALONE tests (tests/run.py)

SOURCES = ["chapters/*.[ch]", "common/*.[ch]", "viewer/*.[ch]", "tests/*.[ch]", "tests/fuzz/*.c", "bench/*.c"]
THIRD_PARTY = {"viewer/font8x8.h"}  # a public-domain font table kept as published


def c_files():
    files = sorted({os.path.relpath(p, ROOT) for pattern in SOURCES for p in glob.glob(os.path.join(ROOT, pattern))})
    return [f for f in files if f not in THIRD_PARTY]


def test_sources_follow_clang_format(ctx):
    tool = shutil.which("clang-format")
    assert tool, "clang-format is not installed (make deps installs it)"
    files = c_files()
    assert len(files) > 20, "the C sources were not found"
    r = subprocess.run([tool, "--dry-run", "--Werror", "--style=file", *files], cwd=ROOT, capture_output=True,
                       text=True, timeout=300)
    offending = sorted({line.split(":")[0] for line in r.stderr.splitlines() if ": error:" in line})
    assert r.returncode == 0, f"{len(offending)} files differ from .clang-format (run `make format`): " + \
        ", ".join(offending[:20])


def test_lines_fit_120_columns(ctx):
    long_lines = []
    for f in c_files():
        with open(os.path.join(ROOT, f), encoding="utf-8") as source:
            for number, line in enumerate(source, 1):
                if len(line.rstrip("\n")) > 120:
                    long_lines.append(f"{f}:{number}: {len(line.rstrip())} columns")
    assert not long_lines, f"{len(long_lines)} lines over 120 columns:\n" + "\n".join(long_lines[:20])
