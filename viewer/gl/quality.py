"""The insertion renderer's cost knobs (:class:`Quality`) and its two settings: :data:`FULL` for
still frames and export, :data:`DRAGGING` while an object is dragged in the viewer."""

from __future__ import annotations

from dataclasses import dataclass, replace

from phyir.lighting.object_lighting import HALO


@dataclass(frozen=True)
class Quality:
    """Cost knobs: full quality for still frames and export, lower while dragging."""

    spec_samples: int = 128  # GGX samples per pixel for glossy objects (ibl.glsl)
    shadow_size: int = 512  # texels per shadow-map tile
    supersample: float = 1.5  # impostor texels per output pixel (per axis)
    march_steps: int = 32  # depth-panorama marching steps (mirror reflections, placing lights)
    shadow_taps: int = 16  # PCSS blocker-search and filter taps
    peak_subsamples: bool = True  # 2 x 2 samples per peak texel (else one at its centre)
    glossy_receivers: bool = True  # the object replaces what glossy receivers reflect
    halo: float = HALO  # receivers' ambient occlusion reaches this many bounding radii
    relight_tolerance: float = 0.0  # keep the lighting of a moved object while its probe changed less
    impostor_faces: int = 0  # draw the impostor from a decimated mesh of at most this many triangles (0: all)
    shadow_faces: int = 0  # the same for the shadow maps
    proxy_lookups: bool = True  # composite: the radiance an object hides per proxy sphere (else per object)
    blocker_search: bool = True  # composite: PCSS blocker search (else the blocker at the object's bounds)
    reuse_lights: bool = False  # a moved object keeps its lights' room positions (reuse_lights)
    own_shadow_bounds: bool = False  # object.frag: its own contact shadow from its bounding sphere
    light_grid: float = 0.0  # metres: light read on this grid, one ray per texel (0: exact, where it is)
    # the viewer's composite (objects and shadows) at this share of the view's resolution per axis,
    # over the layer at full resolution (composite_up.frag); exports always run at 1
    composite_scale: float = 1.0
    # a moved object's lighting on a worker thread, swapped in when ready (the viewer while dragging:
    # viewer.insertion_pass.InsertionPass; exports and direct calls compute it before drawing)
    background_lighting: bool = False
    relight_interval: float = 0.0  # s from one background job's end to the next one's start
    # a moved object's impostor drawn every this many prepares; in between its last one is turned to
    # where the object is (the viewer while dragging: InsertionPass.impostor_every)
    impostor_every: int = 1


FULL = Quality(supersample=1.5)
DRAGGING = Quality(spec_samples=4, shadow_size=256, supersample=1.0, march_steps=16, shadow_taps=8,
                   peak_subsamples=False, glossy_receivers=False, halo=3.0, relight_tolerance=0.03,
                   impostor_faces=2048, shadow_faces=1024, proxy_lookups=False, blocker_search=False,
                   reuse_lights=True, own_shadow_bounds=True, light_grid=0.05, composite_scale=0.25,
                   relight_interval=0.15)
# exports at draft quality (phyir insert --quality draft): the light where the object is, no grid steps
DRAFT_EXPORT = replace(DRAGGING, light_grid=0.0)
