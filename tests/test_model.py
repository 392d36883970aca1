"""The detector's model code: shapes, the camera-frame projection of the state encoder against
brickgeom's renderer, targets, losses, decoding, and config round trips."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import generate_manuals
from mepnet import _brickgeom as _bg
from mepnet.data import load_manual
from mepnet.model.config import ModelConfig
from mepnet.model.decode import decode
from mepnet.model.losses import total_loss
from mepnet.model.net import StateEncoder, build_model
from mepnet.model.targets import camera_vector, collate, make_sample


@pytest.fixture(scope="module")
def manual(tmp_path_factory: pytest.TempPathFactory):
    out = generate_manuals(tmp_path_factory.mktemp("m"), 1, 5, size=64)
    return load_manual(out / "manual_00000005")


def test_first_hit_projection_matches_the_renderer():
    cfg = ModelConfig.slim()
    asm = _bg.Assembly()
    asm.add(_bg.Component.primitive("3001"), 0, (0, 3, 0))
    asm.add(_bg.Component.primitive("3003"), 1, (6, 3, 4))
    asm.add(_bg.Component.primitive("3022"), 0, (0, 4, 0))
    cam = _bg.Camera(30.0, 225.0).fitted(np.array([[-60.0, 0.0, -40.0], [80.0, 40.0, 60.0]]), 0.8)
    n = 64
    enc = StateEncoder(channels=1, grid=cfg.base_grid, depth_samples=96, out_size=n)
    from mepnet.model.targets import base_voxels

    vox = torch.from_numpy(base_voxels(asm, cfg.base_grid))[None, None]
    cdict = {
        "elevation": cam.elevation,
        "azimuth": cam.azimuth,
        "roll": 0.0,
        "scale": cam.scale,
        "translation": list(cam.translation),
    }
    camv = torch.from_numpy(camera_vector(cdict))[None]
    occ = enc.sample_rays(vox, camv)
    coverage = enc.first_hit_weights(occ).sum(dim=2)[0, 0].numpy()  # (n, n)
    ids = _bg.render(asm, cam, n, n)["ids"]
    ours, theirs = coverage > 0.5, ids >= 0
    iou = (ours & theirs).sum() / (ours | theirs).sum()
    assert iou > 0.85, f"projection IoU {iou:.2f}"


def test_forward_shapes_loss_and_decoding(manual):
    cfg = ModelConfig.tiny()
    torch.manual_seed(0)
    net = build_model(cfg)
    samples = [
        make_sample(manual, manual.main, k, cfg, augment=True, rng=np.random.default_rng(k))
        for k in range(3)
    ]
    batch = collate(samples)
    out = net(batch)
    n = cfg.out_size
    assert out["heatmap"].shape == (3, cfg.k_max, n, n)
    assert out["offset"].shape == (3, cfg.k_max, 2, n, n)
    assert out["rotation"].shape == (3, cfg.k_max, 7, n, n)
    loss, parts = total_loss(out, batch, cfg)
    assert torch.isfinite(loss) and set(parts) == {
        "heatmap",
        "offset",
        "mask",
        "pull",
        "push",
        "rotation",
    }
    # a few steps on this batch lower the loss
    opt = torch.optim.AdamW(net.parameters(), lr=2e-3)
    first = loss.item()
    for _ in range(25):
        loss, _ = total_loss(net(batch), batch, cfg)
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert loss.item() < 0.5 * first
    # decoding gives exactly the stated number of detections per type, inside the image
    net.eval()
    with torch.no_grad():
        out = net(collate(samples[:1]))
    counts = [c.count for c in manual.main.steps[0].components]
    dets = decode(out, counts, cfg, 64)
    assert [len(d) for d in dets] == counts
    for d in dets[0]:
        assert 0 <= d["keypoint"][0] <= 64 and 0 <= d["keypoint"][1] <= 64
        assert len(d["rotation"]) == 7 and abs(sum(d["rotation"]) - 1) < 1e-4


def test_targets_put_one_peak_per_instance(manual):
    cfg = ModelConfig.tiny()
    for k, step in enumerate(manual.main.steps[:5]):
        t = make_sample(manual, manual.main, k, cfg).tensors
        assert int(t["inst_valid"].sum()) == len(step.views)
        assert int((t["heatmap"] == 1.0).sum()) >= 1
        assert t["comp_valid"].sum() == len(step.components)
        assert t["image"].shape == (4, cfg.image_size, cfg.image_size)


def test_config_round_trip_and_errors(tmp_path: Path):
    for cfg in (ModelConfig.slim(), ModelConfig.paper(), ModelConfig.tiny()):
        assert ModelConfig.from_dict(cfg.to_dict()) == cfg
    with pytest.raises(ValueError, match="unknown model settings: nope"):
        ModelConfig.from_dict({"nope": 1})
    p = tmp_path / "c.json"
    import json

    p.write_text(json.dumps(ModelConfig.tiny().to_dict()))
    assert ModelConfig.named(str(p)) == ModelConfig.tiny()
