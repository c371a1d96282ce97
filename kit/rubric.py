"""kit/rubric.json: the one place where criteria and their points are defined."""
import json
import os

KINDS = ("grade", "unit", "compare", "surfaces")


def load(root):
    path = os.path.join(root, "kit", "rubric.json")
    try:
        with open(path) as f:
            rub = json.load(f)
    except (OSError, ValueError) as e:
        raise ValueError(f"{path}: {e}")
    seen = set()
    for i, c in enumerate(rub.get("criteria", [])):
        where = f"{path}: criterion {i + 1}"
        for key in ("chapter", "name", "kind", "points", "exercises", "what"):
            if key not in c:
                raise ValueError(f"{where}: no '{key}'")
        if c["kind"] not in KINDS:
            raise ValueError(f"{where}: kind '{c['kind']}' is not one of {', '.join(KINDS)}")
        if (c["chapter"], c["name"]) in seen:
            raise ValueError(f"{where}: '{c['name']}' twice in {c['chapter']}")
        seen.add((c["chapter"], c["name"]))
    return rub


def statistical(c):
    return c["kind"] == "compare"
