"""Geometry of the DEM silo: rough walls of frozen grains, the initial lattice, the box.

Axes (lengths in d): 2D: x horizontal, y vertical (up); 3D slab: x horizontal across
the width, y across the depth (between the flat front and back plates), z vertical.
The floor's top surface is the plane ``vertical = 0`` and the orifice (a slot spanning
the whole depth in 3D) is ``|x| < orifice / 2`` on it. Side walls and floor are made of
frozen grains of diameter 1 whose surfaces touch the planes ``|x| = width / 2`` and
``vertical = 0``; they are rough, like the glued-bead walls of experiments.
"""

from __future__ import annotations

import math

import numpy as np

#: grains whose vertical coordinate falls below this (in d) have left through the orifice
EXIT_LEVEL = -2.0
#: height of the band above the fill height in which leaving grains are reinserted
INSERT_GAP, INSERT_BAND = 3.0, 3.0


def vertical(p: dict) -> int:
    """Index of the vertical coordinate: 1 (y) in 2D, 2 (z) in the 3D slab."""
    return 1 if p["silo"]["dims"] == 2 else 2


def insert_band(p: dict) -> tuple[float, float]:
    """Vertical range in which reinserted grains are placed (above the free surface)."""
    low = p["silo"]["fill_height"] + INSERT_GAP
    return low, low + INSERT_BAND


def _depth_positions(p: dict) -> np.ndarray:
    """Centres across the depth (3D) of one row of wall grains of diameter 1."""
    depth = p["silo"]["depth"]
    n = max(1, math.ceil(depth - 1e-9))
    return np.linspace(-depth / 2 + 0.5, depth / 2 - 0.5, n) if n > 1 else np.zeros(1)


def wall_grains(p: dict, top: float) -> np.ndarray:
    """Centres (n, 3) of the frozen grains of diameter 1 forming floor and side walls."""
    s = p["silo"]
    half, slot = s["width"] / 2, s["orifice"] / 2
    nfloor = math.ceil(half - slot - 1e-9)
    floor_x = np.linspace(slot + 0.5, half - 0.5, nfloor) if nfloor > 1 else np.array(
        [slot + 0.5])
    floor_x = np.concatenate([-floor_x[::-1], floor_x])
    side_v = np.arange(-0.5, top + 0.5, 1.0)
    side_x = np.array([-half - 0.5, half + 0.5])
    if s["dims"] == 2:
        floor = np.column_stack([floor_x, np.full_like(floor_x, -0.5), 0 * floor_x])
        sx, sv = np.meshgrid(side_x, side_v)
        side = np.column_stack([sx.ravel(), sv.ravel(), 0 * sv.ravel()])
    else:
        ys = _depth_positions(p)
        fx, fy = np.meshgrid(floor_x, ys)
        floor = np.column_stack([fx.ravel(), fy.ravel(), np.full(fx.size, -0.5)])
        sx, sy, sv = np.meshgrid(side_x, ys, side_v)
        side = np.column_stack([sx.ravel(), sy.ravel(), sv.ravel()])
    return np.vstack([floor, side])


def initial_grains(p: dict, n: int, rng: np.random.Generator):
    """Centres (n, 3) on a loose lattice above the floor and diameters (n,) of the grains.

    Diameters are uniform in ``[1 - p, 1 + p]`` (``grains.polydispersity``); the lattice
    spacing leaves room for the largest, and each centre is jittered by a few per cent
    of d so the packing the grains settle into is random.
    """
    s, poly = p["silo"], p["grains"]["polydispersity"]
    a = 1.0 + poly + 0.05
    half = s["width"] / 2
    xs = np.arange(-half + a / 2, half - a / 2 + 1e-9, a)
    if s["dims"] == 2:
        layer = np.column_stack([xs, np.zeros_like(xs)])
    else:
        ys = np.arange(-s["depth"] / 2 + a / 2, s["depth"] / 2 - a / 2 + 1e-9, a)
        if ys.size == 0:
            raise ValueError(f"silo.depth: too thin for grains of diameter up to {1 + poly}")
        lx, ly = np.meshgrid(xs, ys)
        layer = np.column_stack([lx.ravel(), ly.ravel()])
    rows = math.ceil(n / len(layer))
    heights = a / 2 + a * np.arange(rows)
    pos = np.array([[*c, h] for h in heights for c in layer])[:n]
    pos[:, 0] += rng.uniform(-0.02, 0.02, n)
    if s["dims"] == 2:
        pos = np.column_stack([pos[:, 0], pos[:, 2], np.zeros(n)])
    diam = rng.uniform(1.0 - poly, 1.0 + poly, n)
    return pos, diam


def box(p: dict, top: float) -> tuple[list[float], list[float]]:
    """Lower and upper corners of the simulation box."""
    s = p["silo"]
    half = s["width"] / 2 + 1.5
    low_v, high_v = EXIT_LEVEL - 6.0, top + 2.0
    if s["dims"] == 2:
        return [-half, low_v, -0.5], [half, high_v, 0.5]
    depth = s["depth"] / 2 + 0.5
    return [-half, -depth, low_v], [half, depth, high_v]


def grain_mass(diameter: np.ndarray, dims: int) -> np.ndarray:
    """Mass in m (the mass of a grain of diameter d): D^2 for disks, D^3 for spheres."""
    return np.asarray(diameter, dtype=float) ** dims


def place(p: dict, rng: np.random.Generator, diameters, others, radii):
    """Non-overlapping centres in the insert band for new grains of ``diameters``.

    ``others`` (m, 3) and ``radii`` (m,) are the grains already near the band. Returns
    the centres of the grains placed (possibly fewer than asked: the rest wait).
    """
    s, iv = p["silo"], vertical(p)
    low, high = insert_band(p)
    occ_c = np.asarray(others, dtype=float).reshape(-1, 3)
    occ_r = np.asarray(radii, dtype=float).reshape(-1)
    placed = []
    for diam in diameters:
        r = diam / 2
        for _ in range(200):
            c = np.zeros(3)
            c[0] = rng.uniform(-s["width"] / 2 + r, s["width"] / 2 - r)
            c[iv] = rng.uniform(low + r, high - r)
            if s["dims"] == 3:
                c[1] = rng.uniform(-s["depth"] / 2 + r, s["depth"] / 2 - r)
            if np.all(np.sum((occ_c - c) ** 2, axis=1) > (occ_r + r) ** 2):
                occ_c = np.vstack([occ_c, c])
                occ_r = np.append(occ_r, r)
                placed.append(c)
                break
        else:
            break
    return np.array(placed).reshape(-1, 3)
