"""Benchmark of the viewer's object shading settings: time per frame against error
(``phyir bench shading``).

The supplement's Table 2 spheres (diffuse, matte silver, mirror silver; :data:`phyir.evaluation.metrics
.RELIGHT_MATERIALS`) lit by a probe are shaded by the insertion renderer's GLSL
(:meth:`viewer.insertion.InsertionRenderer.shade_gbuffer`, ``shaders/ibl.glsl``) under several
settings and compared with the converged reference: :func:`phyir.evaluation.metrics.render_spheres`
(importance sampling, ``ref_spp`` samples; the mean of two halves with different seeds, whose
difference gives the reference's own noise).

Settings (``shade_gbuffer`` with):

* ``ggx N``: N GGX samples of the probe's residual (the viewer: :data:`viewer.insertion.FULL` 128
  for still frames, :data:`viewer.insertion.DRAGGING` 4 while dragging), peak samples on;
* ``ggx N, no peaks``: the brightest texels left in the sampled residual instead of integrated as
  point samples (:func:`phyir.lighting.object_lighting.peak_samples` disabled for the call);
* ``ggx 128, irradiance 8x16``: a coarser diffuse irradiance map than the viewer's
  (:data:`phyir.lighting.object_lighting.IRRADIANCE_SIZE`);
* for comparison, torch on the CPU: the split-sum ``prefiltered`` method and ``importance`` sampling at a
  few spp (:func:`phyir.shading.render.shade_env`).

Error: relative L1, ``sum |x - ref| / sum |ref|`` over the sphere's pixels, averaged over the probes.
Time: the median of repeated calls after a warm-up (interleaved, see
:func:`phyir.bench.measure.time_calls`); ``frame_ms`` is the whole call minus ``prep_ms``, the
CPU-side lighting preparation (peak samples, mip pyramid, irradiance map) which the viewer does
only when an object moves, so ``frame_ms`` is texture upload, the draw and the read-back.
Probes: the render benchmark's procedural lamp-lit probe (:func:`phyir.bench.render.bench_scene`) and
the real panoramas of ``../shared/panos`` when present (downsampled to 16x32, the scene probes' size).
"""

from __future__ import annotations

import contextlib
import functools
import os
from collections.abc import Callable, Iterator
from pathlib import Path

import torch

FULL = {"size": 64, "ref_spp": 4096, "repeats": 7, "panos": 2, "ggx": (1, 4, 16, 64, 128, 256),
        "no_peaks": (16, 128), "torch_spp": (16, 64, 256)}
QUICK = {"size": 16, "ref_spp": 256, "repeats": 2, "panos": 0, "ggx": (4, 128), "no_peaks": (128,),
         "torch_spp": (16,)}
PROBE_SIZE = (16, 32)
COARSE_IRRADIANCE = (8, 16)
REPO = Path(__file__).resolve().parents[1]


def bench_probes(n_panos: int) -> dict[str, torch.Tensor]:
    """Probes ``[3, 16, 32]``: the procedural one and up to ``n_panos`` real panoramas."""
    from phyir import io, pano
    from phyir.bench.render import bench_scene

    sc = bench_scene("glossy", 16, 32, block=8, probe_size=PROBE_SIZE, seed=3)
    probes = {"procedural lamps": sc.probes[1, 2].float()}
    panos = REPO.parent / "shared" / "panos"
    if n_panos and panos.is_dir():
        for f in sorted(panos.glob("*.hdr"))[:n_panos]:
            probes[f.stem] = pano.resize_area(io.load_panorama(f), *PROBE_SIZE).float()
    return probes


@contextlib.contextmanager
def _patched(no_peaks: bool = False, irradiance: tuple[int, int] | None = None) -> Iterator[None]:
    """Ablations of the viewer's lighting preparation, for the duration of one call."""
    import viewer.insertion as ins

    saved = ins.peak_samples, ins.irradiance_map
    if no_peaks:
        ins.peak_samples = lambda probe: (torch.zeros(0, 3), torch.zeros(0, 3), probe.clone())
    if irradiance is not None:
        ins.irradiance_map = functools.partial(saved[1], size=irradiance)
    try:
        yield
    finally:
        ins.peak_samples, ins.irradiance_map = saved


def _prep(probe: torch.Tensor, settings: dict) -> None:
    """shade_gbuffer's CPU-side preparation of one probe (timed on its own: see the module doc)."""
    from phyir.lighting.object_lighting import irradiance_map, peak_samples, probe_mips

    residual = probe if settings.get("no_peaks") else peak_samples(probe)[2]
    probe_mips(probe)
    probe_mips(residual)
    irradiance_map(probe, **({"size": settings["irradiance"]} if settings.get("irradiance") else {}))


def settings_list(cfg: dict) -> list[dict]:
    out = [{"name": f"ggx {n}", "kind": "glsl", "ggx": n} for n in cfg["ggx"]]
    out += [{"name": f"ggx {n}, no peaks", "kind": "glsl", "ggx": n, "no_peaks": True}
            for n in cfg["no_peaks"]]
    out.append({"name": "ggx 128, irradiance {}x{}".format(*COARSE_IRRADIANCE), "kind": "glsl", "ggx": 128,
                "irradiance": COARSE_IRRADIANCE})
    out.append({"name": "torch prefiltered (split sum)", "kind": "torch", "method": "prefiltered", "spp": 1})
    out += [{"name": f"torch importance {n} spp", "kind": "torch", "method": "importance", "spp": n}
            for n in cfg["torch_spp"]]
    return out


def run_bench(out_dir: str | os.PathLike, *, quick: bool = False, device: str = "cpu",
              repeats: int | None = None, threads: int | None = None,
              log: Callable[[str], None] = print) -> dict:
    """Run the shading benchmark; write ``shading.json`` and ``shading.png``.  GL runs on a headless
    EGL context; ``device`` is where the torch reference renders."""
    from phyir.bench.measure import torch_threads
    from phyir.bench.report import target_config

    cfg = target_config(FULL, QUICK, quick, repeats)

    with torch_threads(threads):
        return _run(Path(out_dir), cfg, device, log)


def _context():
    import moderngl

    from phyir.errors import PhyIRError

    try:
        return moderngl.create_standalone_context(backend="egl", require=330)
    except Exception as e:  # noqa: BLE001 -- any failure to create a context means no GL here
        raise PhyIRError(f"shading benchmark: no headless OpenGL 3.3 context (EGL): {e}") from e


def _run(out: Path, cfg: dict, device: str, log: Callable[[str], None]) -> dict:
    from phyir.bench.measure import time_calls
    from phyir.bench.report import save_target
    from phyir.bench.synth import pair_noise, rel_l1
    from phyir.evaluation.metrics import RELIGHT_MATERIALS, render_spheres, sphere_gbuffer
    from phyir.insert.objects import PRESETS
    from viewer.insertion import InsertionRenderer

    S = cfg["size"]
    probes = bench_probes(cfg["panos"])
    view_dir = torch.tensor([[0.3, -0.2, -1.0]])
    n, v, mask = sphere_gbuffer(view_dir, S)
    n, v, m = n[0], v[0], mask[0].float()
    ctx = _context()
    result: dict = {"config": {**cfg, "device": device, "threads": torch.get_num_threads(),
                               "torch": torch.__version__, "gl_renderer": ctx.info.get("GL_RENDERER", "?"),
                               "probes": list(probes), "loadavg_start": os.getloadavg()}}
    log(f"shading bench: spheres {S}x{S}, {len(probes)} probe(s), reference {cfg['ref_spp']} spp, "
        f"GL {result['config']['gl_renderer']}")
    ins = InsertionRenderer(ctx)
    settings = settings_list(cfg)
    rows: dict[tuple[str, str], dict] = {}
    ref_noise: dict[str, list[float]] = {}
    try:
        for mat in RELIGHT_MATERIALS:
            material = PRESETS[mat.replace("_", "-")]
            for pname, probe in probes.items():
                p_dev = probe[None].to(device)
                halves = [render_spheres(p_dev, view_dir.to(device), mat, size=S, spp=cfg["ref_spp"] // 2,
                                         seed=s)[0].cpu() for s in (1_000_003, 2_000_003)]
                ref = (halves[0] + halves[1]) / 2
                ref_noise.setdefault(mat, []).append(pair_noise(*halves, m) / 2 ** 0.5)

                def call(s: dict, probe=probe, material=material, mat=mat) -> torch.Tensor:
                    if s["kind"] == "torch":
                        return render_spheres(probe[None], view_dir, mat, size=S, spp=s["spp"],
                                              method=s["method"], seed=7)[0]
                    with _patched(s.get("no_peaks", False), s.get("irradiance")):
                        return ins.shade_gbuffer(n, v, material, probe, s["ggx"]) * m

                calls = {s["name"]: functools.partial(call, s) for s in settings}
                calls |= {"prep " + s["name"]: functools.partial(_prep, probe, s) for s in settings
                          if s["kind"] == "glsl"}
                times = time_calls(calls, "cpu", cfg["repeats"])
                for s in settings:
                    raw = rel_l1(calls[s["name"]](), ref, m)
                    r = rows.setdefault((mat, s["name"]), {"errs": [], "raws": [], "times": [], "preps": [],
                                                           "q": [], "cpu": [], "prep_cpu": []})
                    # the reference's own noise removed in quadrature (independent noise adds so)
                    r["errs"].append(max(raw**2 - ref_noise[mat][-1] ** 2, 0.0) ** 0.5)
                    r["raws"].append(raw)
                    r["times"].append(times[s["name"]]["median_s"])
                    r["q"].append((times[s["name"]]["q1_s"], times[s["name"]]["q3_s"]))
                    glsl = s["kind"] == "glsl"
                    r["preps"].append(times["prep " + s["name"]]["median_s"] if glsl else 0.0)
                    r["cpu"].append(times[s["name"]]["cpu_s"])
                    r["prep_cpu"].append(times["prep " + s["name"]]["cpu_s"] if glsl else 0.0)
                log(f"  {mat:<13} {pname:<30} " + "  ".join(
                    f"{s['name']}: {rows[(mat, s['name'])]['errs'][-1]:.4f}" for s in settings[:3]) + " ...")
    finally:
        ins.release()
        ctx.release()
    table = []
    for (mat, name), r in rows.items():
        s = next(x for x in settings if x["name"] == name)
        call_ms = 1e3 * _mean(r["times"])
        prep_ms = 1e3 * _mean(r["preps"])
        table.append({"material": mat, "setting": name, "kind": s["kind"], "ggx": s.get("ggx"),
                      "err": _mean(r["errs"]), "err_max": max(r["errs"]), "err_raw": _mean(r["raws"]),
                      "call_ms": call_ms, "q1_ms": 1e3 * _mean([q[0] for q in r["q"]]),
                      "q3_ms": 1e3 * _mean([q[1] for q in r["q"]]), "prep_ms": prep_ms,
                      "frame_ms": max(call_ms - prep_ms, 0.0) if s["kind"] == "glsl" else call_ms,
                      "call_cpu_ms": 1e3 * _mean(r["cpu"]),
                      "frame_cpu_ms": max(1e3 * (_mean(r["cpu"]) - _mean(r["prep_cpu"])), 0.0),
                      "reference_noise": _mean(ref_noise[mat])})
    result["rows"] = table
    result["config"]["loadavg_end"] = os.getloadavg()
    save_target(out, "shading", result, plot, format_table, log)
    return result


def key_numbers(result: dict) -> dict[str, float]:
    """Headline numbers for the report: error and time per frame of each sphere and setting."""
    out = {}
    for r in result["rows"]:
        k = f"{r['material']}.{r['setting'].replace(' ', '_').replace(',', '')}"
        out[f"{k}.rel_l1"] = r["err"]
        out[f"{k}.frame_ms"] = r["frame_ms"]
    return out


def _ms(x: float | None) -> str:
    return "n/a" if x is None else f"{x:.1f}"


def format_table(result: dict) -> str:
    cfg = result["config"]
    lines = [f"shading: spheres {cfg['size']}x{cfg['size']}, GL {cfg['gl_renderer']}, torch on "
             f"{cfg['device']} {cfg['threads']} thread(s), reference {cfg['ref_spp']} spp, probes: "
             f"{', '.join(cfg['probes'])}; load average {cfg['loadavg_start'][0]:.1f} -> "
             f"{cfg['loadavg_end'][0]:.1f}", "",
             "| sphere | setting | rel L1 (mean) | rel L1 (max) | rel L1 raw | call ms (median) "
             "| prep ms | frame ms (call - prep) | frame CPU ms |",
             "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for r in result["rows"]:
        lines.append(f"| {r['material']} | {r['setting']} | {r['err']:.4f} | {r['err_max']:.4f} | "
                     f"{r['err_raw']:.4f} | {r['call_ms']:.1f} | {r['prep_ms']:.1f} | {r['frame_ms']:.1f} | "
                     f"{_ms(r.get('frame_cpu_ms'))} |")
    noise = {r["material"]: r["reference_noise"] for r in result["rows"]}
    lines += ["", "reference noise (rel L1, removed in quadrature from the rel L1 columns; raw keeps it): "
              + ", ".join(f"{k} {v:.4f}" for k, v in noise.items())]
    return "\n".join(lines)


def plot(result: dict, path: Path) -> None:
    """Error against time per frame, one panel per sphere (log-log)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from phyir.bench.report import save_figure

    mats = list(dict.fromkeys(r["material"] for r in result["rows"]))
    fig, axes = plt.subplots(1, len(mats), figsize=(5 * len(mats), 4.2), squeeze=False)
    for ax, mat in zip(axes[0], mats):
        rows = [r for r in result["rows"] if r["material"] == mat]
        groups = {"GLSL, peaks": [r for r in rows if r["kind"] == "glsl" and "no peaks" not in r["setting"]
                                  and "irradiance" not in r["setting"]],
                  "GLSL, no peaks": [r for r in rows if "no peaks" in r["setting"]],
                  "GLSL, coarse irradiance": [r for r in rows if "irradiance" in r["setting"]],
                  "torch importance (CPU)": [r for r in rows if "importance" in r["setting"]],
                  "torch split sum (CPU)": [r for r in rows if "prefiltered" in r["setting"]]}
        for (label, rs), style in zip(groups.items(), ("o-", "s--", "^", "x:", "r*")):
            if not rs:
                continue
            err = [max(r["err"], 1e-5) for r in rs]  # the mirror sphere is exact: keep it on a log axis
            ax.plot([max(r["frame_ms"], 1e-2) for r in rs], err, style, label=label)
            for r, e in zip(rs, err):
                ax.annotate(r["setting"].split(",")[0].replace("torch ", ""), (max(r["frame_ms"], 1e-2), e),
                            fontsize=6, xytext=(3, 3), textcoords="offset points")
        ax.axhline(max(rows[0]["reference_noise"], 1e-5), color="k", lw=0.8, ls=":", label="reference noise")
        ax.set(xscale="log", yscale="log", xlabel="time per frame (ms)", ylabel="relative L1 vs reference",
               title=f"{mat} ({result['config']['size']} px)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path)


def _mean(xs: list[float]) -> float:
    return sum(xs) / len(xs)
