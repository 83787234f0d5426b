"""The one I/O layer (gtsam_rotid.files): staged writes that never touch a user's files, one "exists" error, one
image-folder order shared by the tracker and the recordings."""

import os

import cv2
import numpy as np
import pytest

from gtsam_rotid import cli, files, simulate
from gtsam_rotid.errors import DatasetExistsError, OutputError, OutputExistsError
from gtsam_rotid.files import check_output, image_files, staged, staged_directory, write_json, write_text
from gtsam_rotid.recordings import read_frames
from gtsam_rotid.tracking import frame_source


def test_a_staged_write_leaves_the_users_tmp_file_alone(tmp_path):
    target = tmp_path / "result.json"
    mine = tmp_path / "result.json.tmp"
    mine.write_text("my notes")
    write_json(target, {"a": 1})
    assert target.read_text() == '{"a": 1}\n'
    assert mine.read_text() == "my notes"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["result.json", "result.json.tmp"]


def test_an_existing_file_is_refused_with_the_one_exists_error(tmp_path):
    target = tmp_path / "out.txt"
    target.write_text("old")
    with pytest.raises(OutputExistsError, match=f"{target} exists; pass overwrite=True") as info:
        write_text(target, "new")
    assert isinstance(info.value, FileExistsError) and isinstance(info.value, OutputError)
    assert issubclass(DatasetExistsError, OutputExistsError)
    assert target.read_text() == "old"
    write_text(target, "new", overwrite=True)
    assert target.read_text() == "new"


def test_a_failed_or_interrupted_write_keeps_the_old_file_and_leaves_nothing(tmp_path):
    target = tmp_path / "out.txt"
    target.write_text("old")
    for error in (OSError(28, "No space left on device"), KeyboardInterrupt()):
        with pytest.raises(OutputError if isinstance(error, OSError) else KeyboardInterrupt) as info:
            with staged(target, overwrite=True) as staging:
                staging.write_text("half")
                raise error
        if isinstance(error, OSError):
            assert str(info.value) == f"cannot write {target}: No space left on device"
        assert target.read_text() == "old"
        assert [p.name for p in tmp_path.iterdir()] == ["out.txt"]


def test_outputs_are_checked_before_any_work(tmp_path):
    with pytest.raises(OutputError, match="is a directory"):
        check_output(tmp_path)
    with pytest.raises(OutputError, match="the directory .*missing does not exist"):
        check_output(tmp_path / "missing" / "x.json")
    assert check_output(tmp_path / "missing" / "x.json", make_parent=True) == tmp_path / "missing" / "x.json"
    (tmp_path / "afile").write_text("")
    with pytest.raises(OutputError, match="is not a directory"):
        check_output(tmp_path / "afile" / "x.json", make_parent=True)


def test_image_folders_are_read_in_natural_order_by_the_tracker_and_the_recordings(tmp_path):
    for i in (10, 2, 1):
        cv2.imwrite(str(tmp_path / f"img{i}.png"), np.full((8, 8), i, np.uint8))
    (tmp_path / ".hidden.png").write_bytes(b"")
    (tmp_path / "notes.txt").write_text("not an image")
    assert [p.name for p in image_files(tmp_path)] == ["img1.png", "img2.png", "img10.png"]
    source, total = frame_source(tmp_path)
    assert total == 3 and [int(image[0, 0]) for image, _ in source] == [1, 2, 10]
    assert [int(frame[0, 0]) for frame in read_frames(tmp_path)] == [1, 2, 10]


def test_calibrate_refuses_to_write_its_result_over_its_own_dataset(tmp_path, capsys):
    dataset, _ = simulate.reference_scene(seed=0, duration=2.0, n_measurements=3)
    root = dataset.save(tmp_path / "ds")
    before = (root / "dataset.json").read_bytes()
    listing = sorted(os.listdir(root))
    code = cli.main(["calibrate", str(root), "-o", str(root / "dataset.json"), "--overwrite"])
    assert code == 1
    err = capsys.readouterr().err
    assert "is a file of the dataset" in err and "write the result elsewhere" in err
    assert (root / "dataset.json").read_bytes() == before
    assert sorted(os.listdir(root)) == listing


def test_a_staged_file_gets_the_permissions_a_plain_write_would(tmp_path):
    plain = tmp_path / "plain.txt"
    plain.write_text("x")
    staged_file = write_text(tmp_path / "staged.txt", "x")
    assert staged_file.stat().st_mode & 0o777 == plain.stat().st_mode & 0o777
    os.chmod(staged_file, 0o640)                 # replacing a file keeps its mode
    write_text(staged_file, "y", overwrite=True)
    assert staged_file.stat().st_mode & 0o777 == 0o640


def _tree(root) -> dict:
    return {str(p.relative_to(root)): p.read_text() for p in sorted(root.rglob("*")) if p.is_file()}


def test_a_staged_directory_replaces_the_old_one_and_leaves_nothing_beside_it(tmp_path):
    target = tmp_path / "out"
    with staged_directory(target) as staging:           # a new directory, its parent made
        assert staging.parent == tmp_path and staging.name.startswith(".out.tmp-")
        (staging / "a.txt").write_text("new")
    assert _tree(target) == {"a.txt": "new"} and os.listdir(tmp_path) == ["out"]
    (target / "b.txt").write_text("old")
    with staged_directory(target) as staging:
        (staging / "c.txt").write_text("newer")
    assert _tree(target) == {"c.txt": "newer"} and os.listdir(tmp_path) == ["out"]


def test_a_failed_or_interrupted_or_refused_staged_directory_keeps_the_old_one(tmp_path, monkeypatch):
    target = tmp_path / "out"
    target.mkdir()
    (target / "old.txt").write_text("old")

    def refuse():
        raise OutputExistsError("changed while writing")

    for error, check in ((OSError(28, "No space left on device"), None), (KeyboardInterrupt(), None),
                         (None, refuse)):
        with pytest.raises(type(error) if error is not None else OutputExistsError):
            with staged_directory(target, check) as staging:
                (staging / "half.txt").write_text("half")
                if error is not None:
                    raise error
        assert _tree(target) == {"old.txt": "old"}
        assert os.listdir(tmp_path) == ["out"], "no hidden sibling left behind"
    rename = os.rename

    def no_rename_in(source, destination):              # the new one cannot be moved in: the old one comes back
        if ".out.tmp-" in str(source):
            raise OSError(18, "Invalid cross-device link")
        rename(source, destination)

    monkeypatch.setattr(os, "rename", no_rename_in)
    monkeypatch.setattr(files, "exchange", lambda a, b: False)  # the two-rename path (no atomic exchange)
    with pytest.raises(OSError, match="cross-device"):
        with staged_directory(target) as staging:
            (staging / "new.txt").write_text("new")
    assert _tree(target) == {"old.txt": "old"} and os.listdir(tmp_path) == ["out"]


def test_a_directory_is_replaced_in_one_atomic_step_where_the_system_can(tmp_path, monkeypatch):
    target = tmp_path / "out"
    target.mkdir()
    (target / "old.txt").write_text("old")
    probe_a, probe_b = tmp_path / "a", tmp_path / "b"
    probe_a.write_text("a")
    probe_b.write_text("b")
    if not files.exchange(probe_a, probe_b):
        pytest.skip("this system has no atomic exchange (renameat2); the two-rename path is tested above")
    assert probe_a.read_text() == "b" and probe_b.read_text() == "a"

    def no_rename(source, destination):  # the swap must not go through a moment without the target
        raise AssertionError(f"os.rename({source}, {destination}) called")

    monkeypatch.setattr(os, "rename", no_rename)
    with staged_directory(target) as staging:
        (staging / "new.txt").write_text("new")
    assert _tree(target) == {"new.txt": "new"}
    assert sorted(os.listdir(tmp_path)) == ["a", "b", "out"], "the old one deleted, nothing hidden left"


def test_a_dataset_set_aside_by_an_interrupted_save_is_named_when_loading(tmp_path):
    from gtsam_rotid.dataset import Dataset
    from gtsam_rotid.errors import DatasetNotFoundError

    (tmp_path / ".ds.old-1a2b3c4d").mkdir()
    with pytest.raises(DatasetNotFoundError, match=r"left the previous dataset at .*\.ds\.old-1a2b3c4d: rename it"):
        Dataset.load(tmp_path / "ds")
