#!/usr/bin/env bash
# Gradescope runs this once, as root, when it builds the autograder's image (its base images are
# Ubuntu; 22.04 or newer is assumed: Python >= 3.10 at /usr/bin/python3, the same package names as
# Debian 12).  The archive is already unpacked in /autograder/source: the instructor's kit.
#
# usage: setup.sh [--dry-run]
#   --dry-run   print the apt-get commands instead of running them, and skip the sandbox probe
#               (tests/grade_autograder.py runs it so, with AUTOGRADER_ROOT at a fake /autograder)
set -euo pipefail

PACKAGES=""  # written by make_archive.py
ROOT="${AUTOGRADER_ROOT:-/autograder}"
SOURCE="$ROOT/source"

dry_run=0
case "${1:-}" in
  --dry-run) dry_run=1 ;;
  "") ;;
  *) echo "setup.sh: unknown argument $1 (usage: setup.sh [--dry-run])" >&2; exit 2 ;;
esac

# The build packages of the Makefile (BUILD_PACKAGES) and bubblewrap, the sandbox every
# submission's build and runs go through (kit/sandbox.py).
if [ "$dry_run" = 1 ]; then
  echo "would run: apt-get update"
  echo "would run: apt-get install -y --no-install-recommends $PACKAGES"
else
  export DEBIAN_FRONTEND=noninteractive
  apt-get update
  # shellcheck disable=SC2086  # a list of package names
  apt-get install -y --no-install-recommends $PACKAGES
fi

# kit/ holds the held-out references and the rubric, which only the judge (root, outside the
# sandbox) reads: nobody else may.  Inside the sandbox kit/ is not even visible; this also holds
# for a grader that falls back to a plain unprivileged user.  (The Makefile, scenes/ and tests/
# stay readable: a sandbox may be lent them.)
test -f "$SOURCE/kit/grade.py" || { echo "setup.sh: $SOURCE/kit/grade.py: missing (unpack the archive there)" >&2; exit 2; }
chmod -R go-rwx "$SOURCE/kit"
chmod 0755 "$SOURCE/run_autograder" "$SOURCE/setup.sh"

# Can a sandbox start in this image?  If not, every grading will say why instead of a score.
if [ "$dry_run" = 0 ]; then
  reason=$(/usr/bin/python3 -c 'import sys; sys.path.insert(0, sys.argv[1]); import sandbox
print(sandbox.unavailable() or "")' "$SOURCE/kit")
  if [ -z "$reason" ]; then
    echo "setup.sh: the sandbox starts: submissions will be graded inside it"
  else
    echo "setup.sh: WARNING: bubblewrap's sandbox cannot start in this image: $reason" >&2
    fallback=$(/usr/bin/python3 -c 'import sys; sys.path.insert(0, sys.argv[1]); import sandbox
print(sandbox.fallback_unavailable() or "")' "$SOURCE/kit")
    if [ -z "$fallback" ]; then
      echo "setup.sh: run_autograder grades with the fallback, a separate user (kit/grade.py --sandbox user)" >&2
    else
      echo "setup.sh: WARNING: nor can the fallback (a separate user): $fallback; run_autograder will refuse" \
           "to grade here (every criterion 0, with the reason)" >&2
    fi
  fi
fi
echo "setup.sh: done"
