#!/usr/bin/env python3
"""Reference for cms_host::standards::en13231::band_pass: the same zero-phase
Butterworth band (6th-order high-pass and low-pass, cut-offs placed for -3 dB
of the forward-backward response at the band edges) designed and run by
scipy (butter(..., output="sos") + sosfiltfilt). Only the interior is
written: the two implementations pad the ends differently.

    python3 tests/scripts/standards_reference.py > host/tests/data/standards/band_30_100.csv
"""
import numpy as np
from scipy.signal import butter, sosfiltfilt

DX_MM = 1.0
N = 3000
ORDER = 6
LO_MM, HI_MM = 30.0, 100.0
KEEP = slice(1000, 2000)

rng = np.random.default_rng(5)
x = np.arange(N) * DX_MM
z = (20 * np.sin(2 * np.pi * x / 15 + 0.3) + 15 * np.sin(2 * np.pi * x / 50 + 1.1)
     + 25 * np.sin(2 * np.pi * x / 150 + 2.0) + 40 * np.sin(2 * np.pi * x / 500) + rng.normal(0, 2, N))
z = np.round(z, 6)  # what the CSV holds is what both sides filter

shift = (np.sqrt(2) - 1) ** (1 / (2 * ORDER))
fs = 1 / DX_MM  # cycles per mm
hp = butter(ORDER, (1 / HI_MM) * shift, "highpass", fs=fs, output="sos")
lp = butter(ORDER, (1 / LO_MM) / shift, "lowpass", fs=fs, output="sos")
y = sosfiltfilt(np.vstack([hp, lp]), z, padlen=N - 1)

print(f"# scipy butter({ORDER}) high-pass {HI_MM} mm + low-pass {LO_MM} mm, sosfiltfilt; dx {DX_MM} mm; "
      f"rows {KEEP.start}..{KEEP.stop} hold the reference band value")
print("x_mm,z_um,band_um")
for i in range(N):
    ref = f"{y[i]:.9f}" if KEEP.start <= i < KEEP.stop else ""
    print(f"{x[i]:.1f},{z[i]:.6f},{ref}")
