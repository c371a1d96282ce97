"""Exercise markers in the sources, and the stubs that replace them.

A marker is the tag [exercise N.M] inside the comment just above a function
definition (chapters/*.c, common/*.h, common/*.c): the body of that function
is the student's.  N is the lecture: exercise 3.2 belongs to the chapter
chapters/03_*.c, exercise 3c.1 to chapters/03c_*.c (lecture 3's third part),
wherever its function lives (optics.h holds 2.x).
Points are not in the marker: they come from kit/rubric.json alone.
"""
import glob
import os
import re

MARKER = re.compile(r"\[exercise (\d+[a-z]?)\.(\d+)\]")
SOURCE_GLOBS = ("chapters/*.c", "chapters/*.h", "common/*.h", "common/*.c")


class Exercise:
    def __init__(self, **kw):
        self.__dict__.update(kw)

    @property
    def id(self):
        return f"{self.lecture}.{self.number}"

    @property
    def order(self):
        return lecture_order(self.lecture) + (self.number,)


def lecture_of(chapter):
    """The lecture of a chapter name: "03_radiosity" -> "3", "03c_hierarchical" -> "3c"."""
    return chapter.split("_")[0].lstrip("0") or "0"


def lecture_order(lecture):
    """A sort key for a lecture: "3" < "3c" < "4" < "10"."""
    digits = lecture.rstrip("abcdefghijklmnopqrstuvwxyz")
    return int(digits), lecture[len(digits):]


def chapter_names(root):
    """{lecture: chapter name} from chapters/NN_name.c and chapters/NNx_name.c ("3c" for 03c_hierarchical)."""
    names = {}
    for path in sorted(glob.glob(os.path.join(root, "chapters", "[0-9][0-9]*_*.c"))):
        name = os.path.splitext(os.path.basename(path))[0]
        if name.split("_")[0][:2].isdigit():
            names[lecture_of(name)] = name
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
        while sig_start < len(text) and text[sig_start] in " \t\n":
            sig_start += 1
        tag_line = text.count("\n", 0, m.start()) + 1
        not_above = ValueError(f"{rel}:{tag_line}: [exercise {m.group(1)}.{m.group(2)}] is not just above a "
                               f"function definition (the comment that holds it must end right above one)")
        paren = text.find("(", sig_start)
        head = text[sig_start:paren]
        names = re.findall(r"[A-Za-z_]\w*", head)
        # the head is a return type and a name: no statement, declaration or comment ends in it
        if paren < 0 or not names or re.search(r"[;{}=#\[\]]|/\*|//", head):
            raise not_above
        name = names[-1]
        try:
            params_end = _skip_code(text, paren + 1, ")")
            brace = text.index("{", params_end)
            if text[params_end:brace].strip():
                raise ValueError
            body_end = _skip_code(text, brace + 1, "}")
        except ValueError:  # no parameter list or body closes
            raise not_above from None
        comment = text[comment_start + 2:comment_end]
        comment = "\n".join(re.sub(r"^\s*\* ?", "", ln) for ln in comment.splitlines()).strip()
        found.append(Exercise(
            lecture=m.group(1), number=int(m.group(2)), file=rel, name=name,
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
    return sorted(found, key=lambda e: e.order)


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


# ---- answers elsewhere: C functions compared after normalising ---------------------------------------
#
# An exercise's answer is its body in the solution.  A handout gives it away when any function of
# any file still contains that body, even renamed: so bodies are compared as token sequences in
# which comments are gone, whitespace does not count and every identifier that is not a C keyword
# is one token "$" (numbers, operators and keywords are kept).  A copy with other variable names,
# other function names or other comments is still found; a different computation is not.

C_KEYWORDS = frozenset("""auto break case char const continue default do double else enum extern float for
goto if inline int long register restrict return short signed sizeof static struct switch typedef union
unsigned void volatile while _Bool _Static_assert bool true false NULL""".split())
_TOKEN = re.compile(r"""
    (?P<comment>/\*.*?\*/|//[^\n]*)
  | (?P<string>"(?:\\.|[^"\\\n])*"|'(?:\\.|[^'\\\n])*')
  | (?P<number>\.?\d(?:[\w.]|[eEpP][-+])*)
  | (?P<name>[A-Za-z_]\w*)
  | (?P<op>->|\+\+|--|<<=|>>=|<<|>>|<=|>=|==|!=|&&|\|\||[-+*/%&|^!=<>]=|\.\.\.|\#\#|[^\s\w])
  | (?P<newline>\n)
""", re.S | re.X)

# An exercise body shorter than this many tokens (e.g. `return r2 * (i + alpha) / (i + 1);`, 16) is
# the shape of countless unrelated lines once names are gone: found inside a longer function it
# would be a false alarm.  Such a body is an answer only where it is a function's whole body (a
# wrapper that computes exactly what the exercise asks), which is how a short answer gets copied.
MIN_TOKENS_INSIDE = 24
# A near copy: a function that has, statement for statement, this share of the answer's tokens
# (an answer with one guard added or dropped, a renamed helper, fmin for min_ignoring_nan).
# Measured on the solution: a copy of chapter 4's survives_roulette that common/ once held (one
# guard fewer) had 0.84 of exercise 4.3; of every other function that is not an exercise, the most
# any has of an exercise is 0.44 (chapter 2's shadow_transmittance of exercise 2.3).
NEAR_COPY_SHARE = 0.75


class Token:
    __slots__ = ("kind", "text", "line")

    def __init__(self, kind, text, line):
        self.kind, self.text, self.line = kind, text, line


def tokens(text, first_line=1):
    """C tokens of text without comments or preprocessor lines, each with its 1-based line."""
    out, line, at_line_start = [], first_line, True
    pos, n = 0, len(text)
    while pos < n:
        if at_line_start:
            m = re.match(r"[ \t]*#", text[pos:pos + 200])
            if m:  # a preprocessor line, with its continuation lines
                end = pos
                while True:
                    end = text.find("\n", end)
                    if end < 0 or text[end - 1] != "\\":
                        break
                    end += 1
                end = n if end < 0 else end
                line += text.count("\n", pos, end)
                pos = end
                continue
        m = _TOKEN.match(text, pos)
        if not m:  # whitespace
            at_line_start = False
            pos += 1
            continue
        kind = m.lastgroup
        s = m.group(0)
        if kind == "newline":
            line += 1
            at_line_start = True
        elif kind == "comment":
            line += s.count("\n")
            at_line_start = False if "\n" not in s else at_line_start
        else:
            out.append(Token(kind, s, line))
            at_line_start = False
        pos = m.end()
    return out


def normalised(toks):
    """The comparable form: identifiers that are not keywords become "$", strings "S"."""
    out = []
    for t in toks:
        if t.kind == "name" and t.text not in C_KEYWORDS:
            if out[-2:-1] == ["$"] and out[-1] in ("->", "."):
                out.pop()  # v->m->exponent is one name, as m->exponent or exponent would be
                continue
            out.append("$")
        elif t.kind == "name":
            out.append(t.text)
        elif t.kind == "string":
            out.append("S")
        else:
            out.append(t.text)
    return tuple(out)


class Function:
    """A C function definition found in a file: name, 1-based line of its name, and the
    normalised tokens of its body without the outer braces."""

    def __init__(self, file, name, line, body):
        self.file, self.name, self.line, self.body = file, name, line, body


def functions(text, file):
    """Every function definition in C text: at brace depth 0, `name ( ... ) {`."""
    toks = tokens(text)
    found, depth, i = [], 0, 0
    while i < len(toks):
        t = toks[i].text
        if t == "{" and depth == 0 and i > 0 and toks[i - 1].text == ")":
            # back over the parameter list to the name before it
            k, level = i - 1, 0
            while k >= 0:
                level += {")": 1, "(": -1}.get(toks[k].text, 0)
                if level == 0:
                    break
                k -= 1
            end, level = i, 0
            while end < len(toks):
                level += {"{": 1, "}": -1}.get(toks[end].text, 0)
                if level == 0:
                    break
                end += 1
            if k > 0 and toks[k - 1].kind == "name" and toks[k - 1].text not in C_KEYWORDS:
                found.append(Function(file, toks[k - 1].text, toks[k - 1].line, normalised(toks[i + 1:end])))
            i = end + 1
            continue
        depth += {"{": 1, "}": -1}.get(t, 0)
        i += 1
    return found


def markdown_code(text, file):
    """The fenced code blocks of a Markdown file (``` or ~~~, any info string but `render`), each
    as the functions it defines plus the whole block as one fragment named "code block"."""
    found = []
    for m in re.finditer(r"^(```|~~~)([^\n]*)\n(.*?)^\1[ \t]*$", text, re.S | re.M):
        if m.group(2).strip().startswith("render"):
            continue
        line = text.count("\n", 0, m.start(3)) + 1
        code = m.group(3)
        found += [Function(file, f.name, f.line + line - 1, f.body) for f in functions(code, file)]
        found.append(Function(file, "code block", line, normalised(tokens(code))))
    return found


def exercise_tokens(ex):
    """The normalised body of an exercise as the solution writes it, without its outer braces."""
    return normalised(tokens(ex.body[1:-1]))


def contains(haystack, needle):
    """True when the token tuple needle occurs contiguously in haystack."""
    n = len(needle)
    if n == 0 or n > len(haystack):
        return False
    first = needle[0]
    for i in range(len(haystack) - n + 1):
        if haystack[i] == first and haystack[i:i + n] == needle:
            return True
    return False


def statements(toks):
    """A normalised body cut after every ';', '{' and '}'."""
    out, current = [], []
    for t in toks:
        current.append(t)
        if t in (";", "{", "}"):
            out.append(tuple(current))
            current = []
    if current:
        out.append(tuple(current))
    return out


def copied_share(function, answer):
    """The share of answer's tokens in statements that function has too (0..1)."""
    have = set(statements(function.body))
    parts = statements(answer)
    return sum(len(p) for p in parts if p in have) / max(1, sum(len(p) for p in parts))


def gives_away(function, answer):
    """True when function's body is answer, or (for answers long enough to mean something)
    contains it or most of its statements."""
    if len(answer) < MIN_TOKENS_INSIDE:
        return function.body == answer
    return contains(function.body, answer) or copied_share(function, answer) >= NEAR_COPY_SHARE


def answers_in_tree(root, exercises, files):
    """The places in files (relative to root; .c, .h and .md) whose code contains the body of one of
    exercises: a list of (Function, Exercise)."""
    answers = [(ex, exercise_tokens(ex)) for ex in exercises]
    answers = [(ex, a) for ex, a in answers if a]
    found = []
    for rel in files:
        if not rel.endswith((".c", ".h", ".md")):
            continue
        try:
            with open(os.path.join(root, rel), encoding="utf-8") as f:
                text = f.read()
        except (OSError, UnicodeDecodeError):
            continue
        for fn in markdown_code(text, rel) if rel.endswith(".md") else functions(text, rel):
            for ex, answer in answers:
                if gives_away(fn, answer):
                    found.append((fn, ex))
    return found
