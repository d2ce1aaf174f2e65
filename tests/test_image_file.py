"""New images saved as PNG from a thread: the same pixels as Blender's own save, control handed back meanwhile."""
import threading

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
Image = pytest.importorskip("PIL.Image")

from perceptual_uv.bridge import image_file  # noqa: E402
from perceptual_uv.core.progress import run_generator  # noqa: E402


@pytest.fixture(autouse=True)
def _empty(empty_scene):
    yield


def _new_image(name, *, alpha, colorspace="sRGB", float_buffer=False, seed=0):
    values = np.random.default_rng(seed).random((40, 60, 4)).astype(np.float32)
    if not alpha:
        values[..., 3] = 1.0
    image = bpy.data.images.new(name, 60, 40, alpha=alpha, float_buffer=float_buffer)
    image.colorspace_settings.name = colorspace
    image.pixels.foreach_set(values.ravel())
    return image


def _pixels(image):
    values = np.empty(len(image.pixels), dtype=np.float32)
    image.pixels.foreach_get(values)
    return values


@pytest.mark.parametrize("alpha, colorspace", [(False, "sRGB"), (True, "Non-Color")])
def test_the_png_holds_what_blenders_own_save_writes(tmp_path, alpha, colorspace):
    reference = _new_image("reference", alpha=alpha, colorspace=colorspace)
    reference.filepath_raw = str(tmp_path / "blender.png")
    reference.file_format = "PNG"
    reference.save()
    image = _new_image("ours", alpha=alpha, colorspace=colorspace)
    before = _pixels(image)
    path, warning = run_generator(image_file.iter_save_or_pack(image, str(tmp_path / "maps")))
    assert warning is None and path == str(tmp_path / "maps" / "ours.png")
    ours, blenders = Image.open(path), Image.open(tmp_path / "blender.png")
    assert ours.mode == blenders.mode == ("RGBA" if alpha else "RGB")
    assert np.array_equal(np.asarray(ours), np.asarray(blenders))
    # the image is the file's now, as image.save() leaves it, and reads back the same pixels
    assert image.source == "FILE" and not image.is_dirty and image.colorspace_settings.name == colorspace
    assert np.array_equal(_pixels(image), before)


def _held(monkeypatch, name):
    """Replace ``image_file.<name>`` by a version that waits for the returned event before it runs."""
    release = threading.Event()
    function = getattr(image_file, name)

    def held(*args):
        assert release.wait(10)
        return function(*args)

    monkeypatch.setattr(image_file, name, held)
    return release


def test_the_generator_hands_control_back_while_the_png_is_encoded(tmp_path, monkeypatch):
    release = _held(monkeypatch, "_png_bytes")
    saving = image_file.iter_save_or_pack(_new_image("held", alpha=False), str(tmp_path), interval=0.001)
    assert next(saving) is None  # the encoder is still waiting: the caller has control
    release.set()
    path, warning = run_generator(saving)
    assert warning is None and path == str(tmp_path / "held.png")


def test_an_existing_file_is_kept_and_the_new_one_numbered(tmp_path):
    (tmp_path / "map.png").write_bytes(b"someone else's file")
    (tmp_path / "map.001.png").write_bytes(b"another one")
    path, _ = run_generator(image_file.iter_save_or_pack(_new_image("map", alpha=False), str(tmp_path)))
    assert path == str(tmp_path / "map.002.png")
    assert (tmp_path / "map.png").read_bytes() == b"someone else's file"


def test_without_a_folder_the_png_is_packed(monkeypatch):
    image = _new_image("packed", alpha=True)
    before = _pixels(image)
    path, warning = run_generator(image_file.iter_save_or_pack(image, None))
    assert path is None and warning is None
    assert image.packed_file is not None and image.packed_file.data[:8] == b"\x89PNG\r\n\x1a\n"
    assert np.array_equal(_pixels(image), before)


def test_an_unwritable_folder_packs_the_image_and_says_why(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    image = _new_image("blocked", alpha=False)
    path, warning = run_generator(image_file.iter_save_or_pack(image, str(blocker / "maps")))
    assert path is None and image.packed_file is not None
    assert "could not save the image" in warning and "packed into the .blend" in warning
    assert "\n" not in warning


def test_a_float_image_keeps_blenders_save(tmp_path):
    image = _new_image("float_map", alpha=False, colorspace="Non-Color", float_buffer=True)
    path, warning = run_generator(image_file.iter_save_or_pack(image, str(tmp_path)))
    assert warning is None and path == str(tmp_path / "float_map.png")
    assert image.source == "FILE" and not image.is_dirty


@pytest.mark.parametrize("mode, suffix, decoded", [("RGB", "png", True), ("RGBA", "png", True), ("RGB", "jpg", True),
                                                   ("L", "png", False), ("P", "png", False), ("L", "jpg", False)])
def test_a_file_image_reads_as_blender_holds_it(tmp_path, mode, suffix, decoded):
    stored = (np.random.default_rng(1).random((37, 53, 4)) * 255).astype(np.uint8)
    path = tmp_path / f"texture.{suffix}"
    Image.fromarray(stored, "RGBA").convert(mode).save(path)
    image = bpy.data.images.load(str(path))
    # RGB and RGBA files are decoded from the file without Blender loading the image; other modes fall back
    assert (image_file.image_size(image) == (53, 37)) and (image.has_data != decoded)
    pixels = run_generator(image_file.iter_read_image(image))
    assert image.has_data != decoded
    assert pixels.dtype == np.float32 and pixels.shape == (37, 53, 4)
    assert np.array_equal(pixels.ravel(), _pixels(image))  # foreach_get: what Blender holds


def test_a_16_bit_png_is_read_as_the_floats_blender_holds(tmp_path):
    import struct
    import zlib

    rows = np.random.default_rng(4).integers(0, 65536, (5, 7, 3)).astype(">u2")
    raw = b"".join(b"\x00" + row.tobytes() for row in rows)  # filter type 0 per row

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    png = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 7, 5, 16, 2, 0, 0, 0))
           + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))
    (tmp_path / "deep.png").write_bytes(png)
    image = bpy.data.images.load(str(tmp_path / "deep.png"))
    assert image_file._decodable_size(image_file._file_source(image)) is None  # not 8-bit: Blender's floats
    assert np.array_equal(run_generator(image_file.iter_read_image(image)).ravel(), _pixels(image))
    assert image.is_float


def test_the_decode_runs_while_the_generator_hands_control_back(tmp_path, monkeypatch):
    stored = (np.random.default_rng(2).random((20, 30, 3)) * 255).astype(np.uint8)
    Image.fromarray(stored, "RGB").save(tmp_path / "texture.png")
    image = bpy.data.images.load(str(tmp_path / "texture.png"))
    release = _held(monkeypatch, "_decode_rgba")
    reading = image_file.iter_read_image(image, interval=0.001)
    assert next(reading) is None
    release.set()
    pixels = run_generator(reading)
    # bottom row first, bytes / 255, alpha 1 for an RGB file: by hand from the bytes written
    assert np.array_equal(pixels[0, :, :3], stored[-1] * np.float32(1 / 255))
    assert np.all(pixels[..., 3] == 1.0)


def test_an_edited_image_is_read_from_blender_not_from_its_file(tmp_path):
    stored = (np.random.default_rng(3).random((8, 8, 3)) * 255).astype(np.uint8)
    Image.fromarray(stored, "RGB").save(tmp_path / "texture.png")
    image = bpy.data.images.load(str(tmp_path / "texture.png"))
    edited = np.full(8 * 8 * 4, 0.5, dtype=np.float32)
    image.pixels.foreach_set(edited)
    assert image.is_dirty and image_file._file_source(image) is None
    assert np.array_equal(run_generator(image_file.iter_read_image(image)).ravel(), _pixels(image))


def test_a_damaged_png_gives_blenders_answer_not_a_decoder_error(tmp_path):
    stored = (np.random.default_rng(6).random((32, 32, 3)) * 255).astype(np.uint8)
    Image.fromarray(stored, "RGB").save(tmp_path / "whole.png")
    data = (tmp_path / "whole.png").read_bytes()
    (tmp_path / "cut.png").write_bytes(data[: len(data) // 2])  # the header says 32 x 32, the pixels stop halfway
    image = bpy.data.images.load(str(tmp_path / "cut.png"))
    assert image_file._decodable_size(image_file._file_source(image)) == (32, 32)
    with pytest.raises(ValueError, match="has no pixels"):  # Blender cannot load it either: the clear message
        run_generator(image_file.iter_read_image(image))
