"""Safetensors files read with errors that name the file (`biomotion.io.tensors`)."""

import numpy as np
import pytest
from safetensors.numpy import save_file

from biomotion.errors import DataFormatError
from biomotion.io.tensors import read_metadata, read_tensors


def test_a_valid_file_reads(tmp_path):
    path = tmp_path / "w.safetensors"
    save_file({"a": np.arange(6, dtype=np.float32).reshape(2, 3)}, str(path), metadata={"format": "x"})
    assert read_metadata(path) == {"format": "x"}
    assert read_tensors(path, numpy=True)["a"].shape == (2, 3)
    assert tuple(read_tensors(path)["a"].shape) == (2, 3)


@pytest.mark.parametrize("damage", ["cut", "garbage", "empty", "folder", "missing"])
def test_a_damaged_file_is_a_data_format_error_naming_it(tmp_path, damage):
    """A checkpoint cut short or overwritten surfaced as safetensors' own SafetensorError, an internal error of the
    CLI (bad-input corpus cases checkpoint-truncated, checkpoint-garbage-tokenizer, train-*-garbage)."""
    path = tmp_path / "generator.safetensors"
    save_file({"a": np.zeros(1000, dtype=np.float32)}, str(path))
    data = path.read_bytes()
    if damage == "cut":
        path.write_bytes(data[: len(data) // 2])
    elif damage == "garbage":
        path.write_bytes(bytes(range(256)) * 8)
    elif damage == "empty":
        path.write_bytes(b"")
    elif damage == "folder":
        path.unlink()
        path.mkdir()
    else:
        path.unlink()
    for read in (read_metadata, read_tensors):
        with pytest.raises(DataFormatError, match=r"generator\.safetensors: .*generator weights"):
            read(path, "generator weights")
