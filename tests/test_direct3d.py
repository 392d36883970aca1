"""The Direct3D baseline: CoordConv channels against the camera, translation targets in the
turned world, a tiny model that learns, quantisation with the connection constraint, training
and evaluation from the command line, and weights that do not fit refused in one line."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from mepnet import _brickgeom as _bg
from mepnet.detector.config import ModelConfig
from mepnet.detector.direct3d import (
    decode_direct3d,
    turned_translation,
    world_translation,
)
from mepnet.detector.losses import total_loss
from mepnet.detector.net import Direct3DNet, build_model, coord_channels
from mepnet.detector.targets import camera_vector, collate
from mepnet.detector.weights import load_model, save_model
from mepnet.manual import load_manual, write_manual
from mepnet.stage2.direct3d import NEIGHBOURHOOD, class_yaw, quantise
from mepnet.train.data import training_sample

TINY = ModelConfig(**{**ModelConfig.tiny().to_dict(), "head": "direct3d"})
ENV = {**os.environ, "OMP_NUM_THREADS": "1", "RAYON_NUM_THREADS": "1"}


@pytest.fixture(autouse=True)
def one_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def manuals(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two small synthetic manuals (64 px) for training, one for validation and evaluation."""
    root = tmp_path_factory.mktemp("d3")
    config = {"image_size": 64, "components": (8, 14)}
    for split, seeds in (("train", (11, 12)), ("val", (13,))):
        for seed in seeds:
            m = _bg.synth_manual(seed, config)
            write_manual(
                root / split / f"manual_{seed:08d}", m, {"kind": "synthetic"}, writer="mepnet.synth"
            )
    return root


def run(module: str, *args: str, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", module, *map(str, args)],
        capture_output=True,
        text=True,
        timeout=timeout,
        env=ENV,
    )


def one_line_error(r: subprocess.CompletedProcess[str], *fragments: str) -> None:
    assert r.returncode == 2, (r.stdout, r.stderr)
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    for f in fragments:
        assert f in lines[0], lines[0]


# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", range(4))
def test_coord_channels_hold_the_world_point_each_cell_shows(seed: int):
    rng = np.random.default_rng(seed)
    cam = _bg.Camera(
        float(rng.uniform(15, 40)),
        float(rng.uniform(0, 360)),
        0.0,
        float(rng.uniform(0.003, 0.02)),
        (float(rng.uniform(-0.5, 0.5)), float(rng.uniform(-0.5, 0.5))),
    )
    cdict = {
        "elevation": cam.elevation,
        "azimuth": cam.azimuth,
        "roll": 0.0,
        "scale": cam.scale,
        "translation": list(cam.translation),
    }
    vec = torch.from_numpy(camera_vector(cdict))[None].double()
    n, size = 16, 64
    _, cells = coord_channels(vec, n, n)
    ldu = cells[0].numpy().reshape(3, -1).T * np.array([10.0, 8.0, 10.0])
    px, _ = cam.project(ldu, size, size)
    rows, cols = np.divmod(np.arange(n * n), n)  # the cells in row-major order
    want = np.stack([cols + 0.5, rows + 0.5], axis=1) * size / n
    assert np.abs(px - want).max() < 1e-4  # (the camera vector is float32)


def test_translation_targets_are_the_true_poses_in_the_turned_world(manuals: Path):
    man = load_manual(manuals / "train" / "manual_00000011")
    truth = man.answers.main
    for k in range(4):
        s = training_sample(man, (None, k), TINY, augment=True, rng=np.random.default_rng(k))
        turn = int(s.tensors["turn"])
        got = s.tensors["inst_translation"].numpy()
        valid = s.tensors["inst_valid"].numpy() > 0
        step = truth.truth(k)
        want = [truth.instances[i].t for e in step.instances_of for i in e]
        assert valid.sum() == len(want)
        for t, w in zip(got[valid], want, strict=True):
            assert np.array_equal(world_translation(t, turn), np.array(w, dtype=float))
            assert np.array_equal(t, turned_translation(w, turn))


def test_a_tiny_direct3d_learns_a_batch(manuals: Path):
    man = load_manual(manuals / "train" / "manual_00000011")
    torch.manual_seed(0)
    net = build_model(TINY).train()
    assert isinstance(net, Direct3DNet)
    batch = collate(
        [training_sample(man, (None, k), TINY, False, np.random.default_rng(k)) for k in (1, 2, 3)]
    )
    out = net(batch)
    n = TINY.out_size
    assert out["translation"].shape == (3, TINY.k_max, 3, n, n)
    assert out["rotation"].shape == (3, TINY.k_max, 7, n, n)
    opt = torch.optim.AdamW(net.parameters(), lr=3e-3)
    first = None
    for _ in range(30):
        loss, parts = total_loss(net(batch), batch, TINY)
        first = first or (loss.item(), parts)
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert set(parts) == {"heatmap", "translation", "rotation"}
    assert loss.item() < 0.5 * first[0], (first, parts)
    assert parts["translation"] < first[1]["translation"]
    # decoding: the stated number of instances per type, their translations finite
    net.eval()
    with torch.no_grad():
        out = net(collate([training_sample(man, (None, 1), TINY, False, np.random.default_rng(0))]))
    counts = [c.count for c in man.main.steps[1].components]
    dets = decode_direct3d(out, counts, TINY, (64, 64))
    assert [len(d) for d in dets] == counts[: TINY.k_max]
    for d in dets:
        assert d.translations.shape == (len(d), 3) and np.isfinite(d.translations).all()
        assert np.abs(d.rotations.sum(axis=1) - 1).max() < 1e-5


def test_quantise_returns_the_nearest_valid_placement():
    brick, plate = _bg.Component.primitive("3001"), _bg.Component.primitive("3022")
    asm = _bg.Assembly()
    asm.add(brick, 0, (0, 3, 0))
    true = (0, 4, 0)  # a 2x2 plate on the brick's studs
    assert asm.check(plate, 0, true) == "on_studs"
    # near the true translation: rounding finds it
    got = quantise(asm, plate, 0, np.array([0.3, 4.4, -0.2]))
    assert got == (true, "on_studs")
    # off by more than a cell: the nearest valid placement within the neighbourhood
    rng = np.random.default_rng(0)
    for _ in range(200):
        t = np.array(true, float) + rng.uniform(-2.5, 2.5, size=3) * np.array(NEIGHBOURHOOD)
        q = quantise(asm, plate, 1, t)
        if q is None:
            continue
        pos, attach = q
        assert asm.check(plate, 1, pos) == attach
        assert (np.abs(np.array(pos) - np.rint(t)) <= np.array(NEIGHBOURHOOD)).all()
    # inside the brick: pushed out to a valid placement, never a colliding one
    q = quantise(asm, plate, 0, np.array([0.0, 2.0, 0.0]))
    assert q is not None and asm.check(plate, 0, q[0]) == q[1]
    # far above anything: nothing connects within the neighbourhood
    assert quantise(asm, plate, 0, np.array([0.0, 30.0, 0.0])) is None
    assert quantise(asm, plate, 0, np.array([np.nan, 4.0, 0.0])) is None
    # the rotation class the part's symmetry allows
    assert class_yaw(brick, np.array([0.9, 0.0, 0.1, 0.0, 0.0, 0.0, 0.0])) == 1  # 2-fold
    slope = _bg.Component.primitive("3039")
    assert slope.symmetry == 1
    assert class_yaw(slope, np.array([0.5, 0.0, 0.0, 0.1, 0.1, 0.3, 0.0])) == 2


def test_train_head_direct3d_and_evaluate_its_weights(tmp_path: Path, manuals: Path):
    out = tmp_path / "run"
    r = run(
        "mepnet.train",
        "--out",
        out,
        "--data",
        manuals / "train",
        "--head",
        "direct3d",
        "--model",
        "tiny",
        "--steps",
        "4",
        "--batch-size",
        "2",
        "--workers",
        "0",
        "--threads",
        "1",
        "--no-progress",
        "--log-every",
        "1",
        "--val-dir",
        manuals / "val",
        "--val-every",
        "4",
        "--val-cd-points",
        "200",
    )
    assert r.returncode == 0, r.stderr
    model, cfg = load_model(out / "model.safetensors")
    assert isinstance(model, Direct3DNet) and cfg.head == "direct3d"
    rows = json.loads((out / "metrics.json").read_text())
    assert any("loss_translation" in row for row in rows)
    assert any(row.get("split") == "val" for row in rows)
    r = run(
        "mepnet.eval",
        "--data",
        manuals / "val",
        "--predictor",
        "direct3d",
        "--weights",
        out / "model.safetensors",
        "--cd-points",
        "200",
        "--no-progress",
        "--json",
        tmp_path / "m.json",
    )
    assert r.returncode == 0, r.stderr
    m = json.loads((tmp_path / "m.json").read_text())
    assert m["predictor"] == "direct3d" and m["n_components"] > 0
    assert 0.0 <= m["component_acc"] <= 1.0
    reg = m["regression"]  # how near the regressed translations come, before quantisation
    assert 0 < reg["instances"] <= m["n_components"]
    assert len(reg["median_abs_error_cells"]) == 3
    assert 0.0 <= reg["rounds_to_truth"] <= reg["truth_in_neighbourhood"] <= 1.0
    assert "within the quantiser's reach" in r.stdout


def test_regression_errors_are_measured_against_the_nearest_true_instance():
    from mepnet.eval import _regression_errors, _regression_metrics
    from mepnet.manual import ComponentRef
    from mepnet.stage2.base import Prediction

    brick, plate = ComponentRef("3001", None), ComponentRef("3020", None)
    gt = [(brick, 0, (0, 0, 0)), (brick, 0, (8, 0, 0)), (plate, 1, (0, 3, 0))]
    preds = [
        Prediction(0, brick, 0, (8, 0, 0), extra={"regressed": [7.6, 0.2, -0.4]}),
        Prediction(0, brick, 0, (0, 0, 0), extra={"regressed": [0.3, -1.2, 0.0]}),
        Prediction(1, plate, 1, None, extra={"regressed": [0.0, 3.0, 9.0]}),
        Prediction(1, plate, 1, (0, 3, 0)),  # no regression (another predictor's)
    ]
    errs = _regression_errors(preds, gt)
    assert len(errs) == 3
    np.testing.assert_allclose(errs[0], [-0.4, 0.2, -0.4])  # the brick at x=8, not at 0
    np.testing.assert_allclose(errs[1], [0.3, -1.2, 0.0])
    m = _regression_metrics(errs)
    assert m is not None and m["instances"] == 3
    assert m["rounds_to_truth"] == pytest.approx(1 / 3)
    assert m["truth_in_neighbourhood"] == pytest.approx(2 / 3)  # z 9 cells off is beyond it
    np.testing.assert_allclose(m["median_abs_error_cells"], [0.3, 0.2, 0.4])
    assert _regression_metrics([]) is None


def test_the_shipped_weights_are_direct3d_small_and_documented():
    """The shipped Direct3D weights load as a Direct3D network, are at most 20 MB, and their
    JSON says how they were trained and what they reach."""
    from mepnet.stage2 import bundled_direct3d_weights

    path = bundled_direct3d_weights()
    model, cfg = load_model(path)
    assert isinstance(model, Direct3DNet) and cfg.head == "direct3d"
    assert path.stat().st_size <= 20 * 2**20
    doc = json.loads(path.with_suffix(".json").read_text())
    assert "--head direct3d" in doc["trained_with"]["command"]
    assert doc["model_config"] == json.loads(json.dumps(cfg.to_dict()))
    assert 0 < doc["metrics_20_test_manuals"]["ours"]["component_acc"] < 1


def test_weights_that_do_not_fit_are_refused_in_one_line(tmp_path: Path, manuals: Path):
    data = manuals / "val"
    # the shipped weights by default
    r = run("mepnet.eval", "--data", data, "--predictor", "direct3d", "--cd-points", "200")
    assert r.returncode == 0 and "direct3d" in r.stdout, r.stderr
    # the detector's weights are not Direct3D's, and Direct3D's are not the detector's
    det, d3, wrong = tmp_path / "det", tmp_path / "d3", tmp_path / "wrong"
    for folder in (det, d3, wrong):
        folder.mkdir()
    save_model(det, build_model(ModelConfig.tiny()).state_dict(), ModelConfig.tiny().to_dict())
    save_model(d3, build_model(TINY).state_dict(), TINY.to_dict())
    for predictor, weights, says in (
        ("direct3d", det, "holds mepnet weights"),
        ("mepnet", d3, "holds direct3d weights"),
        ("abys", d3, "holds direct3d weights"),
    ):
        r = run(
            "mepnet.eval",
            "--data",
            data,
            "--predictor",
            predictor,
            "--weights",
            weights / "model.safetensors",
        )
        one_line_error(r, "model.safetensors", says)
    # not weights at all, and weights whose tensors do not fit their config
    junk = tmp_path / "junk.safetensors"
    junk.write_bytes(b"\x00" * 64)
    r = run("mepnet.eval", "--data", data, "--predictor", "direct3d", "--weights", junk)
    one_line_error(r, "junk.safetensors")
    save_model(wrong, build_model(ModelConfig.tiny()).state_dict(), TINY.to_dict())
    r = run(
        "mepnet.eval",
        "--data",
        data,
        "--predictor",
        "direct3d",
        "--weights",
        wrong / "model.safetensors",
    )
    one_line_error(r, "model.safetensors", "tensors")
    # the detector from Direct3D's weights (the other way round starts from the shared encoders:
    # tests/test_train.py)
    r = run(
        "mepnet.train",
        "--out",
        tmp_path / "ft",
        "--data",
        manuals / "train",
        "--model",
        "tiny",
        "--init",
        d3 / "model.safetensors",
        "--steps",
        "1",
    )
    one_line_error(r, "--init", "direct3d")
