#!/usr/bin/env python3
"""An independent EN 15610 (Method A) implementation, in plain Python (no
project code, no numpy), to cross-check cms_host::standards::en15610 through
`cms-host analyze PROFILE.csv --json`.

It follows the standard as docs/corrugation-and-standards.md reads it (and
as the MIT-licensed `phonometry` package implements it; written from the
definitions, not from either implementation):

* spike removal (section 7.2): derivatives by central differences; a spike
  where r'' < -1e7 um/m^2 and r' changes sign; its edges the nearest samples
  either side where |r'| < 5e3 um/m; removed (replaced by the straight line
  between the edges) when its height above that line h > w^2 / 3 m, w the
  edge-to-edge width; passes repeated until one removes nothing;
* curvature processing (section 7.3): the path of the centre of a wheel of
  radius 0.375 m rolled along the record, less the radius:
  r'(x_i) = max_x [r(x) - (R - sqrt(R^2 - (x - x_i)^2))];
* the spectrum: segments of 1 m, 50 % overlap, each detrended (least-squares
  line) and Hann-windowed (periodic); one-sided power normalised by the
  window's power; base-ten one-third octaves (centres 10^(k/10) per metre,
  edges x10^(+-0.05)), each DFT line's power shared between bands by the
  part of its width (one line spacing, centred on it) inside each; level
  10 lg(sum / 1 um^2); bands whose nominal wavelength is at most a quarter
  of the segment and whose upper edge is below Nyquist.

Run it to regenerate the checked-in profile and levels:

    python3 tests/scripts/en15610_reference.py host/tests/data/standards

writes en15610_profile.csv (x_mm,height_um: sines of 5-300 mm, broadband
roughness, spikes and pits) and en15610_levels.csv (nominal wavelength mm,
level dB).
"""
import cmath
import math
import random
import sys

DX_MM = 1.0
LENGTH_MM = 12_000.0
SEGMENT_MM = 1000.0
R_UM = 375_000.0


def profile():
    rnd = random.Random(15610)
    n = int(LENGTH_MM / DX_MM)
    x = [i * DX_MM for i in range(n)]
    sines = [(5.0, 0.8), (8.0, 1.5), (16.0, 3.0), (31.5, 6.0), (50.0, 10.0), (100.0, 15.0), (200.0, 20.0), (300.0, 25.0)]
    phases = [rnd.uniform(0, 2 * math.pi) for _ in sines]
    # Broadband roughness: 200 sines, log-spaced 3-500 mm, amplitude ~ wavelength^0.7.
    rough = []
    for k in range(200):
        w = 3.0 * (500.0 / 3.0) ** (k / 199)
        rough.append((w, 0.04 * w ** 0.7, rnd.uniform(0, 2 * math.pi)))
    z = []
    for xi in x:
        v = sum(a * math.sin(2 * math.pi * xi / w + p) for (w, a), p in zip(sines, phases))
        v += sum(a * math.sin(2 * math.pi * xi / w + p) for w, a, p in rough)
        v += rnd.gauss(0.0, 0.2)
        z.append(v)
    # Spikes (dirt: one or two samples standing 20-60 um proud) and pits
    # (2-6 mm wide, 10-30 um deep).
    for _ in range(12):
        i = rnd.randrange(50, n - 50)
        h = rnd.uniform(20, 60)
        z[i] += h
        if rnd.random() < 0.5:
            z[i + 1] += 0.7 * h
    for _ in range(8):
        i = rnd.randrange(50, n - 50)
        width = rnd.randint(2, 6)
        depth = rnd.uniform(10, 30)
        for j in range(width):
            z[i + j] -= depth * math.sin(math.pi * (j + 0.5) / width)
    # What the CSV holds is what both sides analyse.
    return x, [round(v, 4) for v in z]


def derivatives(z, dx_m):
    n = len(z)
    d1 = [0.0] * n
    d2 = [0.0] * n
    for i in range(1, n - 1):
        d1[i] = (z[i + 1] - z[i - 1]) / (2 * dx_m)
        d2[i] = (z[i + 1] - 2 * z[i] + z[i - 1]) / (dx_m * dx_m)
    d1[0] = (z[1] - z[0]) / dx_m
    d1[-1] = (z[-1] - z[-2]) / dx_m
    return d1, d2


def remove_spikes(z, dx_mm):
    z = list(z)
    dx_m = dx_mm / 1000.0
    removed = 0
    while True:
        d1, d2 = derivatives(z, dx_m)
        n = len(z)
        count = 0
        i = 1
        while i < n - 1:
            if d2[i] < -1e7 and d1[i - 1] > 0 > d1[i + 1]:
                left = i - 1
                while left > 0 and abs(d1[left]) >= 5e3:
                    left -= 1
                right = i + 1
                while right < n - 1 and abs(d1[right]) >= 5e3:
                    right += 1
                w = (right - left) * dx_m
                line = z[left] + (z[right] - z[left]) * (i - left) / (right - left)
                h = (z[i] - line) * 1e-6  # m
                if h > w * w / 3.0:
                    for j in range(left + 1, right):
                        z[j] = z[left] + (z[right] - z[left]) * (j - left) / (right - left)
                    count += 1
                    i = right
                    continue
            i += 1
        removed += count
        if count == 0:
            return z, removed


def curvature(z, dx_mm):
    dx_um = dx_mm * 1000.0
    lo, hi = min(z), max(z)
    rng = hi - lo
    reach = int(math.ceil(math.sqrt(max(2 * R_UM * rng - rng * rng, 0.0)) / dx_um)) + 1
    sag = [R_UM - math.sqrt(R_UM * R_UM - (t * dx_um) ** 2) for t in range(reach + 1)]
    n = len(z)
    return [max(z[k] - sag[abs(k - i)] for k in range(max(0, i - reach), min(n, i + reach + 1))) for i in range(n)]


def fft(a):
    """Mixed-radix (2, 5, else direct) decimation in time."""
    n = len(a)
    if n == 1:
        return list(a)
    p = 2 if n % 2 == 0 else 5 if n % 5 == 0 else n
    if p == n:
        return [sum(a[j] * cmath.exp(-2j * math.pi * j * k / n) for j in range(n)) for k in range(n)]
    m = n // p
    subs = [fft(a[r::p]) for r in range(p)]
    out = [0j] * n
    for k in range(n):
        out[k] = sum(subs[r][k % m] * cmath.exp(-2j * math.pi * r * k / n) for r in range(p))
    return out


def spectrum(z, dx_mm):
    m = int(round(SEGMENT_MM / dx_mm))
    hop = m // 2
    w = [0.5 - 0.5 * math.cos(2 * math.pi * i / m) for i in range(m)]
    sw2 = sum(v * v for v in w)
    power = [0.0] * (m // 2 + 1)
    segments = 0
    for s in range(0, len(z) - m + 1, hop):
        seg = z[s:s + m]
        xm = (m - 1) / 2
        mean = sum(seg) / m
        sxx = sum((i - xm) ** 2 for i in range(m))
        slope = sum((i - xm) * (v - mean) for i, v in enumerate(seg)) / sxx
        y = [(v - mean - slope * (i - xm)) * w[i] for i, v in enumerate(seg)]
        spec = fft(y)
        for k in range(1, m // 2 + 1):
            p = abs(spec[k]) ** 2 / (m * sw2)
            power[k] += p * (1 if k == m // 2 else 2)
        segments += 1
    power = [p / segments for p in power]
    df = 1.0 / (m * dx_mm / 1000.0)  # per metre
    nyquist = 1.0 / (2 * dx_mm / 1000.0)
    levels = []
    for k in range(0, 40):
        fc = 10 ** (k / 10)
        lo, hi = fc * 10 ** -0.05, fc * 10 ** 0.05
        if hi >= nyquist or nominal(k) > SEGMENT_MM / 4:
            continue
        total = 0.0
        for j in range(1, len(power)):
            a, b = (j - 0.5) * df, (j + 0.5) * df
            overlap = max(0.0, min(b, hi) - max(a, lo))
            total += power[j] * overlap / df
        if total > 0:
            levels.append((nominal(k), 10 * math.log10(total)))
    return levels


def nominal(k):
    """The preferred (nominal) wavelength of band k, mm."""
    table = [1000, 800, 630, 500, 400, 315, 250, 200, 160, 125]
    return table[k % 10] / 10 ** (k // 10)


def main():
    out = sys.argv[1] if len(sys.argv) > 1 else "."
    x, z = profile()
    with open(f"{out}/en15610_profile.csv", "w") as f:
        f.write("# tests/scripts/en15610_reference.py: sines of 5-300 mm, broadband roughness, spikes and pits\n")
        f.write("x_mm,height_um\n")
        for xi, zi in zip(x, z):
            f.write(f"{xi:.1f},{zi:.4f}\n")
    despiked, removed = remove_spikes(z, DX_MM)
    processed = curvature(despiked, DX_MM)
    levels = spectrum(processed, DX_MM)
    with open(f"{out}/en15610_levels.csv", "w") as f:
        f.write(f"# tests/scripts/en15610_reference.py: {removed} spikes removed; curvature R = 0.375 m; "
                f"segments {SEGMENT_MM:.0f} mm, 50 % overlap\n")
        f.write("nominal_wavelength_mm,level_db\n")
        for w, level in levels:
            f.write(f"{w:g},{level:.4f}\n")
    print(f"{removed} spikes removed; {len(levels)} bands", file=sys.stderr)


if __name__ == "__main__":
    main()
