"""service.image_io: sRGB PNG, EXR (single/multi-part) and npz round trips and validation."""

from __future__ import annotations

import io

import numpy as np
import pytest

from service.image_io import (
    decode_exr,
    decode_exr_multipart,
    decode_npz,
    decode_png,
    encode_exr,
    encode_exr_multipart,
    encode_npz,
    encode_png,
    linear_to_srgb,
    srgb_to_linear,
)

RNG = np.random.default_rng(1234)


# --------------------------------------------------------------------------------------
# sRGB curve
# --------------------------------------------------------------------------------------
def test_srgb_formulas_exact():
    x = np.array([0.0, 0.001, 0.0031308, 0.01, 0.18, 0.5, 1.0])
    expected = np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)
    np.testing.assert_allclose(linear_to_srgb(x), expected, rtol=0, atol=1e-15)
    s = np.array([0.0, 0.02, 0.04045, 0.05, 0.5, 0.7353569830524495, 1.0])
    expected = np.where(s <= 0.04045, s / 12.92, ((s + 0.055) / 1.055) ** 2.4)
    np.testing.assert_allclose(srgb_to_linear(s), expected, rtol=0, atol=1e-15)
    assert linear_to_srgb(np.array(0.5)) == pytest.approx(0.7353569830524495, abs=1e-15)


def test_srgb_inverse_and_clipping():
    x = np.linspace(0, 1, 10001)
    np.testing.assert_allclose(srgb_to_linear(linear_to_srgb(x)), x, atol=1e-12)
    # the two pieces meet continuously at the thresholds
    assert abs(12.92 * 0.0031308 - (1.055 * 0.0031308 ** (1 / 2.4) - 0.055)) < 1e-7
    np.testing.assert_allclose(linear_to_srgb(np.array([-1.0, 2.0, np.nan])), [0.0, 1.0, 0.0], atol=1e-12)
    assert linear_to_srgb(np.zeros(3, np.float32)).dtype == np.float32
    assert linear_to_srgb(np.zeros((2, 3, 3))).shape == (2, 3, 3)


# --------------------------------------------------------------------------------------
# PNG
# --------------------------------------------------------------------------------------
def test_png_known_values():
    rgb = np.zeros((2, 3, 3), dtype=np.float32)
    rgb[0, 0] = 0.5  # -> 188
    rgb[0, 1] = 1.0  # -> 255
    rgb[0, 2] = (0.0, 0.5, 1.0)
    rgb[1, 0] = 7.0  # clipped -> 255
    rgb[1, 1] = -1.0  # clipped -> 0
    rgb[1, 2] = 0.001  # linear segment: 12.92 * 0.001 * 255 = 3.29 -> 3
    out = decode_png(encode_png(rgb))
    assert out.dtype == np.uint8 and out.shape == (2, 3, 3)
    np.testing.assert_array_equal(out[0, 0], [188, 188, 188])
    np.testing.assert_array_equal(out[0, 1], [255, 255, 255])
    np.testing.assert_array_equal(out[0, 2], [0, 188, 255])
    np.testing.assert_array_equal(out[1], [[255] * 3, [0] * 3, [3] * 3])


def test_png_round_trip_matches_formula_and_row_order():
    rgb = RNG.random((17, 23, 3))
    rgb[0, :] = 1.0  # top row white: row 0 must stay on top
    rgb[-1, :] = 0.0
    out = decode_png(encode_png(rgb))
    expected = np.rint(255 * np.where(rgb <= 0.0031308, 12.92 * rgb, 1.055 * rgb ** (1 / 2.4) - 0.055))
    np.testing.assert_array_equal(out, expected.astype(np.uint8))
    # reading the PNG with Pillow directly gives the same (top row first)
    from PIL import Image

    img = Image.open(io.BytesIO(encode_png(rgb)))
    assert img.size == (23, 17) and img.mode == "RGB" and img.getpixel((0, 0)) == (255, 255, 255)


def test_png_grey_input():
    grey = np.linspace(0, 1, 12, dtype=np.float64).reshape(3, 4)
    out = decode_png(encode_png(grey))
    assert out.shape == (3, 4, 3)
    np.testing.assert_array_equal(out[..., 0], out[..., 2])
    np.testing.assert_array_equal(out[..., 0], np.rint(255 * linear_to_srgb(grey)).astype(np.uint8))


@pytest.mark.parametrize(
    "bad",
    [
        np.zeros((4, 4, 4), np.float32),  # RGBA
        np.zeros((4,), np.float32),
        np.zeros((4, 4, 3), np.uint8),  # not linear float
        np.zeros((0, 4, 3), np.float32),
    ],
)
def test_png_bad_input(bad):
    with pytest.raises(ValueError):
        encode_png(bad)


def test_decode_png_bad_data():
    with pytest.raises(ValueError):
        decode_png(b"not a png at all")
    with pytest.raises(ValueError):
        decode_png(b"")


# --------------------------------------------------------------------------------------
# EXR
# --------------------------------------------------------------------------------------
def _gbuffer(h: int, w: int) -> dict[str, np.ndarray]:
    z = (RNG.random((h, w)) * 100).astype(np.float32)
    z[0, :] = np.inf  # background
    n = RNG.normal(size=(h, w, 3)).astype(np.float32)
    n /= np.linalg.norm(n, axis=2, keepdims=True)
    ids = RNG.integers(0, 2**32, size=(h, w), dtype=np.uint64).astype(np.uint32)
    ids[0, 0] = 4_000_000_000
    ids[0, 1] = 2**32 - 1
    return {
        "RGB": RNG.random((h, w, 3)).astype(np.float32) * 4,  # HDR values survive
        "Z": z,
        "N": n,
        "P": RNG.normal(size=(h, w, 3)) * 1e3,  # float64 in, float32 out
        "id": ids,
        "object": RNG.integers(0, 65535, size=(h, w)).astype(np.uint16),
        "mask": (RNG.random((h, w)) > 0.5).astype(np.float32),
    }


def test_exr_round_trip():
    src = _gbuffer(31, 45)
    out = decode_exr(encode_exr(src))
    assert set(out) == set(src)
    for key in ("RGB", "Z", "N", "mask"):
        assert out[key].dtype == np.float32 and out[key].shape == src[key].shape, key
        np.testing.assert_array_equal(out[key], src[key])
    np.testing.assert_array_equal(out["P"], src["P"].astype(np.float32))
    assert np.isinf(out["Z"][0]).all() and (out["Z"][0] > 0).all()
    for key in ("id", "object"):
        assert out[key].dtype == np.uint32 and out[key].shape == (31, 45)
        np.testing.assert_array_equal(out[key], src[key].astype(np.uint32))
    assert out["id"][0, 0] == 4_000_000_000 and out["id"][0, 1] == 2**32 - 1


def test_exr_channel_names_and_row_order():
    import OpenEXR

    h, w = 4, 5
    z = np.arange(h * w, dtype=np.float32).reshape(h, w)
    data = encode_exr({"RGB": np.zeros((h, w, 3), np.float32), "Z": z, "N": np.zeros((h, w, 3), np.float32),
                       "id": np.arange(h * w, dtype=np.uint32).reshape(h, w)})
    f = OpenEXR.File(io.BytesIO(data), separate_channels=True)
    chans = f.channels()
    assert set(chans) == {"R", "G", "B", "Z", "N.x", "N.y", "N.z", "id"}
    assert chans["id"].type() == OpenEXR.UINT and chans["Z"].type() == OpenEXR.FLOAT
    assert f.header()["lineOrder"] == OpenEXR.INCREASING_Y
    lo, hi = f.header()["dataWindow"]
    assert tuple(lo) == (0, 0) and tuple(hi) == (w - 1, h - 1)
    np.testing.assert_array_equal(chans["Z"].pixels[0], [0, 1, 2, 3, 4])  # row 0 = top scanline


def test_exr_colour_layers_are_named_rgb():
    """diffuse and reflected are colours: EXR tools group <layer>.R/.G/.B, not .x/.y/.z."""
    import OpenEXR

    rng = np.random.default_rng(1)
    arrays = {"RGB": rng.random((3, 4, 3), np.float32), "diffuse": rng.random((3, 4, 3), np.float32),
              "reflected": rng.random((3, 4, 3), np.float32), "N": rng.random((3, 4, 3), np.float32)}
    data = encode_exr(arrays)
    chans = set(OpenEXR.File(io.BytesIO(data), separate_channels=True).channels())
    assert {"diffuse.R", "diffuse.G", "diffuse.B", "reflected.B", "N.x"} <= chans and "diffuse.x" not in chans
    back = decode_exr(data)
    assert set(back) == set(arrays)
    for key, value in arrays.items():
        np.testing.assert_array_equal(back[key], value)


def test_exr_non_contiguous_input():
    base = RNG.random((6, 8, 3)).astype(np.float32)
    view = base[::-1, ::2]  # strided, negative stride
    out = decode_exr(encode_exr({"RGB": view, "Z": base[:, ::2, 1].T.copy().T}))
    np.testing.assert_array_equal(out["RGB"], view)
    np.testing.assert_array_equal(out["Z"], base[:, ::2, 1])


def test_exr_multipart_round_trip():
    parts = [
        ("view0", _gbuffer(8, 12)),
        ("view1", {"Z": np.full((20, 7), np.inf, np.float32), "id": np.full((20, 7), 3_999_999_999, np.uint32)}),
        ("centroid peel 2", {"RGB": RNG.random((5, 30, 3)).astype(np.float32), "N": np.zeros((5, 30, 3))}),
    ]
    data = encode_exr_multipart(parts)
    out = decode_exr_multipart(data)
    assert [name for name, _ in out] == ["view0", "view1", "centroid peel 2"]
    for (_, src), (_, got) in zip(parts, out, strict=True):
        assert set(got) == set(src)
        for key, arr in src.items():
            expected = arr.astype(np.uint32) if arr.dtype.kind in "iu" else arr.astype(np.float32)
            np.testing.assert_array_equal(got[key], expected)
            assert got[key].dtype == expected.dtype
    with pytest.raises(ValueError, match="decode_exr_multipart"):
        decode_exr(data)
    # a single-part file through the multipart reader
    single = decode_exr_multipart(encode_exr({"Z": np.ones((2, 2), np.float32)}))
    assert len(single) == 1 and set(single[0][1]) == {"Z"}


@pytest.mark.parametrize(
    "channels",
    [
        {},
        {"RGB": np.zeros((4, 4), np.float32)},  # RGB needs 3 channels
        {"RGB": np.zeros((4, 4, 4), np.float32)},
        {"N": np.zeros((4, 4, 2), np.float32)},
        {"Z": np.zeros((4, 4, 1), np.float32)},
        {"Z": np.zeros((4, 4), np.int32)},  # depth must be float
        {"id": np.zeros((4, 4), np.float32)},  # ids must be integer
        {"id": np.full((4, 4), -1, np.int64)},  # negative
        {"id": np.full((4, 4), 2**32, np.uint64)},  # too large for uint32
        {"object": np.zeros((4, 4, 2), np.uint16)},
        {"Z": np.zeros((4, 4), np.float32), "id": np.zeros((4, 5), np.uint32)},  # size mismatch
        {"Z": np.zeros((0, 4), np.float32)},
        {"Z": np.zeros(16, np.float32)},
        {"flag": np.zeros((4, 4), bool)},
        {"name": np.zeros((4, 4), np.complex64)},
        {"N": np.zeros((4, 4, 3), np.float32), "N.x": np.zeros((4, 4), np.float32)},  # channel twice
        {"": np.zeros((4, 4), np.float32)},
    ],
)
def test_exr_bad_input(channels):
    with pytest.raises(ValueError):
        encode_exr(channels)


def test_exr_multipart_bad_input():
    z = {"Z": np.zeros((2, 2), np.float32)}
    for parts in ([], [("a", z), ("a", z)], [("", z)], [("a", {})], [("a",)], "abc"):
        with pytest.raises(ValueError):
            encode_exr_multipart(parts)


def test_decode_exr_bad_data():
    good = encode_exr({"Z": np.ones((8, 8), np.float32)})
    for bad in (b"", b"garbage" * 20, good[:40], good[:4] + bytes(60)):
        with pytest.raises(ValueError):
            decode_exr(bad)
        with pytest.raises(ValueError):
            decode_exr_multipart(bad)


# --------------------------------------------------------------------------------------
# npz
# --------------------------------------------------------------------------------------
def test_npz_round_trip():
    arrays = {"depth": np.array([[1.0, np.inf]], np.float32), "ids": np.arange(6, dtype=np.uint32).reshape(2, 3),
              "mask": np.array([True, False])}
    data = encode_npz(arrays)
    with np.load(io.BytesIO(data), allow_pickle=False) as npz:
        assert set(npz.files) == set(arrays)
    out = decode_npz(data)
    for k, v in arrays.items():
        assert out[k].dtype == v.dtype
        np.testing.assert_array_equal(out[k], v)
    with pytest.raises(ValueError):
        encode_npz({"x": np.array([object()])})
    with pytest.raises(ValueError):
        encode_npz({})
    with pytest.raises(ValueError):
        decode_npz(b"nope")



def test_jpeg_levels_match_the_png_levels_within_one():
    """encode_jpeg's table-driven sRGB levels are encode_png's within one level (NaN → 0,
    clipped); the JPEG itself decodes close to them."""
    from PIL import Image

    from service.image_io import _exact_levels, _fast_levels, encode_jpeg

    rgb = RNG.random((64, 96, 3)).astype(np.float32) ** 3  # many dark values, where sRGB is steepest
    rgb[0, 0], rgb[0, 1], rgb[0, 2] = np.nan, -1.0, 7.0
    fast = _fast_levels(rgb).astype(int)
    exact = _exact_levels(np.nan_to_num(np.clip(rgb, 0, 1))).astype(int)
    assert np.abs(fast - exact).max() <= 1 and (fast != exact).mean() < 0.01
    assert fast[0, :3].tolist() == [[0, 0, 0], [0, 0, 0], [255, 255, 255]]
    smooth = np.ascontiguousarray(np.broadcast_to(np.linspace(0, 1, 96, dtype=np.float32)[None, :, None],
                                                  (64, 96, 3)))
    data = encode_jpeg(smooth, quality=90)
    assert data[:3] == b"\xff\xd8\xff"
    decoded = np.asarray(Image.open(io.BytesIO(data)).convert("RGB")).astype(int)
    assert np.abs(decoded - decode_png(encode_png(smooth)).astype(int)).mean() < 2
    with pytest.raises(ValueError, match="encode_jpeg"):
        encode_jpeg(np.zeros((4, 4, 3), np.uint8))
