"""Colour table of the embedded library: official LDraw codes, names and values, written out as
`LDConfig.ldr` `!COLOUR` lines."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class ColourSpec:
    code: int
    name: str
    value: str
    edge: str
    alpha: int | None = None


TRANSPARENT = 128

COLOURS: tuple[ColourSpec, ...] = (
    ColourSpec(0, "Black", "#1B2A34", "#808080"),
    ColourSpec(1, "Blue", "#1E5AA8", "#333333"),
    ColourSpec(2, "Green", "#00852B", "#333333"),
    ColourSpec(4, "Red", "#B40000", "#333333"),
    ColourSpec(5, "Dark_Pink", "#D3359D", "#333333"),
    ColourSpec(6, "Brown", "#543324", "#1E1E1E"),
    ColourSpec(7, "Light_Grey", "#8A928D", "#333333"),
    ColourSpec(8, "Dark_Grey", "#545955", "#333333"),
    ColourSpec(10, "Bright_Green", "#58AB41", "#333333"),
    ColourSpec(14, "Yellow", "#FAC80A", "#333333"),
    ColourSpec(15, "White", "#F4F4F4", "#333333"),
    ColourSpec(19, "Tan", "#D7BA8C", "#333333"),
    ColourSpec(22, "Purple", "#671F81", "#333333"),
    ColourSpec(25, "Orange", "#D67923", "#333333"),
    ColourSpec(26, "Magenta", "#901F76", "#333333"),
    ColourSpec(27, "Lime", "#A5CA18", "#333333"),
    ColourSpec(28, "Dark_Tan", "#897D62", "#333333"),
    ColourSpec(70, "Reddish_Brown", "#5F3109", "#808080"),
    ColourSpec(71, "Light_Bluish_Grey", "#969696", "#333333"),
    ColourSpec(72, "Dark_Bluish_Grey", "#646464", "#333333"),
    ColourSpec(73, "Medium_Blue", "#7396C8", "#333333"),
    ColourSpec(85, "Medium_Lilac", "#441A91", "#333333"),
    ColourSpec(191, "Bright_Light_Orange", "#FCAC00", "#333333"),
    ColourSpec(272, "Dark_Blue", "#19325A", "#333333"),
    ColourSpec(288, "Dark_Green", "#00451A", "#808080"),
    ColourSpec(308, "Dark_Brown", "#352100", "#808080"),
    ColourSpec(320, "Dark_Red", "#720012", "#333333"),
    ColourSpec(378, "Sand_Green", "#708E7C", "#333333"),
    ColourSpec(379, "Sand_Blue", "#70819A", "#333333"),
    ColourSpec(484, "Dark_Orange", "#91501C", "#333333"),
    ColourSpec(33, "Trans_Dark_Blue", "#0020A0", "#000B38", TRANSPARENT),
    ColourSpec(34, "Trans_Green", "#237841", "#174F2B", TRANSPARENT),
    ColourSpec(36, "Trans_Red", "#C91A09", "#660D05", TRANSPARENT),
    ColourSpec(40, "Trans_Brown", "#635F52", "#2A2823", TRANSPARENT),
    ColourSpec(41, "Trans_Medium_Blue", "#559AB7", "#326276", TRANSPARENT),
    ColourSpec(43, "Trans_Light_Blue", "#AEE9EF", "#59D1DE", TRANSPARENT),
    ColourSpec(46, "Trans_Yellow", "#F5CD2F", "#B49208", TRANSPARENT),
    ColourSpec(47, "Trans_Clear", "#FCFCFC", "#C9C9C9", TRANSPARENT),
    ColourSpec(16, "Main_Colour", "#FFFF80", "#333333"),
    ColourSpec(24, "Edge_Colour", "#7F7F7F", "#333333"),
)


def colour_line(c: ColourSpec) -> str:
    line = f"0 !COLOUR {c.name} CODE {c.code} VALUE {c.value} EDGE {c.edge}"
    return line if c.alpha is None else f"{line} ALPHA {c.alpha}"


def ldconfig(header: list[str]) -> str:
    """`LDConfig.ldr`: the given header lines, then one `!COLOUR` line per colour."""
    return "\n".join(header + [""] + [colour_line(c) for c in COLOURS]) + "\n"
