"""``python -m cms.fleet.synth OUT_DIR [--count N] [--frames F] [--points P]``

A synthetic fleet: N recordings written by ``cms-host bench recording``
(a known rail, no rendering), each with a survey block — one of a few
lines and tracks, a year, a start chainage along the line — and a
corrugated zone of its own place, wavelength and amplitude (some under the
limits), so that the dataset's partitions and queries have something to
tell apart. Deterministic: recording k is the same on every run.
``CMS_HOST`` names the binary (default ``cms-host`` on PATH).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from typing import Optional

LINES = ("LN 1 Northtown–Southville", "LN 2 Harbour branch", "LN 7 Ridge loop")
TRACKS = ("up main", "down main")
YEARS = (2024, 2025, 2026)
WAVELENGTHS_MM = (30.0, 50.0, 80.0, 150.0, 400.0)


def spec(k: int, frames: int) -> dict:
    """Recording ``k``'s survey and rail."""
    length_m = frames * 0.017
    zone_from = (k * 0.37) % max(length_m - 1.0, 0.1)
    return {
        "line": LINES[k % len(LINES)],
        "track": TRACKS[(k // len(LINES)) % len(TRACKS)],
        "date": f"{YEARS[(k // 6) % len(YEARS)]}-{1 + k % 12:02d}-{1 + k % 28:02d}",
        "start_chainage": f"{k // 6}+{(k * 137) % 1000:03d}.000",
        "zone_m": (round(zone_from, 3), round(zone_from + 1.0, 3)),
        "wavelength_mm": WAVELENGTHS_MM[k % len(WAVELENGTHS_MM)],
        "amplitude_um": float((k * 7) % 41),
        "seed": 1000 + k,
    }


def write_one(cms_host: str, out: str, k: int, frames: int, points: int) -> str:
    s = spec(k, frames)
    name = os.path.join(out, f"run-{k:04d}.cmsrec")
    toml = os.path.join(out, f".run-{k:04d}.survey.toml")
    with open(toml, "w") as f:
        for key in ("line", "track", "date", "start_chainage"):
            f.write(f'{key} = "{s[key]}"\n')
        f.write('chainage = "up"\n')
    cmd = [
        cms_host, "bench", "recording", "--frames", str(frames), "--points", str(points),
        "--seed", str(s["seed"]), "--survey", toml, "--zone-m", f"{s['zone_m'][0]}:{s['zone_m'][1]}",
        "--wavelength-mm", str(s["wavelength_mm"]), "--amplitude-um", str(s["amplitude_um"]), "--out", name,
    ]
    r = subprocess.run(cmd, capture_output=True, text=True)
    os.unlink(toml)
    if r.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)}: {r.stderr.strip()}")
    return name


def write_site(
    out: str,
    cms_host: str,
    survey: dict,
    dates: list[str],
    amplitudes_um: list[float],
    frames: int,
    points: int,
    zone_m: tuple[float, float],
    wavelength_mm: float = 50.0,
    gnss: Optional[str] = None,
) -> list[str]:
    """One site surveyed on each of ``dates``: the same rail (``survey``'s
    line, track, start chainage), its zone corrugated at ``amplitudes_um``
    in turn, a new noise seed each survey (as docs/trend.md's surveys).
    With ``gnss`` (a track register) a simulated receiver's fixes ride
    along from the survey's start chainage. The recordings' paths, in date
    order."""
    os.makedirs(out, exist_ok=True)
    paths = []
    for i, (date, amp) in enumerate(zip(dates, amplitudes_um)):
        name = os.path.join(out, f"site-{i}.cmsrec")
        toml = os.path.join(out, f".site-{i}.survey.toml")
        with open(toml, "w") as f:
            for key, value in {**survey, "date": date}.items():
                f.write(f'{key} = "{value}"\n')
        cmd = [
            cms_host, "bench", "recording", "--frames", str(frames), "--points", str(points), "--seed", str(10 + i),
            "--survey", toml, "--zone-m", f"{zone_m[0]}:{zone_m[1]}", "--wavelength-mm", str(wavelength_mm),
            "--amplitude-um", str(amp), "--out", name,
        ]
        if gnss is not None:
            cmd += ["--gnss", gnss]
        r = subprocess.run(cmd, capture_output=True, text=True)
        os.unlink(toml)
        if r.returncode != 0:
            raise RuntimeError(f"{' '.join(cmd)}: {r.stderr.strip()}")
        paths.append(name)
    return paths


def write_fleet(out: str, count: int, frames: int, points: int, cms_host: str, jobs: int = 2) -> list[str]:
    """Writes the fleet into ``out``; the recordings' paths."""
    os.makedirs(out, exist_ok=True)
    with ThreadPoolExecutor(max_workers=jobs) as pool:
        return list(pool.map(lambda k: write_one(cms_host, out, k, frames, points), range(count)))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m cms.fleet.synth", description=__doc__.split("\n\n")[1])
    p.add_argument("out", metavar="OUT_DIR")
    p.add_argument("--count", type=int, default=100)
    p.add_argument("--frames", type=int, default=150, help="frames per recording, 17 mm apart (150: 2.5 m)")
    p.add_argument("--points", type=int, default=120, help="points per laser line and frame")
    p.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    a = p.parse_args(argv)
    try:
        paths = write_fleet(a.out, a.count, a.frames, a.points, os.environ.get("CMS_HOST", "cms-host"), a.jobs)
    except (RuntimeError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    print(f"{a.out}: {len(paths)} recordings")
    return 0


if __name__ == "__main__":
    sys.exit(main())
