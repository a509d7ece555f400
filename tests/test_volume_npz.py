"""The .npz volume reader (scratch: shows that a reader is one module of formats/)."""

import numpy as np
import pytest

from pointillist.imaging.volumes import load_volume


def test_npz_reads_its_one_array_and_refuses_others(tmp_path, rng):
    data = rng.integers(-1024, 2000, size=(3, 4, 5)).astype(np.int16)
    np.savez_compressed(tmp_path / "v.npz", ct=data)
    volume = load_volume(tmp_path / "v.npz", spacing=(0.5, 0.5, 2.0))
    assert volume.data.dtype == np.int16 and np.array_equal(volume.data, data)
    assert volume.spacing == (0.5, 0.5, 2.0)
    np.savez(tmp_path / "two.npz", a=data, b=data)
    with pytest.raises(ValueError, match="one array"):
        load_volume(tmp_path / "two.npz")
    (tmp_path / "bad.npz").write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="bad.npz"):
        load_volume(tmp_path / "bad.npz")
