"""The parts of the embedded default library: real LDraw part numbers with their real sizes.

Sizes are in studs. `nx` runs along x and `nz` along z, following the real library's orientation:
rectangular parts are long in x; slopes are `nx` studs wide in x and 2 studs deep in z, sloping
down toward -z; the cheese slopes fall toward -z too, the headlight brick's side stud and a
bracket's side plate face -z; the corner plate's missing cell is at +x, +z; the technic brick's
pin hole runs along z.
"""

from __future__ import annotations

from dataclasses import dataclass

BRICK = "brick"
PLATE = "plate"
TILE = "tile"
SLOPE = "slope"
INVERTED_SLOPE = "inverted_slope"
ROUND_PLATE = "round_plate"
ROUND_BRICK = "round_brick"
GRILLE = "grille"
"""A tile with slots through its top (no studs)."""
JUMPER = "jumper"
"""A 1 x 2 plate with one stud in the middle."""
CHEESE = "cheese"
"""A 30 degree slope 1 x `nx` x 2/3, no stud."""
HEADLIGHT = "headlight"
"""A 1 x 1 brick with a stud on its front face too."""
BRACKET = "bracket"
"""A plate with a second plate hanging down from its front edge, studs facing -z."""
ARCH = "arch"
WEDGE = "wedge"
"""A plate with a corner cut off at 45 degrees."""
CORNER_PLATE = "corner_plate"
"""A plate 2 x 2 with one 1 x 1 corner cell missing: an L of three studs."""
CONE = "cone"
"""A 1 x 1 cone with a hollow stud on top."""
TECHNIC_BRICK = "technic_brick"
"""A brick with a pin hole through it along z."""


@dataclass(frozen=True)
class PartSpec:
    number: str
    description: str
    kind: str
    nx: int
    nz: int
    bars: bool = True
    """Whether a 1 x N part has bars under it (the real 1 x 2 tile has none)."""
    rows: int = 0
    """Brackets: rows of studs on the plate that hangs down (1 for 1 x 2 - 1 x 2, 2 for 2 x 2)."""

    @property
    def filename(self) -> str:
        return f"{self.number}.dat"


def _rect(kind: str, name: str, rows: list[tuple[str, int, int]]) -> list[PartSpec]:
    return [PartSpec(n, f"{name} {a} x {b}", kind, b, a) for n, a, b in rows]


PARTS: tuple[PartSpec, ...] = (
    *_rect(BRICK, "Brick", [
        ("3005", 1, 1), ("3004", 1, 2), ("3622", 1, 3), ("3010", 1, 4), ("3009", 1, 6),
        ("3008", 1, 8), ("3003", 2, 2), ("3002", 2, 3), ("3001", 2, 4), ("2456", 2, 6),
        ("3007", 2, 8), ("3006", 2, 10),
    ]),
    *_rect(PLATE, "Plate", [
        ("3024", 1, 1), ("3023", 1, 2), ("3623", 1, 3), ("3710", 1, 4), ("3666", 1, 6),
        ("3460", 1, 8), ("4477", 1, 10), ("3022", 2, 2), ("3021", 2, 3), ("3020", 2, 4),
        ("3795", 2, 6), ("3034", 2, 8), ("3832", 2, 10), ("3031", 4, 4), ("3032", 4, 6),
        ("3958", 6, 6), ("3035", 4, 8), ("3036", 6, 8), ("3030", 4, 10),
    ]),
    *_rect(TILE, "Tile", [
        ("3070b", 1, 1), ("63864", 1, 3), ("2431", 1, 4), ("6636", 1, 6), ("4162", 1, 8), ("3068b", 2, 2),
    ]),
    PartSpec("3069b", "Tile 1 x 2", TILE, 2, 1, bars=False),
    PartSpec("3040b", "Slope Brick 45 2 x 1", SLOPE, 1, 2),
    PartSpec("3039", "Slope Brick 45 2 x 2", SLOPE, 2, 2),
    PartSpec("3038", "Slope Brick 45 2 x 3", SLOPE, 3, 2),
    PartSpec("3037", "Slope Brick 45 2 x 4", SLOPE, 4, 2),
    PartSpec("3665", "Slope Brick 45 2 x 1 Inverted", INVERTED_SLOPE, 1, 2),
    PartSpec("3660", "Slope Brick 45 2 x 2 Inverted", INVERTED_SLOPE, 2, 2),
    PartSpec("6141", "Plate 1 x 1 Round", ROUND_PLATE, 1, 1),  # (4073 is the same part's older number)
    PartSpec("3062b", "Brick 1 x 1 Round with Hollow Stud", ROUND_BRICK, 1, 1),
    PartSpec("2412b", "Tile 1 x 2 Grille", GRILLE, 2, 1),
    PartSpec("3794b", "Plate 1 x 2 with 1 Centre Stud", JUMPER, 2, 1),
    PartSpec("54200", "Slope 30 1 x 1 x 2/3", CHEESE, 1, 1),
    PartSpec("4070", "Brick 1 x 1 with Headlight", HEADLIGHT, 1, 1),
    PartSpec("99781", "Bracket 1 x 2 - 1 x 2 Down", BRACKET, 2, 1, rows=1),
    PartSpec("44728", "Bracket 1 x 2 - 2 x 2 Down", BRACKET, 2, 1, rows=2),
    PartSpec("3659", "Arch 1 x 4", ARCH, 4, 1),
    PartSpec("2450", "Plate 3 x 3 without Corner", WEDGE, 3, 3),
    PartSpec("2420", "Plate 2 x 2 Corner", CORNER_PLATE, 2, 2),
    PartSpec("85984", "Slope 31 1 x 2 x 2/3", CHEESE, 2, 1),
    PartSpec("4589", "Cone 1 x 1", CONE, 1, 1),
    PartSpec("3941", "Brick 2 x 2 Round", ROUND_BRICK, 2, 2),
    PartSpec("3700", "Technic Brick 1 x 2 with Hole", TECHNIC_BRICK, 2, 1),
)

BY_NUMBER: dict[str, PartSpec] = {p.number: p for p in PARTS}
