# ruff: noqa: E501  (tables of cases: one case per entry reads better than wrapped)
"""Cases of the second robustness corpus, classes 6-9: weights files, numeric options, training
inputs, messages (tests/support/robustness/corpus.py)."""

from __future__ import annotations

import json
import re
from pathlib import Path

from support.robustness import inputs as mk
from support.robustness.cases import (
    EXPORT,
    INSERT,
    PRED,
    SYNTH,
    TRAIN,
    class1,
    class2,
    class3,
    class4,
    class5,
)
from support.robustness.checks import (
    SIZES,
    VALUES,
    WEIGHTS,
    Case,
    both,
    copy,
    fifo,
    link,
    mkdir,
    named,
    python_warning_format,
    warned,
    write,
)


def _weights(name: str, data_fn):
    def setup(w: Path) -> None:
        (w / name).write_bytes(data_fn())
    return setup


def class6(b: Path) -> list[Case]:
    """Weights files: sidecars and metadata that are not what they claim."""
    w = ["--weights", "w.safetensors"]
    sidecar = lambda text: both(link(str(WEIGHTS), "w.safetensors"), write(**{"w.json": text}))  # noqa: E731
    deep = "[" * 100_000 + "]" * 100_000
    dup = lambda t: t.replace('{"', '{"lnet.head.0.bias": ' + json.dumps(json.loads(t)["lnet.head.0.bias"])  # noqa: E731
                              + ', "', 1) if "lnet.head.0.bias" in t else t
    return [
        Case(6, "sidecar-huge-number", PRED + w, expect="either", names=("w.json",), setup=sidecar("1e999999"),
             check=python_warning_format),
        Case(6, "sidecar-a-list", PRED + w, expect="either", names=("w.json",), setup=sidecar("[1, 2, 3]"),
             check=python_warning_format),
        Case(6, "sidecar-deep-nesting", PRED + w, expect="either", names=("w.json",), setup=sidecar(deep),
             check=python_warning_format),
        Case(6, "sidecar-resolution-list", PRED + w, expect="either", names=("w.json",),
             setup=sidecar('{"data": {"resolution": [64, 128]}}'), check=python_warning_format),
        Case(6, "sidecar-fifo", PRED + w, expect="either", names=("w.json",), timeout=40,
             setup=both(link(str(WEIGHTS), "w.safetensors"), fifo("w.json"))),
        Case(6, "sidecar-devzero", PRED + w, expect="either", names=("w.json",), timeout=40,
             setup=both(link(str(WEIGHTS), "w.safetensors"), link("/dev/zero", "w.json"))),
        Case(6, "sidecar-binary", PRED + w, expect="either", names=("w.json",), setup=sidecar(b"\xff\xfe\x00garbage"),
             check=python_warning_format),
        Case(6, "metadata-config-deep-nesting", PRED + w, names=("w.safetensors",),
             setup=_weights("w.safetensors", lambda: mk.safetensors_with(WEIGHTS, {"phyir.config": deep}))),
        Case(6, "metadata-config-4mb-string", PRED + w, names=("w.safetensors",),
             setup=_weights("w.safetensors", lambda: mk.safetensors_with(
                 WEIGHTS, {"phyir.config": json.dumps("x" * 4_000_000)}))),
        Case(6, "metadata-unicode-key", PRED + w, names=("w.safetensors",),
             setup=_weights("w.safetensors", lambda: mk.safetensors_with(
                 WEIGHTS, {"phyir.config": json.dumps({"\u540d\u524d\u202e": 1, "size": "lite"})}))),
        Case(6, "metadata-format-with-bidi", PRED + w, names=("w.safetensors",),
             setup=_weights("w.safetensors", lambda: mk.safetensors_with(
                 WEIGHTS, {"format": "phyir-weights-1\u202e\n"}))),
        Case(6, "tensors-duplicate-names", PRED + w, expect="either", names=("w.safetensors",),
             setup=_weights("w.safetensors", lambda: mk.safetensors_with(WEIGHTS, header_edit=dup))),
        Case(6, "tensor-dtype-f8", PRED + w, names=("w.safetensors",),
             setup=_weights("w.safetensors", lambda: mk.safetensors_with(
                 WEIGHTS, header_edit=lambda t: re.sub(r'"dtype": ?"[A-Z0-9]+"', '"dtype": "F8_E4M3"', t, count=1)))),
        Case(6, "tensor-offsets-overlap", PRED + w, names=("w.safetensors",),
             setup=_weights("w.safetensors", lambda: mk.safetensors_with(
                 WEIGHTS, header_edit=lambda t: t.replace('"data_offsets": [0, ', '"data_offsets": [4, ', 1)))),
        Case(6, "weights-a-scene-file", PRED + ["--weights", "{b}/scene.exr"], names=("scene.exr",)),
        Case(6, "weights-a-checkpoint", PRED + ["--weights", "{b}/run/gm/checkpoint.pt"], names=("checkpoint.pt",)),
        Case(6, "insert-weights-fifo", ["insert", "{b}/pano.hdr"] + INSERT[2:] + ["-o", "o.png", "--weights",
                                                                                 "f.safetensors"],
             names=("f.safetensors",), setup=fifo("f.safetensors"), gl=True, timeout=40),
        Case(6, "export-weights-truncated", ["export", "{b}/pano.hdr", "--gltf", "o.glb", "--weights", "t.safetensors"],
             names=("t.safetensors",), setup=_weights("t.safetensors", lambda: WEIGHTS.read_bytes()[:100_000])),
    ]


def _option_cases(cls: int, tag: str, argv: list[str], option: str, values, gl: bool = False) -> list[Case]:
    return [Case(cls, f"{tag}{option}={v!r}", argv + [f"{option}={v}"], expect="either", names=(option,), gl=gl)
            for v in values]


def class7(b: Path) -> list[Case]:
    """Numbers and sizes in every spelling, on the options not parsed by phyir.commands.options."""
    out = []
    out += _option_cases(7, "export", EXPORT, "--lights", VALUES)
    out += _option_cases(7, "export", EXPORT, "--fov", VALUES)
    out += _option_cases(7, "export", EXPORT + ["--object", "sphere", "--at", "64,40"], "--scale", VALUES[:4])
    out += _option_cases(7, "export", EXPORT, "--grid", SIZES)
    out += _option_cases(7, "export", EXPORT + ["--object", "sphere"], "--at", ("1,2,3", "1e400,2", "64", ""))
    out += _option_cases(7, "synth", SYNTH[:3] + SYNTH[5:] + ["--out", "d", "--probe-grid", "none"], "--size",
                         SIZES[:6] + ("٣٢x٦٤",))
    out += _option_cases(7, "synth", SYNTH + ["--out", "d"], "--shard", ("1/0", "0/-1", "2/2", "0/1e400", "٠/١", "/"))
    out += [Case(7, "synth--count=1e12", ["synth", "--out", "d", "--count", "1000000000000", "--size", "16x32",
                                          "--probe-grid", "4x8", "--probe-size", "4x8", "--spp", "1", "--quiet"],
                 expect="either", names=("--count",), timeout=60)]
    out += _option_cases(7, "train", TRAIN + ["--data", "{b}/data", "--out", "run"], "--size", SIZES[:6])
    out += _option_cases(7, "train", TRAIN + ["--data", "{b}/data", "--out", "run"], "--probe-grid",
                         ("4X8", "4x", "-4x-8", "1e400x8"))
    out += _option_cases(7, "predict", PRED, "--net-size", SIZES[:6] + (" 64 x 128 ",))
    out += _option_cases(7, "insert", INSERT + ["-o", "o.png"], "--size", ("64X32", "64x", "-64x-32", " 64x32"),
                         gl=True)
    out += [Case(7, "insert--path-10000-points", INSERT[:4] + ["--path", ":".join(f"{20 + i % 80},{45}"
                                                                                 for i in range(10_000)),
                                                              "--frames", "3", "--quality", "draft", "-o", "a.png"],
                 expect="either", names=("--path",), gl=True, timeout=120)]
    for opt in ("--fov", "--zoom", "--exposure", "--timeout", "--threads", "--yaw"):
        out += _option_cases(7, "view", ["view", "{b}/scene.exr", "--headless", "--screenshot", "s.png",
                                         "--no-model", "--size", "320x200"], opt, ("1e400", "nan", "-0"), gl=True)
    out += _option_cases(7, "view", ["view", "{b}/scene.exr", "--headless", "--screenshot", "s.png",
                                     "--no-model"], "--size", ("0x0", "64X", "100000x100000"), gl=True)
    return out


def class8(b: Path) -> list[Case]:
    """Training from data, checkpoints and configs that are not what they claim."""
    t = TRAIN + ["--out", "run"]
    td = t + ["--data", "{b}/data"]
    manifest = lambda splits: json.dumps({"splits": splits})  # noqa: E731
    return [
        Case(8, "data-empty-folder", t + ["--data", "e"], names=("e",), setup=mkdir("e")),
        Case(8, "data-non-scenes", t + ["--data", "d"], names=("a.exr",),
             setup=write(**{"d__a.exr": "hello", "d__b.exr": "world",
                            "d__manifest.json": manifest({"train": ["a.exr"], "val": ["b.exr"], "test": []})})),
        Case(8, "data-only-temporaries", t + ["--data", "d"], names=("d",),
             setup=write(**{"d__.a.exr.123-deadbeef.phyir.tmp": "x",
                            "d__manifest.json": manifest({"train": ["a.exr"], "val": [], "test": []})})),
        Case(8, "data-manifest-traversal", t + ["--data", "d"], names=("passwd",),
             setup=write(**{"d__manifest.json": manifest({"train": ["../../../../../../etc/passwd"], "val": [],
                                                          "test": []})})),
        Case(8, "data-manifest-string-split", t + ["--data", "d"], names=("manifest",),
             setup=both(copy(b, "data", "d"), write(**{"d__manifest.json": manifest(
                 {"train": "scene_000000.exr", "val": [], "test": []})}))),
        Case(8, "data-manifest-a-list", t + ["--data", "d"], names=("manifest.json",),
             setup=both(copy(b, "data", "d"), write(**{"d__manifest.json": "[]"}))),
        Case(8, "data-member-fifo", t + ["--data", "d"], expect="either", names=("scene_000000.exr",),
             timeout=60, check=warned,
             setup=both(copy(b, "data", "d"), lambda w: (w / "d" / "scene_000000.exr").unlink(),
                        fifo("d/scene_000000.exr"))),
        Case(8, "workers-64", td[:td.index("--workers")] + td[td.index("--workers") + 2:] + ["--workers", "64"],
             expect="either", names=("--workers",), timeout=240),
        Case(8, "batch-larger-than-data", td[:td.index("--batch-size")] + td[td.index("--batch-size") + 2:]
             + ["--batch-size", "64"], expect="either", names=("batch",), check=warned, timeout=120),
        Case(8, "resume-truncated-checkpoint", td, names=("checkpoint.pt",),
             setup=both(copy(b, "run", "run"), lambda w: _truncate(w / "run" / "gm" / "checkpoint.pt", 1_000_000))),
        Case(8, "resume-garbage-checkpoint", td, names=("checkpoint.pt",),
             setup=both(copy(b, "run", "run"), write(**{"run__gm__checkpoint.pt": b"PK\x03\x04" + bytes(5000)}))),
        Case(8, "resume-other-architecture", td + ["--model", "full"], names=("checkpoint.pt",),
             setup=copy(b, "run", "run"), timeout=120),
        Case(8, "resume-checkpoint-a-folder", td, names=("checkpoint.pt",),
             setup=both(mkdir("run/gm/checkpoint.pt"))),
        Case(8, "config-unknown-key", td + ["--config", "c.json"], names=("learning_rate",),
             setup=write(**{"c.json": '{"learning_rate": 0.1}'})),
        Case(8, "config-a-list", td + ["--config", "c.json"], names=("c.json",), setup=write(**{"c.json": "[1]"})),
        Case(8, "config-a-number", td + ["--config", "c.json"], names=("c.json",), setup=write(**{"c.json": "5"})),
        Case(8, "config-wrong-types", td + ["--config", "c.json"], names=("--schedule",),
             setup=write(**{"c.json": '{"schedule": ["cosine"]}'})),
        Case(8, "config-loss-not-a-table", td + ["--config", "c.json"], names=("loss",),
             setup=write(**{"c.json": '{"loss": 5}'})),
        Case(8, "config-train-only-a-string", td + ["--config", "c.json"], names=("train",),
             setup=write(**{"c.json": '{"train_only": "gmnet"}'})),
        Case(8, "config-data-a-number", TRAIN + ["--out", "run", "--config", "c.json"], names=("data",),
             setup=write(**{"c.json": '{"data": 5}'})),
        Case(8, "config-toml-syntax", td + ["--config", "c.toml"], names=("c.toml",),
             setup=write(**{"c.toml": "lr = \n[["})),
        Case(8, "config-utf8-bom", td + ["--config", "c.json"], expect="either", names=("c.json",),
             setup=write(**{"c.json": b"\xef\xbb\xbf{\"seed\": 1}"}), timeout=120),
        Case(8, "config-deep-nesting", td + ["--config", "c.json"], names=("c.json",),
             setup=write(**{"c.json": "[" * 100_000 + "]" * 100_000})),
        Case(8, "config-yaml", td + ["--config", "c.yaml"], names=("c.yaml",), setup=write(**{"c.yaml": "lr: 1\n"})),
        Case(8, "init-a-scene-file", TRAIN[:-3] + ["--no-cache", "--out", "run", "--data", "{b}/data", "--init",
                                                   "{b}/scene.exr"], names=("scene.exr",)),
        Case(8, "init-a-folder", TRAIN[:-3] + ["--no-cache", "--out", "run", "--data", "{b}/data", "--init", "i"],
             names=("i", "folder"), setup=mkdir("i")),
        Case(8, "train-only-nothing", td + ["--train-only", "no.such.module"], names=("no.such.module",)),
        Case(8, "reinit-nothing", td + ["--reinit", "no.such.module"], names=("no.such.module",)),
        Case(8, "loss-unknown-key", td + ["--loss", "unknown_term=1"], names=("unknown_term",)),
    ]


def _truncate(p: Path, n: int) -> None:
    with open(p, "r+b") as f:
        f.truncate(n)


def class9(b: Path) -> list[Case]:
    """What the messages say about odd file names and values."""
    junk = b"not an image at all"
    cases = []
    for tag, name in (("spaces-quotes", "a \"b\" 'c'.hdr"), ("unicode", "pano_\u00fc_\u65e5\u672c.hdr"),
                      ("line-separator", "a\u2028b.hdr"), ("bidi-override", "evil\u202egpj.hdr"),
                      ("carriage-return", "a\rb.hdr"), ("very-long", "n" * 250 + ".hdr"),
                      ("zero-width", "a\u200bb\ufeff.hdr")):
        shown = re.sub("[\r\u2028\u202e\u200b\ufeff]", lambda m: repr(m.group())[1:-1], name)
        cases.append(Case(9, f"info-name-{tag}", ["info", name], names=(shown,), setup=named(name, junk)))
    return cases + [
        Case(9, "info-name-starting-with-dash", ["info", "--", "-x.hdr"], names=("-x.hdr",),
             setup=named("-x.hdr", junk)),
        Case(9, "info-dash-name-without-separator", ["info", "-x.hdr"], names=("FILE",),
             setup=named("-x.hdr", junk)),
        Case(9, "info-empty-name", ["info", ""], names=("''",)),
        Case(9, "predict-weights-esc-name", PRED + ["--weights", "\x1b[2J.safetensors"], names=("\\x1b[2J",)),
        Case(9, "export-mesh-esc-name", EXPORT + ["--object", "m\x1b[31m.obj", "--at", "64,40"],
             names=("m\\x1b[31m.obj",), setup=named("m\x1b[31m.obj", b"garbage")),
        Case(9, "train-data-newline-name", TRAIN + ["--out", "run", "--data", "d\nx"], names=("d\\nx",)),
        Case(9, "eval-gt-newline-name", ["eval", "{b}/pred", "--gt", "g\ny", "--relight", "0"], names=("g\\ny",)),
        Case(9, "predict-device-bogus", PRED + ["--device", "bogus"], names=("--device",)),
        Case(9, "predict-device-meta", PRED + ["--device", "meta"], names=("--device",)),
        Case(9, "predict-device-esc", PRED + ["--device", "\x1b[2J"], names=("--device",)),
        Case(9, "eval-device-bogus", ["eval", "--data", "{b}/data", "--split", "val", "--relight", "0",
                                      "--device", "bogus"], names=("--device",)),
        Case(9, "bench-device-bogus-cuda", ["bench", "modules", "--quick", "--device", "cuda:x", "-o", "r"],
             names=("--device",)),
        Case(9, "predict-outputs-esc", PRED + ["--outputs", "depth,\x1b[2J"], names=("--outputs",)),
        Case(9, "insert-material-esc", INSERT + ["--material", "\x1b[31m", "-o", "o.png"], names=("--material",)),
        Case(9, "view-device-bogus", ["view", "{b}/pano.hdr", "--headless", "--screenshot", "s.png",
                                      "--device", "bogus", "--timeout", "30"], names=("bogus",), gl=True),
    ]


def all_cases(base: Path) -> list[Case]:
    cases = []
    for fn in (class1, class2, class3, class4, class5, class6, class7, class8, class9):
        cases += fn(base)
    for c in cases:
        c.base = base
    keys = [c.key for c in cases]
    assert len(keys) == len(set(keys)), "duplicate case names"
    return cases
