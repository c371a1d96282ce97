#!/usr/bin/python3
"""Grade a student's tree by the rubric (kit/rubric.json); write REPORT/report.json and report.html.

usage: kit/grade.py SUBMISSION [--report DIR] [--chapters "01_local ..."] [--seed N] [--jobs N]
                   [--statistical-only] [--timeout S] [--memory MIB] [--name NAME]
       kit/grade.py --make-reference [--jobs N]     (instructor: render kit/reference/ with this tree's build/:
                                                    the statistics and the report's picture of each criterion)

  SUBMISSION          a filled-in handout or any copy of this project (a directory)
  --report DIR        where the report goes (default SUBMISSION/out/grade)
  --chapters "A B"    chapters to grade (default: the handout's, else every chapter in the rubric)
  --seed N            grading seed (default 1): compare criteria render batch b with seed N * 1000 + b;
                      grade criteria run with every chapter seed shifted by N (tests/lib.py Context;
                      1 = the tests' own seeds)
  --jobs N            renders run at once and make -j (default 2)
  --statistical-only  only the criteria of kind compare, without their pictures (for calibration)
  --timeout S         per criterion, whole process group killed after S seconds (default 300)
  --memory MIB        address-space limit of every process of the submission (default 4096)

The submission is copied into a temporary directory; the grader's tests/,
scenes/, kit/ and Makefile replace the student's; it is built there with
its own build directory (compile errors go into the report, and the chapter
scores 0).  Every criterion runs in its own process group under the limits;
a crash, hang, NaN pixel or missing output fails that criterion with a
message.  Exit status 0 whenever grading ran, 2 on bad arguments.
"""
import datetime
import hashlib
import html
import json
import os
import re
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import time

KIT = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(KIT)
sys.path.insert(0, KIT)
import compare  # noqa: E402
import rubric as rubric_module  # noqa: E402

OVERLAY = ("tests", "scenes", "kit", "Makefile")
IGNORE = shutil.ignore_patterns("build", "out", ".git", "__pycache__", "node_modules", "*.o")


def usage_error(message):
    print(f"kit/grade.py: {message} (see --help)", file=sys.stderr)
    sys.exit(2)


def parse_args(argv):
    opts = {"report": None, "chapters": None, "seed": 1, "jobs": 2, "statistical_only": False, "timeout": 300.0,
            "memory": 4096, "make_reference": False, "name": None, "submission": None}
    valued = {"--report": str, "--chapters": str, "--seed": int, "--jobs": int, "--timeout": float,
              "--memory": int, "--name": str}
    i = 0
    while i < len(argv):
        a = argv[i]
        if a in ("-h", "--help"):
            print(__doc__.strip())
            sys.exit(0)
        elif a == "--statistical-only":
            opts["statistical_only"] = True
        elif a == "--make-reference":
            opts["make_reference"] = True
        elif a in valued:
            if i + 1 >= len(argv):
                usage_error(f"{a} needs a value")
            try:
                opts[a[2:].replace("-", "_")] = valued[a](argv[i + 1])
            except ValueError:
                usage_error(f"{a} {argv[i + 1]}: not a valid {valued[a].__name__}")
            i += 1
        elif a.startswith("-"):
            usage_error(f"unknown option {a}")
        elif opts["submission"] is None:
            opts["submission"] = a
        else:
            usage_error(f"unexpected argument {a}")
        i += 1
    if opts["jobs"] < 1 or opts["timeout"] <= 0 or opts["memory"] < 64 or opts["seed"] < 0:
        usage_error("--jobs, --timeout, --memory and --seed must be positive")
    return opts


def limited(memory_mib):
    def set_limits():
        limit = memory_mib * 1024 * 1024
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
        resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
    return set_limits


def run_limited(cmd, cwd, timeout, memory, env=None):
    """(returncode or None on timeout, stdout, stderr); the whole process group dies on timeout."""
    p = subprocess.Popen(cmd, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, stdin=subprocess.DEVNULL,
                         start_new_session=True, preexec_fn=limited(memory), env=env)
    try:
        out, err = p.communicate(timeout=timeout)
        return p.returncode, out.decode(errors="replace"), err.decode(errors="replace")
    except subprocess.TimeoutExpired:
        try:
            os.killpg(p.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        out, err = p.communicate()
        return None, out.decode(errors="replace"), err.decode(errors="replace")
    finally:
        try:  # leftovers of a finished criterion (a child that outlived it)
            os.killpg(p.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass


def prepare(submission, work):
    src = os.path.join(work, "src")
    shutil.copytree(submission, src, ignore=IGNORE, symlinks=False, ignore_dangling_symlinks=True)
    for name in OVERLAY:
        dst = os.path.join(src, name)
        if os.path.isdir(dst) and not os.path.islink(dst):
            shutil.rmtree(dst)
        elif os.path.lexists(dst):
            os.remove(dst)
        s = os.path.join(ROOT, name)
        if os.path.isdir(s):
            shutil.copytree(s, dst, ignore=IGNORE)
        elif os.path.exists(s):
            shutil.copy2(s, dst)
    return src


def build(src, chapters, units, opts):
    """{target: error text or None}; chapters that do not compile get their compiler output."""
    targets = [f"build/{c}" for c in chapters] + [f"build/tests/{u}" for u in units]
    env = dict(os.environ, MAKEFLAGS="")
    code, out, err = run_limited(["make", "-k", f"-j{opts['jobs']}", "BUILD=build", *targets], src, 900,
                                 opts["memory"], env)
    result = {}
    for t in targets:
        if os.path.exists(os.path.join(src, t)):
            result[t] = None
            continue
        code, out, err = run_limited(["make", "BUILD=build", t], src, 600, opts["memory"], env)
        text = (out + err).strip()
        lines = [ln for ln in text.splitlines() if "error" in ln or "undefined reference" in ln]
        result[t] = ("\n".join(lines[:30]) + "\n\n" if lines else "") + text[-4000:] if code is not None \
            else "the build timed out"
    return result


def run_unit(src, c, opts):
    """(passed, message, measured): every case of the C unit test, against the submission's common/."""
    exe = os.path.join(src, "build", "tests", c["test"])
    code, out, err = run_limited([exe], src, opts["timeout"], opts["memory"])
    if code is None:
        return False, f"timed out after {opts['timeout']:.0f} s", []
    failed = [ln[5:] for ln in out.splitlines() if ln.startswith("FAIL ")]
    passed = [ln for ln in out.splitlines() if ln.startswith("ok   ")]
    measured = [{"quantity": "cases passed", "measured": len(passed), "expected": len(passed) + len(failed),
                 "passed": not failed, "text": f"{len(passed)} of {len(passed) + len(failed)} cases passed"}]
    if failed:
        return False, f"{len(failed)} of {len(failed) + len(passed)} cases failed: " + "; ".join(failed[:5]), measured
    if code != 0 or not passed:
        return False, compare.describe_exit(code, err) + f" after {len(passed)} cases passed", measured
    return True, f"{len(passed)} cases passed", measured


def submission_hash(submission):
    """(sha256 hex, number of files) over the submission's files as graded (the same files prepare()
    copies): each file's path relative to the submission and its bytes, in sorted order.  Two
    gradings of one hash graded the same code."""
    digest, count = hashlib.sha256(), 0
    skip_dirs = {"build", "out", ".git", "__pycache__", "node_modules"}
    for top, dirs, files in os.walk(submission):
        dirs[:] = sorted(d for d in dirs if d not in skip_dirs)
        for name in sorted(files):
            path = os.path.join(top, name)
            if name.endswith(".o") or not os.path.isfile(path) or os.path.islink(path):
                continue
            rel = os.path.relpath(path, submission)
            digest.update(rel.encode() + b"\0")
            with open(path, "rb") as f:
                digest.update(hashlib.sha256(f.read()).digest())
            count += 1
    return digest.hexdigest(), count


TODO_CALL = re.compile(r'\bTODO_ONCE\(\s*"(\w+)"\s*\)')


def stubs_in_source(src):
    """{(file, line, name)} of every TODO_ONCE("name") call in the submission's C sources: the
    stubs a handout starts with that are still there, even those no run reached (a stub that
    calls another)."""
    found = set()
    for folder in ("chapters", "common"):
        top = os.path.join(src, folder)
        for name in sorted(os.listdir(top)) if os.path.isdir(top) else []:
            if not name.endswith((".c", ".h")):
                continue
            try:
                with open(os.path.join(top, name), errors="replace") as f:
                    for number, line in enumerate(f, 1):
                        if line.lstrip().startswith(("*", "/*", "//")):  # a comment about stubs (common/todo.h)
                            continue
                        for m in TODO_CALL.finditer(line):
                            found.add((f"{folder}/{name}", number, m[1]))
            except OSError:
                continue
    return found


def still_to_write(results, in_source=()):
    """The stubs the runs reported and those still in the source, once each, sorted by file and
    line, each with the criteria that reached it: [{"name", "file", "line", "criteria": [...]}]."""
    found = {key: {"name": key[2], "file": key[0], "line": key[1], "criteria": []} for key in in_source}
    for r in results:
        for t in r.get("todos", []):
            key = (t["file"], t["line"], t["name"])
            found.setdefault(key, {"name": t["name"], "file": t["file"], "line": t["line"], "criteria": []})
            found[key]["criteria"].append(r["name"])
    return [found[k] for k in sorted(found)]


def run_criterion(src, c, opts, images_dir):
    cmd = [sys.executable, os.path.join(src, "kit", "criterion.py"), src, "build", json.dumps(c), str(opts["seed"]),
           str(opts["jobs"]), images_dir]
    env = dict(os.environ, OMP_NUM_THREADS=str(opts["jobs"]), PYTHONDONTWRITEBYTECODE="1")
    code, out, err = run_limited(cmd, src, c.get("timeout", opts["timeout"]), opts["memory"], env)
    if code is None:
        return {"passed": False, "p_value": None, "images": {},
                "message": f"timed out after {c.get('timeout', opts['timeout']):.0f} s (process group killed)"}
    marker = out.rfind("@@RESULT@@ ")
    if marker < 0:
        return {"passed": False, "p_value": None, "images": {},
                "message": "the criterion died: " + compare.describe_exit(code, err)}
    return json.loads(out[marker + len("@@RESULT@@ "):])


def chapters_to_grade(opts, rub):
    in_rubric = []
    for c in rub["criteria"]:
        if c["chapter"] not in in_rubric:
            in_rubric.append(c["chapter"])
    if opts["chapters"]:
        chosen = opts["chapters"].split()
        unknown = [c for c in chosen if c not in in_rubric]
        if unknown:
            usage_error(f"no criteria for {' '.join(unknown)} in kit/rubric.json (chapters: {' '.join(in_rubric)})")
        return chosen
    handout = os.path.join(ROOT, "kit", "handout.json")
    if os.path.exists(handout):
        with open(handout) as f:
            return [c for c in json.load(f)["chapters"] if c in in_rubric]
    return in_rubric


def make_reference(opts, rub):
    for c in rub["criteria"]:
        if c["kind"] == "compare":
            compare.make_reference(ROOT, "build", c, rub, opts["jobs"])
            compare.make_preview(ROOT, "build", c, opts["jobs"])
            print(f"picture: {compare.preview_path(c)}", flush=True)
        elif c["kind"] == "surfaces":
            compare.make_surfaces_reference(ROOT, "build", c)
        else:
            continue
        print(f"reference: {compare.reference_path(c)}", flush=True)


STYLE = """
body{font-family:sans-serif;margin:2em;max-width:80em;line-height:1.35}
table{border-collapse:collapse;width:100%}
td,th{border:1px solid #ccc;padding:6px 8px;vertical-align:top;text-align:left}
.pass{color:#070}.fail{color:#b00}.todo{background:#fff4d6;border:1px solid #e0b040;padding:8px 14px;margin:1em 0}
.todo li{margin:2px 0}code{background:#f2f2f2;padding:0 3px}pre{white-space:pre-wrap;background:#f6f6f6;padding:6px}
.sentence{margin:0 0 4px 0}details{margin:4px 0;font-size:92%}details li{margin:2px 0}
figure{display:inline-block;margin:4px 14px 4px 0;vertical-align:top}figcaption{font-size:85%;max-width:256px;overflow-wrap:anywhere}
img{image-rendering:pixelated;border:1px solid #999;width:256px}.swatch{display:inline-block;width:12px;height:12px;
vertical-align:middle;border:1px solid #555;margin:0 3px 0 8px}.meta{color:#555;font-size:90%}
"""

IMAGE_CAPTIONS = (("student", "your submission"), ("reference", "the solution"),
                  ("tiles", "the tiles that differ, filled: stronger = larger difference"),
                  ("heat", "|difference| / standard error"))


def html_todos(report):
    h = html.escape
    todos = report.get("still_to_write", [])
    if not todos:
        return []
    items = "".join(f"<li><code>{h(t['name'])}</code> ({h(t['file'])}:{t['line']}): " +
                    (f"reached by {h(', '.join(t['criteria']))}" if t["criteria"] else
                     "no run reached it yet (a function that calls it is still to write too)") + "</li>"
                    for t in todos)
    return [f"<div class=todo><b>Still to write:</b> " +
            ", ".join(f"<code>{h(t['name'])}</code> ({h(t['file'])}:{t['line']})" for t in todos) +
            f"<details><summary>which criteria reached each stub</summary><ul>{items}</ul></details>"
            "<small>These functions are still the handout's stubs (<code>TODO_ONCE</code>; a run that reaches one "
            "prints <code>TODO name is not implemented</code>). Criteria that reach them cannot pass yet.</small>"
            "</div>"]


def html_images(c):
    h = html.escape
    im = c.get("images") or {}
    if not im:
        return ""
    preview = c.get("preview") or {}
    notes = {"student": preview.get("student", ""), "reference": preview.get("reference", "")}
    figures = "".join(f"<figure><img src='{h(im[k])}' alt='{h(label)}'><figcaption><b>{h(label)}</b>"
                      f"{'<br>' + h(notes[k]) if notes.get(k) else ''}</figcaption></figure>"
                      for k, label in IMAGE_CAPTIONS if k in im)
    marked = sum(1 for m in c.get("measured", []) if m.get("quantity") == "tiles that differ from the solution's"
                 and m.get("measured"))
    grid = preview.get("grid", "tiles")
    legend = (f"<div class=meta>Grid: the {h(grid)} the test compares. Outlined:"
              f"<span class=swatch style='background:rgb{compare.png.BRIGHTER}'></span>brighter than the "
              "solution"
              f"<span class=swatch style='background:rgb{compare.png.DARKER}'></span>darker than the solution; "
              "tiles without a mark agree." + ("" if marked else " No tile differs.") + "</div>")
    return f"<div>{figures}</div>{legend}"


def html_criterion(c):
    h = html.escape
    cls = "pass" if c["passed"] else "fail"
    p = "" if c["p_value"] is None else f"<br><small>p = {c['p_value']:.3g}</small>"
    measured = c.get("measured") or []
    details = ""
    if len(measured) > 1:
        details += (f"<details><summary>all {len(measured)} measured values</summary><ul>" +
                    "".join(f"<li class={'pass' if m.get('passed') else 'fail'}>{h(m['text'])}</li>" for m in measured)
                    + "</ul></details>")
    if c.get("commands"):
        details += (f"<details><summary>commands it ran ({len(c['commands'])})</summary><ul>" +
                    "".join(f"<li><code>{h(x)}</code></li>" for x in c["commands"]) + "</ul></details>")
    if c.get("todos"):
        details += ("<div class=meta>reached the stubs " +
                    ", ".join(f"<code>{h(t['name'])}</code>" for t in c["todos"]) + "</div>")
    message = c["message"]
    body = f"<pre>{h(message)}</pre>" if "\n" in message else f"<p class=sentence>{h(message)}</p>"
    test = f"<br><small>{h(c['test'])}</small>" if c.get("test") else ""
    images = html_images(c)
    return (f"<tr><td>{h(c['name'])}<br><small>exercises "
            f"{h(', '.join(c['exercises']))}; {h(c.get('kind', ''))}</small>{test}</td><td>{c['points']} / {c['max']}"
            f"</td><td class={cls}>{'pass' if c['passed'] else 'FAIL'}{p}</td><td>{body}{details}</td></tr>" +
            (f"<tr><td colspan=4>{images}</td></tr>" if images else ""))


def write_html(path, report, name):
    h = html.escape
    out = ["<!doctype html><meta charset=utf-8><title>grading report</title><style>" + STYLE + "</style>",
           f"<h1>Grading report{': ' + h(name) if name else ''}</h1>",
           f"<p><b>{report['total']} / {report['max']}</b> points.</p>"]
    out += html_todos(report)
    for chapter in report["chapters"]:
        rows = [c for c in report["criteria"] if c["chapter"] == chapter]
        got = sum(c["points"] for c in rows)
        out.append(f"<h2>{h(chapter)}: {got} / {sum(c['max'] for c in rows)}</h2>")
        if report["build_errors"].get(chapter):
            out.append(f"<p class=fail>does not compile:</p><pre>{h(report['build_errors'][chapter])}</pre>")
        out.append("<table><tr><th>criterion</th><th>points</th><th>result</th><th>what was measured</th></tr>")
        out += [html_criterion(c) for c in rows]
        out.append("</table>")
    out.append(f"<p class=meta>Graded {h(report.get('date', ''))} with seed {report['seed']}; submission sha256 "
               f"{h(report.get('submission_sha256', ''))} ({report.get('submission_files', '?')} files); "
               f"{report.get('seconds', '?')} s. Family-wise alpha {report['family_alpha']} over the statistical "
               f"criteria ({h(report['statistics'])}): a correct solution fails a grading by chance at most that "
               f"often.</p>")
    with open(path, "w") as f:
        f.write("\n".join(out) + "\n")


def main(argv):
    opts = parse_args(argv)
    try:
        rub = rubric_module.load(ROOT)
    except ValueError as e:
        usage_error(str(e))
    if opts["make_reference"]:
        make_reference(opts, rub)
        return
    if opts["submission"] is None:
        usage_error("no SUBMISSION directory given")
    submission = os.path.abspath(opts["submission"])
    if not os.path.isdir(submission):
        usage_error(f"SUBMISSION {opts['submission']}: not a directory")
    chapters = chapters_to_grade(opts, rub)
    report_dir = os.path.abspath(opts["report"] or os.path.join(submission, "out", "grade"))
    os.makedirs(report_dir, exist_ok=True)
    criteria = [c for c in rub["criteria"] if c["chapter"] in chapters and
                (not opts["statistical_only"] or rubric_module.statistical(c))]
    start = time.time()
    date = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    digest, files = submission_hash(submission)
    work = tempfile.mkdtemp(prefix="gi-grade-")
    try:
        src = prepare(submission, work)
        present = [c for c in chapters if os.path.exists(os.path.join(src, "chapters", c + ".c"))]
        all_chapters = sorted(os.path.splitext(f)[0] for f in os.listdir(os.path.join(src, "chapters"))
                              if f.endswith(".c") and f[:2].isdigit()) if os.path.isdir(
                                  os.path.join(src, "chapters")) else []
        units = sorted({c["test"] for c in criteria if c["kind"] == "unit"})
        built = build(src, all_chapters, units, opts)
        results = []
        for c in criteria:
            row = {"chapter": c["chapter"], "name": c["name"], "points": 0, "max": c["points"], "passed": False,
                   "p_value": None, "message": "", "exercises": c["exercises"], "kind": c["kind"]}
            if c["kind"] == "grade":
                row["test"] = f"tests/{c['module']}.py {c['test']}"
            error = built.get(f"build/{c['chapter']}")
            t0 = time.time()
            if c["chapter"] not in present:
                row["message"] = f"chapters/{c['chapter']}.c is not in the submission"
            elif error:
                row["message"] = f"{c['chapter']} does not compile:\n" + error[:1500]
            elif c["kind"] == "unit":
                if built.get(f"build/tests/{c['test']}"):
                    row["message"] = f"tests/{c['test']}.c does not compile against the submission's common/:\n" + \
                        built[f"build/tests/{c['test']}"][:1500]
                else:
                    row["passed"], row["message"], row["measured"] = run_unit(src, c, opts)
                    row["commands"] = [f"build/tests/{c['test']}"]
            else:
                r = run_criterion(src, c, opts, "" if opts["statistical_only"] else report_dir)
                row.update({k: r[k] for k in ("passed", "p_value", "message")})
                row["images"] = r.get("images", {})
                if r.get("preview"):
                    row["preview"] = r["preview"]
                row.update({k: r.get(k, []) for k in ("measured", "commands", "todos")})
            row["points"] = c["points"] if row["passed"] else 0
            row["seconds"] = round(time.time() - t0, 2)
            results.append(row)
            print(f"{'pass' if row['passed'] else 'FAIL'} {c['chapter']}: {c['name']} ({row['points']}/{c['points']})"
                  + ("" if row["passed"] else ": " + row["message"].splitlines()[0][:200] if row["message"] else ""),
                  flush=True)
        report = {"submission": submission, "total": sum(r["points"] for r in results),
                  "max": sum(r["max"] for r in results), "criteria": results, "chapters": chapters,
                  "still_to_write": still_to_write(results, stubs_in_source(src)), "date": date,
                  "submission_sha256": digest, "submission_files": files,
                  "seed": opts["seed"], "family_alpha": rub["family_alpha"],
                  "statistics": "Welch's t per tile and channel and on the image mean, one-sided F on the noise, "
                                "Holm within a criterion, Bonferroni over the compare criteria",
                  "build_errors": {c: built.get(f"build/{c}") for c in chapters if built.get(f"build/{c}")},
                  "seconds": round(time.time() - start, 1)}
        with open(os.path.join(report_dir, "report.json"), "w") as f:
            json.dump(report, f, indent=1)
        write_html(os.path.join(report_dir, "report.html"), report, opts["name"] or os.path.basename(submission))
        print(f"{report['total']} / {report['max']} points in {report['seconds']} s; report: "
              f"{os.path.join(report_dir, 'report.html')}")
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main(sys.argv[1:])
