"""cloudsieve.atomic: outputs appear whole under their name, or not at all."""

from __future__ import annotations

import os

import pytest

from cloudsieve.atomic import check_destination, make_temp_path, remove, replace, write_text
from cloudsieve.errors import DestinationExistsError, DestinationNotWritableError


def test_write_text_replaces_and_leaves_no_temporary(tmp_path):
    path = tmp_path / "report.md"
    write_text(path, "one\n")
    write_text(path, "two\n")
    assert path.read_text() == "two\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report.md"]
    assert os.stat(path).st_mode & 0o777 == 0o666 & ~_umask()


def test_a_failed_write_leaves_nothing(tmp_path):
    with pytest.raises(TypeError):
        write_text(tmp_path / "x.json", 3)  # not text: nothing written
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(DestinationNotWritableError):
        write_text(tmp_path / "missing" / "x.json", "x")


def test_temporary_folder_replaces_a_folder(tmp_path):
    dst = tmp_path / "tiles"
    dst.mkdir()
    (dst / "old").write_text("old")
    with pytest.raises(DestinationExistsError):
        check_destination(str(dst), overwrite=False, folder=True)
    check_destination(str(dst), overwrite=True, folder=True)
    tmp = make_temp_path(str(dst), directory=True)
    open(os.path.join(tmp, "new"), "w").close()
    replace(tmp, str(dst))
    assert sorted(os.listdir(dst)) == ["new"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tiles"]
    remove(str(tmp_path / "not-there"))  # nothing to remove: no error


def test_a_folder_never_replaced_by_a_file_nor_a_file_by_a_folder(tmp_path):
    folder, file = tmp_path / "ee.laz", tmp_path / "tiles"
    folder.mkdir()
    file.write_text("x")
    for overwrite in (False, True):
        with pytest.raises(DestinationExistsError) as exc:
            check_destination(str(folder), overwrite=overwrite)
        assert str(exc.value) == (f"{folder} is a folder: cloudsieve never replaces a folder with a file "
                                  "(remove it, or choose another name)")
        with pytest.raises(DestinationExistsError) as exc:
            check_destination(str(file), overwrite=overwrite, folder=True)
        assert str(exc.value) == (f"{file} is a file: cloudsieve never replaces a file with a folder "
                                  "(remove it, or choose another name)")


def test_a_folder_holding_foreign_entries_is_never_replaced(tmp_path):
    dst = tmp_path / "out"
    dst.mkdir()
    (dst / "notes.txt").write_text("mine")
    with pytest.raises(DestinationExistsError) as exc:
        check_destination(str(dst), overwrite=True, folder=True, foreign=lambda p: "notes.txt")
    assert str(exc.value) == (f"{dst} holds notes.txt: cloudsieve replaces only a folder of its own output "
                              "(remove it, or choose another name)")
    check_destination(str(dst), overwrite=True, folder=True, foreign=lambda p: None)


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask
