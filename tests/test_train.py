"""python -m mepnet.train: the model learns, checkpoints round-trip, a killed run resumes to the
same weights, two torchrun processes stay identical, bad input exits 2 with one line."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from mepnet import _brickgeom as _bg
from mepnet.detector.config import ModelConfig
from mepnet.detector.losses import total_loss
from mepnet.detector.net import DIRECT3D_FROM_DETECTOR, build_model
from mepnet.detector.targets import collate
from mepnet.detector.weights import load_model, read_safetensors, write_safetensors
from mepnet.manual import write_manual
from mepnet.train.checkpoint import load_checkpoint, save_checkpoint
from mepnet.train.cli import main
from mepnet.train.data import FolderSteps, GeneratedSteps, ResumableSampler
from mepnet.train.distributed import param_checksum

TINY = ModelConfig.tiny()
# one thread, no workers, no progress bar: deterministic and quiet
COMMON = ["--model", "tiny", "--batch-size", "2", "--workers", "0", "--threads", "1"]
COMMON += ["--no-progress", "--log-every", "1"]
ENV = {**os.environ, "OMP_NUM_THREADS": "1", "RAYON_NUM_THREADS": "1"}


@pytest.fixture(autouse=True)
def one_thread():
    """Deterministic, and no oversubscription on a small machine."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def manuals(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two small synthetic manuals (64 px) for training and one for validation."""
    root = tmp_path_factory.mktemp("manuals")
    config = {"image_size": 64, "components": (8, 14)}
    for split, seeds in (("train", (11, 12)), ("val", (13,))):
        for seed in seeds:
            m = _bg.synth_manual(seed, config)
            write_manual(
                root / split / f"manual_{seed:08d}", m, {"kind": "synthetic"}, writer="mepnet.synth"
            )
    return root


def train(*args: str, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "mepnet.train", *COMMON, *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        env=ENV,
    )


def steps_of(folder: Path) -> FolderSteps:
    """The main-build steps of the manuals in ``folder`` as training samples, unaugmented
    (keys ``(index, epoch)``)."""
    return FolderSteps([folder], model_config=TINY, seed=0, augment=False, submodules=False)


def weights(path: Path) -> dict[str, torch.Tensor]:
    return read_safetensors(path)[0]


def one_error_line(capsys: pytest.CaptureFixture[str], *needles: str) -> str:
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0, err
    assert err.startswith("mepnet.train: error: "), err
    for n in needles:
        assert n in err, err
    return err


# ---------------------------------------------------------------------------------------------


def test_overfits_a_fixed_tiny_batch(manuals: Path):
    torch.manual_seed(0)
    ds = steps_of(manuals / "train")
    batch = collate([ds[(i, 0)] for i in (1, 2)])
    model = build_model(TINY).train()
    opt = torch.optim.AdamW(model.parameters(), lr=3e-3)
    losses = []
    for _ in range(30):
        loss, _ = total_loss(model(batch), batch, TINY)
        opt.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        opt.step()
        losses.append(float(loss.detach()))
    assert losses[-1] < 0.5 * losses[0], losses


def test_checkpoint_round_trip_is_exact(tmp_path: Path, manuals: Path):
    torch.manual_seed(1)
    ds = steps_of(manuals / "train")
    batch = collate([ds[(0, 0)]])
    model = build_model(TINY)
    opt = torch.optim.AdamW(model.parameters(), lr=1e-3, weight_decay=0.01)
    for _ in range(2):
        loss, _ = total_loss(model(batch), batch, TINY)
        opt.zero_grad()
        loss.backward()
        opt.step()
    rng = torch.get_rng_state().tolist()
    save_checkpoint(
        tmp_path,
        model_state=model.state_dict(),
        optimizer_state=opt.state_dict(),
        doc={"step": 2, "rng": rng},
    )
    assert not pickle_free_violations(tmp_path)
    model_state, optim_state, doc = load_checkpoint(tmp_path)
    fresh = build_model(TINY)
    fresh.load_state_dict(model_state)
    fresh_opt = torch.optim.AdamW(fresh.parameters(), lr=5.0)
    fresh_opt.load_state_dict(optim_state)
    for (k, a), b in zip(model.state_dict().items(), fresh.state_dict().values(), strict=True):
        assert torch.equal(a, b), k
    want, got = opt.state_dict(), fresh_opt.state_dict()
    assert want["param_groups"] == got["param_groups"]
    assert want["state"].keys() == got["state"].keys()
    for i, s in want["state"].items():
        for k, v in s.items():
            assert torch.equal(v, got["state"][i][k]), (i, k)
    assert doc["step"] == 2 and doc["rng"] == rng
    assert json.loads((tmp_path / "checkpoint.json").read_text())["id"] == doc["id"]


def pickle_free_violations(folder: Path) -> list[Path]:
    """Files that look like pickles / torch.save archives."""
    return [
        p for p in folder.iterdir() if p.read_bytes()[:2] == b"PK" or p.read_bytes()[:1] == b"\x80"
    ]


def test_killed_run_resumes_to_the_same_weights(tmp_path: Path, manuals: Path):
    data = ["--data", str(manuals / "train"), "--val-dir", str(manuals / "val")]
    plan = [*data, "--steps", "6", "--checkpoint-every", "3", "--val-every", "3"]
    straight = train(*plan, "--out", str(tmp_path / "a"))
    assert straight.returncode == 0, straight.stderr
    killed = train(*plan, "--out", str(tmp_path / "b"), "--debug-kill-at-step", "4")
    assert killed.returncode == -9, killed.stderr
    assert json.loads((tmp_path / "b" / "checkpoint.json").read_text())["step"] == 3
    resumed = train("--resume", "--out", str(tmp_path / "b"))  # settings from the checkpoint
    assert resumed.returncode == 0, resumed.stderr
    wa, wb = (
        weights(tmp_path / "a" / "model.safetensors"),
        weights(tmp_path / "b" / "model.safetensors"),
    )
    assert wa.keys() == wb.keys()
    for k in wa:
        assert torch.equal(wa[k], wb[k]), k
    ca, cb = (
        weights(tmp_path / "a" / "checkpoint.safetensors"),
        weights(tmp_path / "b" / "checkpoint.safetensors"),
    )
    for k in ca:
        assert torch.equal(ca[k], cb[k]), k

    def rows(run: str) -> list[dict]:
        timing = ("samples_per_s", "data_wait_share", "seconds")
        doc = json.loads((tmp_path / run / "metrics.json").read_text())
        return [{k: v for k, v in r.items() if k not in timing} for r in doc]

    # the rows the killed run logged after its checkpoint are replaced, not duplicated
    assert rows("a") == rows("b")
    assert [r["step"] for r in rows("b") if r["split"] == "val"] == [3, 6]
    assert (tmp_path / "b" / "curves.png").stat().st_size > 0
    model, cfg = load_model(tmp_path / "b" / "model.safetensors")
    assert cfg == TINY and not model.training


def test_generated_data_resumes_and_ignores_worker_count(tmp_path: Path):
    plan = ["--steps", "3", "--checkpoint-every", "2", "--samples-per-manual", "2"]
    plan += ["--generate-seeds", "50", "60"]
    a = train(*plan, "--out", str(tmp_path / "a"))
    assert a.returncode == 0, a.stderr
    # with no data workers the manuals are generated between the steps: the log says the run
    # mostly waited for data
    shares = [
        r["data_wait_share"] for r in json.loads((tmp_path / "a" / "metrics.json").read_text())
    ]
    assert len(shares) == 3 and all(0 <= x <= 1 for x in shares)
    assert sum(shares) / len(shares) > 0.3, shares
    assert "waiting for data" in a.stdout
    killed = train(*plan, "--out", str(tmp_path / "b"), "--debug-kill-at-step", "2")
    assert killed.returncode == -9, killed.stderr
    b = train("--resume", "--out", str(tmp_path / "b"), "--workers", "2")
    assert b.returncode == 0, b.stderr
    wa, wb = (
        weights(tmp_path / "a" / "model.safetensors"),
        weights(tmp_path / "b" / "model.safetensors"),
    )
    for k in wa:
        assert torch.equal(wa[k], wb[k]), k


def test_generated_streams_never_share_a_manual():
    def seeds(rank: int, world: int, n: int) -> list[int]:
        s = GeneratedSteps(
            model_config=TINY,
            seed=0,
            seed_range=(100, 10_000),
            generator={},
            batch_size=4,
            samples_per_manual=2,
            augment=False,
            submodules=False,
            rank=rank,
            world_size=world,
        )
        return [s.manual_seed(q)[0] for q in range(n)]

    all_seeds = [x for r in range(3) for x in seeds(r, 3, 50)]
    assert len(set(all_seeds)) == len(all_seeds)


def test_resumable_sampler_continues_mid_epoch():
    data = list(range(23))
    full = ResumableSampler(data, num_replicas=2, rank=1, seed=5)  # type: ignore[arg-type]
    full.set_epoch(3)
    part = ResumableSampler(data, num_replicas=2, rank=1, seed=5)  # type: ignore[arg-type]
    part.set_epoch(3)
    part.skip = 4
    assert list(part) == list(full)[4:] and len(part) == len(full) - 4
    assert all(epoch == 3 for _, epoch in full)


def test_two_torchrun_processes_end_with_identical_parameters(tmp_path: Path):
    out = tmp_path / "ddp"
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node=2"]
    cmd += ["-m", "mepnet.train", *COMMON, "--steps", "3", "--out", str(out)]
    cmd += ["--samples-per-manual", "2", "--generate-seeds", "70", "80", "--debug-checksums"]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=180, env=ENV)
    assert r.returncode == 0, r.stderr[-3000:]
    sums = [(out / f"params_rank{i}.sha256").read_text().strip() for i in (0, 1)]
    assert sums[0] == sums[1]
    model, _ = load_model(out / "model.safetensors")
    assert param_checksum(model) == sums[0]
    doc = json.loads((out / "checkpoint.json").read_text())
    assert doc["world_size"] == 2 and len(doc["ranks"]) == 2


# ---------------------------------------------------------------------------------------------
# Bad input: exit 2, one line on stderr naming the file


@pytest.fixture(scope="module")
def finished(tmp_path_factory: pytest.TempPathFactory, manuals: Path) -> Path:
    """A finished one-step run (its checkpoint is copied and damaged by the tests)."""
    out = tmp_path_factory.mktemp("finished") / "run"
    r = train("--data", str(manuals / "train"), "--steps", "1", "--out", str(out))
    assert r.returncode == 0, r.stderr
    return out


def copy_run(finished: Path, tmp_path: Path) -> Path:
    out = tmp_path / "run"
    shutil.copytree(finished, out)
    return out


def test_missing_and_empty_data_folders(tmp_path: Path, capsys: pytest.CaptureFixture[str]):
    missing = tmp_path / "nope"
    assert main(["--data", str(missing), "--out", str(tmp_path / "o")]) == 2
    one_error_line(capsys, str(missing), "no such data folder")
    (tmp_path / "empty").mkdir()
    assert main(["--data", str(tmp_path / "empty"), "--out", str(tmp_path / "o")]) == 2
    one_error_line(capsys, "empty", "no manual folders")


def test_existing_checkpoint_needs_resume(
    finished: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
):
    out = copy_run(finished, tmp_path)
    assert main(["--data", "x", "--out", str(out)]) == 2
    one_error_line(capsys, str(out), "--resume")


def test_resume_with_changed_settings_is_refused(
    finished: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
):
    out = copy_run(finished, tmp_path)
    assert main(["--resume", "--out", str(out), "--batch-size", "3"]) == 2
    one_error_line(capsys, "checkpoint.safetensors", "batch_size=2")
    assert main(["--resume", "--out", str(out), "--model", "slim"]) == 2
    one_error_line(capsys, "checkpoint.safetensors", "model")


def test_pickle_checkpoint_is_refused(
    finished: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
):
    out = copy_run(finished, tmp_path)
    # what torch.save writes begins with a zip header; a bare pickle with the PROTO opcode
    for head in (b"PK\x03\x04", b"\x80\x04\x95"):
        (out / "checkpoint.safetensors").write_bytes(head + b"\x00" * 64)
        assert main(["--resume", "--out", str(out)]) == 2
        one_error_line(capsys, "checkpoint.safetensors", "pickle")


def test_header_length_starting_with_0x80_is_not_a_pickle(tmp_path: Path):
    """A safetensors header of 0x..80 bytes begins with the byte a pickle begins with."""
    t = {"w": torch.arange(3, dtype=torch.float32)}
    for pad in range(0, 300):
        write_safetensors(tmp_path / "x.safetensors", t, {"pad": "x" * pad})
        if (tmp_path / "x.safetensors").read_bytes()[0] == 0x80:
            break
    else:
        raise AssertionError("no padding gave a header length ending in 0x80")
    got, meta = read_safetensors(tmp_path / "x.safetensors")
    assert torch.equal(got["w"], t["w"]) and meta["pad"] == "x" * pad


def test_corrupt_and_incomplete_checkpoints_are_refused(
    finished: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
):
    out = copy_run(finished, tmp_path)
    path = out / "checkpoint.safetensors"
    tensors, meta = read_safetensors(path)
    name = next(k for k in tensors if k.startswith("model/"))
    write_safetensors(path, {k: v for k, v in tensors.items() if k != name}, meta)
    assert main(["--resume", "--out", str(out), "--threads", "0"]) == 2
    one_error_line(capsys, str(path), "missing tensors", name[len("model/") :])

    path.write_bytes(path.read_bytes()[:100])
    assert main(["--resume", "--out", str(out)]) == 2
    one_error_line(capsys, str(path), "safetensors")

    path.unlink()
    assert main(["--resume", "--out", str(out)]) == 2
    one_error_line(capsys, str(path), "missing")


def test_settings_file_and_flags(tmp_path: Path, capsys: pytest.CaptureFixture[str]):
    settings = tmp_path / "train.json"
    settings.write_text(json.dumps({"batch_size": 7, "lr": 0.001, "data": ["a"]}))
    assert main(["--config", str(settings), "--lr", "0.002", "--print-config"]) == 0
    cfg = json.loads(capsys.readouterr().out)
    assert (cfg["batch_size"], cfg["lr"], cfg["data"]) == (7, 0.002, ["a"])
    assert main(["--config", str(settings), "--out", str(tmp_path / "o")]) == 2
    one_error_line(capsys, "a: no such data folder")
    settings.write_text(json.dumps({"batch_sise": 7}))
    assert main(["--config", str(settings)]) == 2
    one_error_line(capsys, str(settings), "batch_sise")


def test_init_fine_tunes_from_given_weights(finished: Path, tmp_path: Path, manuals: Path):
    """--init loads the weights (a fresh optimizer; at lr 0 the parameters stay exactly those
    weights); without it the same seed gives other weights."""
    init = finished / "model.safetensors"
    runs = {}
    for name, extra in (("init", ["--init", str(init)]), ("fresh", [])):
        out = tmp_path / name
        r = train("--data", str(manuals / "train"), "--steps", "1", "--lr", "0", "--seed", "5",
                  "--out", str(out), *extra)  # fmt: skip
        assert r.returncode == 0, r.stderr
        runs[name] = load_model(out / "model.safetensors")[0]
    want = load_model(init)[0]
    got = dict(runs["init"].named_parameters())
    for k, v in want.named_parameters():
        assert torch.equal(v, got[k]), k
    fresh = dict(runs["fresh"].named_parameters())
    assert any(not torch.equal(v, fresh[k]) for k, v in want.named_parameters())
    saved = json.loads((tmp_path / "init" / "config.json").read_text())["train"]
    assert saved["init"] == str(init)


def test_direct3d_starts_from_the_detectors_encoders(
    finished: Path, tmp_path: Path, manuals: Path, capsys: pytest.CaptureFixture[str]
):
    """--head direct3d --init DETECTOR: at lr 0 the tensors the two networks share are the
    detector's exactly, the regression heads are a fresh run's (same seed); a detector run cannot
    start from Direct3D weights (one line, exit 2)."""
    init = finished / "model.safetensors"
    runs = {}
    for name, extra in (("init", ["--init", str(init)]), ("fresh", [])):
        out = tmp_path / name
        r = train("--data", str(manuals / "train"), "--steps", "1", "--lr", "0", "--seed", "5",
                  "--head", "direct3d", "--out", str(out), *extra)  # fmt: skip
        assert r.returncode == 0, r.stderr
        runs[name] = dict(load_model(out / "model.safetensors")[0].named_parameters())
    det = dict(load_model(init)[0].named_parameters())  # (batch-norm statistics move at lr 0)
    shared = [k for k in runs["init"] if k.startswith(DIRECT3D_FROM_DETECTOR)]
    own = [k for k in runs["init"] if not k.startswith(DIRECT3D_FROM_DETECTOR)]
    assert shared and own and any(k.startswith("translation.") for k in own)
    for k in shared:
        assert torch.equal(runs["init"][k], det[k]), k
    assert any(not torch.equal(runs["fresh"][k], det[k]) for k in shared)
    for k in own:
        assert torch.equal(runs["init"][k], runs["fresh"][k]), k
    d3 = str(tmp_path / "init" / "model.safetensors")
    bad = ["--data", str(manuals / "train"), "--steps", "1", "--init", d3]
    assert main([*bad, "--out", str(tmp_path / "bad"), *COMMON]) == 2
    one_error_line(capsys, d3, "direct3d network", "--head")


def test_bf16_training_follows_fp32(finished: Path, tmp_path: Path, manuals: Path):
    """--precision bf16 runs the passes in bfloat16 (the weights end up other than fp32's from
    the same start and data) and trains the same network (they differ by far less than the
    steps moved them); a bad precision is one line, exit 2."""
    init = finished / "model.safetensors"
    got = {}
    for p in ("fp32", "bf16"):
        out = tmp_path / p
        r = train("--data", str(manuals / "train"), "--steps", "3", "--lr", "1e-3", "--seed", "5",
                  "--init", str(init), "--precision", p, "--out", str(out))  # fmt: skip
        assert r.returncode == 0, r.stderr
        got[p] = dict(load_model(out / "model.safetensors")[0].named_parameters())
        assert json.loads((out / "config.json").read_text())["train"]["precision"] == p
    start = dict(load_model(init)[0].named_parameters())
    moved = torch.cat([(got["fp32"][k] - v).flatten() for k, v in start.items()]).norm()
    apart = torch.cat([(got["bf16"][k] - got["fp32"][k]).flatten() for k in start]).norm()
    assert 0 < apart < 0.5 * moved, (float(apart), float(moved))
    r = train("--data", str(manuals / "train"), "--steps", "1", "--precision", "fp16",
              "--out", str(tmp_path / "bad"))  # fmt: skip
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "precision" in r.stderr, r.stderr


def test_init_weights_must_exist_and_fit(
    finished: Path, tmp_path: Path, manuals: Path, capsys: pytest.CaptureFixture[str]
):
    data = ["--data", str(manuals / "train"), "--steps", "1"]
    assert main([*data, "--out", str(tmp_path / "a"), "--init", str(tmp_path / "nope")]) == 2
    one_error_line(capsys, "nope", "no such weights file")
    init = str(finished / "model.safetensors")
    assert main([*data, "--out", str(tmp_path / "b"), "--init", init, "--model", "slim"]) == 2
    one_error_line(capsys, init, "do not fit", "image_size")
    (tmp_path / "junk.safetensors").write_bytes(b"\x10\x00" + b"x" * 40)
    junk = str(tmp_path / "junk.safetensors")
    assert main([*data, "--out", str(tmp_path / "c"), "--init", junk]) == 2
    one_error_line(capsys, junk)


class _Zeros(torch.utils.data.IterableDataset):
    def __iter__(self):
        while True:
            yield torch.zeros(1)


def _abort_at_exit(worker_id: int) -> None:
    """worker_init_fn: worker 1 aborts as it exits, as one did on a GPU machine (SIGABRT,
    "terminate called without an active exception") after a finished run's last checkpoint;
    worker 0 takes a second to exit, so the abort comes while the loader waits for worker 0
    (not for the aborting worker itself, which its join could reap first)."""
    import multiprocessing.util
    import time

    if worker_id == 1:
        multiprocessing.util.Finalize(None, os.abort, exitpriority=100)
    else:
        multiprocessing.util.Finalize(None, time.sleep, args=(1.0,), exitpriority=100)


def test_a_worker_dying_as_the_workers_stop_is_a_note_not_a_traceback(
    capsys: pytest.CaptureFixture[str],
):
    from mepnet.train.loop import Data
    from torch.utils.data import DataLoader

    loader = DataLoader(
        _Zeros(),
        batch_size=None,
        num_workers=2,
        worker_init_fn=_abort_at_exit,
        persistent_workers=True,
        multiprocessing_context="fork",
    )
    data = Data(loader, None, 0, 1)
    batches = data.batches(0)
    for _ in range(2):
        assert next(batches).shape == (1,)
    batches.close()
    data.close()  # raised RuntimeError ("... killed by signal: Aborted") before
    assert "ended abnormally" in capsys.readouterr().err
    assert loader._iterator is None
