#!/usr/bin/env bash
# Instructions per row of every detection method and row size, counted by
# valgrind's callgrind: a figure that does not depend on the machine's load or
# clock, to set beside `cms-host bench speed`. Not part of CI.
#
#   scripts/instructions.sh [ROWS]        (default 256; takes a few minutes)
#   METHODS="cwt cog" SIZES="752x3" scripts/instructions.sh   (a subset)
#
# Each configuration runs `cms-host bench speed` twice under callgrind, with
# 64 and 64 + ROWS timed rows and no warm-up; the difference divided by ROWS
# is the cost of one `Detector::detect` call (start-up, row synthesis and the
# report cancel out). Rows as in `bench speed`: 12-bit, σ = 2.5 px, 30 dB, 64
# distinct rows cycled, so a multiple of 64 averages over all of them.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

command -v valgrind >/dev/null || { echo "valgrind not found (apt-get install valgrind)" >&2; exit 1; }
ROWS=${1:-256}
[[ "$ROWS" =~ ^[1-9][0-9]*$ ]] || { echo "ROWS must be a positive integer" >&2; exit 2; }

cargo build --release -q -p cms-host
BIN="${CARGO_TARGET_DIR:-target}/release/cms-host"

METHODS=${METHODS:-"cwt cwt-paper max cog cog-filtered gaussian parabolic blais-rioux linear fir-zero"}
SIZES=${SIZES:-"640x1 640x3 752x1 752x3 1280x1 1280x3"}

count() {
    valgrind --tool=callgrind --callgrind-out-file=/dev/null \
        "$BIN" bench speed --method "$1" --size "$2" --rows "$3" --reps 1 --warmup 0 2>&1 >/dev/null |
        sed -n 's/.*Collected : \([0-9]*\).*/\1/p'
}

echo "# Instructions per row (callgrind, $ROWS rows per configuration)"
echo
printf '| method |'
for s in $SIZES; do printf ' %s px × %s |' "${s%x*}" "${s#*x}"; done
printf '\n|---|'
for _ in $SIZES; do printf -- '---:|'; done
echo
for m in $METHODS; do
    printf '| %s |' "$m"
    for s in $SIZES; do
        a=$(count "$m" "$s" 64)
        b=$(count "$m" "$s" $((64 + ROWS)))
        printf ' %d |' $(((b - a) / ROWS))
    done
    echo
done
