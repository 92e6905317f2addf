"""The silo shapes the tests build again and again (not a test module).

Each returns a :class:`spotpde.grid.Grid`; lengths in d, the orifice at ``x = 0`` on the
floor ``z = 0`` unless ``bottom`` says otherwise.
"""

from __future__ import annotations

from spotpde.grid import Grid, Hopper


def box(half: float, top: float, h: float, *, dims: int = 2, walls: str = "reflecting",
        bottom: float = 0.0) -> Grid:
    """A rectangular silo ``[-half, half]`` wide (3D: the same in ``y``)."""
    return Grid(dims, (-half, half), (bottom, top), h, walls)


def cylinder(radius: float, top: float, h: float, walls: str = "reflecting", *,
             bottom: float = 0.0) -> Grid:
    """A cylindrical silo of ``radius`` on an axisymmetric ``(r, z)`` grid."""
    return Grid(2, (0.0, radius), (bottom, top), h, walls, coordinates="axisymmetric")


def hopper(angle: float, half: float, top: float, h: float, orifice_half_width: float, *,
           cone: bool = False, shift: float = 0.0, walls: str = "reflecting") -> Grid:
    """A wedge hopper in a box ``[-half, half]`` (moved by ``shift``), or with ``cone`` a
    conical hopper in a cylinder of radius ``half``; walls ``angle`` degrees from the
    vertical from the edges of an orifice ``2 orifice_half_width`` wide."""
    shape = Hopper(angle, 0.0, orifice_half_width)
    if cone:
        return Grid(2, (0.0, half), (0.0, top), h, walls, coordinates="axisymmetric",
                    hopper=shape)
    return Grid(2, (-half + shift, half + shift), (0.0, top), h, walls, hopper=shape)
