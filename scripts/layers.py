#!/usr/bin/env python3
"""Checks the host library's layers: each top-level module of host/src may
import (`crate::x`, non-comment lines) only modules of its own layer or the
layers below it, and no two folders import each other.

Usage: python3 scripts/layers.py   (exit 1 and one line per breach)
"""
import pathlib
import re
import sys

# Lowest first; a module may use its own layer and those below.
LAYERS = [
    ["error", "progress", "output", "plot", "model"],
    ["link", "gnss", "input", "recording", "calib"],
    ["measure"],
    ["analyze"],
    ["report"],
    ["sim"],
    ["device"],
    ["serve"],
    ["bench"],
]
LEVEL = {m: i for i, layer in enumerate(LAYERS) for m in layer}
ROOT = pathlib.Path(__file__).resolve().parent.parent / "host" / "src"


def top(path: pathlib.Path) -> str:
    rel = path.relative_to(ROOT).parts
    return rel[0].removesuffix(".rs")


def main() -> int:
    edges: dict[tuple[str, str], str] = {}
    bad = []
    for f in sorted(ROOT.rglob("*.rs")):
        me = top(f)
        if me in ("lib", "main", "cli"):
            continue
        if me not in LEVEL:
            bad.append(f"{f.relative_to(ROOT.parent.parent)}: module `{me}` is in no layer of scripts/layers.py")
            continue
        for n, line in enumerate(f.read_text().splitlines(), 1):
            code = line.split("//", 1)[0]
            for other in re.findall(r"\bcrate::([a-z_0-9]+)", code):
                if other in ("Error", "Class") or other == me:
                    continue
                edges.setdefault((me, other), f"{f.relative_to(ROOT.parent.parent)}:{n}")
                if other in LEVEL and LEVEL[other] > LEVEL[me]:
                    bad.append(f"{f.relative_to(ROOT.parent.parent)}:{n}: `{me}` (layer {LEVEL[me]}) imports `{other}` (layer {LEVEL[other]})")
    for (a, b), where in edges.items():
        if a < b and (b, a) in edges:
            bad.append(f"{where}: `{a}` and `{b}` import each other (also {edges[(b, a)]})")
    for line in bad:
        print(line)
    print(f"layers: {len(edges)} imports between {len(LEVEL)} modules, {len(bad)} breaches")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
