"""Whether a previous output can be replaced, checked before a run (cosemdepth.output_safety.replaceable): it names the entry
in the way, and a check that passes changes nothing (not even a folder's times)."""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "data"))
from _writers import snapshot  # noqa: E402

from cosemdepth.errors import ConfigError  # noqa: E402
from cosemdepth.output_safety.replaceable import FS_IMMUTABLE_FL, check_replaceable, fs_flags  # noqa: E402


def previous_output(root: Path) -> Path:
    out = root / "out"
    (out / "traj" / "depth").mkdir(parents=True)
    (out / "predictions.json").write_text("{}")
    (out / "traj" / "depth" / "0.npy").write_bytes(b"x")
    return out


def test_a_replaceable_output_passes_and_is_left_exactly_as_it_was(tmp_path):
    out = previous_output(tmp_path)
    before = snapshot(tmp_path)
    check_replaceable(out, "--out folder")
    check_replaceable(tmp_path / "missing", "--out folder")  # nothing there: nothing to replace
    assert snapshot(tmp_path) == before  # sizes and mtimes of every file and folder, the probed folders included


@pytest.fixture
def immutable(tmp_path):
    """``chattr +i`` on a path for the test (the tests run where chattr works: root on ext4/xfs/tmpfs)."""
    made = []

    def make(path: Path) -> Path:
        r = subprocess.run(["chattr", "+i", str(path)], capture_output=True, text=True)
        assert r.returncode == 0 and shutil.which("chattr"), f"chattr +i {path}: {r.stderr}"
        made.append(path)
        return path

    yield make
    for path in reversed(made):
        subprocess.run(["chattr", "-i", str(path)], check=True)


def test_an_immutable_entry_is_named(tmp_path, immutable):
    out = previous_output(tmp_path)
    entry = immutable(out / "traj" / "depth" / "0.npy")
    assert fs_flags(entry) & FS_IMMUTABLE_FL
    with pytest.raises(
        ConfigError,
        match=rf"^{entry}: cannot replace the --out folder: this entry in it is "
        r"immutable \(chattr -i removes that\); nothing was written$",
    ):
        check_replaceable(out, "--out folder")


def test_a_folder_that_cannot_change_is_named(tmp_path, immutable):
    out = previous_output(tmp_path)
    folder = immutable(out / "traj")
    with pytest.raises(ConfigError, match=rf"{out / 'traj'}: cannot replace the --out folder"):
        check_replaceable(out, "--out folder")
    assert folder.is_dir()


@pytest.fixture
def append_only():
    """``chattr +a`` on a folder for the test."""
    made = []

    def make(path: Path) -> Path:
        r = subprocess.run(["chattr", "+a", str(path)], capture_output=True, text=True)
        assert r.returncode == 0, f"chattr +a {path}: {r.stderr}"
        made.append(path)
        return path

    yield make
    for path in reversed(made):
        subprocess.run(["chattr", "-a", str(path)], check=True)


def test_an_append_only_folder_is_refused_without_leaving_a_probe_in_it(tmp_path, append_only):
    """An append-only folder takes a new entry but never lets it go: the probe must not try."""
    from cosemdepth.output_safety.outdir import probe_writable
    from cosemdepth.output_safety.replaceable import FS_APPEND_FL, probe_folder
    from cosemdepth.output_safety.staging import OutputFiles

    (tmp_path / "q").mkdir()
    folder = append_only(tmp_path / "q")
    assert fs_flags(folder) & FS_APPEND_FL
    assert probe_folder(folder) == (
        "the folder is append-only: entries can be added but not removed (chattr -a removes that)"
    )
    with pytest.raises(
        ConfigError,
        match=rf"^{folder}: cannot write the --out folder \({folder}: the folder is "
        "append-only",
    ):
        probe_writable(folder, f"{folder}: cannot write the --out folder")
    with pytest.raises(ConfigError, match="append-only"):
        with OutputFiles(folder, "--out folder", command="evaluate") as out:
            out.add_text("metrics.json", "{}")
    assert list(folder.iterdir()) == []  # no probe, no temporary file


def test_an_immutable_folder_is_named_by_the_probe(tmp_path, immutable):
    from cosemdepth.output_safety.replaceable import probe_folder

    (tmp_path / "q").mkdir()
    folder = immutable(tmp_path / "q")
    assert probe_folder(folder).startswith("the folder is immutable: entries cannot be added or removed")
    assert probe_folder(tmp_path) is None
