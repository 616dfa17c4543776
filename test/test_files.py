"""Atomic writes: the old file or the new one, never a part, and no temporary left behind."""

import os
import stat

import pytest

import sfs_ros.core.exchange.files as files_module
from sfs_ros.core.exchange.files import FILE_MODE, write_atomic, write_atomic_all


def test_write_replaces_the_file_with_the_documented_mode(tmp_path):
    path = tmp_path / "a.txt"
    path.write_bytes(b"old")
    assert write_atomic(path, b"new") == path
    assert path.read_bytes() == b"new"
    assert stat.S_IMODE(path.stat().st_mode) == FILE_MODE
    assert [p.name for p in tmp_path.iterdir()] == ["a.txt"]


@pytest.mark.parametrize("failure", [OSError("disk full"), KeyboardInterrupt(), SystemExit(3)])
def test_a_failure_while_writing_keeps_the_old_files_and_no_temporary(tmp_path, monkeypatch,
                                                                      failure):
    first, second = tmp_path / "report.json", tmp_path / "mesh.ply"
    first.write_bytes(b"old report")
    second.write_bytes(b"old mesh")
    calls = []

    def fail_on_second(fd):
        calls.append(fd)
        if len(calls) == 2:        # the second file's fsync: the first is staged already
            raise failure

    monkeypatch.setattr(files_module.os, "fsync", fail_on_second)
    with pytest.raises(type(failure)):
        write_atomic_all([(first, b"new report"), (second, b"new mesh")])
    assert first.read_bytes() == b"old report" and second.read_bytes() == b"old mesh"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mesh.ply", "report.json"]


def test_a_failed_rename_removes_the_temporaries_not_yet_renamed(tmp_path, monkeypatch):
    first, second = tmp_path / "report.json", tmp_path / "mesh.ply"
    second.write_bytes(b"old mesh")
    real_replace = os.replace

    def replace_once(src, dst, **dir_fds):
        if os.path.basename(dst) == second.name:
            raise KeyboardInterrupt
        real_replace(src, dst, **dir_fds)

    monkeypatch.setattr(files_module.os, "replace", replace_once)
    with pytest.raises(KeyboardInterrupt):
        write_atomic_all([(first, b"new report"), (second, b"new mesh")])
    # Renamed in order: the report is new, the mesh still the old one, nothing else.
    assert first.read_bytes() == b"new report" and second.read_bytes() == b"old mesh"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mesh.ply", "report.json"]


def test_files_are_renamed_in_the_order_given(tmp_path, monkeypatch):
    order = []
    real_replace = os.replace
    monkeypatch.setattr(files_module.os, "replace",
                        lambda src, dst, **dir_fds: (order.append(os.path.basename(dst)),
                                                     real_replace(src, dst, **dir_fds)))
    paths = write_atomic_all([(tmp_path / "b", b"2"), (tmp_path / "a", b"1")])
    assert paths == [tmp_path / "b", tmp_path / "a"] and order == ["b", "a"]


def test_a_missing_folder_is_an_error_and_writes_nothing(tmp_path):
    with pytest.raises(FileNotFoundError):
        write_atomic(tmp_path / "missing" / "a.txt", b"x")
    assert list(tmp_path.iterdir()) == []


def test_within_creates_folders_and_never_follows_a_link_below_it(tmp_path):
    root, elsewhere = tmp_path / "out", tmp_path / "elsewhere"
    root.mkdir()
    elsewhere.mkdir()
    assert write_atomic(root / "a" / "b" / "m.ply", b"mesh", within=root).read_bytes() == b"mesh"
    # A folder swapped for a link after the path was checked: refused, nothing written there.
    (root / "c").symlink_to(elsewhere, target_is_directory=True)
    with pytest.raises(OSError):
        write_atomic(root / "c" / "m.ply", b"mesh", within=root)
    assert list(elsewhere.iterdir()) == []
    # A link as the file itself is replaced, not written through.
    (root / "d.ply").symlink_to(elsewhere / "target.ply")
    write_atomic(root / "d.ply", b"mesh", within=root)
    assert not (root / "d.ply").is_symlink() and not (elsewhere / "target.ply").exists()
    with pytest.raises(ValueError, match="not inside the output folder"):
        write_atomic(tmp_path / "x.ply", b"mesh", within=root)


def test_an_error_names_the_destination_never_the_temporary(tmp_path):
    """A destination that is a folder (the rename fails) and a file where a folder should
    be (``within``): each error names the path asked for; no temporary is left."""
    (tmp_path / "m.ply").mkdir()
    with pytest.raises(IsADirectoryError) as failed:
        write_atomic(tmp_path / "m.ply", b"mesh")
    assert failed.value.filename == str(tmp_path / "m.ply") and ".tmp" not in str(failed.value)
    (tmp_path / "a").write_bytes(b"a file")
    with pytest.raises(NotADirectoryError) as failed:
        write_atomic(tmp_path / "a" / "b" / "c.txt", b"x", within=tmp_path)
    assert failed.value.filename == str(tmp_path / "a")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a", "m.ply"]
    assert list((tmp_path / "m.ply").iterdir()) == []


def test_a_long_name_is_written_and_none_removes_a_file_in_its_turn(tmp_path):
    long = tmp_path / ("x" * 250 + ".ply")      # its temporary would pass 255 bytes whole
    assert write_atomic(long, b"mesh").read_bytes() == b"mesh"
    report, mesh = tmp_path / "m.report.json", tmp_path / "m.ply"
    report.write_bytes(b"old report")
    write_atomic_all([(report, None), (mesh, b"mesh")])
    assert not report.exists() and mesh.read_bytes() == b"mesh"
    write_atomic_all([(report, None), (mesh, b"mesh 2"), (report, b"new report")])
    assert report.read_bytes() == b"new report" and mesh.read_bytes() == b"mesh 2"
