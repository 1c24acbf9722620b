"""The light-at-a-point diagnostic (phyir.evaluation.light_gain, printed by benchmarks.light_at_gain):
its sphere kernel against the closed form, its regions, and its report on the analytic box room."""

from __future__ import annotations

import math
import re

import pytest
import torch
from support.scenes import LAMP_CENTRE, box_room

from phyir.evaluation import light_gain as gain


def test_the_sphere_kernel_integrates_uniform_light_to_pi():
    # every visible normal of a diffuse sphere under radiance 1 gets irradiance pi
    for point in ((0.0, -0.2, -0.8), (1.0, 0.5, 2.0)):
        assert float(gain.sphere_kernel(point).sum()) == pytest.approx(math.pi, rel=0.01)


def test_the_regions_partition_the_directions():
    masks = torch.stack(list(gain.region_masks().values()))
    assert len(masks) == 12
    assert bool((masks.sum(0) == 1).all())


def report(scene, point) -> tuple[float, dict[str, tuple[float, float]]]:
    out = "\n".join(gain.report(scene, point, "box"))
    ratio = float(re.search(r"is ([0-9.]+)x as bright", out).group(1))
    row = r"\| (\w+ [^|]+?) \| ([0-9.]+) \| ([0-9.]+) \|"
    rows = {m[0]: (float(m[1]), float(m[2])) for m in re.findall(row, out)}
    return ratio, rows


def test_the_report_on_the_box_room():
    """The ratio is the real protocol's brute-force diffuse sphere under the two probes; under the
    ceiling lamp the sphere is brighter and the gain is in the upper directions; a point at the camera
    is refused (the camera would be inside the sphere)."""
    from phyir.evaluation import real_lighting as RL
    from phyir.lighting.at_point import LightAtPoint

    scene = box_room()
    point = (0.4, -0.5, -1.2)
    ratio, rows = report(scene, point)
    probes = LightAtPoint(scene, gain.SIZE).probes_at(torch.tensor([point, (0.0, 0.0, 0.0)]))
    px, _ = RL.render_sphere(torch.stack([RL.at_size(p, RL.INTEGRATION_SIZE) for p in probes]), "diffuse",
                             centre=point)
    assert ratio == pytest.approx(float(px[0].mean() / px[1].mean()), abs=0.011)  # printed to 2 digits
    assert len(rows) == 12 and sum(a for a, _ in rows.values()) == pytest.approx(1.0, abs=0.01)
    below_lamp = (float(LAMP_CENTRE[0]), 0.3, float(LAMP_CENTRE[2]))
    ratio, rows = report(scene, below_lamp)
    assert ratio > 1.2
    up = sum(b - a for k, (a, b) in rows.items() if k.startswith("up"))
    assert up > 0.5 * (ratio - 1)
    with pytest.raises(ValueError, match="inside the sphere"):
        gain.check_point((0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="three numbers"):
        gain.check_point((1.0, math.nan, 0.0))
