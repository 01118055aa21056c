#!/usr/bin/env python3
"""OpenCV's camera calibration of checkerboard photographs: the oracle that
`cms-host calibrate camera` is checked against (the product does not depend on
OpenCV; this script is only run by hand).

    pip install opencv-python-headless
    python3 tests/scripts/opencv_calibrate.py --board 9x6 --fix-aspect \
        host/tests/data/opencv/left*.jpg [--corners corners.csv]

Does what OpenCV's calibration sample does: findChessboardCorners
(adaptive threshold + normalise + fast check), cornerSubPix with an 11 × 11
half-window, calibrateCamera with five distortion coefficients (k1 k2 p1 p2
k3) and, with --fix-aspect, CALIB_FIX_ASPECT_RATIO at fx/fy = 1 (the zero skew
is always fixed in OpenCV); with --max-view-rms, again without the views
whose RMS error exceeds that. Prints fx, fy, cx, cy, the distortion, the overall
and per-image RMS reprojection error (px). --corners writes every detected
corner as `image,index,u,v` (pixel centres at integer coordinates) so that a
detector's corners can be compared with OpenCV's.
"""

import argparse
import sys

import cv2
import numpy as np


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--board", default="9x6", help="inner corners COLSxROWS")
    ap.add_argument("--square-mm", type=float, default=25.0)
    ap.add_argument("--fix-aspect", action="store_true")
    ap.add_argument("--corners", help="write the detected corners to this CSV")
    ap.add_argument("--max-view-rms", type=float, help="calibrate again without the views above this RMS (px)")
    ap.add_argument("images", nargs="+")
    a = ap.parse_args()
    cols, rows = (int(s) for s in a.board.lower().split("x"))
    objp = np.zeros((rows * cols, 3), np.float32)
    objp[:, :2] = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2) * a.square_mm

    obj, img_pts, names, size = [], [], [], None
    csv = open(a.corners, "w") if a.corners else None
    for path in a.images:
        gray = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
        if gray is None:
            print(f"{path}: cannot read", file=sys.stderr)
            continue
        size = gray.shape[::-1]
        flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK
        ok, corners = cv2.findChessboardCorners(gray, (cols, rows), flags)
        if not ok:
            print(f"{path}: board not found", file=sys.stderr)
            continue
        crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 0.0001)
        corners = cv2.cornerSubPix(gray, corners, (11, 11), (-1, -1), crit)
        obj.append(objp)
        img_pts.append(corners)
        names.append(path)
        if csv:
            for k, (u, v) in enumerate(corners.reshape(-1, 2)):
                csv.write(f"{path},{k},{u:.6f},{v:.6f}\n")
    if len(obj) < 3:
        print("fewer than 3 usable images", file=sys.stderr)
        return 1

    flags = 0
    k0 = np.eye(3)
    if a.fix_aspect:
        flags |= cv2.CALIB_FIX_ASPECT_RATIO
    rms, k, dist, rvecs, tvecs = cv2.calibrateCamera(obj, img_pts, size, k0, None, flags=flags)
    if a.max_view_rms is not None:
        keep = []
        for n, (o, p, r, t) in enumerate(zip(obj, img_pts, rvecs, tvecs)):
            proj, _ = cv2.projectPoints(o, r, t, k, dist)
            e = np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - p.reshape(-1, 2)) ** 2, axis=1)))
            if e <= a.max_view_rms:
                keep.append(n)
            else:
                print(f"{names[n]}: dropped, RMS {e:.4f} px", file=sys.stderr)
        obj, img_pts, names = [obj[n] for n in keep], [img_pts[n] for n in keep], [names[n] for n in keep]
        rms, k, dist, rvecs, tvecs = cv2.calibrateCamera(obj, img_pts, size, k0, None, flags=flags)
    print(f"images {len(obj)} of {len(a.images)}, {size[0]} x {size[1]}")
    print(f"fx {k[0, 0]:.4f}  fy {k[1, 1]:.4f}  cx {k[0, 2]:.4f}  cy {k[1, 2]:.4f}")
    d = dist.ravel()
    print(f"k1 {d[0]:.6f}  k2 {d[1]:.6f}  p1 {d[2]:.6f}  p2 {d[3]:.6f}  k3 {d[4]:.6f}")
    print(f"rms {rms:.4f} px")
    for name, o, p, r, t in zip(names, obj, img_pts, rvecs, tvecs):
        proj, _ = cv2.projectPoints(o, r, t, k, dist)
        e = np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - p.reshape(-1, 2)) ** 2, axis=1)))
        print(f"  {name}: {e:.4f} px")
    return 0


if __name__ == "__main__":
    sys.exit(main())
