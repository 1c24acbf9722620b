"""Lighting at a point of a real panorama, without ground truth (issue 20's protocol).

A small sphere (:data:`SPHERE_RADIUS`) at :data:`SPHERE_CENTRE`, 0.8 m in front of the camera (the
camera looks along -z, docs/conventions.md), is shaded with the RELIGHT_MATERIALS presets of
:mod:`phyir.evaluation.metrics` (diffuse, matte silver, mirror silver) and seen from the camera:

* **truth**: the HDR panorama itself used as distant incident light.  The panorama *is* the light
  arriving at the camera; using it 0.8 m away ignores that parallax, which is the approximation.
* **ours**: the same sphere lit by the probe a :data:`LIGHT_METHODS` entry gives at the point
  (``probe_field``: the predicted scene's probe grid interpolated in 3D by
  :class:`phyir.lighting.object_lighting.ProbeField`; ``projection``: the panorama re-read from the
  point along the predicted depth, :func:`phyir.lighting.projection.project_probes`, LNet's probe
  where the camera did not see; ``light_at``: :func:`phyir.lighting.at_point.light_at`, the same
  projection with lamps splatted and the probe field as fallback; ``light_at_camera``: the same read
  at the camera instead of the point — no parallax, so what is left is what the input lost: an LDR
  copy's clipped light and how much of it :mod:`phyir.lighting.hdr_recovery` gave back, held against
  the exact light there).  A new method is one more entry
  ``name: callable(scene, points, probe_size) -> probes [N,3,h,w]``.
* **naive**: the auto-exposed 8-bit LDR copy of the panorama used as the environment, what an artist
  without PhyIR would light the object with.

Every sphere is shaded by :func:`integrate`, a brute-force quadrature written independently of
:mod:`phyir.shading.render` (the renderer under test): each texel of the environment, area-resized
to :data:`INTEGRATION_SIZE` (:data:`ROUGH_INTEGRATION_SIZE` for the wide lobes), is a direction
with its solid angle, and each sphere pixel sums f(n,v,l) L(l) max(n.l, 0) dω over all texels in
float64, with the one BRDF of :mod:`phyir.shading.brdf`.  Only the mirror's specular lobe
(GGX α = 10⁻³, far narrower than a texel) takes its exact limit instead: F(n.v) G1(n.v)² L(reflected
direction).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
from torch import Tensor

from phyir import pano
from phyir.color import luminance
from phyir.evaluation.metrics import RELIGHT_MATERIALS, sphere_gbuffer
from phyir.scene import PanoScene
from phyir.shading import brdf as B

SPHERE_CENTRE = (0.0, -0.2, -0.8)  # metres; the camera looks along -z
SPHERE_RADIUS = 0.15  # metres: small against the room, so one probe at its centre lights it
SPHERE_PIXELS = 32  # sphere image size (orthographic: the sphere spans ~11 degrees)
INTEGRATION_SIZE = (64, 128)  # texels of the brute-force sum: 2.8 deg, ~1/5 of matte silver's lobe
ROUGH_INTEGRATION_SIZE = (32, 64)  # for lobes at least as wide as GGX alpha = 0.5 (and the cosine)
MIRROR_ALPHA = 0.01  # GGX alpha below which the specular lobe takes its delta limit
CHUNK = 2048  # texels per step of the brute-force sum (bounds memory to ~50 MB)
MATERIALS = tuple(RELIGHT_MATERIALS)

Material = tuple[tuple[float, float, float], float, float]
LightMethod = Callable[[PanoScene, Tensor, tuple[int, int]], Tensor]


# ---------------------------------------------------------------------------------------------
# light at a point: the methods under test


def probe_field_light(scene: PanoScene, points: Tensor, probe_size: tuple[int, int]) -> Tensor:
    """The predicted probe grid interpolated at each point (what an inserted object is lit by)."""
    from phyir.lighting.object_lighting import ProbeField

    field = ProbeField(scene)
    probes = torch.stack([field.probe_at(p) for p in points.reshape(-1, 3)])
    return at_size(probes, probe_size)


def projection_light(scene: PanoScene, points: Tensor, probe_size: tuple[int, int]) -> Tensor:
    """The panorama projected from each point along the predicted depth, the scene's grid probe where
    unseen (LNet's for ``phyir predict --lighting lnet``, as ``--lighting projection`` writes;
    :func:`light_at_point` falls back to the interpolated probe field instead)."""
    from phyir.inference import lnet_probes_at
    from phyir.lighting.projection import project_probes

    pts = points.reshape(-1, 3).float()
    fallback = at_size(lnet_probes_at(scene.probes, pts), probe_size)
    return project_probes(scene, pts, probe_size, fallback)[0]


def light_at_point(scene: PanoScene, points: Tensor, probe_size: tuple[int, int]) -> Tensor:
    """:func:`phyir.lighting.at_point.light_at`: what inserted objects are lit by."""
    from phyir.lighting.at_point import light_at

    return light_at(scene, points.reshape(-1, 3).float(), probe_size)


def light_at_camera(scene: PanoScene, points: Tensor, probe_size: tuple[int, int]) -> Tensor:
    """:func:`light_at_point` at the camera for every point (see the module doc)."""
    return light_at_point(scene, torch.zeros_like(points.reshape(-1, 3)), probe_size)


LIGHT_METHODS: dict[str, LightMethod] = {
    "probe_field": probe_field_light,
    "projection": projection_light,
    "light_at": light_at_point,
    "light_at_camera": light_at_camera,
}
AT_CAMERA = frozenset({"light_at_camera"})  # methods that read the light at the camera, not the point


def at_size(probes: Tensor, size: tuple[int, int]) -> Tensor:
    """``probes [...,3,h,w]`` area-resized to ``size`` (as they are when already that size)."""
    return probes if tuple(probes.shape[-2:]) == tuple(size) else pano.resize_area(probes, *size)


# ---------------------------------------------------------------------------------------------
# the brute-force integrator


def sphere_pixels(centre: tuple[float, float, float] = SPHERE_CENTRE,
                  size: int = SPHERE_PIXELS) -> tuple[Tensor, Tensor, Tensor]:
    """Normals [P,3], view vectors [P,3] (toward the camera) of the visible sphere pixels, float64,
    and the disk mask [S,S] that places them back into an S x S image."""
    c = torch.tensor(centre, dtype=torch.float64)
    n, v, mask = sphere_gbuffer((c / c.norm())[None], size)
    m = mask[0, 0]
    return n[0][:, m].T.contiguous(), v[0][:, m].T.contiguous(), m


def integrate(envs: Tensor, normals: Tensor, views: Tensor, material: Material,
              size: tuple[int, int] | None = None) -> tuple[Tensor, Tensor]:
    """(diffuse, specular) outgoing radiance [E,P,3] (float64) of pixels with ``normals``/``views``
    [P,3] lit by each distant environment ``envs [E,3,h,w]``, summed over ``size`` texels (default
    :func:`integration_size` of the roughness).

    The specular BRDF is linear in F0 (only Fresnel depends on it: F = φ + F0 (1 − φ)), so the sum
    runs over scalar kernels — f_d for base colour 1 and f_s for F0 = 1 and F0 = 0 (= f_s(1) φ), from
    :mod:`phyir.shading.brdf` — and the material's colours combine them afterwards: exact, and 3x
    cheaper than RGB kernels.  The cosines come from dot products as matrix products (n.h and v.h
    from |v + l|² = 2 + 2 v.l): the [P,T,3] half vectors would cost more than the BRDF itself.
    """
    base = torch.tensor(material[0], dtype=torch.float64)
    r, metal = (torch.tensor(float(x), dtype=torch.float64) for x in material[1:])
    E = envs.shape[0]
    h, w = size or integration_size(float(r))
    env = pano.resize_area(torch.nan_to_num(envs.double(), nan=0.0, posinf=0.0).clamp_min(0), h, w)
    light = env.reshape(E * 3, h * w).T  # [T, E*3]
    dirs = pano.directions(h, w, dtype=torch.float64).reshape(3, -1).T
    omega = pano.solid_angles(h, w, dtype=torch.float64).reshape(-1)
    n, v = normals.double(), views.double()
    nv = (n * v).sum(-1, keepdim=True)
    mirror = bool(B.alpha_from_roughness(r) < MIRROR_ALPHA)
    one, zero = torch.ones((), dtype=torch.float64), torch.zeros((), dtype=torch.float64)
    acc = torch.zeros(3, n.shape[0], E * 3, dtype=torch.float64)
    for start in range(0, dirs.shape[0], CHUNK):
        l, dw, Lc = dirs[start:start + CHUNK], omega[start:start + CHUNK], light[start:start + CHUNK]
        nl, vl = n @ l.T, v @ l.T
        inv = torch.rsqrt((2 + 2 * vl).clamp_min(1e-24))
        nh, vh = (nv + nl) * inv, (1 + vl) * inv
        weight = nl.clamp_min(0) * dw  # [P,t]
        lit = ((nl > 0) & (nv > 0)).double()
        if float(metal) < 1:
            acc[0] += (B.brdf_diffuse(one, zero) * lit * weight) @ Lc
        if not mirror:
            fs1 = B.brdf_specular(nl, nv, nh, vh, one, r, one) * weight  # metallic 1, base 1: F0 = 1
            acc[1] += (fs1 * B.fresnel_ue4(vh, zero)) @ Lc  # F0 = 0
            acc[2] += fs1 @ Lc
    to_epc = lambda a: a.reshape(-1, E, 3).transpose(0, 1)  # noqa: E731
    diffuse = base * (1 - metal) * to_epc(acc[0])
    f0 = B.f0_from_material(base, metal)
    if mirror:
        return diffuse, mirror_specular(envs, n, v, f0, r)
    return diffuse, (1 - f0) * to_epc(acc[1]) + f0 * to_epc(acc[2])


def integration_size(roughness: float) -> tuple[int, int]:
    """Texels enough for a lobe: :data:`ROUGH_INTEGRATION_SIZE` from GGX alpha 0.5 up (its lobe and
    the cosine lobe span tens of degrees), :data:`INTEGRATION_SIZE` below."""
    return ROUGH_INTEGRATION_SIZE if roughness * roughness >= 0.5 else INTEGRATION_SIZE


def mirror_specular(envs: Tensor, n: Tensor, v: Tensor, f0: Tensor, rough: Tensor) -> Tensor:
    """The specular lobe's delta limit [E,P,3]: ∫ D F G/(4 n.v n.l) L n.l dω → F(n.v) G1(n.v)² L(r)
    as α → 0 (dω_l = 4 (v.h) dω_h and ∫ D (n.h) dω_h = 1), L bilinear at the environment's own
    resolution in the reflected direction r."""
    nv = (n * v).sum(-1, keepdim=True)
    refl = 2 * nv * n - v
    k = B.schlick_k(rough)
    lobe = B.fresnel_ue4(nv, f0) * B.g1_schlick(nv, k) ** 2 * (nv > 0)
    look = torch.stack([pano.sample_dir(e.double(), refl.T, dim=0).T for e in envs])
    return lobe * look


def render_sphere(envs: Tensor, material: str, centre: tuple[float, float, float] = SPHERE_CENTRE,
                  size: int = SPHERE_PIXELS) -> tuple[Tensor, Tensor]:
    """Sphere pixel radiance [E,P,3] of a RELIGHT_MATERIALS preset under each env, and the disk mask."""
    n, v, mask = sphere_pixels(centre, size)
    d, s = integrate(envs, n, v, RELIGHT_MATERIALS[material])
    return d + s, mask


def to_image(pixels: Tensor, mask: Tensor) -> Tensor:
    """Sphere pixels [P,3] back into an image [3,S,S] (zero outside the disk)."""
    img = torch.zeros(3, *mask.shape, dtype=pixels.dtype)
    img[:, mask] = pixels.T
    return img


# ---------------------------------------------------------------------------------------------
# metrics


def sphere_metrics(ours: Tensor, truth: Tensor) -> dict[str, float]:
    """Errors of sphere pixels ``ours`` against ``truth`` [P,3]: ``rel_l1`` (Σ|o−t| / Σt),
    ``si_rel_l1`` (the same after scaling ours by its least-squares factor: is the *shape* of the
    lighting right?), ``ratio`` (mean ours / mean truth: is the intensity right?) and ``colour_deg``
    (angle between the mean RGB of both: is the colour right?)."""
    o, t = ours.double().flatten(), truth.double().flatten()
    tot = t.sum().clamp_min(1e-30)
    a = (o @ t) / (o @ o).clamp_min(1e-30)
    mo, mt = ours.double().mean(0), truth.double().mean(0)
    cos = (mo @ mt) / (mo.norm() * mt.norm()).clamp_min(1e-30)
    return {"rel_l1": float((o - t).abs().sum() / tot), "si_rel_l1": float((a * o - t).abs().sum() / tot),
            "ratio": float(o.mean() / t.mean().clamp_min(1e-30)),
            "colour_deg": math.degrees(math.acos(float(cos.clamp(-1, 1))))}


def peak_direction(env: Tensor, size: tuple[int, int]) -> Tensor:
    """Unit direction [3] of the brightest texel (luminance) of ``env [3,h,w]`` area-resized to ``size``
    (so a panorama and a probe are compared at the same angular resolution)."""
    e = at_size(torch.nan_to_num(env.float(), nan=0.0, posinf=0.0), size)
    i = int(luminance(e).flatten().argmax())
    return pano.directions(*size).reshape(3, -1)[:, i]


def peak_error_deg(env: Tensor, panorama: Tensor, size: tuple[int, int]) -> float:
    """Angle (degrees) between the brightest directions of ``env`` and of the ``panorama``."""
    c = float(peak_direction(env, size) @ peak_direction(panorama, size))
    return math.degrees(math.acos(max(-1.0, min(1.0, c))))


# ---------------------------------------------------------------------------------------------
# one panorama


def evaluate_lighting(hdr: Tensor, ldr: Tensor, ldr_scale: float, preds: dict[str, PanoScene],
                      methods: dict[str, LightMethod] | None = None,
                      centre: tuple[float, float, float] = SPHERE_CENTRE) -> tuple[dict, dict[str, Tensor]]:
    """Lighting metrics at ``centre`` for the HDR input and its LDR copy.

    ``preds`` holds the scenes predicted from the HDR (``"hdr"``) and from the LDR copy (``"ldr"``).
    Units: the LDR copy is the HDR times ``ldr_scale`` (the auto-exposure), clipped, so the LDR rows
    compare against the truth times ``ldr_scale`` (the integral is linear in L: that is the HDR
    truth in the LDR's units); the naive baseline (the LDR copy as environment) is the same in both.
    Returns ``({"hdr"|"ldr": {method: {"<material>.<metric>": v, "peak_deg": v}}}, sphere images)``
    with the HDR row's sphere images [3,S,S] keyed ``"<who>/<material>"`` (who: truth, methods).
    """
    methods = LIGHT_METHODS if methods is None else methods
    X = torch.tensor(centre, dtype=torch.float32)[None]
    size = tuple(preds["hdr"].probe_size)
    probes = {(inp, m): fn(preds[inp], X, size)[0].float() for inp in preds for m, fn in methods.items()}
    keys = list(probes)
    lo = [pano.resize_area(hdr.float(), *INTEGRATION_SIZE), pano.resize_area(ldr.float(), *INTEGRATION_SIZE)]
    envs = torch.stack(lo + [at_size(p, INTEGRATION_SIZE) for p in probes.values()])
    full = {"truth": hdr, "naive": ldr} | {k: probes[k] for k in keys}  # mirror look-ups at full res
    results: dict[str, dict[str, dict[str, float]]] = {inp: {} for inp in preds}
    images: dict[str, Tensor] = {}
    for mat in MATERIALS:
        px, mask = _render_all(envs, list(full.values()), mat)
        truth, naive = px[0], px[1]
        images[f"truth/{mat}"] = to_image(truth, mask)
        for inp in preds:
            t = truth * (ldr_scale if inp == "ldr" else 1.0)
            for i, (kin, m) in enumerate(keys):
                if kin == inp:
                    results[inp].setdefault(m, {}).update(_prefix(mat, sphere_metrics(px[2 + i], t)))
                    if inp == "hdr" and m not in AT_CAMERA:  # at the camera, HDR is the truth
                        images[f"{m}/{mat}"] = to_image(px[2 + i], mask)
            naive_m = sphere_metrics(naive, truth * ldr_scale)
            results[inp].setdefault("naive", {}).update(_prefix(mat, naive_m))
    for inp in preds:
        for kin, m in keys:
            if kin == inp:
                results[inp][m]["peak_deg"] = peak_error_deg(probes[(kin, m)], hdr, size)
        results[inp]["naive"]["peak_deg"] = peak_error_deg(ldr, hdr, size)
    return results, images


def _render_all(envs: Tensor, full: list[Tensor], material: str) -> tuple[Tensor, Tensor]:
    """Sphere pixels [E,P,3] of every environment; the mirror lobe reads each at its own resolution."""
    n, v, mask = sphere_pixels()
    mat = RELIGHT_MATERIALS[material]
    d, s = integrate(envs, n, v, mat)
    if B.alpha_from_roughness(torch.tensor(float(mat[1]))) < MIRROR_ALPHA:
        f0 = B.f0_from_material(torch.tensor(mat[0], dtype=torch.float64),
                                torch.tensor(float(mat[2]), dtype=torch.float64))
        r = torch.tensor(float(mat[1]), dtype=torch.float64)
        s = torch.cat([mirror_specular(e[None], n, v, f0, r) for e in full])
    return d + s, mask


def _prefix(p: str, d: dict[str, float]) -> dict[str, float]:
    return {f"{p}.{k}": v for k, v in d.items()}
