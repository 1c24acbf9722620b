"""The layout of a PhyIR scene file (docs/file-formats.md): each layer's channel names, the mask and
metadata prefixes, and the probes part's atlas attributes."""

from __future__ import annotations

from phyir.errors import InputError

META_PREFIX = "phyir."

# channel names of each layer in the scene part (docs/file-formats.md)
LAYER_CHANNELS: dict[str, tuple[str, ...]] = {
    "image": ("R", "G", "B"),
    "depth": ("depth.Z",),
    "normal": ("normal.X", "normal.Y", "normal.Z"),
    "albedo": ("albedo.R", "albedo.G", "albedo.B"),
    "roughness": ("roughness.Y",),
    "metallic": ("metallic.Y",),
}
MASK_PREFIX = "mask."


def probe_layout(p: str, attrs: dict[str, str], H: int, W: int) -> tuple[int, int, int, int]:
    """(Hp, Wp, h, w) from the probes part's attributes, checked against its H x W atlas."""
    grid, size = attrs.get("probeGrid"), attrs.get("probeSize")
    try:
        Hp, Wp = (int(v) for v in grid.split("x"))  # type: ignore[union-attr]
        ph, pw = (int(v) for v in size.split("x"))  # type: ignore[union-attr]
    except (AttributeError, ValueError):
        raise InputError(p, f"probes part: probeGrid {grid!r} / probeSize {size!r} are not "
                            "strings of the form 'AxB'") from None
    if min(Hp, Wp, ph, pw) < 1 or (Hp * ph, Wp * pw) != (H, W):
        raise InputError(p, f"probes part: probeGrid {grid} x probeSize {size} does not match the "
                            f"atlas size {H}x{W}")
    return Hp, Wp, ph, pw
