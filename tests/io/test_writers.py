"""lfring.io.writers: stacks, GIFs, in-memory encoding, and outputs that cannot be written."""

import numpy as np
import pytest

from lfring.errors import InvalidInputError
from lfring.io.atomic import atomic_path
from lfring.io.writers import (
    check_writable,
    encode_file,
    encode_float_tiff,
    write_float_tiff,
    write_gif,
    write_image,
    write_tiff_stack,
)


@pytest.fixture
def frames():
    rng = np.random.default_rng(0)
    return rng.integers(0, 256, (3, 16, 20, 3), dtype=np.uint8)


def test_tiff_stack_round_trip(tmp_path, frames):
    import json

    import tifffile

    p = write_tiff_stack(tmp_path / "s.tif", frames.astype(np.uint16) * 257, metadata={"depths_m": [0.3, 0.5, 1.0]})
    with tifffile.TiffFile(p) as tf:
        np.testing.assert_array_equal(tf.asarray(), frames.astype(np.uint16) * 257)
        assert json.loads(tf.pages[0].description)["depths_m"] == [0.3, 0.5, 1.0]
    with pytest.raises(InvalidInputError, match="uint8 or uint16"):
        write_tiff_stack(tmp_path / "f.tif", frames.astype(np.float32))


def test_gif_round_trip(tmp_path, frames):
    from gif_frames import read_gif

    grey = frames[..., 0]
    p = write_gif(tmp_path / "s.gif", np.stack([grey] * 3, axis=-1))
    back = read_gif(p)
    assert back.shape[0] == 3 and back.shape[1:3] == (16, 20)
    np.testing.assert_array_equal(back[..., 0], grey)  # grey levels survive the palette
    with pytest.raises(InvalidInputError, match="uint8"):
        write_gif(tmp_path / "x.gif", frames.astype(np.uint16))


@pytest.mark.parametrize("suffix", [".png", ".tif"])
def test_encode_file_is_what_write_image_writes(tmp_path, frames, suffix):
    p = write_image(tmp_path / f"a{suffix}", frames[0])
    assert encode_file(frames[0], suffix) == p.read_bytes()


def test_encode_float_tiff(tmp_path):
    data = np.array([[0.3, np.nan], [1.0, 2.5]], np.float32)
    p = write_float_tiff(tmp_path / "d.tiff", data)
    assert encode_float_tiff(data) == p.read_bytes()


def test_check_writable(tmp_path):
    f = tmp_path / "file"
    f.write_text("x")
    with pytest.raises(InvalidInputError, match="is a file, not a folder"):
        check_writable([f / "deeper" / "out.png"], overwrite=True)
    # The library names its parameter; the CLI says --overwrite (lfring.cli.words).
    with pytest.raises(InvalidInputError, match="exists; pass overwrite=True"):
        check_writable([f], overwrite=False)
    with pytest.raises(InvalidInputError, match="it is a folder"):
        check_writable([tmp_path], overwrite=True)
    check_writable([tmp_path / "new" / "a.png", f], overwrite=True)


def test_atomic_path_names_the_target_not_the_temporary(tmp_path, monkeypatch):
    import tempfile

    def denied(*args, dir=None, **kwargs):
        raise PermissionError(13, "Permission denied", str(dir))

    monkeypatch.setattr(tempfile, "mkstemp", denied)
    with pytest.raises(PermissionError) as info:
        with atomic_path(tmp_path / "out.png"):
            pass
    assert info.value.filename == str(tmp_path / "out.png")


def test_a_stop_as_the_temporary_file_is_made_leaves_nothing(tmp_path, monkeypatch):
    """Ctrl-C that comes right after the atomic write's temporary file was created (still inside
    tempfile) stops the write and leaves neither the file nor its temporary beside it."""
    import signal
    import tempfile

    from lfring.io import atomic

    real = tempfile.mkstemp

    def cut(*args, **kwargs):
        made = real(*args, **kwargs)
        signal.raise_signal(signal.SIGINT)
        return made

    monkeypatch.setattr(atomic.tempfile, "mkstemp", cut)
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            atomic.atomic_write_bytes(tmp_path / "out.bin", b"data")
    finally:
        signal.signal(signal.SIGINT, previous)
    assert list(tmp_path.iterdir()) == []
