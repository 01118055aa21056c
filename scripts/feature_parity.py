#!/usr/bin/env python3
"""The wheel's build and the test build select the same features.

python/tests/run.sh builds the `cms` wheel (maturin: `cargo rustc -p cms-py
--release --features pyo3/extension-module`) inside `cargo test --workspace
--release`'s target folder. Where the two builds select different features
of a crate, that crate and everything above it (cms-host included) is
compiled twice, which costs CI minutes. python/Cargo.toml names the
features the test build's dev-dependencies add; this script compares the
two builds' unit graphs (cargo's `--unit-graph`, unstable, so the pinned
cargo is asked with RUSTC_BOOTSTRAP=1) and names every crate whose features
differ. Exit 0 when none, 1 otherwise.
"""
import json
import os
import subprocess
import sys


def features(args):
    env = dict(os.environ, RUSTC_BOOTSTRAP="1")
    out = subprocess.run(
        ["cargo", *args, "--release", "--unit-graph", "-Z", "unstable-options"],
        env=env, check=True, capture_output=True, text=True,
    ).stdout
    found = {}
    for unit in json.loads(out)["units"]:
        if unit["mode"] != "build" or unit["target"]["kind"] == ["custom-build"]:
            continue
        key = (unit["pkg_id"], tuple(unit["target"]["kind"]))
        found.setdefault(key, set()).add(tuple(sorted(unit["features"])))
    return found


def main():
    os.chdir(os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
    wheel = features(["build", "-p", "cms-py", "--features", "pyo3/extension-module"])
    tests = features(["test", "--workspace", "--no-run"])
    differ = [k for k in sorted(wheel) if k in tests and wheel[k] != tests[k]]
    for pkg, kind in differ:
        print(f"{pkg} ({'/'.join(kind)}): wheel {sorted(wheel[(pkg, kind)])}, tests {sorted(tests[(pkg, kind)])}")
    if differ:
        print(f"feature_parity: {len(differ)} crate(s) built with other features for the wheel; "
              "name the tests' features in python/Cargo.toml", file=sys.stderr)
        return 1
    print(f"feature_parity: the wheel's {len(wheel)} units have the test build's features")
    return 0


if __name__ == "__main__":
    sys.exit(main())
