"""Atomic writes replace a file whole, and write through a symlink: the link's target is replaced, the link stays."""

import os

from cosemdepth.output_safety.atomic import atomic_path, atomic_write_text


def test_a_symlink_is_written_through(tmp_path):
    target = tmp_path / "real" / "model.onnx"
    target.parent.mkdir()
    target.write_text("old")
    link = tmp_path / "m.onnx"
    os.symlink(target, link)
    atomic_write_text(link, "new")
    assert link.is_symlink() and os.readlink(link) == str(target) and target.read_text() == "new"
    with atomic_path(link) as tmp:  # writers that take a file name (onnx, safetensors, PIL)
        assert tmp.parent == target.parent
        tmp.write_text("newer")
    assert link.is_symlink() and target.read_text() == "newer"
    assert sorted(os.listdir(target.parent)) == ["model.onnx"] and sorted(os.listdir(tmp_path)) == ["m.onnx", "real"]


def test_a_plain_file_is_replaced_whole(tmp_path):
    f = tmp_path / "a.json"
    atomic_write_text(f, "1")
    atomic_write_text(f, "22")
    assert f.read_text() == "22" and os.listdir(tmp_path) == ["a.json"]
    assert oct(f.stat().st_mode & 0o777) == oct(0o666 & ~_umask())


def _umask() -> int:
    m = os.umask(0)
    os.umask(m)
    return m
