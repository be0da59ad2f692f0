"""HDR image reading and writing: round trips, hand-made Radiance bytes, and every bad input."""
from __future__ import annotations

import numpy as np
import OpenEXR
import pytest

from iblbench.foundation.errors import InputError
from iblbench.scenes.imageio import read_exr, read_hdr, read_image, write_exr, write_hdr


def hdr_bytes(width: int, height: int, scanlines: bytes) -> bytes:
    return b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y %d +X %d\n" % (height, width) + scanlines


def test_exr_round_trip_is_exact(tmp_path):
    image = np.random.default_rng(1).lognormal(size=(7, 11, 3)).astype(np.float32)
    write_exr(tmp_path / "a.exr", image)
    back = read_image(tmp_path / "a.exr")
    assert back.dtype == np.float32 and back.shape == (7, 11, 3)
    np.testing.assert_array_equal(back, image)


def test_exr_half_channels_are_read_and_extra_channels_ignored(tmp_path):
    rgb = np.random.default_rng(2).random((4, 6, 3)).astype(np.float16)
    channels = {name: np.ascontiguousarray(rgb[..., i]) for i, name in enumerate("RGB")}
    channels["A"] = np.ones((4, 6), np.float32)
    OpenEXR.File({}, channels).write(str(tmp_path / "h.exr"))
    np.testing.assert_array_equal(read_exr(tmp_path / "h.exr"), rgb.astype(np.float32))


def test_exr_without_rgb_channels_is_refused(tmp_path):
    OpenEXR.File({}, {"Y": np.ones((4, 4), np.float32)}).write(str(tmp_path / "y.exr"))
    with pytest.raises(InputError, match="no R, G, B channel") as err:
        read_exr(tmp_path / "y.exr")
    assert err.value.source.endswith("y.exr")


def test_write_exr_replaces_atomically_and_leaves_no_temp_files(tmp_path):
    write_exr(tmp_path / "a.exr", np.zeros((2, 2, 3)))
    write_exr(tmp_path / "a.exr", np.full((3, 5, 3), 2.0))
    assert [p.name for p in tmp_path.iterdir()] == ["a.exr"]
    np.testing.assert_array_equal(read_exr(tmp_path / "a.exr"), np.full((3, 5, 3), 2.0))


def test_hdr_flat_pixel_decodes_by_shared_exponent(tmp_path):
    # (m, e) = (128, 129) is 128 * 2^(129-136) = 1.0; a zero exponent is black.
    pixels = bytes((128, 64, 32, 129, 255, 0, 1, 136, 9, 9, 9, 0))
    (tmp_path / "f.hdr").write_bytes(hdr_bytes(3, 1, pixels))
    np.testing.assert_array_equal(
        read_hdr(tmp_path / "f.hdr")[0], [[1.0, 0.5, 0.25], [255.0, 0.0, 1.0], [0.0, 0.0, 0.0]]
    )


def test_hdr_hand_made_rle_scanline(tmp_path):
    width = 10
    scanline = bytes((2, 2, 0, width))
    scanline += bytes((128 + 10, 64))  # R: one run of 10
    scanline += bytes((10,)) + bytes(range(10))  # G: one literal chunk of 10
    scanline += bytes((128 + 4, 32, 6, 1, 2, 3, 4, 5, 6))  # B: run of 4, literal of 6
    scanline += bytes((128 + 10, 130))  # E: 2^(130-136) = 1/64
    (tmp_path / "r.hdr").write_bytes(hdr_bytes(width, 1, scanline))
    expected = np.stack(
        [np.full(10, 64.0), np.arange(10.0), [32, 32, 32, 32, 1, 2, 3, 4, 5, 6]], axis=-1
    ) / 64
    np.testing.assert_array_equal(read_hdr(tmp_path / "r.hdr")[0], expected)


@pytest.mark.parametrize("rle", [True, False])
def test_hdr_round_trip_within_rgbe_precision(tmp_path, rle):
    rng = np.random.default_rng(3)
    image = rng.lognormal(sigma=3.0, size=(5, 40, 3)).astype(np.float32)
    image[:, 10:30] = image[:, 10:11]  # long runs for the encoder
    image[2, 3] = 0.0
    write_hdr(tmp_path / "a.hdr", image, rle=rle)
    back = read_image(tmp_path / "a.hdr")
    # Rounded 8-bit mantissas: error ≤ half a step of 2^(e-8), and the largest channel ≥ 2^(e-1).
    assert np.all(np.abs(back - image) <= image.max(axis=-1, keepdims=True) / 256)
    np.testing.assert_array_equal(back[2, 3], 0.0)


def test_hdr_rle_and_flat_files_decode_identically_and_rle_is_smaller(tmp_path):
    image = np.tile(np.linspace(0.1, 3.0, 64, dtype=np.float32)[:, None], (4, 1, 3))
    image[:, :32] = 1.5
    write_hdr(tmp_path / "rle.hdr", image, rle=True)
    write_hdr(tmp_path / "flat.hdr", image, rle=False)
    np.testing.assert_array_equal(read_hdr(tmp_path / "rle.hdr"), read_hdr(tmp_path / "flat.hdr"))
    assert (tmp_path / "rle.hdr").stat().st_size < (tmp_path / "flat.hdr").stat().st_size


def _assert_input_error(path, match):
    with pytest.raises(InputError, match=match) as err:
        read_image(path)
    assert err.value.source == str(path)


def test_missing_file(tmp_path):
    _assert_input_error(tmp_path / "nope.exr", "file not found")
    _assert_input_error(tmp_path / "nope.hdr", "file not found")


@pytest.mark.parametrize("name", ["bad.exr", "bad.hdr"])
def test_garbage_bytes(tmp_path, name):
    (tmp_path / name).write_bytes(bytes(np.random.default_rng(4).integers(0, 256, 4000, np.uint8)))
    _assert_input_error(tmp_path / name, "corrupt|not a Radiance")


def test_truncated_exr(tmp_path, capfd):
    write_exr(tmp_path / "a.exr", np.random.default_rng(5).random((32, 32, 3)))
    data = (tmp_path / "a.exr").read_bytes()
    (tmp_path / "a.exr").write_bytes(data[: len(data) // 2])
    capfd.readouterr()
    _assert_input_error(tmp_path / "a.exr", r"corrupt OpenEXR file \(\(EXR_ERR_BAD_CHUNK_LEADER\)")
    # OpenEXR prints that reason to stderr beside its exception (found by test_fuzz.py).
    assert capfd.readouterr() == ("", "")


@pytest.mark.parametrize("rle", [True, False])
def test_truncated_hdr(tmp_path, rle):
    write_hdr(tmp_path / "a.hdr", np.random.default_rng(6).random((16, 32, 3)), rle=rle)
    data = (tmp_path / "a.hdr").read_bytes()
    (tmp_path / "a.hdr").write_bytes(data[: len(data) - 100])
    _assert_input_error(tmp_path / "a.hdr", "truncated")


def test_truncated_hdr_header(tmp_path):
    (tmp_path / "a.hdr").write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n")
    _assert_input_error(tmp_path / "a.hdr", "truncated Radiance header")


def test_hdr_corrupt_run_length(tmp_path):
    scanline = bytes((2, 2, 0, 8, 128 + 9, 1))  # a run of 9 in a scanline 8 wide
    (tmp_path / "a.hdr").write_bytes(hdr_bytes(8, 1, scanline))
    _assert_input_error(tmp_path / "a.hdr", "corrupt run-length data in scanline 0")


@pytest.mark.parametrize(
    "header, match",
    [
        (b"#?RADIANCE\nFORMAT=32-bit_rle_xyze\n\n-Y 1 +X 1\n", "unsupported Radiance format"),
        (b"#?RADIANCE\n\n+Y 1 +X 1\n", "unsupported resolution line"),
    ],
)
def test_hdr_unsupported_variants(tmp_path, header, match):
    (tmp_path / "a.hdr").write_bytes(header + bytes(4))
    _assert_input_error(tmp_path / "a.hdr", match)


@pytest.mark.parametrize("header", [b"#?RADIANCE\nFORMAT=32-bit\rrle\n\n-Y 1 +X 1\n",
                                    b"#?RADIANCE\n\n-Y 1\x0c+X 1\n"])
def test_hdr_errors_quoting_the_file_stay_on_one_line(tmp_path, header):
    # A quoted header line may hold characters that end a line (found by test_fuzz.py).
    (tmp_path / "a.hdr").write_bytes(header + bytes(4))
    with pytest.raises(InputError) as err:
        read_image(tmp_path / "a.hdr")
    assert len(str(err.value).splitlines()) == 1


def test_unsupported_extension(tmp_path):
    (tmp_path / "a.png").write_bytes(b"\x89PNG")
    _assert_input_error(tmp_path / "a.png", r"unsupported extension '\.png'")


def test_atomic_writes_leave_readable_files_and_no_temporaries(tmp_path):
    import os
    import stat

    from iblbench.foundation.atomic import atomic_path

    target = tmp_path / "sub" / "result.txt"
    with atomic_path(target) as tmp:
        tmp.write_text("done")
    mask = os.umask(0)
    os.umask(mask)
    assert stat.S_IMODE(target.stat().st_mode) == 0o666 & ~mask
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_text("half")
            raise RuntimeError("killed mid-write")
    assert target.read_text() == "done" and [p.name for p in target.parent.iterdir()] == ["result.txt"]
