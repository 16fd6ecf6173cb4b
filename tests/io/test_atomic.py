"""Output folders written all or nothing, and output paths checked before work (io.atomic)."""

import os

import pytest

from metalens_cli.errors import InputError
from metalens_cli.io.atomic import atomic_folder, check_folder_unused, check_output_file, check_output_folder


def test_atomic_folder_publishes_everything_or_nothing(tmp_path):
    target = tmp_path / "new" / "out"
    with pytest.raises(KeyboardInterrupt):
        with atomic_folder(target) as staging:
            (staging / "a.txt").write_text("a")
            raise KeyboardInterrupt
    assert not target.exists() and os.listdir(tmp_path / "new") == []
    with atomic_folder(target) as staging:
        (staging / "a.txt").write_text("a")
    assert os.listdir(target) == ["a.txt"] and os.listdir(tmp_path / "new") == ["out"]
    (target / "keep.txt").write_text("user's")
    with atomic_folder(target) as staging:  # an existing folder: files moved in, others kept
        (staging / "a.txt").write_text("b")
    assert sorted(os.listdir(target)) == ["a.txt", "keep.txt"] and (target / "a.txt").read_text() == "b"
    assert os.listdir(tmp_path / "new") == ["out"]


@pytest.mark.parametrize(
    "make, path, words",
    [
        (lambda t: None, "missing/x.csv", "does not exist"),
        (lambda t: (t / "d.csv").mkdir(), "d.csv", "is a folder"),
        (lambda t: os.mkfifo(t / "f.csv"), "f.csv", "not a regular file"),
        (lambda t: None, "a" * 300 + ".csv", "bytes"),
        (lambda t: None, "x.txt", "does not end in .csv"),
    ],
)
def test_check_output_file_refuses(tmp_path, make, path, words):
    make(tmp_path)
    with pytest.raises(InputError, match=words) as info:
        check_output_file(tmp_path / path, "--csv", suffixes=(".csv",))
    assert info.value.field == "--csv"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".metalens-")]


def test_check_output_paths_refuse_unwritable_folders_even_for_root():
    with pytest.raises(InputError, match="cannot write in folder"):
        check_output_file("/proc/x.csv", "--csv")
    with pytest.raises(InputError, match="cannot write in folder"):
        check_output_folder("/proc/new/out", "-o")


def test_check_output_folder_creates_nothing(tmp_path):
    assert check_output_folder(tmp_path / "a" / "b", "-o") == tmp_path / "a" / "b"
    assert os.listdir(tmp_path) == []
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match="not a folder"):
        check_output_folder(tmp_path / "file" / "out", "-o")


def test_a_published_folder_has_the_permissions_of_mkdir(tmp_path):
    from metalens_cli.io.atomic import atomic_folder

    old = os.umask(0o022)
    try:
        with atomic_folder(tmp_path / "out") as staging:
            (staging / "a.txt").write_text("x")
        (tmp_path / "made").mkdir()
    finally:
        os.umask(old)
    assert (tmp_path / "out").stat().st_mode & 0o777 == (tmp_path / "made").stat().st_mode & 0o777 == 0o755


def test_check_folder_unused_refuses_a_folder_holding_anything(tmp_path):
    check_folder_unused(tmp_path / "new", "--output")  # absent, then empty: fine
    (tmp_path / "new").mkdir()
    check_folder_unused(tmp_path / "new", "--output")
    (tmp_path / "new" / "b.png").write_text("user's")
    (tmp_path / "new" / ".hidden").write_text("user's")
    with pytest.raises(InputError) as refused:
        check_folder_unused(tmp_path / "new", "--output")
    assert refused.value.field == "--output" and "holds '.hidden' (and 1 more)" in refused.value.message
    assert "--overwrite" in refused.value.expected


def test_a_failed_write_in_a_folder_names_the_target_file_not_its_staging_copy(tmp_path):
    import errno

    with pytest.raises(OSError) as failed, atomic_folder(tmp_path / "out") as staging:
        raise OSError(errno.EFBIG, os.strerror(errno.EFBIG), str(staging / "a.png"))
    assert failed.value.errno == errno.EFBIG and failed.value.filename == str(tmp_path / "out" / "a.png")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    "make, what",
    [
        (lambda p: p.mkdir(), "is a folder"),
        (os.mkfifo, "is not a regular file"),
        (lambda p: p.symlink_to(p.with_name("victim")), "is a symbolic link"),
    ],
)
def test_a_folder_published_into_never_replaces_anything_but_a_regular_file(tmp_path, make, what):
    """--overwrite replaces same-named regular files; a folder, FIFO or link in a file's place is
    refused naming it, before any file is moved (the folder keeps all of the old files, none of
    the run's) and the staging folder is removed."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "a.png").write_text("old a")
    (tmp_path / "victim").write_text("the user's")
    make(out / "b.png")
    with pytest.raises(InputError, match=rf"--output: '{out / 'b.png'}', where this run writes a file, {what}"):
        with atomic_folder(out) as staging:
            (staging / "a.png").write_text("new a")
            (staging / "b.png").write_text("new b")
    assert (out / "a.png").read_text() == "old a" and (tmp_path / "victim").read_text() == "the user's"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "victim"]
