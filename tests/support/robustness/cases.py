# ruff: noqa: E501  (tables of cases: one case per entry reads better than wrapped)
"""The cases of the second robustness corpus (tests/support/robustness/corpus.py), one function per
class of issue 22.  None repeats a case of tests/robustness/ (those are the first corpus)."""

from __future__ import annotations

import signal
from pathlib import Path

from support.robustness import inputs as mk
from support.robustness.checks import (
    Case,
    both,
    chain,
    copy,
    fifo,
    interrupted,
    link,
    mkdir,
    no_nan_json,
    on_temporary,
    outputs_whole,
    same_info_as,
    sock,
    then,
    warned,
    write,
)

PRED = ["predict", "{b}/pano.hdr", "-o", "out.exr", "-q"]
EXPORT = ["export", "{b}/scene.exr", "--gltf", "o.glb"]
INSERT = ["insert", "{b}/scene.exr", "--object", "sphere", "--at", "64,40", "--quality", "draft"]
EVAL = ["eval", "{b}/pred", "--gt", "{b}/gt", "--relight", "0"]
SYNTH = ["synth", "--count", "1", "--size", "16x32", "--probe-grid", "4x8", "--probe-size", "4x8",
         "--spp", "1", "--quiet"]
TRAIN = ["train", "--size", "32x64", "--probe-grid", "4x8", "--max-steps", "1", "--batch-size", "2",
         "--workers", "0", "--no-val", "--no-progress", "--init", "scratch", "--no-cache"]
HDR_HEAD = "#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n"


def class1(b: Path) -> list[Case]:
    """Special files where a regular file is expected."""
    return [
        Case(1, "predict-weights-fifo", PRED + ["--weights", "w.safetensors"], names=("w.safetensors", "pipe"),
             setup=fifo("w.safetensors"), timeout=30),
        Case(1, "predict-weights-socket", PRED + ["--weights", "w.safetensors"], names=("w.safetensors", "socket"),
             setup=sock("w.safetensors")),
        Case(1, "predict-weights-folder", PRED + ["--weights", "w.safetensors"], names=("w.safetensors", "folder"),
             setup=mkdir("w.safetensors")),
        Case(1, "predict-weights-devzero-link", PRED + ["--weights", "z.safetensors"],
             names=("z.safetensors", "device"), setup=link("/dev/zero", "z.safetensors"), timeout=30),
        Case(1, "train-config-fifo", TRAIN + ["--data", "{b}/data", "--out", "run", "--config", "c.json"],
             names=("c.json", "pipe"), setup=fifo("c.json"), timeout=30),
        Case(1, "train-config-devzero-link", TRAIN + ["--data", "{b}/data", "--out", "run", "--config",
                                                      "z.json"], names=("z.json",),
             setup=link("/dev/zero", "z.json"), timeout=30),
        Case(1, "train-config-folder", TRAIN + ["--data", "{b}/data", "--out", "run", "--config", "c.toml"],
             names=("c.toml",), setup=mkdir("c.toml")),
        Case(1, "train-data-fifo", TRAIN + ["--data", "d", "--out", "run"], names=("d", "not a folder"), setup=fifo("d"),
             timeout=30),
        Case(1, "train-init-fifo", TRAIN[:-3] + ["--no-cache", "--data", "{b}/data", "--out", "run",
                                                  "--init", "i.safetensors"],
             names=("i.safetensors", "pipe"), setup=fifo("i.safetensors"), timeout=30),
        Case(1, "export-mesh-fifo", EXPORT + ["--object", "m.obj", "--at", "64,40"], names=("m.obj",),
             setup=fifo("m.obj"), timeout=30),
        Case(1, "export-scene-fifo", ["export", "s.exr", "--gltf", "o.glb"], names=("s.exr",),
             setup=fifo("s.exr"), timeout=30),
        Case(1, "export-exr-output-fifo", EXPORT + ["--exr", "f.exr"], names=("f.exr",), setup=fifo("f.exr"),
             timeout=30),
        Case(1, "export-glb-output-socket", ["export", "{b}/scene.exr", "--gltf", "s.glb"], names=("s.glb",),
             setup=sock("s.glb")),
        Case(1, "insert-mesh-socket", INSERT[:3] + ["m.obj"] + INSERT[4:] + ["-o", "o.png"],
             names=("m.obj",), setup=sock("m.obj"), gl=True),
        Case(1, "insert-out-fifo", INSERT + ["-o", "o.png"], names=("o.png",), setup=fifo("o.png"),
             gl=True, timeout=60),
        Case(1, "eval-gt-member-fifo", ["eval", "p", "--gt", "g", "--relight", "0"], names=("a.exr", "pipe"),
             setup=both(copy(b, "pred/a.exr", "p/a.exr"), fifo("g/a.exr")), timeout=30),
        Case(1, "eval-json-fifo", EVAL + ["--json", "r.json"], names=("r.json",), setup=fifo("r.json"),
             timeout=30),
        Case(1, "info-proc-status", ["info", "/proc/self/status"], names=("/proc/self/status",)),
        Case(1, "info-proc-mem", ["info", "/proc/self/mem"], names=("/proc/self/mem",)),
        Case(1, "predict-proc-cpuinfo", ["predict", "/proc/cpuinfo", "-o", "o.exr"], names=("/proc/cpuinfo",)),
        Case(1, "predict-folder-named-exr", ["predict", "x.exr", "-o", "o.exr"], names=("x.exr",),
             setup=mkdir("x.exr")),
        Case(1, "info-dev-stdin-pipe", ["info", "/dev/stdin"], names=("/dev/stdin",),
             stdin=mk.hdr(HDR_HEAD + "-Y 4 +X 8\n", bytes(128))),
        Case(1, "predict-folder-with-fifo-member", ["predict", "d", "-o", "out", "-q"], expect="ok",
             setup=both(copy(b, "pano.hdr", "d/a.hdr"), fifo("d/b.hdr")), timeout=60,
             check=lambda r: None if (r.folder / "out" / "a.exr").exists() else ("SILENT-NONSENSE", "no a.exr")),
        Case(1, "view-fifo", ["view", "f.hdr", "--headless", "--screenshot", "s.png", "--timeout", "20",
                              "--no-model"], names=("f.hdr",), setup=fifo("f.hdr"), gl=True, timeout=60),
    ]


def class2(b: Path) -> list[Case]:
    """Decoders fed headers that lie."""
    big_obj = b"v 0 0 0\n" * 600_000 + b"v 1 0 0\nv 0 1 0\nf 600001 600002 600003\n"
    ply = (b"ply\nformat ascii 1.0\nelement vertex 4000000000\nproperty float x\nproperty float y\n"
           b"property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
           b"0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")
    stl = b"\0" * 80 + (4_000_000).to_bytes(4, "little") + b"\0" * 200
    off = b"OFF\n3000000000 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"
    gradient = [[(x * 500, y * 1000, (x + y) * 300) for x in range(128)] for y in range(64)]
    rows16 = b"".join(b"\0" + b"".join(v.to_bytes(2, "big") for px in row for v in px) for row in gradient)
    g8 = [[(x * 2, y * 4, x + y) for x in range(128)] for y in range(64)]
    rows8 = b"".join(b"\0" + bytes(v for px in row for v in px) for row in g8)
    attrs = mk.exr_many_attributes(1)
    pos = attrs.index(b"x0\0string\0") + len(b"x0\0string\0")
    attr_huge = attrs[:pos] + (0x7FFFFFFF).to_bytes(4, "little") + attrs[pos + 4:]
    return [
        Case(2, "hdr-1e8x2e8-truncated", ["info", "h.hdr"], names=("h.hdr",),
             setup=write(**{"h.hdr": mk.hdr(HDR_HEAD + "-Y 100000000 +X 200000000\n", b"\x02\x02")})),
        Case(2, "hdr-4096x8192-truncated", ["info", "h.hdr"], names=("h.hdr",),
             setup=write(**{"h.hdr": mk.hdr(HDR_HEAD + "-Y 4096 +X 8192\n", b"\x02\x02\x20\x00" * 25)})),
        Case(2, "hdr-2048x4096-half-body", ["info", "h.hdr"], names=("h.hdr",),
             setup=write(**{"h.hdr": mk.hdr(HDR_HEAD + "-Y 2048 +X 4096\n", b"\x80\x80\x80\x81" * 1_000_000)})),
        Case(2, "hdr-axes-swapped", ["info", "h.hdr"], expect="either", names=("h.hdr",),
             setup=lambda w: (w / "h.hdr").write_bytes(
                 (b / "pano.hdr").read_bytes().replace(b"-Y 64 +X 128", b"+X 128 -Y 64"))),
        Case(2, "hdr-flipped-y", ["info", "h.hdr"], expect="either", names=("h.hdr",),
             setup=lambda w: (w / "h.hdr").write_bytes(
                 (b / "pano.hdr").read_bytes().replace(b"-Y 64 +X 128", b"+Y 64 +X 128"))),
        Case(2, "hdr-negative-size", ["info", "h.hdr"], names=("h.hdr",),
             setup=write(**{"h.hdr": mk.hdr(HDR_HEAD + "-Y -64 +X 128\n", bytes(100))})),
        Case(2, "hdr-4mb-header-line", ["info", "h.hdr"], names=("h.hdr",),
             setup=write(**{"h.hdr": b"#?RADIANCE\n" + b"A" * 4_000_000})),
        Case(2, "hdr-1m-header-lines", ["info", "h.hdr"], names=("h.hdr",),
             setup=write(**{"h.hdr": b"#?RADIANCE\n" + b"X=1\n" * 1_000_000})),
        Case(2, "png-iccp-100mb", ["info", "p.png"], expect="either", names=("p.png",),
             setup=write(**{"p.png": lambda: mk.png(128, 64, extra=mk.iccp_bomb(100 << 20))})),
        Case(2, "png16-ztxt-200mb", ["info", "p.png"], expect="either", names=("p.png",),
             setup=write(**{"p.png": lambda: mk.png(128, 64, 16, extra=mk.ztxt_bomb(200 << 20))})),
        Case(2, "png16-interlaced", ["info", "p.png"], expect="either", names=("p.png",),
             setup=write(**{"p.png": mk.png_adam7(gradient, 16), "twin.png": mk.png(128, 64, 16, rows=rows16)}),
             check=same_info_as("twin.png", "p.png")),
        Case(2, "png8-interlaced", ["info", "p.png"], expect="either", names=("p.png",),
             setup=write(**{"p.png": mk.png_adam7(g8, 8), "twin.png": mk.png(128, 64, 8, rows=rows8)}),
             check=same_info_as("twin.png", "p.png")),
        Case(2, "png16-palette", ["info", "p.png"], names=("p.png",),
             setup=write(**{"p.png": mk.png(128, 64, 16, 3, rows=(b"\0" + bytes(256)) * 64)})),
        Case(2, "png-ihdr-2g", ["info", "p.png"], names=("p.png",),
             setup=write(**{"p.png": mk.png(2**31 - 1, 2**30, idat=mk.png_chunk(b"IDAT", b"x"))})),
        Case(2, "png-300k-empty-idat", ["info", "p.png"], expect="either", names=("p.png",),
             setup=write(**{"p.png": mk.png(128, 64, idat=mk.png_chunk(b"IDAT", b"") * 300_000)})),
        Case(2, "png-no-idat", ["info", "p.png"], names=("p.png",),
             setup=write(**{"p.png": mk.png(128, 64, idat=b"")})),
        Case(2, "jpeg-sof-65500", ["info", "j.jpg"], names=("j.jpg",),
             setup=write(**{"j.jpg": mk.jpeg_sof(65500, 65500)})),
        Case(2, "jpeg-sof-16384x8192", ["info", "j.jpg"], names=("j.jpg",),
             setup=write(**{"j.jpg": mk.jpeg_sof(16384, 8192, bytes(1000))})),
        Case(2, "jpeg-sof-zero", ["info", "j.jpg"], names=("j.jpg",), setup=write(**{"j.jpg": mk.jpeg_sof(0, 0)})),
        Case(2, "exr-100k-attributes", ["info", "e.exr"], expect="either", names=("e.exr",),
             setup=write(**{"e.exr": lambda: mk.exr_many_attributes(100_000)})),
        Case(2, "exr-attribute-size-2g", ["info", "e.exr"], names=("e.exr",), setup=write(**{"e.exr": attr_huge})),
        Case(2, "exr-many-attributes-predict", ["predict", "e.exr", "-o", "o.exr"], names=("e.exr",),
             setup=write(**{"e.exr": lambda: mk.exr_many_attributes(20_000)})),
        Case(2, "obj-600k-vertices-1-face", EXPORT + ["--object", "m.obj", "--at", "64,40"], expect="either",
             names=("m.obj",), setup=write(**{"m.obj": big_obj}), timeout=120),
        Case(2, "ply-ascii-4g-vertices", EXPORT + ["--object", "m.ply", "--at", "64,40"], names=("m.ply",),
             setup=write(**{"m.ply": ply})),
        Case(2, "stl-claims-4m-faces", EXPORT + ["--object", "m.stl", "--at", "64,40"], names=("m.stl",),
             setup=write(**{"m.stl": stl})),
        Case(2, "off-3g-vertices", EXPORT + ["--object", "m.off", "--at", "64,40"], names=("m.off",),
             setup=write(**{"m.off": off})),
        Case(2, "glb-buffer-1tb", EXPORT + ["--object", "m.glb", "--at", "64,40"], names=("m.glb",),
             setup=write(**{"m.glb": mk.glb_triangle(1 << 40)})),
        Case(2, "glb-buffer-2gb", EXPORT + ["--object", "m.glb", "--at", "64,40"], names=("m.glb",),
             setup=write(**{"m.glb": mk.glb_triangle(2**31 - 4)})),
        Case(2, "obj-face-index-huge", EXPORT + ["--object", "m.obj", "--at", "64,40"], names=("m.obj",),
             setup=write(**{"m.obj": b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 999999999999\nf -99999999 1 2\n"})),
    ]


def class3(b: Path) -> list[Case]:
    """Output paths that can't be written."""
    long = "a" * 300
    return [
        Case(3, "insert-out-existing-folder", INSERT + ["-o", "o.png"], names=("o.png",), setup=mkdir("o.png"),
             gl=True),
        Case(3, "export-glb-existing-folder", EXPORT[:-1] + ["o.glb"], names=("o.glb",), setup=mkdir("o.glb")),
        Case(3, "export-exr-existing-folder", EXPORT + ["--exr", "e.exr"], names=("e.exr",),
             setup=mkdir("e.exr"), check=outputs_whole("o.glb", "e.exr")),
        Case(3, "eval-json-existing-folder", EVAL + ["--json", "r.json"], names=("r.json",), setup=mkdir("r.json")),
        Case(3, "eval-markdown-existing-folder", EVAL + ["--json", "r.json", "--markdown", "r.md"],
             names=("r.md",), setup=mkdir("r.md"), check=outputs_whole("r.json")),
        Case(3, "synth-out-existing-file", SYNTH + ["--out", "d"], names=("d",), setup=write(d="x")),
        Case(3, "bench-out-existing-file", ["bench", "modules", "--quick", "-o", "d"], names=("d",),
             setup=write(d="x")),
        Case(3, "predict-name-too-long", PRED[:3] + [long + ".exr"], names=(long,)),
        Case(3, "predict-folder-name-too-long", ["predict", "{b}/pano.hdr", "-o", long, "-q"], names=(long,)),
        Case(3, "insert-name-too-long", INSERT + ["-o", long + ".png"], names=(long,), gl=True),
        Case(3, "export-name-too-long", EXPORT[:-1] + [long + ".glb"], names=(long,)),
        Case(3, "eval-json-too-long", EVAL + ["--json", long + ".json"], names=(long,)),
        Case(3, "synth-out-too-long", SYNTH + ["--out", long], names=(long,)),
        Case(3, "train-out-too-long", TRAIN + ["--data", "{b}/data", "--out", long], names=(long,)),
        Case(3, "export-glb-on-proc", EXPORT[:-1] + ["/proc/phyir.glb"], names=("/proc/phyir",)),
        Case(3, "eval-json-on-proc", EVAL + ["--json", "/proc/self/phyir.json"], names=("/proc/self/phyir.json",)),
        Case(3, "synth-out-on-proc", SYNTH + ["--out", "/proc/phyir-d"], names=("/proc/phyir-d",)),
        Case(3, "train-out-on-proc", TRAIN + ["--data", "{b}/data", "--out", "/proc/phyir-run"],
             names=("/proc/phyir-run",)),
        Case(3, "insert-out-on-proc", INSERT + ["-o", "/proc/phyir.png"], names=("/proc/phyir.png",), gl=True),
        Case(3, "export-under-a-file", EXPORT[:-1] + ["f.txt/o.glb"], names=("f.txt",), setup=write(**{"f.txt": "x"})),
        Case(3, "insert-under-a-file", INSERT + ["-o", "f.txt/o.png"], names=("f.txt",),
             setup=write(**{"f.txt": "x"}), gl=True),
        Case(3, "export-fsize-100k", EXPORT, names=("o",), fsize=100_000,
             check=outputs_whole("o.glb", "o_env.exr")),
        Case(3, "insert-fsize-20k", INSERT + ["-o", "o.exr"], names=("o.",), fsize=20_000, gl=True,
             check=outputs_whole("o.exr", "o.png")),
        Case(3, "insert-path-fsize-20k", INSERT[:4] + ["--path", "20,45:100,45", "--frames", "4", "--quality",
                                                       "draft", "-o", "a.png"], names=("a",), fsize=3_000,
             gl=True, check=outputs_whole("a.gif")),
        Case(3, "synth-fsize-2k", SYNTH + ["--out", "d"], names=("d",), fsize=2_000),
        Case(3, "train-fsize-1m", TRAIN + ["--data", "{b}/data", "--out", "run"], names=("run",),
             fsize=1_000_000, timeout=120),
        Case(3, "eval-fsize-100", EVAL + ["--json", "r.json", "--markdown", "r.md"], names=("r.",), fsize=100,
             check=outputs_whole("r.json", "r.md")),
        Case(3, "insert-out-is-the-input", ["insert", "s.exr"] + INSERT[2:] + ["-o", "s.exr"], names=("s.exr",),
             setup=copy(b, "scene.exr", "s.exr"), gl=True),
        Case(3, "export-exr-is-the-glb", EXPORT + ["--exr", "o.glb"], names=("o.glb",)),
        Case(3, "eval-json-and-markdown-same", EVAL + ["--json", "r.txt", "--markdown", "r.txt"], names=("r.txt",)),
        Case(3, "predict-out-empty-string", ["predict", "{b}/pano.hdr", "-o", "", "-q"], names=("-o",)),
    ]


def class4(b: Path) -> list[Case]:
    """Signals in the middle of writing."""
    big = ["export", "{b}/big_scene.exr", "--gltf", "o.glb"]
    return [
        Case(4, "export-sigterm-mid-write", big, expect="signal", trigger=on_temporary(signal.SIGTERM),
             check=chain(interrupted, outputs_whole("o.glb", "o_env.exr"))),
        Case(4, "export-sigint-mid-write", big, expect="signal", trigger=on_temporary(signal.SIGINT),
             check=chain(interrupted, outputs_whole("o.glb", "o_env.exr"))),
        Case(4, "export-sighup-mid-write", big, expect="signal", trigger=on_temporary(signal.SIGHUP),
             check=chain(interrupted, outputs_whole("o.glb", "o_env.exr"))),
        Case(4, "eval-sigint-after-tables", EVAL + ["--json", "r.json", "--markdown", "r.md"], expect="signal",
             trigger=on_temporary(signal.SIGINT, "stdout"),
             check=chain(interrupted, outputs_whole("r.json", "r.md"))),
        Case(4, "eval-sighup-after-tables", EVAL + ["--json", "r.json", "--markdown", "r.md"], expect="signal",
             trigger=on_temporary(signal.SIGHUP, "stdout"),
             check=chain(interrupted, outputs_whole("r.json", "r.md"))),
        Case(4, "synth-sigterm-then-resume", ["synth", "--out", "d", "--count", "4", "--size", "32x64",
                                              "--probe-grid", "4x8", "--probe-size", "4x8", "--spp", "1",
                                              "--quiet"], expect="signal",
             trigger=on_temporary(signal.SIGTERM, "d"),
             check=chain(interrupted, then(SYNTH[:1] + ["--out", "d", "--count", "4", "--size", "32x64",
                                                        "--probe-grid", "4x8", "--probe-size", "4x8", "--spp",
                                                        "1", "--quiet"]),
                         then(["predict", "d", "-o", "p", "-q"]))),
        Case(4, "synth-sighup", ["synth", "--out", "d", "--count", "3", "--size", "32x64", "--probe-grid",
                                 "4x8", "--probe-size", "4x8", "--spp", "1", "--quiet"], expect="signal",
             trigger=on_temporary(signal.SIGHUP, "d")),
        Case(4, "predict-sighup-mid-write", ["predict", "{b}/big_scene.exr", "-o", "o.exr", "-q"],
             expect="signal", trigger=on_temporary(signal.SIGHUP), check=chain(interrupted, outputs_whole("o.exr"))),
        Case(4, "insert-path-sigint", INSERT[:4] + ["--path", "20,45:100,45", "--frames", "12", "--quality",
                                                    "draft", "-o", "a.png"], expect="signal", gl=True,
             trigger=on_temporary(signal.SIGINT), check=chain(interrupted, outputs_whole("a.gif"))),
        Case(4, "train-sigterm-mid-checkpoint", TRAIN[:5] + ["--max-steps", "40", "--batch-size", "2", "--workers",
                                                           "0", "--no-val", "--no-progress", "--init", "scratch",
                                                           "--no-cache", "--ckpt-every", "1", "--data", "{b}/data",
                                                           "--out", "run"], expect="signal", timeout=180,
             trigger=on_temporary(signal.SIGTERM, ""),
             check=chain(interrupted, then(TRAIN[:5] + ["--max-steps", "2", "--batch-size", "2", "--workers",
                                                        "0", "--no-val", "--no-progress", "--init", "scratch",
                                                        "--no-cache", "--ckpt-every", "1", "--data",
                                                        "{b}/data".replace("{b}", str(b)), "--out", "run"]))),
        Case(4, "info-stdout-closed", ["info", "{b}/scene.exr", "{b}/pano.hdr", "{b}/pano.png"], expect="either",
             close_stdout=True),
        Case(4, "eval-stdout-closed", EVAL, expect="either", close_stdout=True),
    ]


def class5(b: Path) -> list[Case]:
    """Inputs that carry no information: the command must say so."""
    degenerate = b"v 0 0 0\nv 0 0 0\nv 0 0 0\nf 1 2 3\n"
    huge = b"v -1e6 0 -1e6\nv 1e6 0 -1e6\nv 0 1e6 1e6\nv 0 0 1e6\nf 1 2 3\nf 1 3 4\nf 2 3 4\nf 1 2 4\n"
    cases = [Case(5, f"predict-{name}", ["predict", f"{{b}}/{name}", "-o", "o.exr", "-q"], expect="either",
                  names=(name,), check=warned)
             for name in ("nan.exr", "inf.exr", "negative.exr", "spike.exr", "black.exr", "white.png",
                          "black16.png")]
    return cases + [
        Case(5, "insert-nan-probes", ["insert", "{b}/nan_probes.exr"] + INSERT[2:] + ["-o", "o.png"],
             expect="either", names=("nan_probes.exr",), gl=True, check=warned),
        Case(5, "insert-negative-depth", ["insert", "{b}/neg_depth.exr"] + INSERT[2:] + ["-o", "o.png"],
             expect="either", names=("neg_depth.exr",), gl=True, check=warned),
        Case(5, "export-nan-probes", ["export", "{b}/nan_probes.exr", "--gltf", "o.glb"], expect="either",
             names=("nan_probes.exr",), check=chain(no_nan_json("o.glb"), warned)),
        Case(5, "export-negative-depth", ["export", "{b}/neg_depth.exr", "--gltf", "o.glb"], expect="either",
             names=("neg_depth.exr",), check=chain(no_nan_json("o.glb"), warned)),
        Case(5, "export-zero-depth", ["export", "{b}/zero_depth.exr", "--gltf", "o.glb"], expect="either",
             names=("zero_depth.exr",), check=chain(no_nan_json("o.glb"), warned)),
        Case(5, "export-nan-depth", ["export", "{b}/nan_depth.exr", "--gltf", "o.glb"], expect="either",
             names=("nan_depth.exr",), check=chain(no_nan_json("o.glb"), warned)),
        Case(5, "export-object-1e300-away", EXPORT + ["--object", "sphere", "--position", "1e300,0,0"],
             names=("--position",), check=no_nan_json("o.glb")),
        Case(5, "export-camera-inside-object", EXPORT + ["--object", "sphere", "--position", "0,0,0",
                                                         "--scale", "5"], names=("--position",)),
        Case(5, "export-degenerate-mesh", EXPORT + ["--object", "m.obj", "--at", "64,40"], names=("m.obj",),
             setup=write(**{"m.obj": degenerate}), check=no_nan_json("o.glb")),
        Case(5, "export-mesh-1e6-m", EXPORT + ["--object", "m.obj", "--at", "64,40"], expect="either",
             names=("m.obj",), setup=write(**{"m.obj": huge}), check=warned),
        Case(5, "insert-degenerate-mesh", INSERT[:3] + ["m.obj"] + INSERT[4:] + ["-o", "o.png"], names=("m.obj",),
             setup=write(**{"m.obj": degenerate}), gl=True),
        Case(5, "insert-mesh-1e6-m", INSERT[:3] + ["m.obj"] + INSERT[4:] + ["-o", "o.png"], expect="either",
             names=("m.obj",), setup=write(**{"m.obj": huge}), gl=True, check=warned),
        Case(5, "export-material-2", EXPORT + ["--object", "sphere", "--at", "64,40", "--material", "2,2,2,2,2"],
             names=("--material",)),
        Case(5, "export-material-nan", EXPORT + ["--object", "sphere", "--at", "64,40", "--material",
                                                 "nan,0.5,0.5,0.5,0.5"], names=("--material",)),
        Case(5, "eval-nan-depth-prediction", ["eval", "p", "--gt", "{b}/gt", "--relight", "0", "--json", "r.json"],
             expect="either", names=("a.exr",), setup=copy(b, "nan_depth.exr", "p/a.exr"),
             check=chain(no_nan_json("r.json"), warned)),
        Case(5, "predict-outputs-empty", ["predict", "{b}/pano.hdr", "-o", "o.exr", "--outputs", " , "],
             names=("--outputs",)),
    ]
