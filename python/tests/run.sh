#!/usr/bin/env bash
# The Python side's tests: a virtual environment of the pinned versions
# (tests/requirements.txt) made under the Cargo target folder, the `cms`
# package built into it from the workspace (maturin, sharing the target
# folder's compiled crates), then pytest: a synthetic fleet of
# recordings, the Dask job on a scheduler and workers started from the
# command line and on a LocalCluster, from and into a bucket of an
# S3-compatible server (moto_server) started here, every recording's
# figures against `cms-host analyze --json`, the DuckDB queries.
#
# Never skips: a missing Python, package or binary fails the run.
#   CMS_HOST          the release cms-host to compare with (default: built here)
#   CARGO_TARGET_DIR  where the venv and the build go (default: the workspace's target/)
#   PYTHON            the interpreter (3.9 or later; default python3)
#   CMS_FLEET_COUNT   recordings in the fleet (default 100)
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../.." && pwd)
target=${CARGO_TARGET_DIR:-$root/target}
python=${PYTHON:-python3}
command -v "$python" >/dev/null || { echo "run.sh: no $python (Python 3.9 or later is needed)" >&2; exit 1; }
"$python" -c 'import sys; sys.exit(sys.version_info < (3, 9))' || { echo "run.sh: $python is older than 3.9" >&2; exit 1; }
if [ -z "${CMS_HOST:-}" ]; then
    CARGO_TARGET_DIR=$target cargo build --release -p cms-host
    CMS_HOST=$target/release/cms-host
fi
[ -x "$CMS_HOST" ] || { echo "run.sh: no cms-host at $CMS_HOST" >&2; exit 1; }
venv=$target/cms-py-venv
stamp=$venv/.requirements
# The environment is remade when the pins change.
if ! cmp -s "$here/requirements.txt" "$stamp"; then
    rm -rf "$venv"
    "$python" -m venv "$venv"
    "$venv/bin/pip" install --quiet --disable-pip-version-check -r "$here/requirements.txt"
    cp "$here/requirements.txt" "$stamp"
fi
export PATH=$venv/bin:$PATH
# The wheel's own build shares the target folder's compiled dependencies.
(cd "$root/python" && CARGO_TARGET_DIR=${CMS_PY_TARGET_DIR:-$target} \
    pip install --quiet --disable-pip-version-check --no-build-isolation --no-deps --force-reinstall .)
export CMS_HOST
cd "$here"
exec python -m pytest -q -p no:cacheprovider "$@"
