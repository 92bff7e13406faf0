"""StagedDir replaces the contents of the output folder, never the folder itself (a symlink stays, an existing folder
keeps its inode, mode, group and setgid bit); a failed, killed or interrupted run leaves the previous output whole;
OutputFiles writes through a symlinked folder and never replaces a file changed since cosemdepth wrote it."""

import json
import os
import stat
from pathlib import Path

import pytest

from cosemdepth.errors import ConfigError
from cosemdepth.output_safety.outdir import LOCK_NAME, MARKER, STAGING_PREFIX, read_marker
from cosemdepth.output_safety.staging import OutputFiles, StagedDir


def _write(out: Path, files: dict[str, str], command: str = "predict", **kw) -> None:
    with StagedDir(out, command, **kw) as tmp:
        for name, text in files.items():
            (tmp / name).parent.mkdir(parents=True, exist_ok=True)
            (tmp / name).write_text(text)


def _contents(folder: Path) -> dict[str, str]:
    return {
        p.relative_to(folder).as_posix(): p.read_text()
        for p in sorted(folder.rglob("*"))
        if p.is_file() and p.name != MARKER
    }


def _hidden(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith(".") and p.name != MARKER)


@pytest.fixture
def umask_027():
    old = os.umask(0o027)
    yield
    os.umask(old)


def _other_gid() -> int:
    """A group this process may give its folders other than its own: any group as root, else a supplementary one
    (its own group when it has no other)."""
    if os.geteuid() == 0:
        return 4242
    return next((g for g in os.getgroups() if g != os.getegid()), os.getegid())


def test_a_new_folder_gets_the_usual_permissions_and_its_parents_group(tmp_path, umask_027):
    parent = tmp_path / "shared"
    parent.mkdir()
    gid = _other_gid()
    os.chown(parent, -1, gid)
    os.chmod(parent, 0o2775)  # a setgid group folder: what is made in it belongs to its group
    _write(parent / "a" / "out", {"x/y.txt": "1"})
    out = parent / "a" / "out"
    for folder in (parent / "a", out, out / "x"):
        st = folder.stat()
        assert stat.S_IMODE(st.st_mode) == 0o2750 and st.st_gid == gid, folder  # 0777 - umask 027, setgid
    f = (out / "x" / "y.txt").stat()
    assert stat.S_IMODE(f.st_mode) == 0o640 and f.st_gid == gid
    plain = tmp_path / "plain"
    _write(plain, {"z.txt": "1"})
    assert stat.S_IMODE(plain.stat().st_mode) == 0o750


def test_an_existing_folder_keeps_its_inode_mode_group_and_setgid_bit(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    gid = _other_gid()
    os.chown(out, -1, gid)
    os.chmod(out, 0o2770)
    before = out.stat()
    for files in ({"a.txt": "first", "d/b.txt": "first"}, {"c.txt": "second"}):  # empty, then a previous output
        _write(out, files)
        st = out.stat()
        assert (st.st_ino, stat.S_IMODE(st.st_mode), st.st_gid) == (before.st_ino, 0o2770, gid)
        assert _contents(out) == files and _hidden(out) == []  # the previous output is gone, whole
        assert all(p.stat().st_gid == gid for p in out.rglob("*"))
    assert sorted(read_marker(out)["files"]) == ["c.txt"]


def test_a_symlink_stays_and_its_target_receives_the_output(tmp_path):
    target = tmp_path / "results"
    target.mkdir()
    link = tmp_path / "out"
    os.symlink(target, link)
    _write(link, {"a.txt": "1"})
    _write(link, {"b.txt": "2"})  # replaces the previous output in the target
    assert link.is_symlink() and os.readlink(link) == str(target)
    assert _contents(target) == {"b.txt": "2"} and read_marker(target)["command"] == "predict"
    dangling = tmp_path / "later"
    os.symlink(tmp_path / "not-yet", dangling)
    _write(dangling, {"c.txt": "3"})
    assert dangling.is_symlink() and _contents(tmp_path / "not-yet") == {"c.txt": "3"}


def test_a_failed_run_leaves_the_previous_output_whole(tmp_path):
    out = tmp_path / "out"
    _write(out, {"a.txt": "old"})
    with pytest.raises(RuntimeError):
        with StagedDir(out, "predict") as tmp:
            (tmp / "a.txt").write_text("new")
            raise RuntimeError("model failed")
    assert _contents(out) == {"a.txt": "old"} and _hidden(out) == []
    with pytest.raises(RuntimeError):
        with StagedDir(tmp_path / "new" / "out", "predict") as tmp:
            raise RuntimeError("model failed")
    assert sorted(os.listdir(tmp_path)) == ["out"]  # the folders the run created are gone


def test_a_file_edited_during_the_run_stops_the_replacement(tmp_path):
    out = tmp_path / "out"
    _write(out, {"labels/1.png": "old"})
    with pytest.raises(ConfigError, match=f"{out / 'labels' / '1.png'}: changed since cosemdepth predict"):
        with StagedDir(out, "predict") as tmp:
            (tmp / "new.txt").write_text("new")
            (out / "labels" / "1.png").write_text("hand-corrected")
    assert _contents(out) == {"labels/1.png": "hand-corrected"} and _hidden(out) == []


def _killed_run(out: Path, files: dict[str, str], after: int) -> int:
    """Replace ``out``'s contents in a child process that dies (os._exit) at its ``after``-th rename; returns the
    number of renames a whole replacement makes when ``after`` is larger."""
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: count renames, die at the chosen one
        os.close(r)
        real_rename, count = os.rename, [0]

        def rename(src, dst):
            count[0] += 1
            if count[0] == after:
                os._exit(9)
            real_rename(src, dst)

        os.rename = rename
        try:
            _write(out, files)
        finally:
            os.write(w, str(count[0]).encode())
            os._exit(0)
    os.close(w)
    done = os.read(r, 100)
    os.close(r)
    os.waitpid(pid, 0)
    return int(done) if done else -1


def test_a_run_killed_at_any_point_of_the_replacement_leaves_one_whole_output(tmp_path):
    old = {"depth/1.npy": "old1", "depth/2.npy": "old2", "predictions.json": "old"}
    new = {"depth/1.npy": "new1", "labels/1.png": "new", "predictions.json": "new"}
    _write(tmp_path / "probe", old)
    total = _killed_run(tmp_path / "probe", new, after=10**6)
    # out: the marker, depth/, predictions.json; the aside folder renamed; in: depth/, labels/, predictions.json, marker
    assert total == 3 + 1 + 4
    outcomes = set()
    for after in range(1, total + 1):
        out = tmp_path / f"out{after}"
        _write(out, old)
        _killed_run(out, new, after)
        # the next run finishes or undoes the replacement before its own checks: one whole output, no leftovers
        StagedDir(out, "predict").check()
        assert _contents(out) in (old, new), after
        outcomes.add("new" if _contents(out) == new else "old")
        assert _hidden(out) == [] and read_marker(out) is not None
        assert sorted(read_marker(out)["files"]) == sorted(_contents(out))
        _write(out, {"x.txt": "again"})
        assert _contents(out) == {"x.txt": "again"}
    assert outcomes == {"old", "new"}  # killed before the previous output was entirely aside: put back; after: done


def test_a_killed_runs_partial_output_is_removed_a_live_runs_is_not_touched(tmp_path):
    out = tmp_path / "out"
    _write(out, {"a.txt": "old"})
    stale = out / f"{STAGING_PREFIX}dead"
    (stale / "depth").mkdir(parents=True)
    (stale / LOCK_NAME).write_text("")  # nobody holds its lock: its run is gone
    (stale / "depth" / "1.npy").write_text("partial")
    _write(out, {"b.txt": "new"})
    assert _contents(out) == {"b.txt": "new"} and _hidden(out) == []
    with StagedDir(out, "predict") as tmp:  # a live run: its lock is held
        with pytest.raises(ConfigError, match="another cosemdepth run is writing this folder"):
            StagedDir(out, "predict").check()
        (tmp / "c.txt").write_text("mine")
    assert _contents(out) == {"c.txt": "mine"}


def test_output_files_write_through_a_symlink_and_keep_edited_files(tmp_path):
    target = tmp_path / "metrics"
    target.mkdir()
    os.symlink(target, tmp_path / "link")
    for text in ("one", "two"):
        with OutputFiles(tmp_path / "link", command="evaluate", names=("metrics.json",)) as files:
            files.add_text("metrics.json", text)
    assert (tmp_path / "link").is_symlink() and (target / "metrics.json").read_text() == "two"
    assert json.loads((target / MARKER).read_text())["files"]["metrics.json"]["size"] == 3
    (target / "metrics.json").write_text("mine")
    with pytest.raises(ConfigError, match=f"{target / 'metrics.json'}: changed since cosemdepth evaluate"):
        with OutputFiles(tmp_path / "link", command="evaluate", names=("metrics.json",)) as files:
            files.add_text("metrics.json", "three")
    assert (target / "metrics.json").read_text() == "mine"
