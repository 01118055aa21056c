#!/usr/bin/env python3
"""Generates the example inputs of `cms-host detect` and their ground truth.

    python3 examples/make_stripes.py          # rewrites the files below

Standard library only (PNG written with zlib + struct); a fixed seed makes
the output reproducible, and the committed files are its output.

examples/stripes.png  (16-bit grayscale PNG, 752 x 64, 12-bit values, sBIT=12)
    What a laser-triangulation head sees on a corrugated rail: three laser
    stripes per row, of unequal brightness (peak 1800, 1100 and 600 counts
    above the background) and width (Gaussian sigma 2.2, 2.6 and 3.0 px). Down
    the rows each stripe's centre drifts by a sine of a few pixels (amplitude
    3.0, 4.0, 2.5 px; period 48, 40, 56 rows; its own phase), as the stripe
    does when the head passes over corrugation. Background about 200 counts
    with a gentle gradient (+30 counts left to right, -10 top to bottom),
    additive Gaussian noise of sigma 4 counts, values rounded and clipped to
    0..4095. Eight hot pixels (+700 to +2500 counts, single pixels) are placed
    at random in the background, at least 20 px from every stripe centre, so
    the truth below stays the truth. A pixel's value is the profile sampled at
    its centre: pixel i is at coordinate i px, as in the detector's output.

examples/stripes.truth.csv
    row,stripe,position_px,width_px,amplitude: the centres used above (stripe
    in ascending position, 0-based like `cms-host detect`).

examples/rows.csv  (8-bit values, 6 rows x 120 samples)
    The CSV path: two stripes per row (peak 150 and 90 counts, sigma 2.0 and
    2.5 px) on a background of 20 counts, noise sigma 1.5 counts.

examples/rows.truth.csv
    Same columns as stripes.truth.csv.
"""

import math
import os
import random
import struct
import zlib

HERE = os.path.dirname(os.path.abspath(__file__))
SEED = 20250607


def gauss_profile(x, centre, sigma, amplitude):
    return amplitude * math.exp(-((x - centre) ** 2) / (2.0 * sigma * sigma))


def png_gray16(width, height, rows, significant_bits):
    """A 16-bit grayscale PNG (Sub filter on every row) as bytes."""

    def chunk(kind, data):
        body = kind + data
        return struct.pack(">I", len(data)) + body + struct.pack(">I", zlib.crc32(body) & 0xFFFFFFFF)

    raw = bytearray()
    for row in rows:
        assert len(row) == width
        line = struct.pack(">%dH" % width, *row)
        raw.append(1)  # filter type Sub, 2 bytes per pixel
        raw.extend(line[:2])
        raw.extend((line[i] - line[i - 2]) & 0xFF for i in range(2, len(line)))
    ihdr = struct.pack(">IIBBBBB", width, height, 16, 0, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", ihdr)
        + chunk(b"sBIT", bytes([significant_bits]))
        + chunk(b"IDAT", zlib.compress(bytes(raw), 9))
        + chunk(b"IEND", b"")
    )


def stripes_image(rng):
    width, height = 752, 64
    # (base centre px, sigma px, peak counts, drift amplitude px, period rows, phase rad)
    stripes = [
        (188.3, 2.2, 1800.0, 3.0, 48.0, 0.3),
        (371.7, 2.6, 1100.0, 4.0, 40.0, 2.1),
        (559.2, 3.0, 600.0, 2.5, 56.0, 4.4),
    ]
    truth = []
    rows = []
    for r in range(height):
        centres = []
        for k, (c, sigma, amp, drift, period, phase) in enumerate(stripes):
            centre = c + drift * math.sin(2.0 * math.pi * r / period + phase)
            centres.append(centre)
            truth.append((r, k, centre, sigma, amp))
        row = []
        for x in range(width):
            v = 200.0 + 30.0 * x / (width - 1) - 10.0 * r / (height - 1)
            for (c, sigma, amp, *_), centre in zip(stripes, centres):
                v += gauss_profile(x, centre, sigma, amp)
            v += rng.gauss(0.0, 4.0)
            row.append(min(4095, max(0, int(round(v)))))
        rows.append(row)
    # Hot pixels, away from the stripes.
    placed = 0
    while placed < 8:
        r = rng.randrange(height)
        x = rng.randrange(width)
        if all(abs(x - t[2]) >= 20.0 for t in truth if t[0] == r):
            rows[r][x] = min(4095, rows[r][x] + rng.randint(700, 2500))
            placed += 1
    return width, height, rows, truth


def csv_rows(rng):
    width, height = 120, 6
    stripes = [(38.4, 2.0, 150.0, 1.5, 0.0), (81.9, 2.5, 90.0, 1.0, 1.0)]
    truth = []
    rows = []
    for r in range(height):
        row = [20.0] * width
        for k, (c, sigma, amp, drift, phase) in enumerate(stripes):
            centre = c + drift * math.sin(2.0 * math.pi * r / 6.0 + phase)
            truth.append((r, k, centre, sigma, amp))
            for x in range(width):
                row[x] += gauss_profile(x, centre, sigma, amp)
        rows.append([min(255, max(0, int(round(v + rng.gauss(0.0, 1.5))))) for v in row])
    return rows, truth


def write_truth(path, truth):
    with open(path, "w", newline="\n") as f:
        f.write("row,stripe,position_px,width_px,amplitude\n")
        for r, k, centre, sigma, amp in truth:
            f.write("%d,%d,%.6f,%.3f,%.1f\n" % (r, k, centre, sigma, amp))


def main():
    rng = random.Random(SEED)
    width, height, rows, truth = stripes_image(rng)
    with open(os.path.join(HERE, "stripes.png"), "wb") as f:
        f.write(png_gray16(width, height, rows, 12))
    write_truth(os.path.join(HERE, "stripes.truth.csv"), truth)

    rows, truth = csv_rows(rng)
    with open(os.path.join(HERE, "rows.csv"), "w", newline="\n") as f:
        for row in rows:
            f.write(",".join(str(v) for v in row) + "\n")
    write_truth(os.path.join(HERE, "rows.truth.csv"), truth)


if __name__ == "__main__":
    main()
