"""The ``output_dir`` parameter made into the folder a node writes in, without a running
node: created if needed, refused by name when empty or when it cannot be made."""

import pytest

from sfs_ros.ros.params import ParameterError, output_folder


def test_the_output_folder_and_its_subfolder_are_made(tmp_path):
    assert output_folder(str(tmp_path / "a" / "meshes"), "the meshes") == \
        tmp_path / "a" / "meshes"
    made = output_folder(str(tmp_path / "out"), "the bags", "bags")
    assert made == tmp_path / "out" / "bags" and made.is_dir()


def test_an_empty_output_folder_is_refused_with_what_it_is_for(tmp_path):
    with pytest.raises(ParameterError) as refused:
        output_folder("  ", "the meshes")
    assert refused.value.name == "output_dir"
    assert str(refused.value) == ("invalid parameter 'output_dir': is required: the folder "
                                  "for the meshes")


def test_an_output_folder_that_cannot_be_made_names_the_parameter(tmp_path):
    (tmp_path / "file").write_text("not a folder")
    with pytest.raises(ParameterError) as refused:
        output_folder(str(tmp_path / "file" / "meshes"), "the meshes")
    assert refused.value.name == "output_dir" and "file" in refused.value.reason
