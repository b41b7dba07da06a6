#!/usr/bin/env python3
"""How fish meet the walls: live guppy pairs (legacy files) next to simulated trial files.

A cross-check outside fishprobe (h5py and numpy; fishprobe itself never needs Python) of how
M_ConvNet meets the walls; docs/validation.md, "M_ConvNet and the virtual guppy against
held-back real pairs", shows its output. For each source it prints
  - the heading's change over 1, 5, 25 and 75 frames (median |Δθ| in rad): tracking jitter
    shows as a large 1-frame change that does not add up over 5 frames;
  - where the fish is: the share of frames 0-1.5, 1.5-3 and 3-6 cm from the nearest wall, the
    share there with the nose in (heading more than 45° into that wall) and their speed;
  - the share of frames within 1 cm of a wall, and (near walls, < 4 cm, moving > 2 cm/s) how
    far the heading and the motion point into the wall (sine of the angle; 0: along it).

  python3 scripts/wall_check.py --real ../shared/data/guppy-pairs/legacy/train --sim a.hdf5 b.hdf5
"""
import argparse
import glob
import os

import h5py
import numpy as np

LAGS = (1, 5, 25, 75)


def wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


def legacy_tracks(directory):
    """(x, y, heading) per fish of every legacy pair file, in robofish.io coordinates."""
    for f in sorted(glob.glob(os.path.join(directory, "*.hdf5"))):
        with h5py.File(f, "r") as h:
            for k in ("1", "2"):
                if k in h:
                    a = h[k][:].astype(np.float64)
                    yield a[:, 0] - 50, 50 - a[:, 1], np.arctan2(-a[:, 3], a[:, 2])


def sim_tracks(files):
    """(x, y, heading) per fish entity of robofish.io trial files."""
    for f in files:
        with h5py.File(f, "r") as h:
            for name, e in h["entities"].items():
                if e.attrs.get("category") in ("fish", "organism"):
                    p = e["positions"][:].astype(np.float64)
                    o = e["orientations"][:].astype(np.float64)
                    yield p[:, 0], p[:, 1], np.arctan2(o[:, 1], o[:, 0])


def summarise(label, tracks):
    lag = {k: [] for k in LAGS}
    wall, nose, speed, head_in, move_in = [], [], [], [], []
    for x, y, th in tracks:
        for k in LAGS:
            d = np.abs(wrap(th[k:] - th[:-k]))
            lag[k].append(d[np.isfinite(d)])
        d = np.stack([50 - x, 50 + x, 50 - y, 50 + y], 1)
        i = np.argmin(np.nan_to_num(d, nan=1e9), 1)
        wd = d[np.arange(len(d)), i]
        nx, ny = np.array([-1, 1, 0, 0])[i], np.array([0, 0, -1, 1])[i]
        into = -(np.cos(th) * nx + np.sin(th) * ny)
        v = np.r_[np.hypot(np.diff(x), np.diff(y)) * 25, np.nan]
        m = np.r_[np.arctan2(np.diff(y), np.diff(x)), np.nan]
        m_into = -(np.cos(m) * nx + np.sin(m) * ny)
        ok = np.isfinite(wd) & np.isfinite(into)
        wall.append(wd[ok])
        nose.append(np.degrees(np.arcsin(np.clip(into[ok], -1, 1))))
        speed.append(v[ok])
        near = ok & (wd < 4) & (v > 2) & np.isfinite(m_into)
        head_in.append(into[near])
        move_in.append(m_into[near])
    wd, ang, v = (np.concatenate(a) for a in (wall, nose, speed))
    print(f"== {label}: {len(wd)} fish-frames")
    print("  heading change, median |Δθ| (rad): " + ", ".join(
        f"{k} frames {np.median(np.concatenate(lag[k])):.3f}" for k in LAGS))
    for lo, hi in ((0, 1.5), (1.5, 3), (3, 6)):
        band = (wd >= lo) & (wd < hi)
        n_in = band & (ang > 45)
        sp = np.nanmedian(v[n_in]) if n_in.any() else float("nan")
        print(f"  {lo:.1f}-{hi:.1f} cm from a wall: {100 * band.mean():5.2f} % of frames; "
              f"nose in: {100 * n_in.mean():.2f} % at median {sp:.1f} cm/s")
    print(f"  within 1 cm of a wall: {100 * (wd <= 1.0001).mean():.2f} % of frames; near walls, "
          f"heading into the wall {np.mean(np.concatenate(head_in)):.3f}, "
          f"motion into the wall {np.mean(np.concatenate(move_in)):.3f}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--real", help="directory of legacy pair files")
    ap.add_argument("--sim", nargs="*", default=[], help="robofish.io trial files")
    a = ap.parse_args()
    if a.real:
        summarise(f"live guppies ({a.real})", legacy_tracks(a.real))
    if a.sim:
        summarise(f"simulated ({len(a.sim)} files)", sim_tracks(a.sim))


if __name__ == "__main__":
    main()
