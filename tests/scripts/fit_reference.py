#!/usr/bin/env python3
"""Reference fits for `host/tests/fit.rs` (issue 5: the rotated-sine fit
against a general nonlinear least-squares solver).

Generates noisy synthetic profiles of the paper's rotated sine with a fixed
seed, writes them as `host/tests/data/fit/<name>.csv` (x_mm,z_mm), fits each
with scipy.optimize.least_squares on the same model and residual as
`cms_host::fit` (vertical residual z - ẑ(x), ẑ solving
-x sinθ + z cosθ = a sin ωx' + b cos ωx' + c with x' = x cosθ + z sinθ),
and writes the results to `host/tests/data/fit/scipy.json`.

The Rust test reads only the checked-in files; Python is not needed at test
time. Rerun (from the repository root) after changing the cases:

    python3 tests/scripts/fit_reference.py
"""

import json
import math
import pathlib

import numpy as np
from scipy.optimize import least_squares

OUT = pathlib.Path(__file__).resolve().parents[2] / "host" / "tests" / "data" / "fit"
SEED = 20240605

# name, wavelength mm, amplitude mm, rotation deg, noise mm, length mm, spacing mm
CASES = [
    ("l50_a100_r0.5", 50.0, 0.100, 0.5, 0.002, 200.0, 1.0),
    ("l50_a50_r1.5", 50.0, 0.050, 1.5, 0.003, 300.0, 1.0),
    ("l100_a100_r2", 100.0, 0.100, 2.0, 0.004, 350.0, 0.95),
    ("l100_a50_r3", 100.0, 0.050, 3.0, 0.005, 400.0, 1.0),
]


def model_z(p, x, z_start):
    """ẑ(x) of the rotated sine, by Newton from z_start (g is monotone in z)."""
    c, theta, a, b, w = p
    si, co = math.sin(theta), math.cos(theta)
    z = np.array(z_start, dtype=float)
    for _ in range(50):
        xr = x * co + z * si
        s, cw = np.sin(w * xr), np.cos(w * xr)
        g = -x * si + z * co - (a * s + b * cw + c)
        gz = co - si * w * (a * cw - b * s)
        step = g / gz
        z = z - step
        if np.max(np.abs(step)) < 1e-15 * (1 + np.max(np.abs(z))):
            break
    return z


def main():
    rng = np.random.default_rng(SEED)
    OUT.mkdir(parents=True, exist_ok=True)
    results = []
    for name, lam, amp, rot_deg, noise, length, dx in CASES:
        theta = math.radians(rot_deg)
        w = 2 * math.pi / lam
        phase = rng.uniform(-math.pi, math.pi)
        offset = rng.uniform(-0.5, 0.5)
        n = int(length / dx) + 1
        # Nearly uniform samples along the measurement frame's x.
        x = 100.0 + dx * np.arange(n) + rng.uniform(-0.05, 0.05, n) * dx
        truth = (offset, theta, amp * math.cos(phase), amp * math.sin(phase), w)
        z = model_z(truth, x, x * math.tan(theta)) + rng.normal(0.0, noise, n)
        path = OUT / f"{name}.csv"
        with path.open("w") as f:
            f.write("x_mm,z_mm\n")
            for xi, zi in zip(x, z):
                f.write(f"{xi:.9f},{zi:.9f}\n")
        # Fit exactly the rounded values written.
        data = np.loadtxt(path, delimiter=",", skiprows=1)
        x, z = data[:, 0], data[:, 1]

        def resid(p):
            return z - model_z(p, x, z)

        # Start near the truth (a reference for the minimum, not a test of
        # start values): wavelength off by 2 %, amplitude by 20 %.
        p0 = np.array([offset + 0.01, theta * 0.9, truth[2] * 0.8, truth[3] * 0.8, w * 1.02])
        sol = least_squares(resid, p0, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15, x_scale="jac")
        c, th, a, b, ww = sol.x
        results.append(
            {
                "file": f"{name}.csv",
                "points": int(len(x)),
                "true_wavelength_mm": lam,
                "true_amplitude_mm": amp,
                "true_rotation_rad": theta,
                "noise_mm": noise,
                "wavelength_mm": 2 * math.pi / ww,
                "amplitude_mm": math.hypot(a, b),
                "phase_rad": math.atan2(b, a),
                "offset_mm": c,
                "rotation_rad": th,
                "rms_residual_mm": float(np.sqrt(np.mean(sol.fun**2))),
                "nfev": int(sol.nfev),
                "status": int(sol.status),
            }
        )
    with (OUT / "scipy.json").open("w") as f:
        json.dump({"seed": SEED, "solver": "scipy.optimize.least_squares(method='lm')", "cases": results}, f, indent=2)
        f.write("\n")
    for r in results:
        print(r["file"], r["wavelength_mm"], r["amplitude_mm"], r["rotation_rad"], r["rms_residual_mm"], r["nfev"])


if __name__ == "__main__":
    main()
