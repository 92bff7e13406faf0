"""``cosemdepth train`` on the command line: SIGKILL during training and during a checkpoint write, then resume;
bad configs, missing data and bad output folders fail with exit code 2, a message naming the culprit, and no
partial output."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

import pytest
import yaml

from cosemdepth.cli.main import main
from cosemdepth.training.checkpoint import DELAY_ENV, load_checkpoint, validate_checkpoint
from cosemdepth.training.events import read_events


def _train_cmd(python, run_dir: Path, tiny_cli, **overrides) -> list[str]:
    return [python, "-m", "cosemdepth", "train", "--out", str(run_dir), *tiny_cli(**overrides)]


def _wait_for(predicate, proc: subprocess.Popen, timeout: float = 120.0, what: str = "") -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        if proc.poll() is not None:
            out = proc.stdout.read() if proc.stdout else ""
            raise AssertionError(f"the run ended (code {proc.returncode}) before {what}:\n{out}")
        if time.monotonic() > deadline:
            proc.kill()
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.02)


def _checkpoints(run_dir: Path) -> dict[int, Path]:
    folder = run_dir / "checkpoints"
    return {int(p.name[5:]): p for p in folder.iterdir() if p.name.startswith("ckpt-")} if folder.exists() else {}


def _kill(proc: subprocess.Popen) -> None:
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL


def test_sigkill_while_training_and_while_writing_a_checkpoint_then_resume(tmp_path, python, cli_env, tiny_cli):
    """(That a resumed run continues bit-exactly is tested in-process, in test_trainer.py.)"""
    run = tmp_path / "run"
    settings = dict(train__epochs=3, train__max_steps=10, train__checkpoint_every=2, train__keep_last=3)
    cmd = _train_cmd(python, run, tiny_cli, **settings)
    ck = run / "checkpoints"

    # 1. killed while the checkpoint of step 4 is being written (the writer sleeps after each file)
    slow = dict(cli_env, **{DELAY_ENV: "0.2"})
    p = subprocess.Popen(cmd, env=slow, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    _wait_for(
        lambda: (
            ck.exists()
            and any(x.name.startswith(".tmp-ckpt-00000004") and (x / "optimizer.pt").exists() for x in ck.iterdir())
        ),
        p,
        what="the checkpoint of step 4 being written",
    )
    _kill(p)
    assert sorted(_checkpoints(run)) == [0, 2]  # the half-written one never got its final name
    assert any(x.name.startswith(".tmp-ckpt-00000004") for x in ck.iterdir())
    for path in _checkpoints(run).values():
        validate_checkpoint(path)

    # 2. the same command resumes from step 2; killed in the middle of training, after the checkpoint of step 6
    #    (no delay: the kill lands wherever the run is after step 7)
    p = subprocess.Popen(cmd, env=cli_env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    events_file = run / "events.jsonl"
    _wait_for(
        lambda: (
            any(e["kind"] == "train" and e["step"] >= 7 for e in read_events(events_file) if e.get("time", 0) > 0)
            and 6 in _checkpoints(run)
        ),
        p,
        what="step 7 after the checkpoint of step 6",
    )
    _kill(p)
    events = read_events(events_file)
    resumes = [e for e in events if e["kind"] == "resume"]
    assert len(resumes) == 1 and resumes[0]["step"] == 2
    assert any(e["kind"] == "checkpoint_temp_removed" for e in events)
    newest = max(_checkpoints(run))
    assert newest >= 6

    # 3. the same command again: resumes from the newest complete checkpoint and finishes
    done = subprocess.run(cmd, env=cli_env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, timeout=300)
    assert done.returncode == 0, done.stdout
    events = read_events(events_file)
    resumes = [e for e in events if e["kind"] == "resume"]
    assert [r["step"] for r in resumes] == [2, newest]
    assert events[-1]["kind"] == "done" and events[-1]["step"] == 10
    kept = _checkpoints(run)
    assert sorted(kept) == [6, 8, 10] and not [x for x in ck.iterdir() if x.name.startswith(".")]
    for path in kept.values():
        validate_checkpoint(path)
        load_checkpoint(path)


def _run_cli(args: list[str], capsys) -> tuple[int, str]:
    code = main(["train", *args])
    return code, capsys.readouterr().err


def _listing(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


@pytest.mark.parametrize(
    "args, needle",
    [
        (["--set", "train.lrr=1"], "train.lrr"),
        (["--set", "train.lr=-0.001"], "train.lr must be a finite number > 0"),
        (["--lr", "-1"], "train.lr"),
        (["--set", "data.train.0.name=imagenet"], "unknown dataset 'imagenet'"),
        (["--set", "model.arch=unet"], "model arch must be one of"),
        (["--set", "data.train.0.name=synthair", "--set", "data.train.0.root=MISSING"], "MISSING"),
        (["--set", "data.train.0.name=midair"], "data.train[0].root"),
        (["--config", "no_such_config"], "no_such_config: config file not found"),
        (["--init-weights", "MISSING"], "train.init_weights: MISSING: model folder not found"),
    ],
)
def test_bad_config_values_fail_cleanly(tmp_path, capsys, tiny_cli, args, needle):
    args = [a.replace("MISSING", str(tmp_path / "no_dataset_here")) for a in args]
    needle = needle.replace("MISSING", str(tmp_path / "no_dataset_here"))
    out = tmp_path / "run"
    code, err = _run_cli(["--out", str(out), *tiny_cli(), *args], capsys)
    assert code == 2
    assert needle in err and "Traceback" not in err
    assert _listing(tmp_path) == []  # nothing written


def test_output_folder_that_is_a_file(tmp_path, capsys, tiny_cli):
    f = tmp_path / "run"
    f.write_text("not a folder")
    code, err = _run_cli(["--out", str(f), *tiny_cli()], capsys)
    assert code == 2 and f"--out {f}: exists and is not a folder" in err
    assert f.read_text() == "not a folder" and _listing(tmp_path) == ["run"]
    code, err = _run_cli(["--out", str(f / "sub"), *tiny_cli()], capsys)
    assert code == 2 and "is a file" in err and _listing(tmp_path) == ["run"]


def test_output_folder_that_is_not_empty_and_not_a_run(tmp_path, capsys, tiny_cli):
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "notes.txt").write_text("mine")
    code, err = _run_cli(["--out", str(tmp_path / "run"), *tiny_cli()], capsys)
    assert code == 2 and "not empty and is not a cosemdepth run" in err
    assert _listing(tmp_path) == ["run", "run/notes.txt"]


def test_unwritable_output_folder(tmp_path, capsys, tiny_cli):
    if os.geteuid() == 0:  # root writes anywhere permissions allow; /sys refuses new entries even to root
        parent = Path("/sys")
        assert parent.is_dir()
    else:
        parent = tmp_path / "locked"
        parent.mkdir()
        parent.chmod(0o555)
    target = parent / "cosemdepth-test-run" / "deeper"
    try:
        code, err = _run_cli(["--out", str(target), *tiny_cli()], capsys)
    finally:
        if parent != Path("/sys"):
            parent.chmod(0o755)
    assert code == 2 and "not writable" in err and str(parent) in err
    assert not (parent / "cosemdepth-test-run").exists()


def test_resuming_with_another_model_is_refused(tmp_path, capsys, tiny_cli):
    out = tmp_path / "run"
    assert _run_cli(["--out", str(out), *tiny_cli(train__max_steps=1)], capsys)[0] == 0
    before = _listing(out)
    code, err = _run_cli(["--out", str(out), *tiny_cli(train__max_steps=2, model__levels=2)], capsys)
    assert code == 2 and "use a new --out folder" in err
    assert _listing(out) == before


def test_print_config(capsys, tmp_path):
    code = main(["train", "--out", str(tmp_path / "x"), "--dataset", "toy", "--lr", "0.01", "--print-config"])
    out = capsys.readouterr().out
    assert code == 0 and "lr: 0.01" in out and "name: toy" in out
    assert not (tmp_path / "x").exists()


def test_bf16_flag_and_key_round_trip(capsys, tmp_path):
    """--bf16 sets train.bf16; the printed config loads back with it; without the flag it stays false."""
    import yaml

    from cosemdepth.training.config import RunConfig

    assert main(["train", "--out", str(tmp_path / "x"), "--dataset", "toy", "--bf16", "--print-config"]) == 0
    on = yaml.safe_load(capsys.readouterr().out)
    assert on["train"]["bf16"] is True and RunConfig.from_dict(on).train.bf16 is True
    assert main(["train", "--out", str(tmp_path / "x"), "--dataset", "toy", "--print-config"]) == 0
    assert yaml.safe_load(capsys.readouterr().out)["train"]["bf16"] is False
    assert (
        main(["train", "--out", str(tmp_path / "x"), "--dataset", "toy", "--set", "train.bf16=true", "--print-config"])
        == 0
    )
    assert yaml.safe_load(capsys.readouterr().out)["train"]["bf16"] is True
    assert not (tmp_path / "x").exists()


def test_init_weights_flag_sets_the_key(capsys, tmp_path):
    assert (
        main(["train", "--out", str(tmp_path / "x"), "--dataset", "toy", "--init-weights", "w/best", "--print-config"])
        == 0
    )
    assert yaml.safe_load(capsys.readouterr().out)["train"]["init_weights"] == "w/best"


def test_the_module_runs_as_a_command(python, cli_env):
    r = subprocess.run(
        [python, "-m", "cosemdepth", "train", "--help"], env=cli_env, capture_output=True, text=True, timeout=120
    )
    assert r.returncode == 0 and "--out" in r.stdout and "KEY=VALUE" in r.stdout
