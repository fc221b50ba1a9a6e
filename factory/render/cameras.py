"""The views, defined once in LDraw terms, and the framing that maps LDraw points to pixels.

LDraw axes: +X right, +Y down, +Z away from the viewer of the standard front view (LDraw is
right-handed; parts face -Z, e.g. the slope of 3039 faces -Z and up). So **Front** is the standard
LDraw front view: the camera is on the -Z side looking along +Z, +X to the right, -Y (up) to the top.

| view      | camera on side | looks along | image right | image up | axes printed (h, v) |
|-----------|----------------|-------------|-------------|----------|---------------------|
| Top       | -Y (above)     | +Y          | +X          | +Z       | X, Z                |
| Front     | -Z             | +Z          | +X          | -Y       | X, Y                |
| Right     | +X             | -X          | +Z          | -Y       | Z, Y                |
| Bottom    | +Y (below)     | -Y          | +X          | -Z       | X, Z                |
| Back      | +Z             | -Z          | -X          | -Y       | X, Y                |
| Left      | -X             | +X          | -Z          | -Y       | Z, Y                |
| Isometric | +X -Y -Z       | (-1,1,1)/√3 | (1,0,1)/√2  | mostly -Y| -                   |

All views are orthographic. A `Framing` holds the centre (LDU) and the view height (LDU) shared by
the six axis views, so one pixel is the same number of LDU in each; the isometric view has its own
height. Pixel coordinates are continuous, origin at the image's top-left corner, x right, y down:
pixel (i, j) covers [i, i+1) x [j, j+1).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from factory.parts import box_corners
from factory.pose import LDU_M, points_to_mujoco

ORTHO_VIEWS = ("Top", "Front", "Right", "Bottom", "Back", "Left")
"""The six orthographic views, in the fixed order of every composite."""
ISOMETRIC = "Isometric"
ALL_VIEWS = (*ORTHO_VIEWS, ISOMETRIC)


@dataclass(frozen=True)
class View:
    name: str
    eye: tuple[float, float, float]
    """Unit vector (LDraw) from the framed centre towards the camera."""
    right: tuple[float, float, float]
    """Unit vector (LDraw) that points to the image's right."""
    up: tuple[float, float, float]
    """Unit vector (LDraw) that points to the image's top."""

    def __post_init__(self):
        r, u, e = (np.asarray(v, float) for v in (self.right, self.up, self.eye))
        m = np.stack([r, u, e], 1)
        if not (np.allclose(m.T @ m, np.eye(3), atol=1e-9) and np.linalg.det(m) > 0):
            raise ValueError(f"view {self.name}: right, up, eye must be a right-handed orthonormal frame")

    def axes(self) -> tuple[tuple[int, int], tuple[int, int]] | None:
        """For an axis view: ((LDraw axis, sign) along image right, (axis, sign) along image up)."""
        out = []
        for v in (self.right, self.up):
            a = np.asarray(v)
            i = int(np.argmax(np.abs(a)))
            if not np.isclose(abs(a[i]), 1.0):
                return None
            out.append((i, int(np.sign(a[i]))))
        return out[0], out[1]


_S3, _S2 = 1 / np.sqrt(3), 1 / np.sqrt(2)
_ISO_EYE = (_S3, -_S3, -_S3)
_ISO_RIGHT = (_S2, 0.0, _S2)
_ISO_UP = tuple(np.cross(_ISO_EYE, _ISO_RIGHT).tolist())

VIEWS: dict[str, View] = {
    "Top": View("Top", eye=(0, -1, 0), right=(1, 0, 0), up=(0, 0, 1)),
    "Front": View("Front", eye=(0, 0, -1), right=(1, 0, 0), up=(0, -1, 0)),
    "Right": View("Right", eye=(1, 0, 0), right=(0, 0, 1), up=(0, -1, 0)),
    "Bottom": View("Bottom", eye=(0, 1, 0), right=(1, 0, 0), up=(0, 0, -1)),
    "Back": View("Back", eye=(0, 0, 1), right=(-1, 0, 0), up=(0, -1, 0)),
    "Left": View("Left", eye=(-1, 0, 0), right=(0, 0, -1), up=(0, -1, 0)),
    ISOMETRIC: View(ISOMETRIC, eye=_ISO_EYE, right=_ISO_RIGHT, up=_ISO_UP),  # type: ignore[arg-type]
}

AXIS_NAMES = "XYZ"
MIN_HEIGHT_LDU = 24.0
"""Smallest view height, so a lone plate is not blown up to fill the image."""


def _as_view(view: str | View) -> View:
    if isinstance(view, View):
        return view
    try:
        return VIEWS[view]
    except KeyError:
        raise ValueError(f"unknown view {view!r}; expected one of {', '.join(VIEWS)}") from None


@dataclass(frozen=True)
class Framing:
    """Where the views look and how much they show: one for a whole step sequence or scene."""

    center: tuple[float, float, float]
    """LDU, LDraw axes."""
    height: float
    """View height in LDU of the six axis views (their width too: images are square)."""
    iso_height: float
    """View height in LDU of the isometric view."""

    @classmethod
    def from_bounds(cls, bounds, margin: float = 0.08, min_height: float = MIN_HEIGHT_LDU) -> Framing:
        """Frame an axis-aligned box [[min xyz], [max xyz]] (LDU) with `margin` of the size each side."""
        b = np.asarray(bounds, float).reshape(2, 3)
        center = (b[0] + b[1]) / 2
        ext = b[1] - b[0]
        height = max(float(ext.max()) * (1 + 2 * margin), min_height)
        corners = box_corners(b) - center
        iso = VIEWS[ISOMETRIC]
        proj = np.stack([corners @ np.asarray(iso.right), corners @ np.asarray(iso.up)], 1)
        iso_height = max(float(np.abs(proj).max()) * 2 * (1 + 2 * margin), min_height)
        return cls(tuple(center.tolist()), height, iso_height)  # type: ignore[arg-type]

    def height_of(self, view: str | View) -> float:
        return self.iso_height if _as_view(view).name == ISOMETRIC else self.height

    def project(self, view: str | View, points, size: int) -> np.ndarray:
        """Points (..., 3) in LDU to continuous pixel coordinates (..., 2) in a size x size image."""
        v = _as_view(view)
        rel = np.asarray(points, float) - np.asarray(self.center)
        scale = size / self.height_of(v)
        x = rel @ np.asarray(v.right) * scale + size / 2
        y = size / 2 - rel @ np.asarray(v.up) * scale
        return np.stack([x, y], -1)

    def coordinate_at(self, view: str | View, pixel: float, axis: str, size: int) -> float:
        """The LDraw coordinate shown at a pixel position along the image's 'h' or 'v' axis."""
        v = _as_view(view)
        ax = v.axes()
        if ax is None:
            raise ValueError(f"view {v.name} is not an axis view")
        (hi, hs), (vi, vs) = ax
        scale = size / self.height
        c = np.asarray(self.center)
        if axis == "h":
            return float(c[hi] + hs * (pixel - size / 2) / scale)
        return float(c[vi] + vs * (size / 2 - pixel) / scale)

    def ticks(self, view: str | View, size: int, target: int = 5) -> dict[str, list[tuple[float, float]]]:
        """Tick marks of an axis view: {'h': [(value LDU, x pixel)], 'v': [(value LDU, y pixel)]}.

        'h' ticks label the LDraw axis along the image's width, 'v' the one along its height; values
        are the LDraw coordinates (signed, in LDU) and the pixels come from `project`.
        """
        v = _as_view(view)
        ax = v.axes()
        if ax is None:
            raise ValueError(f"view {v.name} is not an axis view")
        step = nice_step(self.height / target)
        out: dict[str, list[tuple[float, float]]] = {}
        c = np.asarray(self.center)
        for key, (i, _sign) in zip(("h", "v"), ax):
            lo, hi = c[i] - self.height / 2, c[i] + self.height / 2
            values = np.arange(np.ceil(lo / step) * step, hi + 1e-9, step)
            ticks = []
            for val in values:
                p = c.copy()
                p[i] = val
                px = self.project(v, p, size)
                pos = float(px[0] if key == "h" else px[1])
                if 0 <= pos <= size:
                    ticks.append((float(val) + 0.0, pos))
            out[key] = ticks
        return out

    def camera(self, view: str | View, distance_ldu: float) -> tuple[np.ndarray, np.ndarray, float]:
        """MuJoCo camera (position m, 3x3 rotation whose columns are the camera's x, y, z, fovy m)."""
        v = _as_view(view)
        pos = points_to_mujoco(np.asarray(self.center) + np.asarray(v.eye) * distance_ldu)
        cols = [points_to_mujoco(np.asarray(a, float)) / LDU_M for a in (v.right, v.up, v.eye)]
        return pos, np.stack(cols, 1), self.height_of(v) * LDU_M


def nice_step(raw: float) -> float:
    """A tick step near `raw` LDU from 1, 2, 4, 5 x 10^k (so steps of 20 and 40 LDU, stud pitches)."""
    raw = max(raw, 1e-6)
    k = 10 ** np.floor(np.log10(raw))
    for m in (1, 2, 4, 5, 10):
        if m * k >= raw * 0.75:
            return float(m * k)
    return float(10 * k)


def project(view: str | View, point_ldu, framing: Framing, size: int = 256) -> tuple[float, float]:
    """Pixel (x, y) of an LDraw point (LDU) in a view rendered with `framing` at size x size."""
    px = framing.project(view, np.asarray(point_ldu, float).reshape(3), size)
    return float(px[0]), float(px[1])
