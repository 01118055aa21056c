#!/usr/bin/env python3
"""Fails when the docs or the comments name a file that does not exist.

Reads every tracked Markdown file (all of its text), and the comments of the
Rust sources (`//`, `///`, `//!`, `/* */`), of the TOML manifests, the shell
and Python scripts, the linker scripts (`*.x`) and `.ci/run`. In them it finds

* repository paths: `host/tests/it/listen.rs`, `docs/calibration.md`,
  `tests/it/x.rs` (resolved against the repository root, the crate the file
  belongs to, that crate's `src/`, and the file's own directory), and
  directories written with a trailing slash (`host/src/cli/`);
* Markdown links to files, resolved against the Markdown file's directory,
  and their `#anchor`s (and same-page `#anchor`s), which must name a heading;
* a test named as "the test `name`" (with an underscore or a module path,
  `corrugation_sim::the_reference_beam_meets_annex_a`): some Rust file
  defines `fn name`;
* a name in backquotes said to be "in" a Rust file (`` `fuzz_seeds` in
  `host/tests/it/record.rs` ``): the name must occur in that file.

A path counts as a reference to the repository only when its first directory
exists where it is resolved (so `cal-images/board-00.png`, `a/b.png`,
`OUT_DIR/x.rs` are example names, not references); absolute paths, URLs,
globs and paths git ignores (build outputs) are skipped. For a file outside
every crate (the docs), a path such as `src/fault.rs` also resolves against
each crate, when its parent directory exists there.

Prints `file:line: missing path 'P'` for each and exits 1; exits 0 when every
reference exists. Python 3.11 standard library only. Run from anywhere:

    python3 scripts/check_paths.py            # the whole repository
    python3 scripts/check_paths.py -q         # only the count
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import unicodedata
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

ROOT = Path(__file__).resolve().parent.parent

# Extensions a file reference ends with; anything else with a slash (a Rust
# path, a ratio, "TCP/IP") is not one.
EXTENSIONS = {
    "rs", "md", "toml", "sh", "py", "csv", "json", "txt", "png", "svg", "jpg", "jpeg", "tif", "tiff", "x",
    "lock", "cmsrec", "yml", "yaml", "ld", "c", "h", "cfg", "ini", "pdf", "html", "ron", "bin",
}
# Directories whose files are data, not text to check.
SKIP_PREFIXES = ("fuzz/corpus/", "host/tests/data/", "tests/golden/")

PATH_RE = re.compile(
    r"(?<![\w/.:~$@%-])"  # not inside a longer word, an absolute path, a URL, ~/, $VAR/
    r"((?:\.\.?/)*(?:\.?[A-Za-z0-9_][A-Za-z0-9_.+-]*/)+(?:\.?[A-Za-z0-9_][A-Za-z0-9_.+-]*)?)"
)
GLOB_NEXT = set("*?{[<…$")
LINK_RE = re.compile(r"!?\[(?:[^\]\[]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
REF_DEF_RE = re.compile(r"^\s{0,3}\[[^\]]+\]:\s*<?(\S+?)>?(?:\s+.*)?$")
NAME_IN_RE = re.compile(r"`([A-Za-z_][A-Za-z0-9_]*)`\s+(?:in|of)\s+`([^`\s]+\.rs)`")
TEST_NAME_RE = re.compile(r"\btests?\s+`([a-z_][a-z0-9_]*(?:::[a-z_][a-z0-9_]*)*)`")
SCHEME_RE = re.compile(r"^[a-zA-Z][a-zA-Z0-9+.-]*:")


@dataclass
class Finding:
    file: str
    line: int
    what: str

    def __str__(self) -> str:
        return f"{self.file}:{self.line}: {self.what}"


# --------------------------------------------------------------------------
# The repository's files


def tracked_files() -> list[str]:
    try:
        out = subprocess.run(
            ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
            cwd=ROOT, check=True, capture_output=True,
        ).stdout
        files = [f for f in out.decode().split("\0") if f]
        return [f for f in files if (ROOT / f).exists()]
    except (OSError, subprocess.CalledProcessError):
        files = []
        for dirpath, dirnames, filenames in os.walk(ROOT):
            dirnames[:] = [d for d in dirnames if d not in (".git", "target") and not d.startswith("target")]
            for n in filenames:
                files.append(os.path.relpath(os.path.join(dirpath, n), ROOT).replace(os.sep, "/"))
        return files


class Tree:
    def __init__(self, files: list[str]):
        self.files = set(files)
        self.dirs: set[str] = {""}
        for f in files:
            p = PurePosixPath(f).parent
            while str(p) != ".":
                self.dirs.add(str(p))
                p = p.parent
        self.crates = sorted(
            (str(PurePosixPath(f).parent) if "/" in f else "") for f in files if f.endswith("Cargo.toml")
        )
        self._ignored: dict[str, bool] = {}

    def exists(self, p: str) -> bool:
        return p in self.files or p in self.dirs

    def is_dir(self, p: str) -> bool:
        return p in self.dirs

    def crate_of(self, f: str) -> str | None:
        best = None
        for c in self.crates:
            if c == "" or f.startswith(c + "/"):
                if best is None or len(c) > len(best):
                    best = c
        return best

    def ignored(self, paths: list[str]) -> set[str]:
        """The paths git would ignore (build outputs, fuzzer findings)."""
        todo = [p for p in paths if p not in self._ignored]
        if todo:
            try:
                r = subprocess.run(
                    ["git", "check-ignore", "--no-index", "--stdin", "-z"],
                    cwd=ROOT, input="\0".join(todo).encode(), capture_output=True,
                )
                hit = {x for x in r.stdout.decode().split("\0") if x}
            except OSError:
                hit = set()
            for p in todo:
                self._ignored[p] = p in hit
        return {p for p in paths if self._ignored[p]}


def join(base: str, rel: str) -> str | None:
    p = os.path.normpath(os.path.join(base, rel)).replace(os.sep, "/")
    if p.startswith("../") or p == "..":
        return None
    return "" if p == "." else p


# --------------------------------------------------------------------------
# Comments


def block_comment_end(text: str, i: int) -> int:
    """The index just after the (nested) block comment that opens at `i`."""
    depth, j, n = 1, i + 2, len(text)
    while j < n and depth:
        if text.startswith("/*", j):
            depth, j = depth + 1, j + 2
        elif text.startswith("*/", j):
            depth, j = depth - 1, j + 2
        else:
            j += 1
    return j


def raw_string_end(text: str, i: int) -> int | None:
    """The index just after the raw string (`r"…"`, `r#"…"#`, `br…`) that
    opens at `i`, or `None` if none opens there."""
    if i > 0 and (text[i - 1].isalnum() or text[i - 1] == "_"):
        return None
    m = re.match(r'(?:br|rb|r)(#*)"', text[i:i + 260])
    if not m:
        return None
    end = '"' + m.group(1)
    j = text.find(end, i + m.end())
    return len(text) if j < 0 else j + len(end)


def rust_comments(text: str) -> list[tuple[int, str]]:
    """(line, text) of each comment of Rust source (strings and chars skipped)."""
    out: list[tuple[int, str]] = []
    i, n, line = 0, len(text), 1
    while i < n:
        c = text[i]
        if c == "\n":
            line += 1
            i += 1
        elif text.startswith("//", i):
            j = text.find("\n", i)
            j = n if j < 0 else j
            out.append((line, text[i:j]))
            i = j
        elif text.startswith("/*", i):
            j = block_comment_end(text, i)
            for k, part in enumerate(text[i:j].split("\n")):
                out.append((line + k, part))
            line += text.count("\n", i, j)
            i = j
        elif (c == "r" or c == "b") and (j := raw_string_end(text, i)) is not None:
            line += text.count("\n", i, j)
            i = j
        elif c == '"':
            j = i + 1
            while j < n and text[j] != '"':
                j += 2 if text[j] == "\\" else 1
            line += text.count("\n", i, j)
            i = j + 1
        elif c == "'":
            if i + 1 < n and text[i + 1] == "\\":
                j = text.find("'", i + 2)
                i = (j + 1) if j > 0 else n
            elif i + 2 < n and text[i + 2] == "'":
                i += 3
            else:
                i += 1  # a lifetime
        else:
            i += 1
    return out


def hash_comments(text: str, toml: bool) -> list[tuple[int, str]]:
    """(line, text) of `#` comments of TOML, shell and Python."""
    out = []
    for ln, raw in enumerate(text.split("\n"), 1):
        quote = None
        for k, ch in enumerate(raw):
            if quote:
                if ch == "\\" and quote == '"':
                    continue
                if ch == quote:
                    quote = None
            elif ch in "\"'":
                quote = ch
            elif ch == "#" and (toml or k == 0 or raw[k - 1] in " \t;(") and not raw[k:].startswith("#!"):
                out.append((ln, raw[k:]))
                break
    return out


# --------------------------------------------------------------------------
# Markdown headings


def slug(heading: str) -> str:
    """GitHub's anchor for a heading."""
    h = re.sub(r"`([^`]*)`", r"\1", heading)
    h = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", h)
    h = re.sub(r"<[^>]+>", "", h)
    h = h.strip().lower()
    keep = []
    for ch in h:
        cat = unicodedata.category(ch)
        if ch in "-_ " or cat[0] in "LN" or cat == "Mn":
            keep.append(ch)
    return "".join(keep).replace(" ", "-")


def md_anchors(text: str) -> set[str]:
    anchors: set[str] = set()
    seen: dict[str, int] = {}
    fence = None
    for raw in text.split("\n"):
        m = re.match(r"^\s{0,3}(```+|~~~+)", raw)
        if m:
            if fence is None:
                fence = m.group(1)[0] * 3
            elif raw.strip().startswith(fence):
                fence = None
            continue
        if fence:
            continue
        m = re.match(r"^\s{0,3}#{1,6}\s+(.*?)\s*#*\s*$", raw)
        if m:
            s = slug(m.group(1))
            k = seen.get(s, 0)
            anchors.add(s if k == 0 else f"{s}-{k}")
            seen[s] = k + 1
    anchors.update(re.findall(r'<a\s+(?:name|id)="([^"]+)"', text))
    return anchors


# --------------------------------------------------------------------------
# The check


class Checker:
    def __init__(self, tree: Tree):
        self.tree = tree
        self.findings: list[Finding] = []
        self.pending: list[tuple[Finding, list[str]]] = []  # missing unless git ignores them
        self._anchors: dict[str, set[str]] = {}
        self._text: dict[str, str] = {}
        self._fns: set[str] | None = None

    def text(self, f: str) -> str:
        if f not in self._text:
            self._text[f] = (ROOT / f).read_text(encoding="utf-8", errors="replace")
        return self._text[f]

    def anchors(self, f: str) -> set[str]:
        if f not in self._anchors:
            self._anchors[f] = md_anchors(self.text(f))
        return self._anchors[f]

    # A path in prose or a comment.
    def check_path(self, f: str, line: int, p: str) -> None:
        t = self.tree
        crate = t.crate_of(f)
        fdir = str(PurePosixPath(f).parent)
        fdir = "" if fdir == "." else fdir
        is_dir = p.endswith("/")
        p = p.rstrip("/")
        if p.startswith("./"):
            p = p[2:]
        if "/" not in p:
            return  # "1/", "A/": a fraction, not a directory
        if p.startswith("../"):
            strong = [fdir]
        else:
            strong = [""]
            if crate is not None and crate != "":
                strong += [crate, crate + "/src"]
            strong.append(fdir)
        weak = [c for c in t.crates if c] if crate in (None, "") else []
        anchored, candidates = False, []
        for b in dict.fromkeys(strong):
            full = join(b, p)
            if full is None:
                continue
            head = join(b, p.split("/")[0]) if not p.startswith("../") else str(PurePosixPath(full).parent)
            if head is not None and (t.is_dir(head) or t.exists(full)):
                anchored = True
                candidates.append(full)
        for b in weak:
            full = join(b, p)
            if full is not None and t.is_dir(str(PurePosixPath(full).parent)):
                anchored = True
                candidates.append(full)
        if not anchored:
            if os.environ.get("CHECK_PATHS_DEBUG"):
                print(f"{f}:{line}: not a repository path: {p}", file=sys.stderr)
            return
        if any((t.is_dir(c) if is_dir else t.exists(c)) for c in candidates):
            return
        shown = p + ("/" if is_dir else "")
        self.pending.append((Finding(f, line, f"missing path '{shown}'"), candidates))

    # A Markdown link target.
    def check_link(self, f: str, line: int, target: str) -> None:
        if SCHEME_RE.match(target) or target.startswith("//"):
            return
        path, _, anchor = target.partition("#")
        fdir = str(PurePosixPath(f).parent)
        fdir = "" if fdir == "." else fdir
        if path:
            if path.startswith("/"):
                full = path.lstrip("/")
            else:
                full = join(fdir, path)
                if full is None:
                    return
            full = full.rstrip("/")
            if not self.tree.exists(full):
                self.findings.append(Finding(f, line, f"missing path '{path}' (link)"))
                return
        else:
            full = f
        if anchor and full.endswith(".md") and full in self.tree.files:
            if anchor.lower() not in self.anchors(full) and anchor not in self.anchors(full):
                self.findings.append(Finding(f, line, f"missing anchor '{target}' (no such heading)"))

    # "`name` in `file.rs`": the name occurs in that file.
    def check_name_in(self, f: str, line: int, name: str, p: str) -> None:
        t = self.tree
        crate = t.crate_of(f)
        fdir = str(PurePosixPath(f).parent)
        bases = ["", fdir if fdir != "." else ""] + ([crate, crate + "/src"] if crate else [])
        for b in bases:
            full = join(b, p)
            if full and full in t.files:
                if not re.search(r"\b" + re.escape(name) + r"\b", self.text(full)):
                    self.findings.append(Finding(f, line, f"missing name '{name}' in '{p}'"))
                return

    # "the test `name`": some Rust file defines it.
    def check_test_name(self, f: str, line: int, name: str) -> None:
        if "_" not in name and "::" not in name:
            return
        if self._fns is None:
            self._fns = set()
            for g in self.tree.files:
                if g.endswith(".rs"):
                    self._fns.update(re.findall(r"\bfn\s+([A-Za-z_][A-Za-z0-9_]*)", self.text(g)))
        if name.rsplit("::", 1)[-1] not in self._fns:
            self.findings.append(Finding(f, line, f"missing test '{name}'"))

    def scan_text(self, f: str, line: int, s: str) -> None:
        for m in PATH_RE.finditer(s):
            p = m.group(1)
            end = m.end(1)
            # Sentence punctuation is not part of a path.
            while p and p[-1] in ".-+" and not p.endswith("/"):
                p, end = p[:-1], end - 1
            if end < len(s) and s[end] in GLOB_NEXT:
                continue
            if "//" in p:
                continue
            if not p.endswith("/"):
                last = p.rsplit("/", 1)[-1]
                if "." not in last or last.rsplit(".", 1)[-1].lower() not in EXTENSIONS:
                    continue
            self.check_path(f, line, p)
        for m in NAME_IN_RE.finditer(s):
            self.check_name_in(f, line, m.group(1), m.group(2))
        for m in TEST_NAME_RE.finditer(s):
            self.check_test_name(f, line, m.group(1))

    def scan_markdown(self, f: str) -> None:
        fence = None
        for ln, raw in enumerate(self.text(f).split("\n"), 1):
            m = re.match(r"^\s{0,3}(```+|~~~+)", raw)
            if m:
                if fence is None:
                    fence = m.group(1)[0] * 3
                elif raw.strip().startswith(fence):
                    fence = None
            if fence is None:
                for lm in LINK_RE.finditer(raw):
                    self.check_link(f, ln, lm.group(1))
                rd = REF_DEF_RE.match(raw)
                if rd:
                    self.check_link(f, ln, rd.group(1))
                # Link targets were checked as links; the rest is prose.
                raw = LINK_RE.sub(lambda m: m.group(0).split("](", 1)[0] + "]", raw)
            self.scan_text(f, ln, raw)

    def scan(self, f: str) -> None:
        if f.startswith(SKIP_PREFIXES):
            return
        name = PurePosixPath(f).name
        if f.endswith(".md"):
            self.scan_markdown(f)
            return
        if f.endswith((".rs", ".x")):
            comments = rust_comments(self.text(f))
        elif f.endswith(".toml"):
            comments = hash_comments(self.text(f), toml=True)
        elif f.endswith((".sh", ".py")) or f == ".ci/run" or name == ".gitignore":
            if name == ".gitignore":
                return
            comments = hash_comments(self.text(f), toml=False)
        else:
            return
        for ln, c in comments:
            self.scan_text(f, ln, c)

    def finish(self) -> list[Finding]:
        ignored = self.tree.ignored([c for _, cs in self.pending for c in cs])
        for finding, cands in self.pending:
            if not any(c in ignored for c in cands):
                self.findings.append(finding)
        self.pending.clear()
        uniq = {(x.file, x.line, x.what): x for x in self.findings}
        return sorted(uniq.values(), key=lambda x: (x.file, x.line, x.what))


def run(files: list[str] | None = None) -> list[Finding]:
    """The findings for `files` (default: every text file of the repository)."""
    tree = Tree(tracked_files())
    checker = Checker(tree)
    for f in sorted(files if files is not None else tree.files):
        checker.scan(f)
    return checker.finish()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("-q", "--quiet", action="store_true", help="print only the count")
    ap.add_argument("files", nargs="*", help="repository-relative files to check (default: all)")
    args = ap.parse_args()
    findings = run(args.files or None)
    if not args.quiet:
        for x in findings:
            print(x)
    if findings:
        print(f"check_paths: {len(findings)} missing", file=sys.stderr)
        return 1
    print("check_paths: every path named in the docs and comments exists", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
