#!/usr/bin/env python3
"""Writes examples/track-register-40km.csv: a synthetic track register of
40 km (chainage 10+000 to 50+000) of straights and circular curves, the
centreline of the scale tests and benchmarks of GNSS (`cms-host bench
recording --gnss`, docs/benchmarks.md).

    python3 scripts/make_register.py > examples/track-register-40km.csv

The centreline is integrated in 1 m steps on the WGS 84 ellipsoid (the
meridian and prime-vertical radii at each step's latitude), a straight
keeping its bearing, a curve turning by 1/R per metre; a vertex every
100 m on straights and every 20 m on curves (a 20 m chord of an 800 m
curve is 0.5 mm shorter than its arc), its chainage the length along the
centreline. Deterministic: the same text on every run.
"""

import math

A = 6_378_137.0
F = 1.0 / 298.257_223_563
E2 = F * (2.0 - F)

START = (52.200000, 5.400000)  # lat, lon of 10+000, degrees
BEARING = 60.0                  # degrees from north at 10+000
CHAINAGE0 = 10_000.0
# (length m, radius m: 0 straight, > 0 right, < 0 left)
LAYOUT = [
    (2000, 0), (1200, 1500), (3000, 0), (900, -800), (2500, 0), (1500, 2000),
    (4000, 0), (1000, -1200), (3500, 0), (2000, 3000), (5000, 0), (800, -1000),
    (1600, 2500), (3000, 0), (1000, -900), (7000, 0),
]


def main():
    assert sum(l for l, _ in LAYOUT) == 40_000
    lat, lon = map(math.radians, START)
    b = math.radians(BEARING)
    c = CHAINAGE0
    print("# A synthetic track register: 40 km of straights and circular curves (R 800 to 3000 m),")
    print("# chainage 10+000 to 50+000. Written by scripts/make_register.py; the centreline of")
    print("# `cms-host bench recording --gnss` at scale (docs/benchmarks.md, docs/gnss.md).")
    print("lat_deg,lon_deg,chainage_m")

    def vertex():
        print(f"{math.degrees(lat):.9f},{math.degrees(lon):.9f},{c:.3f}")

    vertex()
    for length, radius in LAYOUT:
        every = 100 if radius == 0 else 20
        for step in range(1, length + 1):
            # One metre on the bearing at the middle of the step.
            bm = b + (0.5 / radius if radius else 0.0)
            w = math.sqrt(1.0 - E2 * math.sin(lat) ** 2)
            m = A * (1.0 - E2) / w**3
            n = A / w
            lat += math.cos(bm) / m
            lon += math.sin(bm) / (n * math.cos(lat))
            if radius:
                b += 1.0 / radius
            c += 1.0
            if step % every == 0:
                vertex()


main()
