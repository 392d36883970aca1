"""Every command ends bad input the same way: one line naming the input and the problem, exit
2, no traceback; Ctrl-C: one line, exit 130; it never deletes or overwrites what it did not
write. One test per defect found by hostile use (issue 11)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from mepnet.files import MANIFEST
from test_files import dead_pid


def bundled() -> Path:
    from mepnet.infer import bundled_manual

    return bundled_manual()


def example_mpd() -> Path:
    from mepnet.infer import bundled_example

    return bundled_example()


def cmd(module: str, *args: str, timeout: float = 600) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", module, *map(str, args)],
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def one_line_error(r: subprocess.CompletedProcess[str], *fragments: str) -> None:
    assert r.returncode == 2, (r.stdout, r.stderr)
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, r.stderr
    assert "Traceback" not in r.stderr
    for f in fragments:
        assert f in lines[0], lines[0]


def test_infer_never_deletes_what_it_did_not_write(tmp_path: Path):
    out = tmp_path / "d"
    out.mkdir()
    (out / "thesis.txt").write_text("x")
    r = cmd("mepnet.infer", bundled(), "--out", out, "--predictor", "oracle", "--no-progress")
    one_line_error(r, str(out), "not written by mepnet")
    assert (out / "thesis.txt").read_text() == "x"
    # --out is the input manual: refused, the manual intact
    manual = tmp_path / "manual"
    import shutil

    shutil.copytree(bundled(), manual)
    before = sorted(p.name for p in manual.iterdir())
    r = cmd("mepnet.infer", manual, "--out", manual, "--predictor", "oracle", "--no-progress")
    one_line_error(r, str(manual))
    assert sorted(p.name for p in manual.iterdir()) == before
    # its own earlier output is replaced; leftovers of a killed run (SIGKILL) are removed
    plan = tmp_path / "plan"
    stale = tmp_path / f".tmp-mepnet-plan-{dead_pid()}-abcdef"
    stale.mkdir()
    for _ in range(2):
        r = cmd("mepnet.infer", bundled(), "--out", plan, "--predictor", "oracle", "--no-progress")
        assert r.returncode == 0, r.stderr
    assert (plan / "plan.json").is_file() and (plan / MANIFEST).is_file()
    assert not stale.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d", "manual", "plan"]


def test_infer_ldraw_checks_size_first_and_writes_atomically(tmp_path: Path):
    r = cmd("mepnet.infer", example_mpd(), "--out", tmp_path / "o", "--size", "0")
    one_line_error(r, "--size")
    assert "mepnet: model" not in r.stdout  # rejected before the report
    assert not (tmp_path / "o").exists()
    r = cmd("mepnet.infer", example_mpd(), "--out", tmp_path / "o", "--size", "32")
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "o" / MANIFEST).is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o"]


def test_json_outputs_are_checked_before_the_work(tmp_path: Path):
    r = cmd(
        "mepnet.eval",
        "--data",
        bundled(),
        "--predictor",
        "oracle",
        "--json",
        tmp_path / "no" / "m.json",
    )
    one_line_error(r, "does not exist")
    assert "Pose Acc" not in r.stdout  # refused before evaluating
    r = cmd("mepnet.eval", "--data", bundled(), "--predictor", "oracle", "--json", tmp_path)
    one_line_error(r, "is a folder")
    r = cmd("mepnet.ldraw", "info", example_mpd(), "--json", tmp_path)
    one_line_error(r, "is a folder")
    assert list(tmp_path.iterdir()) == []  # no stray temporary files


@pytest.mark.parametrize("sigma", ["-5", "nan", "inf"])
def test_bad_sigma(sigma: str):
    r = cmd("mepnet.eval", "--data", bundled(), "--predictor", "oracle-noisy", "--sigma", sigma)
    one_line_error(r, "--sigma")


def test_abys_time_limit_is_checked():
    for limit in ("0", "-1", "nan"):
        r = cmd("mepnet.eval", "--data", bundled(), "--predictor", "abys", "--time-limit", limit)
        one_line_error(r, "--time-limit")


def test_model_settings_are_checked(tmp_path: Path):
    r = cmd(
        "mepnet.train",
        "--out",
        tmp_path / "run",
        "--steps",
        "1",
        "--model",
        "tiny",
        "--model-set",
        "hg_channels=-4",
    )
    one_line_error(r, "hg_channels")
    # a weights file whose header holds an impossible config: refused when loaded
    import torch
    from mepnet.detector.config import ModelConfig
    from mepnet.detector.net import build_model
    from mepnet.detector.weights import save_model

    cfg = ModelConfig.tiny()
    d = cfg.to_dict()
    d["base_grid"] = "big"
    save_model(tmp_path, build_model(cfg).state_dict(), d)
    assert torch  # (torch is what the weights are made of)
    r = cmd(
        "mepnet.eval",
        "--data",
        bundled(),
        "--predictor",
        "mepnet",
        "--weights",
        tmp_path / "model.safetensors",
    )
    one_line_error(r, "model.safetensors", "base_grid")


def test_synth_ranges_and_concurrent_runs(tmp_path: Path):
    config = tmp_path / "gen.json"
    config.write_text(json.dumps({"footprint": [4, 6], "components": [3, 5]}))
    out = tmp_path / "out"
    out.mkdir()
    # another run still writing into the same folder (this process is alive) keeps its
    # temporary folder; a killed run's is removed
    live = out / f".tmp-mepnet-manual_00000009-{os.getpid()}-abc"
    live.mkdir()
    dead = out / f".tmp-mepnet-manual_00000008-{dead_pid()}-abc"
    dead.mkdir()
    r = cmd(
        "mepnet.synth",
        "--out",
        out,
        "--manuals",
        "1",
        "--seed",
        "3",
        "--size",
        "32",
        "--config",
        config,
        "--no-progress",
    )
    assert r.returncode == 0, r.stderr
    assert live.exists() and not dead.exists()
    doc = json.loads((out / "manual_00000003" / "manual.json").read_text())
    assert doc["source"]["generator"]["footprint"] == [4, 6]
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"footprint": [6, 4, 1]}))
    r = cmd("mepnet.synth", "--out", out, "--manuals", "1", "--config", bad)
    one_line_error(r, "generator settings")


def nested_mpd(path: Path, depth: int) -> Path:
    lines = []
    for k in range(depth):
        lines += [f"0 FILE m{k}.ldr", f"1 16 0 0 0 1 0 0 0 1 0 0 0 1 m{k + 1}.ldr", ""]
    lines += [f"0 FILE m{depth}.ldr", "1 4 0 0 0 1 0 0 0 1 0 0 0 1 3001.dat", ""]
    path.write_text("\n".join(lines))
    return path


@pytest.mark.parametrize("depth", [2_000, 20_000])
def test_deep_nesting_is_a_clear_error(tmp_path: Path, depth: int):
    f = nested_mpd(tmp_path / "deep.mpd", depth)
    for args in (
        ("mepnet.ldraw", "info", f),
        ("mepnet.infer", f),
        ("mepnet.ldraw", "to-manual", f, "--out", tmp_path / "m"),
    ):
        r = cmd(*args)
        one_line_error(r, "deep.mpd", "nested")
    assert not (tmp_path / "m").exists()


def test_shallow_nesting_still_works(tmp_path: Path):
    f = nested_mpd(tmp_path / "ok.mpd", 20)
    r = cmd("mepnet.ldraw", "info", f)
    assert r.returncode == 0, r.stderr
    r = cmd("mepnet.ldraw", "to-manual", f, "--out", tmp_path / "m", "--size", "32")
    assert r.returncode == 0, r.stderr


def interrupt(
    args: list[str], ready: str, timeout: float = 300
) -> subprocess.CompletedProcess[str]:
    """Start a command, wait until its stderr shows ``ready``, press Ctrl-C."""
    # Ctrl-C as at a terminal: a suite started in the background (``make test &``) runs with
    # SIGINT ignored, which the command would inherit (and Python then installs no handler)
    p = subprocess.Popen(
        [sys.executable, "-m", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    assert p.stderr is not None
    fd = p.stderr.fileno()
    os.set_blocking(fd, False)
    seen = b""
    t0 = time.monotonic()
    try:
        while ready.encode() not in seen:
            assert p.poll() is None, seen.decode()
            assert time.monotonic() - t0 < timeout, seen.decode()
            try:
                seen += os.read(fd, 65536)
            except BlockingIOError:
                time.sleep(0.05)
        time.sleep(0.5)
        p.send_signal(signal.SIGINT)
        os.set_blocking(fd, True)
        out, err = p.communicate(timeout=120)
    finally:
        if p.poll() is None:
            p.kill()
            p.communicate()
    return subprocess.CompletedProcess(p.args, p.returncode, out.decode(), (seen + err).decode())


def test_ctrl_c_in_infer_is_one_line(tmp_path: Path):
    # a manual long enough (about 30 steps with the detector) that the signal comes mid-run even
    # on a loaded machine
    from conftest import generate_manuals

    data = generate_manuals(tmp_path / "data", 1, 5)
    out = tmp_path / "out"
    out.mkdir()
    r = interrupt(
        ["mepnet.infer", str(data / "manual_00000005"), "--out", str(out / "p")], "step/s"
    )
    assert r.returncode == 130, r.stderr
    assert "Traceback" not in r.stderr
    assert r.stderr.rstrip().splitlines()[-1] == "mepnet.infer: interrupted"
    assert list(out.iterdir()) == []  # nothing half-written


def test_ctrl_c_in_train_is_one_line(tmp_path: Path):
    r = interrupt(
        [
            "mepnet.train",
            "--out",
            str(tmp_path / "run"),
            "--model",
            "tiny",
            "--steps",
            "1000",
            "--batch-size",
            "2",
            "--workers",
            "2",
            "--generate-size",
            "64",
            "--samples-per-manual",
            "2",
        ],
        "step/s",
    )
    assert r.returncode == 130, r.stderr
    assert "Traceback" not in r.stderr
    assert r.stderr.rstrip().splitlines()[-1] == "mepnet.train: interrupted"


def test_train_writes_only_into_a_folder_of_its_own(tmp_path: Path):
    out = tmp_path / "run"
    out.mkdir()
    (out / "model.json").write_text("my own notes")
    r = cmd(
        "mepnet.train",
        "--out",
        out,
        "--model",
        "tiny",
        "--steps",
        "1",
        "--batch-size",
        "1",
        "--workers",
        "0",
    )
    one_line_error(r, str(out), "did not write")
    assert (out / "model.json").read_text() == "my own notes"


def test_synth_caps_worker_processes(tmp_path: Path):
    """--workers 1000 must not start a thousand interpreters (memory): a few per CPU at most."""
    r = cmd(
        "mepnet.synth",
        "--out",
        tmp_path / "o",
        "--manuals",
        "12",
        "--size",
        "16",
        "--workers",
        "1000",
        "--no-progress",
    )
    assert r.returncode == 0, r.stderr
    cap = 4 * (os.cpu_count() or 1)
    if cap < 12:
        assert f"using {cap} worker processes, not 1000" in r.stderr
    assert len(list((tmp_path / "o").glob("manual_*"))) == 12


def test_usage_mistakes_are_one_line():
    for args in (
        ("mepnet.infer", "--size", "abc"),
        ("mepnet.ldraw",),
        ("mepnet.manual", "strip", "x"),
        ("mepnet.eval", "--data", "x"),
        ("mepnet.synth", "--manuals", "1e9", "--out", "o"),
    ):
        r = cmd(*args)
        one_line_error(r, "(see --help)")


def test_json_outputs_replace_only_their_own(tmp_path: Path):
    mine = tmp_path / "mine.json"
    mine.write_text('{"my": "notes"}')
    r = cmd(
        "mepnet.eval",
        "--data",
        bundled(),
        "--predictor",
        "oracle",
        "--json",
        mine,
        "--no-progress",
        "--cd-points",
        "50",
    )
    one_line_error(r, "mine.json", "not written by mepnet.eval")
    assert mine.read_text() == '{"my": "notes"}'
    ours = tmp_path / "ours.json"
    for _ in range(2):  # its own earlier output is replaced
        r = cmd(
            "mepnet.eval",
            "--data",
            bundled(),
            "--predictor",
            "oracle",
            "--json",
            ours,
            "--no-progress",
            "--cd-points",
            "50",
        )
        assert r.returncode == 0, r.stderr
    assert json.loads(ours.read_text())["written_by"] == "mepnet.eval"
    r = cmd("mepnet.ldraw", "info", example_mpd(), "--json", "/dev/null")
    one_line_error(r, "/dev/null", "not a regular file")
    assert Path("/dev/null").is_char_device()
    manual_json = tmp_path / "m"
    import shutil

    shutil.copytree(bundled(), manual_json)
    before = (manual_json / "manual.json").read_bytes()
    r = cmd(
        "mepnet.eval",
        "--data",
        manual_json,
        "--predictor",
        "oracle",
        "--json",
        manual_json / "manual.json",
    )
    one_line_error(r, "manual.json", "not written by mepnet.eval")
    assert (manual_json / "manual.json").read_bytes() == before


def test_inputs_that_are_not_files(tmp_path: Path):
    os.mkfifo(tmp_path / "fifo.ldr")
    r = cmd("mepnet.ldraw", "info", tmp_path / "fifo.ldr", timeout=60)
    one_line_error(r, "fifo.ldr", "not a regular file")
    os.mkfifo(tmp_path / "w.safetensors")
    r = cmd(
        "mepnet.infer",
        bundled(),
        "--out",
        tmp_path / "o",
        "--weights",
        tmp_path / "w.safetensors",
        timeout=60,
    )
    one_line_error(r, "w.safetensors", "not a regular file")


def test_weights_and_checkpoints_with_malformed_headers(tmp_path: Path):
    import torch
    from safetensors.torch import save_file

    for name, meta in (
        ("list", "[1, 2]"),
        ("str", '"x"'),
        ("cfg", '{"format": "mepnet.model", "version": 1, "model_config": "slim"}'),
    ):
        save_file(
            {"a": torch.zeros(1)}, str(tmp_path / f"{name}.safetensors"), metadata={"mepnet": meta}
        )
        r = cmd(
            "mepnet.infer",
            bundled(),
            "--out",
            tmp_path / "o",
            "--weights",
            tmp_path / f"{name}.safetensors",
            "--no-progress",
        )
        one_line_error(r, f"{name}.safetensors")
    run = tmp_path / "run"
    r = cmd(
        "mepnet.train",
        "--out",
        run,
        "--data",
        bundled(),
        "--model",
        "tiny",
        "--steps",
        "1",
        "--batch-size",
        "1",
        "--workers",
        "0",
        "--no-progress",
    )
    assert r.returncode == 0, r.stderr
    from safetensors import safe_open

    with safe_open(str(run / "checkpoint.safetensors"), "pt") as f:
        tensors = {k: f.get_tensor(k) for k in f.keys()}
        doc = json.loads(f.metadata()["mepnet"])
    for change in ({"step": -3}, {"step": "x"}, {"scheduler": [1]}, {"ranks": "x"}):
        save_file(
            tensors,
            str(run / "checkpoint.safetensors"),
            metadata={"mepnet": json.dumps({**doc, **change})},
        )
        r = cmd(
            "mepnet.train",
            "--out",
            run,
            "--resume",
            "--steps",
            "2",
            "--workers",
            "0",
            "--no-progress",
        )
        one_line_error(r, "checkpoint.safetensors", "malformed training state")


@pytest.mark.parametrize(
    "args, fragment",
    [
        (("--lr", "nan"), "--lr"),
        (("--lr", "-1"), "--lr"),
        (("--grad-clip", "-1"), "--grad-clip"),
        (("--plateau-factor", "5"), "--plateau-factor"),
        (("--threads", "100000"), "--threads"),
        (("--seed", "-1"), "--seed"),
    ],
)
def test_training_settings_are_checked(tmp_path: Path, args: tuple[str, ...], fragment: str):
    r = cmd(
        "mepnet.train",
        "--out",
        tmp_path / "run",
        "--data",
        bundled(),
        "--model",
        "tiny",
        "--steps",
        "1",
        "--workers",
        "0",
        *args,
    )
    one_line_error(r, fragment)
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize(
    "config, fragment",
    [
        ([1, 2], "JSON object"),
        ({"batch_size": "2"}, "batch_size"),
        ({"augment": "yes"}, "augment"),
        ({"data": 3}, "data"),
        ({"out": 3}, "out"),
    ],
)
def test_training_config_files_are_checked(tmp_path: Path, config, fragment: str):
    f = tmp_path / "train.json"
    f.write_text(json.dumps(config))
    r = cmd(
        "mepnet.train",
        "--config",
        f,
        "--out",
        tmp_path / "run",
        "--steps",
        "1",
        "--model",
        "tiny",
        "--workers",
        "0",
    )
    one_line_error(r, "train.json", fragment)


def test_two_trainings_into_one_folder(tmp_path: Path):
    out = tmp_path / "run"
    args = [
        "mepnet.train",
        "--out",
        str(out),
        "--data",
        str(bundled()),
        "--model",
        "tiny",
        "--steps",
        "400",
        "--batch-size",
        "1",
        "--workers",
        "0",
    ]
    first = subprocess.Popen(
        [sys.executable, "-m", *args], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE
    )
    try:
        t0 = time.monotonic()
        while not (out / ".mepnet-train.lock").exists():
            assert first.poll() is None and time.monotonic() - t0 < 120
            time.sleep(0.1)
        time.sleep(1.0)
        r = cmd(*args)
        one_line_error(r, str(out), "another training run")
    finally:
        first.kill()
        first.communicate()


def test_synth_settings_the_probe_cannot_hide(tmp_path: Path):
    for cfg in (
        {"components": [-5, -1]},
        {"components": ["a", 2]},
        {"p_submodule": 2.0},
        {"p_submodule": "x"},
    ):
        f = tmp_path / "g.json"
        f.write_text(json.dumps(cfg))
        r = cmd(
            "mepnet.synth",
            "--out",
            tmp_path / "o",
            "--manuals",
            "1",
            "--size",
            "32",
            "--config",
            f,
            "--no-progress",
        )
        one_line_error(r, "generator settings")


def test_file_names_need_not_be_utf8(tmp_path: Path):
    import shutil

    name = os.fsdecode(b"bad\xffname")
    shutil.copytree(bundled(), tmp_path / name)
    for args in (
        (
            "mepnet.infer",
            tmp_path / name,
            "--out",
            tmp_path / "o",
            "--predictor",
            "oracle",
            "--no-progress",
        ),
        (
            "mepnet.eval",
            "--data",
            tmp_path / name,
            "--predictor",
            "oracle-noisy",
            "--no-progress",
            "--cd-points",
            "50",
        ),
        ("mepnet.restyle", "--data", tmp_path / name, "--out", tmp_path / "rs"),
    ):
        r = subprocess.run(
            [sys.executable, "-m", *map(os.fsencode, map(str, args))],
            capture_output=True,
            timeout=600,
        )
        assert r.returncode == 0, r.stderr.decode(errors="replace")
        assert b"Traceback" not in r.stderr


def test_restyle_data_dot(tmp_path: Path):
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "mepnet.restyle",
            "--data",
            ".",
            "--out",
            str(tmp_path / "rs"),
            "--only",
            "page",
        ],
        capture_output=True,
        text=True,
        cwd=bundled(),
        timeout=300,
    )
    assert r.returncode == 0, r.stderr
    assert "restyled 1 manual" in r.stdout
    assert (tmp_path / "rs" / bundled().name / "manual.json").is_file()


def test_errors_in_data_workers_are_one_line(tmp_path: Path):
    import shutil

    data = tmp_path / "data" / "m"
    shutil.copytree(bundled(), data)
    for p in data.glob("step_0*.png"):
        if not p.name.endswith("_ids.png"):
            p.write_bytes(b"garbage")
    r = cmd(
        "mepnet.train",
        "--out",
        tmp_path / "run",
        "--data",
        tmp_path / "data",
        "--model",
        "tiny",
        "--steps",
        "2",
        "--batch-size",
        "1",
        "--workers",
        "1",
        "--no-progress",
    )
    one_line_error(r, "unreadable step image")


def test_notes_do_not_add_lines_to_an_error(tmp_path: Path):
    """A note (64 px images resized for the detector) is said only when the run succeeds."""
    out = tmp_path / "syn"
    r = cmd(
        "mepnet.synth",
        "--out",
        out,
        "--manuals",
        "1",
        "--seed",
        "5",
        "--size",
        "64",
        "--no-progress",
    )
    assert r.returncode == 0, r.stderr
    manual = next(out.iterdir())
    r = cmd("mepnet.infer", manual, "--out", tmp_path / "ok", "--no-progress")
    assert r.returncode == 0 and "resized to the detector's" in r.stderr, r.stderr
    (manual / "step_002.png").write_bytes(b"garbage")
    r = cmd("mepnet.infer", manual, "--out", tmp_path / "bad", "--no-progress")
    one_line_error(r, "step_002.png")


def test_a_closed_pipe_ends_quietly(tmp_path: Path):
    tall = tmp_path / "tall.ldr"  # 2,000 steps: far more output than a pipe buffers
    tall.write_text(
        "".join(f"1 4 0 {-24 * i} 0 1 0 0 0 1 0 0 0 1 3005.dat\n0 STEP\n" for i in range(2000))
    )
    p = subprocess.Popen(
        [sys.executable, "-m", "mepnet.ldraw", "info", "--steps", str(tall)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    assert p.stdout is not None and p.stderr is not None
    p.stdout.readline()
    p.stdout.close()  # as `| head -1` does
    err = p.stderr.read().decode()
    p.stderr.close()
    assert p.wait(timeout=60) == 141, err
    assert "Traceback" not in err and "error" not in err, err


def test_infer_dot_names_the_folder(tmp_path: Path):
    import shutil

    shutil.copytree(bundled(), tmp_path / "m")
    r = subprocess.run(
        [sys.executable, "-m", "mepnet.infer", ".", "--predictor", "oracle", "--no-progress"],
        capture_output=True,
        text=True,
        cwd=tmp_path / "m",
        timeout=300,
    )
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "m" / "m-plan" / "plan.json").is_file()
