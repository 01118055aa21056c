#!/usr/bin/env python3
"""Where the instructions of a `cwt` row go on thumbv7em (QEMU, exact counts).

    scripts/qemu_profile.py [--full] [--track] [--method NAME] [--lines N] [--annotate FN]
    scripts/qemu_profile.py --method line     (the head's line pass over one frame)
    scripts/qemu_profile.py --method encode   (the link's encoder over one calibrated frame)

Builds `cms-qemu-profile` (firmware/qemu/src/bin/profile.rs: 64 of the
benchmark's three-stripe rows through `detect_in` with three 96-px windows,
or `detect` with --full), runs it under qemu-system-arm with `-singlestep -d
exec,nochain` (each instruction its own translation block, logged with its
address) and counts the addresses executed between the image's
`marker_start` and `marker_end`. Prints instructions per row: the total, per
function (inlined code counts in the function it was inlined into) and per
source line. The total agrees with `cms-host bench qemu` to about 1 %
(64 rows and one noise refresh here, 256 there). `--annotate FN` prints,
for each function whose name contains FN, its disassembly with the times
each instruction ran per row (to see what the glue between the loops is).
Not part of CI; needs
qemu-system-arm and the toolchain's llvm-tools (rust-toolchain.toml).
"""
import argparse
import collections
import os
import re
import shutil
import subprocess
import sys
import tempfile

ROWS = 64
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
QEMU_DIR = os.path.join(ROOT, "firmware", "qemu")
TARGET = "thumbv7em-none-eabihf"


def llvm(tool):
    sysroot = subprocess.check_output(["rustc", "--print", "sysroot"], cwd=QEMU_DIR, text=True).strip()
    host = re.search(r"host: (\S+)", subprocess.check_output(["rustc", "-vV"], text=True)).group(1)
    path = os.path.join(sysroot, "lib", "rustlib", host, "bin", tool)
    # Without the toolchain's llvm-tools, the system's LLVM (any recent
    # one disassembles Thumb-2).
    return path if os.path.exists(path) else shutil.which(tool) or path


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--full", action="store_true", help="the full-row search instead of the windows")
    ap.add_argument("--track", action="store_true", help="the windows tracked (detect_tracked, ±20 px)")
    ap.add_argument("--method", default="cwt", help="the method profiled (its name in `bench qemu`)")
    ap.add_argument("--lines", type=int, default=30, help="source lines to print")
    ap.add_argument("--dump", metavar="FILE", help="write the per-row count of every address executed to FILE")
    ap.add_argument("--annotate", metavar="FN", action="append", default=[],
                    help="print the disassembly of the functions named like FN with per-row counts")
    args = ap.parse_args()
    env = dict(os.environ)
    env.pop("CARGO_TARGET_DIR", None)
    if args.full:
        env["CMS_PROFILE_FULL_ROW"] = "1"
    if args.track:
        env["CMS_PROFILE_TRACK"] = "1"
    env["CMS_PROFILE_METHOD"] = args.method
    target_dir = os.path.join(QEMU_DIR, "target")
    subprocess.check_call(
        ["cargo", "build", "--release", "--quiet", "--bin", "cms-qemu-profile", "--target-dir", target_dir],
        cwd=QEMU_DIR, env=env)
    elf = os.path.join(target_dir, TARGET, "release", "cms-qemu-profile")
    # Functions by address, source lines from the disassembly.
    fn_of, line_of, text_of = {}, {}, {}
    fn, src = None, None
    dis = subprocess.check_output([llvm("llvm-objdump"), "-d", "-l", "--no-show-raw-insn", elf], text=True)
    for l in dis.splitlines():
        m = re.match(r"^[0-9a-f]+ <(.*)>:", l)
        if m:
            fn, src = m.group(1), None
            continue
        m = re.match(r"^; (/\S+:\d+)", l)
        if m:
            src = re.sub(r".*/(core/src/|library/core/src/|src/)", "", m.group(1))
            continue
        m = re.match(r"^\s+([0-9a-f]+):", l)
        if m:
            a = int(m.group(1), 16)
            fn_of[a], line_of[a], text_of[a] = fn, src, l.strip()
    per_fn, per_line, per_pc, total, on = collections.Counter(), collections.Counter(), collections.Counter(), 0, False
    pat = re.compile(r"\[[0-9a-f]+/([0-9a-f]+)/")
    with tempfile.TemporaryDirectory() as tmp:
        log = os.path.join(tmp, "trace.log")
        subprocess.check_call(
            ["qemu-system-arm", "-machine", "mps2-an386", "-nographic", "-icount", "shift=0,sleep=off",
             "-semihosting-config", "enable=on,target=native", "-singlestep", "-d", "exec,nochain",
             "-D", log, "-kernel", elf], stdout=subprocess.DEVNULL, timeout=600)
        with open(log) as trace:
            for line in trace:
                m = pat.search(line)
                if not m:
                    continue
                pc = int(m.group(1), 16)
                f = fn_of.get(pc) or "?"
                if "marker_start" in f:
                    on = True
                    continue
                if "marker_end" in f:
                    break
                if on:
                    total += 1
                    per_fn[f] += 1
                    per_line[line_of.get(pc)] += 1
                    per_pc[pc] += 1
    if not on:
        sys.exit("marker_start never ran")
    global ROWS
    if args.method in ("line", "encode"):
        # One frame of 480 rows (firmware/qemu/src/bin/profile.rs).
        ROWS = 480
        what = "line pass" if args.method == "line" else "the link's encoder, calibrated"
        print(f"{what}, one frame of 3 lasers x 480 rows: {total / ROWS:.0f} instructions per row of the frame")
    else:
        what = "detect (full row)" if args.full else (
            "detect_tracked, three 96-px windows, ±20 px tracks" if args.track else "detect_in, three 96-px windows")
        print(f"{args.method}, 752 px x 3 stripes, {what}: {total / ROWS:.0f} instructions per row ({ROWS} rows)")
    print("\nper function (inlined code in its caller):")
    for f, c in per_fn.most_common(20):
        name = re.sub(r"17h[0-9a-f]{16}E$", "", f)
        print(f"{c / ROWS:9.1f}  {name[:110]}")
    print("\nper source line:")
    for s, c in per_line.most_common(args.lines):
        print(f"{c / ROWS:9.1f}  {s}")
    if args.dump:
        with open(args.dump, "w") as f:
            f.write(f"# {elf}\n")
            for a, c in sorted(per_pc.items()):
                f.write(f"{a:#x} {c / ROWS}\n")
    for want in args.annotate:
        for f in sorted({f for f in fn_of.values() if f and want in f}):
            if not any(per_pc[a] for a in fn_of if fn_of[a] == f):
                continue
            print(f"\n{f}:")
            last = None
            for a in sorted(a for a in fn_of if fn_of[a] == f):
                if line_of[a] != last:
                    print(f"              ; {line_of[a]}")
                    last = line_of[a]
                print(f"{per_pc[a] / ROWS:9.2f}  {text_of[a]}")


if __name__ == "__main__":
    main()
