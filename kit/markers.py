"""Exercise markers in the sources, and the stubs that replace them.

A marker is the tag [exercise N.M] inside the comment just above a function
definition (chapters/*.c, common/*.h, common/*.c): the body of that function
is the student's.  N is the lecture number: exercise 3.2 belongs to the
chapter chapters/03_*.c, wherever its function lives (optics.h holds 2.x).
Points are not in the marker: they come from kit/rubric.json alone.
"""
import glob
import os
import re

MARKER = re.compile(r"\[exercise (\d+)\.(\d+)\]")
SOURCE_GLOBS = ("chapters/*.c", "chapters/*.h", "common/*.h", "common/*.c")


class Exercise:
    def __init__(self, **kw):
        self.__dict__.update(kw)

    @property
    def id(self):
        return f"{self.lecture}.{self.number}"


def chapter_names(root):
    """{lecture number: chapter name} from chapters/NN_name.c."""
    names = {}
    for path in sorted(glob.glob(os.path.join(root, "chapters", "[0-9][0-9]_*.c"))):
        name = os.path.splitext(os.path.basename(path))[0]
        names[int(name[:2])] = name
    return names


def _skip_code(text, i, end_char):
    """Index just past the bracket that closes the one before i (end_char ')' or '}'),
    skipping strings, character constants and comments."""
    open_char = {"}": "{", ")": "("}[end_char]
    depth = 1
    n = len(text)
    while i < n:
        c = text[i]
        if c in "\"'":
            j = i + 1
            while j < n and text[j] != c:
                j += 2 if text[j] == "\\" else 1
            i = j + 1
            continue
        if text.startswith("/*", i):
            i = text.index("*/", i + 2) + 2
            continue
        if text.startswith("//", i):
            i = text.index("\n", i)
            continue
        if c == open_char:
            depth += 1
        elif c == end_char:
            depth -= 1
            if depth == 0:
                return i + 1
        i += 1
    raise ValueError("unbalanced brackets")


def parse_file(root, rel):
    """The exercises marked in one file, in file order."""
    with open(os.path.join(root, rel)) as f:
        text = f.read()
    found = []
    for m in MARKER.finditer(text):
        comment_start = text.rfind("/*", 0, m.start())
        comment_end = text.find("*/", m.end())
        if comment_start < 0 or comment_end < 0 or text.rfind("*/", 0, m.start()) > comment_start:
            raise ValueError(f"{rel}:{text.count(chr(10), 0, m.start()) + 1}: marker outside a /* comment */")
        sig_start = comment_end + 2
        while text[sig_start] in " \n":
            sig_start += 1
        paren = text.index("(", sig_start)
        head = text[sig_start:paren]
        name = re.findall(r"[A-Za-z_]\w*", head)[-1]
        params_end = _skip_code(text, paren + 1, ")")
        brace = text.index("{", params_end)
        if text[params_end:brace].strip():
            line = text.count("\n", 0, sig_start) + 1
            raise ValueError(f"{rel}:{line}: the marker must stand just above a function definition")
        body_end = _skip_code(text, brace + 1, "}")
        comment = text[comment_start + 2:comment_end]
        comment = "\n".join(re.sub(r"^\s*\* ?", "", ln) for ln in comment.splitlines()).strip()
        found.append(Exercise(
            lecture=int(m.group(1)), number=int(m.group(2)), file=rel, name=name,
            line=text.count("\n", 0, sig_start) + 1,
            return_type=" ".join(head[:head.rfind(name)].split()),
            params=text[paren + 1:params_end - 1], signature=" ".join(text[sig_start:params_end].split()),
            comment=MARKER.sub("", comment).replace("  */", "").strip(),
            body=text[brace:body_end], body_start=brace, body_end=body_end,
            labels=sorted(set(re.findall(r"\(R\d+\)", comment + text[brace:body_end])),
                          key=lambda s: int(s[2:-1]))))
    return found


def all_exercises(root):
    found = []
    for pattern in SOURCE_GLOBS:
        for path in sorted(glob.glob(os.path.join(root, pattern))):
            found.extend(parse_file(root, os.path.relpath(path, root)))
    ids = [e.id for e in found]
    duplicates = sorted({i for i in ids if ids.count(i) > 1})
    if duplicates:
        raise ValueError(f"exercise ids marked twice: {', '.join(duplicates)}")
    return sorted(found, key=lambda e: (e.lecture, e.number))


# ---- stubs ------------------------------------------------------------------------------------------

def neutral_value(return_type):
    """The value a stub returns: nothing for void, zero/false/NULL, or a zeroed struct."""
    t = " ".join(w for w in return_type.split() if w not in ("static", "inline", "const", "extern"))
    if t == "void":
        return None
    if "*" in t:
        return "NULL"
    if t == "bool":
        return "false"
    if t in ("double", "float"):
        return "0.0"
    if re.fullmatch(r"(unsigned |signed )?(int|long|short|char|long long)|u?int\d+_t|size_t", t):
        return "0"
    return f"({t}){{0}}"


def parameter_names(params):
    names = []
    depth, current = 0, ""
    for c in params + ",":
        if c == "," and depth == 0:
            p = current.strip()
            current = ""
            if p and p != "void" and p != "...":
                names.append(re.findall(r"[A-Za-z_]\w*", p.split("[")[0])[-1])
            continue
        depth += c in "([" and 1 or 0
        depth -= c in ")]" and 1 or 0
        current += c
    return names


def file_scope_statics(text, before):
    """Names of static functions and variables declared at file scope before offset `before`."""
    names = set()
    for m in re.finditer(r"^static\b[^;{=(]*?\b([A-Za-z_]\w*)\s*(\(|=|;|\[)", text[:before], re.M):
        names.add(m.group(1))
    return names


def stub_body(text, ex):
    """The body that replaces ex's: (void) every parameter and every file-scope static the real
    body used (so none becomes unused), TODO_ONCE, and the neutral value."""
    used = set(re.findall(r"[A-Za-z_]\w*", re.sub(r"/\*.*?\*/", "", ex.body, flags=re.S)))
    statics = sorted((used & file_scope_statics(text, ex.body_start)) - {ex.name})
    lines = ["{"]
    voids = parameter_names(ex.params) + statics
    if voids:
        lines.append("    " + ", ".join(f"(void){n}" for n in voids) + ";")
    lines.append(f'    TODO_ONCE("{ex.name}"); /* exercise {ex.id}: write this function */')
    value = neutral_value(ex.return_type)
    if value is not None:
        lines.append(f"    return {value};")
    lines.append("}")
    return "\n".join(lines)


def stub_file(text, exercises):
    """text with the bodies of `exercises` (all in this file) replaced by stubs, and todo.h included."""
    for ex in sorted(exercises, key=lambda e: -e.body_start):
        text = text[:ex.body_start] + stub_body(text, ex) + text[ex.body_end:]
    includes = list(re.finditer(r'^#include [<"].*$', text, re.M))
    at = includes[-1].end() if includes else 0
    return text[:at] + '\n#include "todo.h"' + text[at:]
