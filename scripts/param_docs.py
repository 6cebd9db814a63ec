"""Writes the parameter table of docs/scene_format.md from the library's table
(native/include/haptic_hand_params.h), between the markers below; --check only compares.

    .venv/bin/python scripts/param_docs.py [--check]

`make native` runs it after each build, so a row added to the table appears in the docs.
"""

from __future__ import annotations

import argparse
import json
import math
import pathlib
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "scene_format.md"
BEGIN, END = "<!-- parameter table: begin (scripts/param_docs.py writes it) -->", "<!-- parameter table: end -->"
SECTIONS = ("format", "hand", "hand.skeleton[]", "material", "springs", "coupling", "dt", "frames", "gravity", "solver",
            "contact", "haptics", "device", "bodies", "bodies[]", "skeleton")


def _import_params():
    sys.path.insert(0, str(ROOT / "tests"))
    import conftest  # noqa: F401  (maps addon/ to the package haptic_hand)
    from haptic_hand.engine import params

    return params


def _range(p, params) -> str:
    if p.kind == params.KIND_BOOL:
        return "true, false"
    if p.kind == params.KIND_ENUM:
        return ", ".join(f"`{c}`" for c in p.choices)
    if p.kind not in params.NUMERIC_KINDS:
        return ""
    lo, hi = p.min, p.max
    if not math.isfinite(lo) and not math.isfinite(hi):
        return "finite"
    left = "(" if p.flags & params.OPEN_MIN or not math.isfinite(lo) else "["
    right = ")" if p.flags & params.OPEN_MAX or not math.isfinite(hi) else "]"
    text = f"{left}{lo:g}, {hi:g}{right}".replace("inf", "∞")
    return ("0 or " + text) if p.flags & params.ZERO_OR_RANGE else text


def _where(p, params) -> str:
    if p.flags & params.UI_SCENE:
        return "scene settings" + (" (advanced)" if p.flags & params.UI_ADVANCED else "")
    if p.flags & params.UI_OBJECT:
        return "object settings" + (" (advanced)" if p.flags & params.UI_ADVANCED else "")
    if p.flags & params.UI_DERIVED:
        return "from the scene"
    return "scene file only"


def table_markdown() -> str:
    params = _import_params()

    def section(p):
        key = p.element[:-1] if p.element else p.keys[0]
        return SECTIONS.index(key) if key in SECTIONS else len(SECTIONS)

    rows = sorted((p for p in params.table() if not p.flags & params.INTERNAL), key=section)
    lines = ["| field | default | valid | unit | in Blender | what it is |", "|---|---|---|---|---|---|"]
    for p in rows:
        default = "required" if p.flags & params.REQUIRED else json.dumps(p.default)
        applies = ""
        if p.body:
            kinds = [t for t in params.FOR_TYPES if p.applies_to(t)]
            applies = "" if len(kinds) == len(params.FOR_TYPES) else f" ({', '.join(kinds)})"
        lines.append(f"| `{p.json}`{applies} | `{default}` | {_range(p, params)} | {p.unit} | {_where(p, params)} | "
                     f"{p.description} |")
    return "\n".join(lines)


def updated(text: str) -> str:
    head, rest = text.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    return f"{head}{BEGIN}\n{table_markdown()}\n{END}{tail}"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--check", action="store_true", help="exit 1 when the docs' table is not the library's")
    args = parser.parse_args(argv)
    text = DOC.read_text()
    new = updated(text)
    if args.check:
        if new != text:
            print(f"{DOC} does not hold the library's parameter table: run `make docs`", file=sys.stderr)
            return 1
        return 0
    if new != text:
        DOC.write_text(new)
        print(f"updated the parameter table of {DOC}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
