#!/usr/bin/env python3
"""Size and drift measures of the workspace's Rust sources and docs.

For the Rust sources of core/, host/, study/, tests/, firmware/ and fuzz/
(target dirs and generated files excluded) it counts

* files over 800 lines, in src/ and in tests/ (a crate's tests/ directory);
* functions over 100 lines (from `fn` to its closing brace);
* functions returning `Result<_, String>`, public (`pub`) and all;
* type names (struct, enum, union, type, trait) defined more than once in
  the host crate;
* comments that tell history: issue numbers, `#123`, ISO dates, "previously",
  "used to", "no longer", "before this", "now", "was changed" (printed for a
  human to judge: "now" is often fine);

and, in docs/, the mentions of "issue" and the dates; and the stale paths of
scripts/check_paths.py. A summary by default; `--list` adds every item.

    python3 scripts/code_metrics.py [--list] [--root DIR]

`--root` measures another checkout (a worktree of an older commit, say).
Python 3.11 standard library only.
"""

from __future__ import annotations

import argparse
import re
import sys
from collections import defaultdict
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import check_paths  # noqa: E402

CRATE_DIRS = ("core", "host", "study", "tests", "firmware", "fuzz")
BIG_FILE = 800
BIG_FN = 100

HISTORY_RES = [
    ("issue N", re.compile(r"\bissues?\s*#?\d+", re.I)),
    ("#N", re.compile(r"(?<![\w&#\[/\"'])#\d+\b")),
    ("date", re.compile(r"\b20\d\d-\d\d-\d\d\b")),
    ("previously", re.compile(r"\bpreviously\b", re.I)),
    ("used to", re.compile(r"\bused to\b", re.I)),
    ("no longer", re.compile(r"\bno longer\b", re.I)),
    ("before this", re.compile(r"\bbefore this\b", re.I)),
    ("now", re.compile(r"\bnow\b ", re.I)),
    ("was changed", re.compile(r"\bwas changed\b", re.I)),
]
DOC_ISSUE_RE = re.compile(r"(?<!-)\bissues?\b", re.I)
DATE_RE = re.compile(r"\b20\d\d-\d\d-\d\d\b")


def strip_rust(text: str) -> str:
    """The source with comments, strings and char literals blanked (newlines kept)."""
    out = list(text)
    i, n = 0, len(text)

    def blank(a: int, b: int) -> None:
        for k in range(a, min(b, n)):
            if out[k] != "\n":
                out[k] = " "

    while i < n:
        c = text[i]
        if text.startswith("//", i):
            j = text.find("\n", i)
            j = n if j < 0 else j
            blank(i, j)
            i = j
        elif text.startswith("/*", i):
            j = check_paths.block_comment_end(text, i)
            blank(i, j)
            i = j
        elif (c == "r" or c == "b") and (j := check_paths.raw_string_end(text, i)) is not None:
            blank(i, j)
            i = j
        elif c == '"':
            j = i + 1
            while j < n and text[j] != '"':
                j += 2 if text[j] == "\\" else 1
            blank(i, j + 1)
            i = j + 1
        elif c == "'":
            if i + 1 < n and text[i + 1] == "\\":
                j = text.find("'", i + 2)
                j = n if j < 0 else j + 1
                blank(i, j)
                i = j
            elif i + 2 < n and text[i + 2] == "'":
                blank(i, i + 3)
                i += 3
            else:
                i += 1
        else:
            i += 1
    return "".join(out)


def rust_files(root: Path) -> list[str]:
    check_paths.ROOT = root
    files = []
    for f in check_paths.tracked_files():
        if not f.endswith(".rs") or not f.startswith(tuple(d + "/" for d in CRATE_DIRS)):
            continue
        if "/target/" in f or f.startswith("target/"):
            continue
        head = (root / f).read_text(encoding="utf-8", errors="replace")[:400]
        if "@generated" in head or "DO NOT EDIT" in head:
            continue
        files.append(f)
    return sorted(files)


def is_test_file(f: str) -> bool:
    parts = f.split("/")
    return "tests" in parts[1:-1] or (parts[0] == "tests" and len(parts) > 1 and parts[1] == "tests")


FN_RE = re.compile(r"\bfn\s+([A-Za-z_][A-Za-z0-9_]*)")
TYPE_RE = re.compile(r"\b(struct|enum|union|type|trait)\s+([A-Za-z_][A-Za-z0-9_]*)")


def functions(stripped: str):
    """(name, first line, last line, signature, public) of each fn with a body."""
    line_at = [0] * (len(stripped) + 1)
    ln = 1
    for k, ch in enumerate(stripped):
        line_at[k] = ln
        if ch == "\n":
            ln += 1
    line_at[len(stripped)] = ln
    for m in FN_RE.finditer(stripped):
        # The signature runs to the body's `{` (or `;` for a declaration);
        # brackets of generics and arguments are skipped.
        j, depth = m.end(), 0
        while j < len(stripped):
            ch = stripped[j]
            if ch in "(<[":
                depth += 1
            elif ch in ")]" or (ch == ">" and stripped[j - 1] != "-"):
                depth -= 1
            elif ch == ";" and depth <= 0:
                break
            elif ch == "{" and depth <= 0:
                break
            j += 1
        if j >= len(stripped) or stripped[j] == ";":
            continue
        sig = stripped[m.start():j]
        k, depth = j, 0
        while k < len(stripped):
            if stripped[k] == "{":
                depth += 1
            elif stripped[k] == "}":
                depth -= 1
                if depth == 0:
                    break
            k += 1
        line_start = stripped.rfind("\n", 0, m.start()) + 1
        prefix = stripped[line_start:m.start()]
        public = re.search(r"\bpub\s+(?:(?:const|async|unsafe|extern\s*\S*)\s+)*$", prefix) is not None
        yield m.group(1), line_at[m.start()], line_at[min(k, len(stripped))], " ".join(sig.split()), public


def returns_string_err(sig: str) -> bool:
    if "->" not in sig:
        return False
    ret = sig.split("->", 1)[1]
    ret = re.split(r"\bwhere\b", ret)[0].strip()
    return re.fullmatch(r"(?:std::result::)?Result<.*,\s*(?:std::string::)?String\s*>", ret) is not None


def type_defs(stripped: str):
    """(kind, name, line) of each type defined outside impl and trait blocks."""
    stack: list[str] = []
    last_item = 0
    events = []
    for m in re.finditer(r"[{};\n]", stripped):
        ch = m.group(0)
        events.append((m.start(), ch))
    defs = []
    tmatches = list(TYPE_RE.finditer(stripped))
    ti = 0
    for p, ch in events + [(len(stripped), "")]:
        while ti < len(tmatches) and tmatches[ti].start() < p:
            tm = tmatches[ti]
            ti += 1
            if stack and stack[-1] == "impl":
                continue
            before = stripped[max(0, tm.start() - 1):tm.start()]
            if before and (before.isalnum() or before == "_"):
                continue
            defs.append((tm.group(1), tm.group(2), stripped.count("\n", 0, tm.start()) + 1))
        if ch == "{":
            header = stripped[last_item:p]
            stack.append("impl" if re.search(r"\b(impl|trait)\b", header) else "block")
            last_item = p + 1
        elif ch == "}":
            if stack:
                stack.pop()
            last_item = p + 1
        elif ch == ";":
            last_item = p + 1
    return defs


def measure(root: Path) -> dict:
    files = rust_files(root)
    big_src, big_tests, long_fns, str_err = [], [], [], []
    types: dict[str, set[str]] = defaultdict(set)
    history = []
    total_lines = 0
    for f in files:
        text = (root / f).read_text(encoding="utf-8", errors="replace")
        n = text.count("\n") + (0 if text.endswith("\n") else 1)
        total_lines += n
        if n > BIG_FILE:
            (big_tests if is_test_file(f) else big_src).append((n, f))
        stripped = strip_rust(text)
        for name, a, b, sig, public in functions(stripped):
            if b - a + 1 > BIG_FN:
                long_fns.append((b - a + 1, name, f, a))
            if returns_string_err(sig):
                str_err.append((public, name, f, a, sig))
        if f.startswith("host/"):
            for kind, name, ln in type_defs(stripped):
                types[name].add(f"{f}:{ln} ({kind})")
        for ln, c in check_paths.rust_comments(text):
            for label, rx in HISTORY_RES:
                if rx.search(c):
                    history.append((f, ln, label, c.strip()))
                    break
    # The CI script's, manifests' and scripts' comments too.
    for f in check_paths.tracked_files():
        if f == ".ci/run" or f.endswith(".toml") or (f.startswith("scripts/") and f.endswith((".sh", ".py"))):
            if f.startswith("scripts/") and f.endswith(("check_paths.py", "code_metrics.py")):
                continue
            text = (root / f).read_text(encoding="utf-8", errors="replace")
            for ln, c in check_paths.hash_comments(text, toml=f.endswith(".toml")):
                for label, rx in HISTORY_RES:
                    if rx.search(c):
                        history.append((f, ln, label, c.strip()))
                        break
    dup_types = {k: sorted(v) for k, v in types.items() if len(v) > 1}
    doc_issues, doc_dates = [], []
    for d in sorted((root / "docs").glob("*.md")) + [root / "README.md"]:
        if not d.exists():
            continue
        rel = d.relative_to(root).as_posix()
        for ln, raw in enumerate(d.read_text(encoding="utf-8").split("\n"), 1):
            for _ in DOC_ISSUE_RE.finditer(raw):
                doc_issues.append((rel, ln, raw.strip()))
            for _ in DATE_RE.finditer(raw):
                doc_dates.append((rel, ln, raw.strip()))
    stale = check_paths.run()
    return dict(
        files=files, total_lines=total_lines, big_src=sorted(big_src, reverse=True),
        big_tests=sorted(big_tests, reverse=True), long_fns=sorted(long_fns, reverse=True),
        str_err=str_err, dup_types=dup_types, history=history, doc_issues=doc_issues,
        doc_dates=doc_dates, stale=stale,
    )


def report(m: dict, full: bool) -> None:
    pub_err = [x for x in m["str_err"] if x[0]]
    in_docs = lambda xs: [x for x in xs if x[0].startswith("docs/")]  # noqa: E731
    rows = [
        ("Rust files (lines)", f"{len(m['files'])} ({m['total_lines']})"),
        (f"files over {BIG_FILE} lines in src/", len(m["big_src"])),
        (f"files over {BIG_FILE} lines in tests/", len(m["big_tests"])),
        (f"functions over {BIG_FN} lines", len(m["long_fns"])),
        ("pub fns returning Result<_, String>", len(pub_err)),
        ("all fns returning Result<_, String>", len(m["str_err"])),
        ("type names defined twice or more in host", len(m["dup_types"])),
        ("history comments (to judge)", len(m["history"])),
        ("'issue' mentions in docs/ (README)", f"{len(in_docs(m['doc_issues']))} ({len(m['doc_issues']) - len(in_docs(m['doc_issues']))})"),
        ("dates in docs/ (README)", f"{len(in_docs(m['doc_dates']))} ({len(m['doc_dates']) - len(in_docs(m['doc_dates']))})"),
        ("stale paths (check_paths.py)", len(m["stale"])),
    ]
    w = max(len(r[0]) for r in rows)
    print("== summary")
    for k, v in rows:
        print(f"{k:<{w}}  {v}")
    if not full:
        print("\n(--list for the items)")
        return
    print(f"\n== files over {BIG_FILE} lines, src/")
    for n, f in m["big_src"]:
        print(f"{n:6}  {f}")
    print(f"\n== files over {BIG_FILE} lines, tests/")
    for n, f in m["big_tests"]:
        print(f"{n:6}  {f}")
    print(f"\n== functions over {BIG_FN} lines")
    for n, name, f, a in m["long_fns"]:
        print(f"{n:6}  {name}  {f}:{a}")
    print("\n== functions returning Result<_, String> (pub first)")
    for public, name, f, a, sig in sorted(m["str_err"], key=lambda x: (not x[0], x[2], x[3])):
        print(f"{'pub ' if public else '    '} {name}  {f}:{a}")
    print("\n== type names defined more than once in host")
    for name, where in sorted(m["dup_types"].items()):
        print(f"{name}")
        for w_ in where:
            print(f"    {w_}")
    print("\n== comments that may tell history")
    for f, ln, label, c in m["history"]:
        print(f"{f}:{ln}: [{label}] {c}")
    print("\n== 'issue' in docs/ and README.md")
    for f, ln, raw in m["doc_issues"]:
        print(f"{f}:{ln}: {raw[:160]}")
    print("\n== dates in docs/ and README.md")
    for f, ln, raw in m["doc_dates"]:
        print(f"{f}:{ln}: {raw[:160]}")
    print("\n== stale paths")
    for x in m["stale"]:
        print(x)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--list", action="store_true", help="list every item, not only the counts")
    ap.add_argument("--root", type=Path, default=Path(__file__).resolve().parent.parent,
                    help="the checkout to measure (default: this one)")
    args = ap.parse_args()
    report(measure(args.root.resolve()), args.list)
    return 0


if __name__ == "__main__":
    sys.exit(main())
