"""The README's five-minute tour runs as written.

The commands are the ```bash block under the README's tour heading, one per line (``\\`` continues a
line, ``#`` starts a comment), run in a temporary folder that holds a generated panorama named as the
tour names it (the demo scene's image, area-resized to 128x256 and written with
``phyir.io.save_panorama``: auto-exposed 8-bit sRGB for ``.jpg``/``.png``, linear for ``.hdr``/``.exr``).
Each command runs as its argument list, without a shell (the tour uses no shell syntax; a test
checks that).  The one change: ``phyir-view`` gets ``--headless --screenshot viewN.png`` appended,
since a test has no display and no one to close the window — the tour shows the interactive form.

About 30 s on a 2-core CPU (the model runs once, the viewer twice, insert and export once each).
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
SHELL_SYNTAX = re.compile(r"[|&;<>`$(){}*?]")  # pipes, redirections, substitutions, globs
LDR_SUFFIXES = (".jpg", ".jpeg", ".png")
HDR_SUFFIXES = (".hdr", ".exr")


def tour_block(text: str) -> str:
    """The first ```bash block after the first level-2 heading that names the tour."""
    m = re.search(r"^## [^\n]*\btour\b[^\n]*$", text, re.IGNORECASE | re.MULTILINE)
    assert m, "README.md has no '## ... tour ...' heading"
    section = text[m.end():]
    nxt = re.search(r"^## ", section, re.MULTILINE)
    section = section[:nxt.start()] if nxt else section
    block = re.search(r"^```bash\n(.*?)^```", section, re.MULTILINE | re.DOTALL)
    assert block, "the tour section has no ```bash block"
    return block.group(1)


def tour_commands(block: str) -> list[list[str]]:
    """Each command of the block as its argument list (continuations joined, comments dropped)."""
    commands, pending = [], ""
    for raw in block.splitlines():
        line = pending + raw
        if line.rstrip().endswith("\\"):
            pending = line.rstrip()[:-1] + " "
            continue
        pending = ""
        argv = shlex.split(line, comments=True)
        if argv:
            code = shlex.join(argv)
            assert not SHELL_SYNTAX.search(code), f"tour command needs a shell: {line!r}"
            commands.append(argv)
    return commands


def option(argv: list[str], *names: str) -> str | None:
    for i, a in enumerate(argv[:-1]):
        if a in names:
            return argv[i + 1]
    return None


def make_panorama(path: Path) -> None:
    """A small 2:1 panorama of a synthetic room, written by the project's own writers."""
    import torch

    from phyir import io, pano
    from phyir.color import luminance
    from phyir.synth import demo_scene_path

    image = pano.resize_area(io.load_scene(demo_scene_path()).image.float(), 128, 256)
    if path.suffix.lower() in LDR_SUFFIXES:
        image = (image * (0.18 / luminance(image).median())).clamp(0, 1)  # a camera's auto-exposure
    else:
        assert path.suffix.lower() in HDR_SUFFIXES, f"the tour's panorama {path.name}: unknown format"
    io.save_panorama(torch.nan_to_num(image), path)


def test_the_tour_names_fractions_and_the_commands_that_matter():
    commands = tour_commands(tour_block(README.read_text(encoding="utf-8")))
    programs = [" ".join(c[:2]) if c[0] == "phyir" else c[0] for c in commands]
    for needed in ("phyir predict", "phyir-view", "phyir insert", "phyir export"):
        assert needed in programs, f"the tour has no {needed}"
    assert {c[0] for c in commands} <= {"phyir", "phyir-view"}
    # positions that do not depend on the image's size: fractions, written with a dot
    for c in commands:
        for i, a in enumerate(c):
            if a in ("--at", "--path"):
                assert all("." in x for x in re.split(r"[,:]", c[i + 1])), f"pixel position in the tour: {c}"


@pytest.mark.slow
def test_the_readme_tour_runs_as_written(tmp_path, egl):
    commands = tour_commands(tour_block(README.read_text(encoding="utf-8")))
    predict = next(c for c in commands if c[:2] == ["phyir", "predict"])
    source = next(a for a in predict[2:] if not a.startswith("-"))
    make_panorama(tmp_path / source)

    bindir = Path(sys.executable).parent
    if not (bindir / "phyir").exists() and shutil.which("phyir"):
        bindir = Path(shutil.which("phyir")).parent
    env = dict(os.environ, PATH=f"{bindir}{os.pathsep}{os.environ.get('PATH', '')}",
               OMP_WAIT_POLICY=os.environ.get("OMP_WAIT_POLICY", "PASSIVE"))

    for n, argv in enumerate(commands):
        expected = []
        if argv[0] == "phyir-view":  # the headless form of the same command (see the docstring)
            argv = [*argv, "--headless", "--screenshot", f"view{n}.png"]
            expected.append(f"view{n}.png")
        out = option(argv, "-o", "--output", "--out")
        if out:
            expected.append(out)
            if argv[1] == "insert" and out.endswith(".exr"):
                expected.append(out[:-4] + ".png")
        glb = option(argv, "--gltf")
        if glb:
            expected += [glb, option(argv, "--exr") or glb[:-4] + "_env.exr"]
        r = subprocess.run(argv, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
        said = f"$ {shlex.join(argv)}\n{r.stdout}{r.stderr}"
        assert r.returncode == 0, said
        assert "Traceback" not in r.stderr, said
        if argv[1:2] == ["info"]:
            assert "usable as a panorama: yes" in r.stdout, said
        for name in expected:
            f = tmp_path / name
            assert f.is_file() and f.stat().st_size > 0, f"{name} not written\n{said}"
