"""Path checks before any work, results folders replaced only on success, one-line failure messages."""
import os

import pytest

from addon import paths
from addon.cli import one_line


def test_a_failed_run_leaves_the_old_results_and_no_staging_folder(tmp_path):
    out = tmp_path / "results"
    out.mkdir()
    (out / "report.json").write_text("old")
    with pytest.raises(RuntimeError), paths.staged_folder(str(out)) as stage:
        with open(os.path.join(stage, "report.json"), "w") as f:
            f.write("new")
        raise RuntimeError("Cycles failed half-way")
    assert (out / "report.json").read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["results"]


def test_a_successful_run_replaces_the_old_results_whole(tmp_path):
    out = tmp_path / "results"
    out.mkdir()
    (out / "stale.png").write_text("from an earlier run")
    with paths.staged_folder(str(out)) as stage:
        with open(os.path.join(stage, "report.json"), "w") as f:
            f.write("new")
    assert sorted(p.name for p in out.iterdir()) == ["report.json"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["results"]
    assert oct(out.stat().st_mode & 0o777) == oct(0o777 & ~_umask())


def _umask():
    mask = os.umask(0)
    os.umask(mask)
    return mask


def test_an_empty_results_folder_is_used_without_overwrite(tmp_path):
    (tmp_path / "empty").mkdir()
    assert paths.output_folder("--out", str(tmp_path / "empty"), overwrite=False) == str(tmp_path / "empty")


@pytest.mark.parametrize("head", [b"BLENDER-v300", b"\x1f\x8b\x08\x00", b"\x28\xb5\x2f\xfd\x00"])
def test_plain_and_compressed_blends_are_accepted_before_opening(tmp_path, head):
    f = tmp_path / "a.blend"
    f.write_bytes(head + b"\0" * 16)
    assert paths.input_blend("--blend", str(f)) == str(f)


def test_failure_messages_name_the_final_file_not_lamina_temporaries():
    e = IsADirectoryError(21, "Is a directory", "/work/out/.dirtarget.g996frpo.tmp")
    assert one_line(e) == "Is a directory: /work/out/dirtarget"
    e = OSError(28, "No space left on device", "/r/.scene.blend.ab12cd34.tmp.blend")
    assert one_line(e) == "No space left on device: /r/scene.blend"
    assert one_line(RuntimeError("Error: File format is not supported\n")) == "File format is not supported"
    assert one_line(RuntimeError("writing /r/.results.x1y2z3w4.lamina-tmp/nodes/a.exr")) == "writing /r/results/nodes/a.exr"
