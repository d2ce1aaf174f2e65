"""Images read from and written to PNG and JPEG files while Blender's interface stays responsive.

Reading: Blender loads an image in the main thread on the first access to its size or pixels (0.5 s for a 4096
px PNG on a busy machine), and copying its pixels out is one ``foreach_get`` (1.1 s the first time). An
unmodified 8-bit RGB or RGBA PNG or RGB JPEG is decoded by Pillow in a thread instead, with the same values (the
stored bytes * (1 / 255) in float32, bottom row first, alpha 1 for RGB files), and its size comes from its header
(:func:`image_size`), so Blender does not load it at all; anything else (16-bit and float images, grey or palette
images, edited or generated images, alpha modes other than straight or channel-packed) keeps Blender's load and
``foreach_get``.

Saving: ``image.save()`` encodes a PNG in Blender's main thread: about a third of a second for a 1-2k map on a busy
machine, during which the interface cannot redraw. An 8-bit image's pixels are its stored bytes / 255, so the
bytes come back from one ``foreach_get`` without loss; Pillow encodes them in a thread (it releases the
interpreter lock while it compresses), the generator hands control back meanwhile, and the image then becomes a
file image on the written PNG (``source = 'FILE'``, read again lazily on its next use), as ``image.save()``
leaves it. Float images (the high-precision maps) keep Blender's own save, one step.
"""
import os

import bpy
import numpy as np

from ..core.progress import InThread

__all__ = ["iter_read_image", "image_size", "image_channels", "image_is_float", "iter_save_or_pack"]

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_STORED_ALPHA = ("STRAIGHT", "CHANNEL_PACKED")  # alpha modes whose 8-bit pixels are the stored bytes


def iter_read_image(image, *, interval=0.1):
    """Generator: the pixels of ``image`` as stored, bottom row first; yields None every ``interval`` seconds while
    a thread decodes its file (see the module notes), returns the array.

    Parameters
    ----------
    image : bpy.types.Image
    interval : float, optional

    Returns
    -------
    (h, w, c) float32 ndarray
        ``c = image.channels``; row 0 is the bottom of the image (v = 0). 8-bit images give their stored
        byte values / 255 with no colour-space conversion; float images (EXR, 16-bit PNG) give the values
        Blender holds, which it has already converted to linear for non-linear colour spaces.

    Raises
    ------
    ValueError
        If the image has no pixels (e.g. its file is missing).
    """
    if image is None:
        raise ValueError("no image")
    source = _file_source(image)
    if source is not None and _decodable_size(source) is not None:
        try:
            return (yield from InThread(_decode_rgba, source, interval=interval).wait())
        except (OSError, ValueError):  # a damaged file: Blender's own load decides what it holds
            pass
    width, height = image.size
    channels = image.channels
    if width == 0 or height == 0 or len(image.pixels) == 0:
        raise ValueError(f"image '{image.name}' has no pixels (file missing: '{image.filepath}'?)")
    pixels = np.empty(width * height * channels, dtype=np.float32)
    image.pixels.foreach_get(pixels)
    return pixels.reshape(height, width, channels)


def image_size(image):
    """``(width, height)`` of ``image``: from its file's header when :func:`iter_read_image` decodes that file
    (Blender does not load the image for it), else ``image.size`` (which loads it; ``(0, 0)`` when the file is
    missing)."""
    size = _decoded_size(image)
    return size if size is not None else tuple(image.size)


def image_channels(image):
    """The channels :func:`iter_read_image` gives: 4 for a file it decodes (as Blender holds RGB and RGBA files),
    else ``image.channels``."""
    return 4 if _decoded_size(image) is not None else image.channels


def image_is_float(image):
    """Whether Blender holds ``image`` as floats, without loading a file :func:`iter_read_image` decodes (8-bit)."""
    return False if _decoded_size(image) is not None else image.is_float


def _decoded_size(image):
    """``(width, height)`` of an image :func:`iter_read_image` decodes from its file, from the header; else None."""
    source = _file_source(image)
    return None if source is None else _decodable_size(source)


def _file_source(image):
    """The packed bytes or the file path of an unmodified file image whose 8-bit pixels Blender holds as stored;
    None otherwise. Reads no attribute that makes Blender load the image (``size``, ``file_format``,
    ``is_float``, ``channels`` would)."""
    if image is None or image.source != "FILE" or image.is_dirty or image.alpha_mode not in _STORED_ALPHA:
        return None
    if image.packed_file is not None:
        return image.packed_file.data
    path = bpy.path.abspath(image.filepath_raw or image.filepath, library=image.library)
    return path if path and os.path.isfile(path) else None


def _decodable_size(source):
    """``(width, height)`` of an 8-bit RGB or RGBA PNG or an RGB JPEG (bytes or a path), from its header; None
    for any other file (16-bit PNGs, which Blender holds as floats, grey or palette images, CMYK JPEGs)."""
    import io

    from PIL import Image, UnidentifiedImageError

    head = source[:26] if isinstance(source, bytes) else _file_head(source, 26)
    if head.startswith(_PNG_SIGNATURE):
        if len(head) < 26 or head[12:16] != b"IHDR" or head[24] != 8 or head[25] not in (2, 6):
            return None  # IHDR: width, height, bit depth, colour type (2 RGB, 6 RGBA)
        return int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")
    if not head.startswith(b"\xff\xd8\xff"):
        return None
    try:
        with Image.open(io.BytesIO(source) if isinstance(source, bytes) else source) as header:  # the header only
            return header.size if header.format == "JPEG" and header.mode == "RGB" else None
    except (OSError, UnidentifiedImageError):
        return None


def _file_head(path, count):
    with open(path, "rb") as file:
        return file.read(count)


def _decode_rgba(source):
    """``(h, w, 4)`` float32 pixels of a file :func:`_decodable_size` accepts (bytes or a path), bottom row first,
    the stored bytes * (1 / 255), alpha 1 for RGB."""
    import io

    from PIL import Image

    with Image.open(io.BytesIO(source) if isinstance(source, bytes) else source) as decoded:
        stored = np.asarray(decoded.convert("RGBA"))
    return stored[::-1] * np.float32(1.0 / 255.0)


def iter_save_or_pack(image, output_dir, *, interval=0.1):
    """Generator: save ``image`` next to the .blend (or into ``output_dir``) as PNG, or pack it into the .blend
    when there is nowhere to save; yields None every ``interval`` seconds while the PNG is encoded.

    An existing file is never overwritten: the name gets a ``.001``-style suffix instead.

    Parameters
    ----------
    image : bpy.types.Image
        A new image (generated, its pixels set from numpy).
    output_dir : str or None
    interval : float, optional

    Returns
    -------
    path : str or None
        The saved file, None when the image was packed.
    warning : str or None
        Why the image could not be saved (it is packed into the file instead, the result is kept).
    """
    folder = output_dir or (os.path.dirname(bpy.data.filepath) if bpy.data.filepath else None)
    if image.is_float or image.depth not in (24, 32):
        return _save_in_blender(image, folder)
    values = np.empty(len(image.pixels), dtype=np.float32)
    image.pixels.foreach_get(values)
    width, height = image.size
    shape = (height, width, len(values) // (width * height))
    data = yield from InThread(_png_bytes, values.reshape(shape), 4 if image.depth == 32 else 3,
                               interval=interval).wait()
    if folder is None:
        _pack_png(image, data)
        return None, None
    stem = os.path.join(bpy.path.abspath(folder), bpy.path.clean_name(image.name))
    try:
        path = yield from InThread(_write_new_file, stem, data, interval=interval).wait()
    except OSError as error:
        _pack_png(image, data)
        return None, _unsaved_warning(f"{stem}.png", error.strerror or str(error))
    image.filepath_raw = path
    image.file_format = "PNG"
    image.source = "FILE"  # the pixels are read again from the file when next used, as after image.save()
    image.filepath = bpy.path.relpath(path) if bpy.data.filepath else path
    return path, None


def _png_bytes(values, channels):
    """PNG file bytes of an 8-bit image's ``(h, w, c)`` pixels as ``foreach_get`` gives them (bytes / 255, bottom
    row first), its first ``channels`` (3 or 4) written. Runs in a thread: numpy and Pillow release the
    interpreter lock for the conversion and the compression."""
    import io

    from PIL import Image

    stored = np.rint(values[::-1, :, :channels] * np.float32(255.0)).astype(np.uint8)
    buffer = io.BytesIO()
    Image.fromarray(stored, "RGBA" if channels == 4 else "RGB").save(buffer, "PNG")
    return buffer.getvalue()


def _new_names(stem):
    """``stem.png``, then ``stem.001.png``, ``stem.002.png`` and so on: the names a new image may take."""
    yield f"{stem}.png"
    counter = 1
    while True:
        yield f"{stem}.{counter:03d}.png"
        counter += 1


def _write_new_file(stem, data):
    """Write ``data`` to the first of :func:`_new_names` that no file has; returns the path."""
    os.makedirs(os.path.dirname(stem) or ".", exist_ok=True)
    for path in _new_names(stem):
        try:
            with open(path, "xb") as file:  # exclusive: another program's file of that name is never replaced
                file.write(data)
            return path
        except FileExistsError:
            continue


def _pack_png(image, data):
    image.pack(data=data, data_len=len(data))
    image.file_format = "PNG"
    image.source = "FILE"


def _unsaved_warning(path, reason):
    return (f"could not save the image to '{path}' ({reason}); it is packed into the .blend file instead: save it "
            "from the Image Editor (Image > Save As) to a writable folder")


def _save_in_blender(image, folder):
    """Blender's own PNG save (one step), for images whose pixels are not 8-bit."""
    if folder is None:
        image.pack()
        return None, None
    stem = os.path.join(bpy.path.abspath(folder), bpy.path.clean_name(image.name))
    # never overwrite a file (e.g. an earlier run's image still used elsewhere)
    path = next(name for name in _new_names(stem) if not os.path.exists(name))
    image.filepath_raw = path
    image.file_format = "PNG"
    try:
        image.save()
    except RuntimeError as error:
        image.filepath_raw = ""
        image.pack()
        reason = str(error).strip().splitlines()[-1] if str(error).strip() else "unknown error"
        return None, _unsaved_warning(path, reason)
    image.filepath = bpy.path.relpath(path) if bpy.data.filepath else path
    return path, None
