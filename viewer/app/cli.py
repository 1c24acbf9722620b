"""``phyir-view``'s command line: open a file in an :class:`~viewer.app.App`, then run the window,
save one screenshot or print frame times (``--bench``)."""

from __future__ import annotations

import argparse
import math
import os
import sys
import time

from phyir.cli import OneLineParser
from phyir.commands import options
from phyir.errors import PhyIRError
from viewer.app import cli_objects
from viewer.app.common import gl_current
from viewer.app.core import App
from viewer.compare import MODES
from viewer.gl import window as surfaces
from viewer.layers import LAYERS
from viewer.renderer import CHANNELS, COLORMAPS, TONEMAPS


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WxH (e.g. 1280x720), got {text!r}") from None
    if not (64 <= w <= 8192 and 64 <= h <= 8192):
        raise argparse.ArgumentTypeError(f"window size {w}x{h} out of range (64..8192)")
    return w, h


def _uv(text: str) -> tuple[float, float]:
    try:
        u, v = (float(t) for t in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected U,V (panorama column,row), got {text!r}") from None
    if not (math.isfinite(u) and math.isfinite(v)):
        raise argparse.ArgumentTypeError(f"expected finite U,V, got {text!r}")
    return u, v


def _listen(text: str) -> tuple[str, int]:
    """``[HOST:]PORT`` of the control socket; HOST must be loopback (viewer.remote)."""
    from viewer.remote import loopback_host

    host, _, port = text.rpartition(":")
    try:
        number = int(port)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected [HOST:]PORT (e.g. 5151), got {text!r}") from None
    if not 0 <= number <= 65535:
        raise argparse.ArgumentTypeError(f"port {number} out of range (0..65535; 0: any free port)")
    try:
        return loopback_host(host or "127.0.0.1"), number
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def _bounded(lo: float, hi: float, what: str):
    """An argparse type: a finite float in [lo, hi]."""
    def parse(text: str) -> float:
        try:
            x = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        if not (math.isfinite(x) and lo <= x <= hi):
            raise argparse.ArgumentTypeError(f"{what} must be a finite number in [{lo:g}, {hi:g}], "
                                             f"got {text!r}")
        return x
    return parse


def parser() -> argparse.ArgumentParser:
    p = OneLineParser(
        prog="phyir-view",
        description="Inspect an indoor panorama and what PhyIR infers from it (layers, light probes).")
    p.add_argument("path", nargs="*", help="panoramas (.hdr/.exr/.png/.jpg) or scene files (.exr), "
                                           "all open at once, the first shown; default: the demo scene")
    p.add_argument("--layer", choices=LAYERS, help="layer to show")
    p.add_argument("--probe", type=_uv, action="append", default=[], metavar="U,V",
                   help="pin the probe at panorama column U, row V (repeatable)")
    p.add_argument("--view", choices=("equirect", "perspective"), help="view")
    p.add_argument("--yaw", type=_bounded(-3600, 3600, "--yaw"),
                   help="perspective view: yaw in degrees (toward +x)")
    p.add_argument("--pitch", type=_bounded(-90, 90, "--pitch"),
                   help="perspective view: pitch in degrees (up)")
    p.add_argument("--fov", type=_bounded(1, 179, "--fov"),
                   help="perspective view: vertical field of view in degrees (1..179)")
    p.add_argument("--zoom", type=_bounded(1e-3, 1e3, "--zoom"),
                   help="equirect view: screen pixels per panorama pixel (default fit)")
    p.add_argument("--center", type=_uv, metavar="U,V", help="equirect view: panorama point at the centre")
    p.add_argument("--exposure", type=_bounded(-64, 64, "--exposure"), help="exposure in EV")
    p.add_argument("--tonemap", choices=TONEMAPS, help="tone map of HDR layers")
    p.add_argument("--colormap", choices=COLORMAPS, help="colour map of scalar layers")
    p.add_argument("--channel", choices=CHANNELS,
                   help="HDR and colour layers: one channel (or the luminance) as grey")
    p.add_argument("--listen", type=_listen, metavar="[HOST:]PORT",
                   help="accept commands (JSON lines: open, layer, screenshot, ...; viewer/client.py) on "
                        "a TCP port of 127.0.0.1 (loopback only; 0: any free port, printed)")
    p.add_argument("--watch", action="store_true", help="reload the file whenever it changes on disk")
    p.add_argument("--histogram", action="store_true", help="open the side panel's histogram of the layer")
    p.add_argument("--compare", nargs="?", const="truth", choices=("truth", *MODES), metavar="MODE",
                   help="diff, reldiff, sqerr or split: the shown layer against the reference's "
                        "(--reference, else the second image); alone or 'truth': treat the file's "
                        "layers as ground truth, predict all layers and compare (automatic for "
                        "complete synthetic scenes)")
    p.add_argument("--reference", metavar="FILE",
                   help="open FILE too and compare with it (--compare; default split)")
    p.add_argument("--split", type=_bounded(0, 1, "--split"),
                   help="split view: where the reference starts, fraction of the view's width (0..1)")
    p.add_argument("--show", choices=("prediction", "truth"),
                   help="with ground truth: which layers to show (key G)")
    p.add_argument("--gt", metavar="SCENE", help="ground-truth scene file to compare with")
    p.add_argument("--no-model", action="store_true", help="don't run the model (show the file's layers)")
    p.add_argument("--weights", metavar="FILE", help="model weights (default: the shipped ones)")
    p.add_argument("--device", type=options.device,
                   help="torch device for the model: cpu, cuda or cuda:N (default: CUDA when available)")
    p.add_argument("--screenshot", metavar="OUT.png", help="render once, save a PNG and exit")
    p.add_argument("--size", type=_size, default=None, metavar="WxH", help="window size (default 1400x820)")
    p.add_argument("--headless", action="store_true",
                   help="render through EGL without a window (with --screenshot, --bench or --listen)")
    p.add_argument("--no-ui", action="store_true", help="with --screenshot: only the view, no panels")
    p.add_argument("--timeout", type=options.number(0.1, 86400), default=600.0,
                   help="with --screenshot: longest wait for loading and the model (s)")
    p.add_argument("--threads", type=options.number(1, 1024, integer=True),
                   help="torch threads for inference (default: cores - 1)")
    p.add_argument("--bench", action="store_true",
                   help="print frame times (idle view, and while the model runs) and exit")
    cli_objects.add_arguments(p)
    return p


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    scripted = bool(args.screenshot or args.bench)
    if args.listen and scripted:
        print("phyir-view: --listen runs until closed: not with --screenshot or --bench", file=sys.stderr)
        return 2
    if args.headless and not (scripted or args.listen):
        print("phyir-view: --headless needs --screenshot OUT.png (or --bench, --listen)", file=sys.stderr)
        return 2
    headless = args.headless or (scripted and not surfaces.has_display())
    if not headless and not surfaces.has_display():
        print("phyir-view: no display (DISPLAY/WAYLAND_DISPLAY unset); use --screenshot OUT.png "
              "[--headless] to render without a window (or --headless --listen PORT)", file=sys.stderr)
        return 2
    paths = args.path or [_demo_path()]
    path = paths[0]
    if _compare_mode(args) and not args.reference and len(paths) < 2:
        print(f"phyir-view: --compare {_compare_mode(args)} needs a reference: --reference FILE or a "
              "second image", file=sys.stderr)
        return 2
    try:
        app = App(args.size or ((1280, 720) if scripted else (1400, 820)), headless=headless,
                  ui=not args.no_ui, visible=not scripted, threads=args.threads,
                  recent=False if scripted or headless else None, run_model=not args.no_model,
                  weights=args.weights, device=args.device)
    except Exception as e:  # noqa: BLE001 - no GL: say so in one line
        print(f"phyir-view: cannot create an OpenGL 3.3 context: {e}", file=sys.stderr)
        return 2
    try:
        gt = None
        if args.gt:
            from phyir import io

            gt = io.load_scene(args.gt)
        app.open(path, gt=gt, compare=True if args.compare == "truth" else None)
        open_images(app, args)
        if args.bench:
            return _bench(app, args)
        if not scripted:
            apply_args(app, args, wait=False)
            return _interactive(app, args)
        if not app.wait_idle(args.timeout):
            print(f"phyir-view: {path}: still loading after {args.timeout:g} s", file=sys.stderr)
            return 2
        apply_args(app, args, wait=True)
        for _ in range(3):  # imgui lays windows out over a couple of frames
            app.frame()
        app.screenshot(args.screenshot)
        if app.messages.error:
            print(f"phyir-view: {app.messages.error}", file=sys.stderr)
            return 2
        return 0
    except PhyIRError as e:
        print(f"phyir-view: {e}", file=sys.stderr)
        return 2
    finally:
        app.close()


def _interactive(app: App, args) -> int:
    """The window's loop, or with --headless --listen the control socket's until ``quit`` or Ctrl+C."""
    if args.listen:
        try:
            host, port = app.listen(*args.listen)
        except OSError as e:
            where = f"{args.listen[0]}:{args.listen[1]}"
            print(f"phyir-view: --listen {where}: {e.strerror or e}", file=sys.stderr)
            return 2
        print(f"phyir-view: listening on {host}:{port}", flush=True)
    if app.window is None:
        try:
            app.serve_until(lambda: app.quit_requested)
        except KeyboardInterrupt:
            pass
        return 0
    app.run()
    return 0


def _compare_mode(args) -> str | None:
    """The comparison asked for: --compare MODE, or split for --reference/--split alone."""
    if args.compare in MODES:
        return args.compare
    return "split" if args.reference or args.split is not None else None


def open_images(app: App, args) -> None:
    """The other images of the command line (read once the first is in) and the reference: the
    --reference file, else the second image when a comparison is asked for."""
    for p in args.path[1:]:
        app.images.queue(p)
    if args.reference:
        app.images.set_reference(app.images.index(app.images.queue(args.reference)))
    elif _compare_mode(args) and len(app.images) > 1:
        app.images.set_reference(1)


def _apply_compare(app: App, args, wait: bool) -> None:
    mode = _compare_mode(args)
    if mode is None:
        return
    if app.images.reference is None:  # its file could not be read: app.messages.error says why
        raise PhyIRError(f"--reference {args.reference or args.path[1]}: {app.messages.error or 'not open'}")
    if wait and app.comparison.problem(app.display.layer):
        raise PhyIRError(f"--compare {mode}: {app.comparison.problem(app.display.layer)}")
    app.comparison.set_mode(mode)
    if args.split is not None:
        app.comparison.set_split(args.split)


def apply_args(app: App, args, wait: bool) -> None:
    if args.layer:
        if wait and args.layer not in app.doc.available():
            raise PhyIRError(f"{app.doc.name}: layer {args.layer!r} is not available "
                             f"(have: {', '.join(app.doc.available()) or 'none'})")
        app.display.set_layer(args.layer)
    if args.view:
        app.camera.set_view(args.view)
    persp = {k: v for k, v in (("fov", args.fov), ("yaw", args.yaw and math.radians(args.yaw)),
                                ("pitch", args.pitch and math.radians(args.pitch))) if v is not None}
    if persp:
        app.camera.views["perspective"].update(**persp)
    if wait and (args.zoom or args.center):
        eq = app.camera.views["equirect"]
        if args.zoom:
            eq.zoom_about(args.zoom / eq.zoom, app.view_size())
        if args.center and app.doc.size is not None:
            H, W = app.doc.size
            if not (0 <= args.center[0] <= W and 0 <= args.center[1] <= H):
                raise PhyIRError(f"--center {args.center[0]:g},{args.center[1]:g}: outside the {W}x{H} "
                                 "panorama")
            eq.center = args.center
    if args.show:
        app.display.set_source(args.show == "truth")
    _apply_compare(app, args, wait)
    if args.exposure is not None:
        app.display.set_exposure(args.exposure)
    if args.tonemap:
        app.display.set_tonemap(args.tonemap)
    if args.channel:
        app.display.set_channel(args.channel)
    app.images.watch = bool(args.watch)
    if args.histogram and app.gui is not None:
        app.gui.side_panel.histogram_open = True
    if args.colormap:
        for name in app.display.scalar:
            app.display.set_colormap(args.colormap, name)
    if wait and app.doc.size is not None:  # (no size: the file failed to open, app.messages.error says why)
        H, W = app.doc.size
        for u, v in args.probe:
            if not (0 <= u < W and 0 <= v < H):
                raise PhyIRError(f"--probe {u:g},{v:g}: outside the {W}x{H} panorama "
                                 f"(columns 0..{W - 1}, rows 0..{H - 1})")
            app.pins.pin_probe(u, v)
    if wait:
        cli_objects.add_objects(app.objects, args.objects)
    elif args.objects:
        app.objects.queue(args.objects)


def _bench(app: App, args) -> int:
    """Frame times while the job runs, then of the idle view: the view pass alone, whole frames
    that redraw the view (exposure nudged each frame) and whole frames that reuse it (UI only)."""
    app.sync_parts = True  # each part waits for its GL work: the longest frame's parts say where it went
    ok = app.wait_idle(args.timeout)
    app.sync_parts = False
    if ok:
        apply_args(app, args, wait=True)  # the state asked for (layer, view, objects) is what is timed
    during, n_during, parts = app.loader.job_max_frame, app.loader.job_frames, app.loader.job_max_parts
    for _ in range(3):
        app.frame()
    ev = app.display.hdr.exposure
    redrawn = []
    for k in range(30):
        app.display.set_exposure(ev + 1e-3 * (k % 2))
        redrawn.append(app.frame())
    app.display.set_exposure(ev)
    app.frame()
    cached = sorted(app.frame() for _ in range(30))
    redrawn.sort()
    x, y, w, h = app.view_rect()
    passes = sorted(_time_view_pass(app) for _ in range(30))
    H, W = app.doc.size
    print(f"{app.doc.name}: view {w}x{h} px, panorama {W}x{H}, layer {app.display.layer}, "
          f"GL {app.ctx.info['GL_RENDERER']}")
    print(f"view pass alone: median {_median_ms(passes):.1f} ms, max {1000 * passes[-1]:.1f} ms")
    print(f"whole frame redrawing the view: median {_median_ms(redrawn):.1f} ms, "
          f"max {1000 * redrawn[-1]:.1f} ms")
    print(f"whole frame reusing the view (UI changes only): median {_median_ms(cached):.1f} ms, "
          f"max {1000 * cached[-1]:.1f} ms")
    print(f"while loading/inferring: longest frame {1000 * during:.1f} ms over {n_during} frames "
          f"(job {app.doc.timings.get('job', float('nan')):.1f} s: {_fmt_timings(app.doc.timings)})")
    print("  its parts, wall (UI-thread CPU) ms: " +
          ", ".join(f"{k} {1000 * w:.1f} ({1000 * c:.1f})" for k, (w, c) in parts.items()))
    if app.objects.objects:
        bench_drag(app)
    return 0 if ok else 2


def bench_drag(app: App, frames: int = 60, moves: bool = True) -> None:
    """Whole frames while the first inserted object is dragged to and fro over its surface, in the
    perspective view aimed at the objects (``--object ... --bench``), then the frames after release,
    then (``moves``) :func:`bench_moves`."""
    import numpy as np
    import torch

    from phyir import pano

    objs = app.objects.objects
    centre = np.mean([o.bounding_sphere()[0] for o in objs], axis=0)
    lon, lat = pano.dir_to_lonlat(torch.as_tensor(centre, dtype=torch.float64))
    app.camera.set_view("perspective")
    app.camera.views["perspective"].update(yaw=float(lon), pitch=float(lat))
    for _ in range(3):
        app.frame()
    _until_refined(app)  # the full-quality picture of the view before the drag, as a user sees it
    H, W = app.doc.size
    u, v, _ = pano.points_to_uv(torch.as_tensor(objs[0].bounding_sphere()[0]), H, W)
    view = app.camera.view
    x, y, front = view.uv_to_screen(np.array(float(u)), np.array(float(v)), app.view_size(), (H, W))
    if not (front and app.objects.begin_drag(float(x), float(y))):
        print("dragging: the first object is not under the mouse in the perspective view; skipped")
        return
    times = []
    for k in range(frames):
        t = 2 * math.pi * k / frames
        app.objects.drag_to(float(x) + 60 * math.sin(t), float(y) + 20 * (1 - math.cos(t)))
        times.append(app.frame())
    app.objects.end_drag()
    after, complete = _until_refined(app)
    times.sort()
    faces = sum(len(o.mesh.faces) for o in objs)
    print(f"dragging 1 of {len(objs)} objects ({faces} triangles), perspective view {app.view_size()[0]}x"
          f"{app.view_size()[1]}: {_frame_stats(times)}")
    slices = app.objects.hook.refinement.slices if app.objects.hook.progressive else []
    drew = ", ".join(f"{slices.count(k)} {k}" for k in dict.fromkeys(slices))
    drew = f"{len(slices)} slices: {drew}" if slices else "in one piece"
    print(f"after release: {len(after)} frames until the full-quality picture was complete, "
          f"{1000 * complete:.0f} ms after the release; the longest frame {1000 * max(after):.1f} ms, median "
          f"{_median_ms(sorted(after)):.1f} ms ({drew})")
    if moves:
        bench_moves(app, frames // 2)


def bench_moves(app: App, frames: int) -> None:
    """Whole frames while the camera turns (yaw to and fro by 10 degrees) and while the exposure is
    dragged (to and fro by 2 EV) with the objects in view: both redraw the objects every frame."""
    view = app.camera.views["perspective"]
    yaw, ev = view.yaw, app.display.hdr.exposure
    moves = {"turning the view": lambda t: view.update(yaw=yaw + math.radians(10) * math.sin(t)),
             "dragging the exposure": lambda t: app.display.set_exposure(ev + 2 * math.sin(t))}
    for name, move in moves.items():
        times = []
        for k in range(1, frames + 1):
            move(2 * math.pi * k / frames)
            times.append(app.frame())
        times.sort()
        print(f"{name} with the objects: {_frame_stats(times)}")
        _until_refined(app)


def _until_refined(app: App) -> tuple[list[float], float]:
    """Frames as the event loop draws them (``App.step``: one each 10 ms while refining) until the
    objects' full-quality picture is complete: (each frame's seconds, seconds until complete)."""
    t0, times = time.perf_counter(), []
    while True:
        times.append(app.frame())
        if not app.objects.refining():
            return times, time.perf_counter() - t0
        app.wait_events(0.01)


@gl_current
def _time_view_pass(app: App) -> float:
    target, spec = app.surface.target(), app.composer.frame_spec()
    fw, fh = app.surface.framebuffer_size
    app.ctx.finish()
    t0 = time.perf_counter()
    app.renderer.render(target, app.view_rect(), spec, fb_size=(fw, fh))
    app.ctx.finish()
    return time.perf_counter() - t0


def _frame_stats(times: list[float]) -> str:
    """Median, 95th percentile and maximum of sorted frame ``times`` (s), and their number."""
    p95 = 1000 * times[int(0.95 * (len(times) - 1))]
    return (f"median {_median_ms(times):.1f} ms, 95th percentile {p95:.1f} ms, max {1000 * times[-1]:.1f} ms "
            f"over {len(times)} frames")


def _median_ms(times: list[float]) -> float:
    """The median of sorted ``times`` (s), in milliseconds."""
    return 1000 * times[len(times) // 2]


def _fmt_timings(t: dict[str, float]) -> str:
    return ", ".join(f"{k} {v:.2f} s" for k, v in t.items() if k != "job")


def _demo_path() -> str:
    from phyir.synth import demo_scene_path

    return os.fspath(demo_scene_path())
