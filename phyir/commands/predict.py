"""``phyir predict INPUT... -o OUT``: panoramas to complete scene files."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from phyir.commands import options
from phyir.estimators import DEFAULT_GEOMETRY, DEFAULT_LIGHTING, geometry_networks, lighting_methods

HELP = "predict depth, normals, materials and light probes of panoramas (writes scene .exr files)"

IMAGE_SUFFIXES = (".exr", ".hdr", ".png", ".jpg", ".jpeg")


def registry_help(registry, default: str) -> str:
    """``name: summary; ...`` of a :mod:`phyir.estimators` registry, for an option's --help."""
    return registry.describe(default).replace("%", "%%")  # (argparse formats help with %)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("inputs", nargs="+", metavar="INPUT",
                        help="panorama or scene files (OpenEXR, .hdr, PNG, JPEG) or folders of them")
    parser.add_argument("-o", "--output", required=True, metavar="OUT", type=options.path,
                        help="output .exr file (one input) or folder (created; <name>.exr per input)")
    parser.add_argument("--weights", metavar="FILE", help="weights file (default: the shipped model)")
    parser.add_argument("--device", type=options.device,
                        help="cpu, cuda, cuda:1, ... (default: cuda when available)")
    parser.add_argument("--outputs", metavar="LIST",
                        help="comma-separated subset of depth,normal,albedo,roughness,metallic,probes "
                             "(default: all); layers the input already has are kept, not recomputed")
    parser.add_argument("--lighting", choices=lighting_methods().names(), default=None,
                        help="how the probes are made: "
                             + registry_help(lighting_methods(), DEFAULT_LIGHTING))
    parser.add_argument("--geometry", choices=geometry_networks().names(), default=None,
                        help="the network predicting depth, normals and materials: "
                             + registry_help(geometry_networks(), DEFAULT_GEOMETRY))
    parser.add_argument("--net-size", metavar="HxW", help="network resolution (default: the weights')")
    parser.add_argument("--ldr", action="store_true", help="treat inputs as LDR (no exposure normalisation)")
    parser.add_argument("--half", action="store_true", help="write float16 EXR channels")
    parser.add_argument("--skip-existing", action="store_true", help="leave outputs that already exist")
    parser.add_argument("-q", "--quiet", action="store_true", help="no per-file lines")


def collect_inputs(inputs: list[str]) -> list[Path]:
    """Files as given; folders expanded to their image files (sorted, not recursive)."""
    from phyir.errors import InputError
    from phyir.io import check_input, folder_files

    files: list[Path] = []
    for s in inputs:
        p = Path(s)
        if p.is_dir():  # hidden files (a write's temporaries among them) are not inputs
            found = [Path(q) for q in folder_files(p, IMAGE_SUFFIXES)]
            if not found:
                raise InputError(p, "folder holds no .exr/.hdr/.png/.jpg files")
            files += found
        else:
            check_input(p)  # a regular file: FIFOs, devices, symlink loops refused here, in one line
            files.append(p)
    return files


def output_paths(files: list[Path], output: str) -> list[Path]:
    from phyir.errors import PhyIRError, shown
    from phyir.io import check_output

    out = Path(output)
    if out.suffix.lower() == ".exr" and not out.is_dir():
        check_output(out)  # not a device, FIFO, ...
        if len(files) != 1:
            raise PhyIRError(f"{out}: {len(files)} inputs need an output folder, not a .exr file")
        return [out]
    if out.exists() and not out.is_dir():
        raise PhyIRError(f"{shown(out)}: exists and is not a folder: the output is a .exr file (one "
                         "input) or a folder")
    names = [f.stem + ".exr" for f in files]
    dup = {n for n in names if names.count(n) > 1}
    if dup:
        raise PhyIRError(f"inputs would overwrite each other in {out}: {', '.join(sorted(dup))}")
    return [out / n for n in names]


def uniform_warning(image) -> str | None:
    """[issue 22, class 5] A panorama that is (nearly) one value — black, clipped white, a single
    bright pixel on black — carries no room: say that the layers predicted from it are guesses."""
    import torch

    peak = image.amax(0).flatten().float()
    lo, hi = torch.quantile(peak[:: max(1, peak.numel() // 100_000)], torch.tensor([0.01, 0.99]))
    if float(hi - lo) > 1e-6 * max(float(hi), 1e-30):
        return None
    return (f"the panorama is uniform (99% of its pixels are {float(hi):.3g}): it shows no room, so the "
            "predicted layers are guesses")


def geometry_confidence(scene) -> str:
    """Record the scene's geometry confidence in its meta (the EXR header) and say it in words:
    "; geometry confidence 0.96", with a warning when it is flagged; "" without depth and normals."""
    from phyir.commands.info import format_confidence
    from phyir.evaluation.real import flag_reason, scene_confidence

    if scene.depth is None or scene.normal is None:
        return ""
    c = scene_confidence(scene)
    scene.meta["predict.confidence"] = f"{float(c['confidence']):.3f}"
    text = f"; geometry confidence {format_confidence(float(c['confidence']))}"
    return text + f" (flagged: {flag_reason(c)}; check it)" if c["flagged"] else text


def run(args: argparse.Namespace) -> int:
    import torch
    from tqdm import tqdm

    from phyir.errors import PhyIRError, shown
    from phyir.inference import OUTPUTS, predict_with_report
    from phyir.io import save_scene

    files = collect_inputs(args.inputs)
    outs = output_paths(files, args.output)
    outputs = None
    if args.outputs:
        outputs = [s.strip() for s in args.outputs.split(",") if s.strip()]
        bad = [s for s in outputs if s not in OUTPUTS]
        if not outputs:  # [issue 22] " , " would predict nothing and write the input back
            raise PhyIRError(f"--outputs: no layer named in {args.outputs!r} (choose from "
                             f"{', '.join(OUTPUTS)})")
        if bad:
            raise PhyIRError(f"--outputs: unknown {', '.join(bad)} (choose from {', '.join(OUTPUTS)})")
    net_size = None
    if args.net_size:
        from phyir.inference import check_net_size
        from phyir.synth.dataset import parse_size

        net_size = check_net_size(parse_size(args.net_size, "--net-size"), "--net-size")
    device = torch.device(args.device) if args.device else \
        torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if device.type == "cuda" and not torch.cuda.is_available():
        raise PhyIRError(f"--device {args.device}: CUDA is not available")
    status = 0
    bar = tqdm(total=len(files), unit="pano", disable=len(files) < 2 or args.quiet, file=sys.stderr)
    for src, dst in zip(files, outs):
        if args.skip_existing and dst.exists():
            bar.update(1)
            continue
        try:
            # the model is loaded (once, cached) only if some layer has to be computed
            scene, report = predict_with_report(
                src, weights=args.weights, device=device, outputs=outputs, lighting=args.lighting,
                geometry=args.geometry, net_size=net_size, hdr=False if args.ldr else None)
            uniform = uniform_warning(scene.image)
            if uniform:
                bar.write(f"phyir predict: warning: {shown(src)}: {uniform}", file=sys.stderr)
            confidence = geometry_confidence(scene)
            dst.parent.mkdir(parents=True, exist_ok=True)
            save_scene(scene, dst, half=args.half)
        except PhyIRError as e:  # report and go on with the other inputs
            bar.write(f"phyir predict: error: {shown(str(e))}", file=sys.stderr)
            status = 2
            bar.update(1)
            continue
        if not args.quiet:
            secs = report.seconds
            H, W = scene.size
            parts = ", ".join(f"{k} {v:.2f}" for k, v in secs.items() if k != "total" and v >= 0.01)
            note = "; geometry from the input mirrored through the horizon (the upright pass's normals " \
                "faced away from the camera)" if report.gm_pass == "mirrored" else ""
            if report.hdr_recovery is not None:
                law = " by the JPEG law" if report.hdr_recovery.method == "regions-jpeg" else ""
                note += f"; HDR recovered in {report.hdr_recovery.regions} clipped regions{law} " \
                        f"(energy x{report.hdr_recovery.energy_gain:.2f})"
            if report.normals_from == "depth":
                note += f"; normals from depth: the network's face away from the camera in " \
                        f"{100 * report.normals_away:.0f}% of the view"
            bar.write(f"{shown(src)} -> {shown(dst)} ({H}x{W}, {secs['total']:.2f} s: {parts}; "
                      f"computed: {' '.join(report.computed) or 'nothing'}{note}){confidence}")
        bar.update(1)
    bar.close()
    return status
