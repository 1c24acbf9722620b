"""The geometry confidence reads the same in the viewer's status bar, ``phyir info`` and ``phyir
predict`` for the same score (it read 0.99 in one and 1.00 in the other for 0.996)."""

from __future__ import annotations

import types

import pytest
import torch

from viewer.gl import window as _surfaces

_surfaces.prefer_egl()  # the status bar's module imports imgui (PyOpenGL): EGL first, as the GL tests need

from phyir.cli import main  # noqa: E402
from phyir.commands.info import format_confidence  # noqa: E402
from phyir.io import save_scene  # noqa: E402
from phyir.scene import PanoScene  # noqa: E402
from phyir.synth.analytic import box_room  # noqa: E402


def test_format_rounds_down_to_two_digits():
    assert [format_confidence(c) for c in (0.996, 1.0, 0.29, 0.4999, 0.5, 0.0)] == \
        ["0.99", "1.00", "0.29", "0.49", "0.50", "0.00"]
    assert format_confidence(float("nan")) == "nan"


@pytest.mark.parametrize("score", [0.996, 0.4999, 0.291])
def test_viewer_info_and_predict_show_the_same_digits(score, tmp_path, capsys, monkeypatch):
    from phyir.commands.predict import geometry_confidence
    from phyir.evaluation import real
    from viewer.ui.status_bar import status_text

    facts = {"nadir_up": 1.0, "consistency_deg": 20.0, "far_m": 4.0, "camera_height": 1.5,
             "confidence": score, "flagged": score < real.FLAG_BELOW}
    monkeypatch.setattr(real, "scene_confidence", lambda scene: dict(facts))
    depth, normal = box_room(16, 32, (-2.0, -1.5, -3.0), (2.5, 1.3, 2.0))
    scene = PanoScene(image=torch.full((3, 16, 32), 0.5), depth=depth.float(), normal=normal.float())
    path = tmp_path / "room.exr"
    save_scene(scene, path)
    assert main(["info", str(path)]) == 0
    (info,) = (ln for ln in capsys.readouterr().out.splitlines() if "geometry confidence" in ln)
    cli = info.split("geometry confidence:")[1].split()[0]
    predicted = geometry_confidence(scene).split("geometry confidence ")[1].split()[0]
    ns = types.SimpleNamespace
    app = ns(images=[None], comparison=ns(mode=None), camera=ns(hover=None),
             doc=ns(size=None, confidence=score), frame_times=[], loader=ns(busy=False, job_frames=0))
    viewer = status_text(app).split("geometry confidence ")[1].split()[0]
    assert cli == predicted == viewer == format_confidence(score)
