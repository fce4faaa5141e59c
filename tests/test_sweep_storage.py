"""How a sweep stores its results: compressed chunks, outputs as PNG images, resume checks."""

from __future__ import annotations

import json

import imageio.v3 as iio
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxgfx.sweep import image_path, load_sweep, run_sweep


def _one(p):
    """A tiny frame per item: a uint8 image, a smooth float field and a scalar."""
    y, x = jnp.mgrid[0:12, 0:16]
    depth = 1.0 + (x + y) / 64.0 + p  # exact in float32 however XLA fuses it
    img = (jnp.stack([x * 16, y * 20, jnp.full_like(x, 40)], -1) + 3 * p).astype(jnp.uint8)
    return {"color": img, "depth": depth.astype(jnp.float32), "p": p}


PARAMS = np.arange(5, dtype=np.float32)
ONE_DEVICE = jax.devices()[:1]


def _sweep(out, **kw):
    return run_sweep(_one, PARAMS, out, chunk_size=2, devices=ONE_DEVICE, progress=False, **kw)


def test_images_are_pngs_chunks_are_compressed_and_both_read_back(tmp_path):
    s = _sweep(tmp_path, images=["color"])
    assert s["computed"] == 3
    want = jax.vmap(_one)(jnp.asarray(PARAMS))
    data = load_sweep(tmp_path)
    for key in ("color", "depth", "p"):
        np.testing.assert_array_equal(data[key], np.asarray(want[key]))
    for i in range(5):  # one lossless PNG per item, the chunk holds the rest
        np.testing.assert_array_equal(iio.imread(tmp_path / f"color_{i:05d}.png"), data["color"][i])
    with np.load(tmp_path / "chunk_00000.npz") as z:
        assert sorted(z.files) == ["depth", "p"]
        # compressed: the members are deflated (zip method 8), not stored
        assert all(info.compress_type == 8 for info in z.zip.infolist())
    assert json.loads((tmp_path / "manifest.json").read_text())["images"] == {
        "color": "color_{i:05d}.png"
    }
    assert load_sweep(tmp_path, names=["depth"]).keys() == {"depth"}


def test_a_chunk_missing_an_image_is_rendered_again(tmp_path):
    _sweep(tmp_path, images={"color": "frames/f{i:03d}.png"})
    assert image_path(tmp_path, "frames/f{i:03d}.png", 3) == tmp_path / "frames" / "f003.png"
    (tmp_path / "frames" / "f003.png").unlink()  # item 3 is in chunk 1
    s = _sweep(tmp_path, images={"color": "frames/f{i:03d}.png"})
    assert s["computed"] == 1 and s["skipped"] == 2
    assert (tmp_path / "frames" / "f003.png").is_file()
    # stored as images or not is part of what defines the sweep's files
    with pytest.raises(ValueError, match="PNG images"):
        _sweep(tmp_path)


def test_image_outputs_are_checked_before_any_work(tmp_path):
    with pytest.raises(ValueError, match="uint8"):
        _sweep(tmp_path / "a", images=["depth"])
    with pytest.raises(ValueError, match="does not return"):
        _sweep(tmp_path / "b", images=["nope"])
    with pytest.raises(ValueError, match=r"\{i\}"):
        _sweep(tmp_path / "c", images={"color": "same.png"})
    with pytest.raises(TypeError, match="images"):
        _sweep(tmp_path / "d", images="color")
    assert not any((tmp_path / n).exists() for n in "abcd")
