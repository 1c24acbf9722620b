"""Training data: exposure normalisation, LDR simulation, augmentation, resampling, the dataset
folder reader."""

from __future__ import annotations

import json

import pytest
import torch
from support.tiny_scenes import tiny_scene, write_dataset

from phyir.color import KEY, aces, exposure_scale, luminance
from phyir.errors import InputError
from phyir.learn.camera import hdr_to_ldr_linear
from phyir.learn.datasets import (
    Augment,
    SceneDataset,
    TensorSceneDataset,
    augment_scene,
    normalize_scene,
    read_manifest,
    resize_scene,
)
from phyir.pano import solid_angles
from phyir.transforms import mirror_lr, rotate_yaw

pytestmark = pytest.mark.usefixtures("one_thread")


def test_exposure_normalisation():
    s = tiny_scene(0)
    n = normalize_scene(s)
    assert float(luminance(n.image).median()) == pytest.approx(KEY, rel=1e-5)
    k = float(n.meta["exposure_scale"])
    assert torch.allclose(n.probes, s.probes * k)  # probes in the same units as the image
    # invariant to the input's exposure; a lamp covering a few pixels does not move it
    assert torch.allclose(normalize_scene(s.replace(image=40 * s.image)).image, n.image, rtol=1e-5)
    lamp = s.image.clone()
    lamp[:, :2, :2] = 1e5
    assert float(exposure_scale(lamp)) == pytest.approx(float(exposure_scale(s.image)), rel=1e-3)
    # black and mostly-black images get finite scales
    assert float(exposure_scale(torch.zeros(3, 8, 16))) == 1.0
    dark = torch.zeros(3, 8, 16)
    dark[:, 0, 0] = 2.0
    assert float(exposure_scale(dark)) == pytest.approx(KEY / float(luminance(dark).mean()))


def test_ldr_simulation():
    x = torch.logspace(-3, 3, 64).expand(3, 4, 64)
    y = hdr_to_ldr_linear(x, exposure=1.0)
    assert y.min() >= 0 and y.max() <= 1
    assert (y[..., 1:] >= y[..., :-1]).all()  # monotone
    assert (y == y.max()).float().mean() > 0.1  # bright values saturate
    assert torch.allclose(aces(torch.tensor([0.0])), torch.tensor([0.0]), atol=1e-3)
    # 8-bit quantisation: at most 256 distinct values
    assert y.unique().numel() <= 256


def test_augmentation_keeps_layers_consistent_and_is_reproducible():
    s = tiny_scene(1, grid=(4, 8), probe_size=(8, 16))
    aug = Augment(p_ldr=0.0, exposure_stops=0.0, light_colour_stops=0.0, mirror=False)
    a = augment_scene(s, aug, torch.Generator().manual_seed(5))
    # the rotation is by whole probe blocks and texels: it equals rotate_yaw for some shift
    matches = [k for k in range(0, 128, 16) if torch.equal(rotate_yaw(s, k).image, a.image)]
    assert len(matches) == 1 and matches[0] > 0
    assert torch.equal(rotate_yaw(s, matches[0]).probes, a.probes)
    assert torch.equal(rotate_yaw(s, matches[0]).normal, a.normal)
    no_rot = Augment(p_ldr=0.0, exposure_stops=0.0, light_colour_stops=0.0, rotate=False)
    mirrored = mirror_lr(s)
    seen = set()
    for seed in range(8):  # each draw is either the scene or its mirror image (normals' x negated)
        m = augment_scene(s, no_rot, torch.Generator().manual_seed(seed))
        flip = torch.equal(m.normal, mirrored.normal) and torch.equal(m.image, mirrored.image)
        assert flip or (torch.equal(m.normal, s.normal) and torch.equal(m.image, s.image))
        seen.add(flip)
    assert seen == {True, False}
    # the same (seed, epoch, index) gives the same sample; another epoch another one
    ds = TensorSceneDataset([s, s], augment=Augment())
    first = ds[1].image
    assert torch.equal(ds[1].image, first)
    ds.set_epoch(1)
    assert not torch.equal(ds[1].image, first)


def test_ldr_augmentation_is_marked_and_normalised():
    s = tiny_scene(2)
    a = augment_scene(s, Augment(p_ldr=1.0, rotate=False, mirror=False), torch.Generator().manual_seed(0))
    assert a.meta["ldr"] == "1"
    n = normalize_scene(a)
    assert float(luminance(n.image).median()) == pytest.approx(KEY, rel=1e-4)
    assert torch.isfinite(n.probes).all()


def test_resize_scene_and_merge_probe_grid():
    s = tiny_scene(3, H=64, W=128, grid=(4, 8))
    r = resize_scene(s, 32, 64, grid=(2, 4))
    r.validate()
    assert r.size == (32, 64) and r.probe_grid == (2, 4)
    # merged probe = solid-angle-weighted mean of the 2x2 probes it replaces (phyir.pano.resize_area)
    w = solid_angles(4, 8)[:2, :2]
    want = (s.probes[:2, :2] * w[..., None, None, None]).sum((0, 1)) / w.sum()
    assert torch.allclose(r.probes[0, 0], want, rtol=1e-5)
    assert set(r.masks) == {"emission"} and set(r.masks["emission"].unique().tolist()) <= {0.0, 1.0}


def test_dataset_folder(tmp_path):
    write_dataset(tmp_path, n_train=3, n_val=1, H=32, W=64, grid=(2, 4))
    assert read_manifest(tmp_path)["train"] == [f"scene_{i:06d}.exr" for i in range(3)]
    ds = SceneDataset(tmp_path, "train", size=(32, 64), probe_grid=(1, 2), augment=Augment())
    assert len(ds) == 3
    item = ds[2]
    item.validate()
    assert item.probe_grid == (1, 2)
    assert float(luminance(item.image).median()) == pytest.approx(KEY, rel=1e-4)
    with pytest.raises(InputError, match="split 'test' of the manifest is empty"):
        SceneDataset(tmp_path, "test")


def test_manifest_errors(tmp_path):
    with pytest.raises(InputError, match="no split manifest"):
        read_manifest(tmp_path)
    (tmp_path / "manifest.json").write_text("{not json")
    with pytest.raises(InputError, match="unreadable manifest"):
        read_manifest(tmp_path)
    (tmp_path / "manifest.json").write_text(json.dumps({"count": 3}))
    with pytest.raises(InputError, match="no train/val/test"):
        read_manifest(tmp_path)


def test_dataset_still_being_generated_uses_the_scenes_present(tmp_path):
    write_dataset(tmp_path, n_train=3, n_val=1, H=32, W=64, grid=(2, 4))
    (tmp_path / "scene_000001.exr").unlink()
    with pytest.warns(UserWarning, match="1 of 3 train scenes listed in the manifest are missing"):
        ds = SceneDataset(tmp_path, "train")
    assert [p.name for p in ds.files] == ["scene_000000.exr", "scene_000002.exr"]
    (tmp_path / "scene_000000.exr").unlink()
    (tmp_path / "scene_000002.exr").unlink()
    with pytest.raises(InputError, match="none of the 3 scene files of split 'train' exist yet"):
        SceneDataset(tmp_path, "train")
