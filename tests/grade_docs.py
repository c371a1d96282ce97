"""The documentation says what the programs do: README's option lists
against every chapter's --help (both come from one option table per chapter;
this catches the README falling behind).
"""
import glob
import os
import re

from lib import ROOT

GRADES_NOTHING = True  # no grading, no handout: may run beside the RUN_ALONE tests (tests/run.py)


def built_chapters(ctx):
    return sorted(os.path.basename(p) for p in glob.glob(os.path.join(ROOT, ctx.build, "0*_*"))
                  if os.access(p, os.X_OK) and not p.endswith(".d"))


def help_options(text):
    """{"--name": "--name VALUE"} from the option lines of a --help text."""
    found = {}
    for line in text.splitlines():
        m = re.match(r"  (--[a-z0-9-]+)( [^ ]+)?(?:\s{2,}|$)", line)
        if m:
            found[m.group(1)] = (m.group(1) + (m.group(2) or "")).strip()
    return found


def readme_options(cells):
    """{"--name": "--name VALUE"} from README's backticked `--name VALUE` items."""
    found = {}
    for item in re.findall(r"`(--[^`]+)`", cells):
        item = item.replace("\\|", "|").strip()
        found[item.split()[0]] = item
    return found


def readme_section(name):
    with open(os.path.join(ROOT, "README.md")) as f:
        text = f.read()
    m = re.search(r"<!-- options:%s -->(.*?)<!-- /options -->" % re.escape(name), text, re.S)
    assert m, f"README.md has no <!-- options:{name} --> ... <!-- /options --> block"
    return m.group(1)


def test_readme_options_match_help(ctx):
    """Each chapter's own options, and the driver's, are in README exactly as --help writes them."""
    chapters = built_chapters(ctx)
    assert chapters, "no chapters built"
    problems = []
    driver = None
    for chapter in chapters:
        r = ctx.run(chapter, "--help")
        assert r.returncode == 0, f"{chapter} --help exited {r.returncode}"
        common, _, own = r.stdout.partition(f"\n{chapter} options:\n")
        driver_here = help_options(common)
        assert driver is None or driver_here == driver, f"{chapter}: the shared options differ between chapters"
        driver = driver_here
        documented = readme_options(readme_section(chapter))
        if documented != help_options(own):
            problems.append(f"{chapter}: README {sorted(documented.values())} vs --help "
                            f"{sorted(help_options(own).values())}")
    documented = readme_options(readme_section("driver"))
    if documented != driver:
        problems.append(f"driver: README {sorted(documented.values())} vs --help {sorted(driver.values())}")
    assert not problems, "\n".join(problems)
