"""The bound on worker processes (cosemdepth.workers): an absurd --workers is one line naming the flag and the bound,
before any process is started or any output written, in every command that starts a pool."""

import os

import pytest

from cosemdepth import workers
from cosemdepth.cli.main import main
from cosemdepth.errors import ConfigError
from cosemdepth.training.config import DataConfig
from cosemdepth.workers import WORKERS_PER_CORE, check_workers, max_workers, usable_cores


def test_the_bound_is_per_usable_core(monkeypatch):
    assert usable_cores() == len(os.sched_getaffinity(0))
    monkeypatch.setattr(workers, "usable_cores", lambda: 2)
    assert max_workers() == 2 * WORKERS_PER_CORE
    assert check_workers(0) == 0 and check_workers(2 * WORKERS_PER_CORE) == 2 * WORKERS_PER_CORE
    with pytest.raises(
        ConfigError,
        match=rf"^--workers {2 * WORKERS_PER_CORE + 1}: more worker processes than this "
        rf"machine can run \(at most {2 * WORKERS_PER_CORE}: {WORKERS_PER_CORE} per "
        r"CPU core, 2 cores here\); use fewer$",
    ):
        check_workers(2 * WORKERS_PER_CORE + 1)
    for bad in (-1, 1.5, True, "2"):
        with pytest.raises(ConfigError, match=r"--workers must be an integer >= 0"):
            check_workers(bad)
    with pytest.raises(ConfigError, match=r"synth's --workers must be an integer >= 1, got 0"):
        check_workers(0, "synth's --workers", minimum=1)


def test_train_config_is_bounded(monkeypatch):
    monkeypatch.setattr(workers, "usable_cores", lambda: 1)
    DataConfig(num_workers=WORKERS_PER_CORE)  # checked when made
    with pytest.raises(ConfigError, match=rf"^data.num_workers {WORKERS_PER_CORE + 1}: more worker processes"):
        DataConfig(num_workers=WORKERS_PER_CORE + 1)


@pytest.mark.parametrize(
    "argv",
    [
        ["predict", "--model", "M", "--flight", "--images", "I", "--poses", "P.txt", "--hfov", "90", "--out", "{out}"],
        ["evaluate", "--model", "M", "--dataset", "synthair", "--root", "R", "--out", "{out}"],
        ["synth", "--out", "{out}", "--frames", "8", "--size", "32"],
    ],
)
def test_an_absurd_worker_count_stops_the_command_before_anything_is_written(argv, tmp_path, capsys):
    out = tmp_path / "out"
    argv = [a.replace("{out}", str(out)) for a in argv] + ["--workers", "100000"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert f"--workers 100000: more worker processes than this machine can run (at most {max_workers()}" in err
    assert list(tmp_path.iterdir()) == []
