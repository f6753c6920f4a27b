"""The runtime's PNG encoder (runtime/src/png_encode.cpp, ``outputs.encode_pngs``):
the bytes Pillow's ``save(format="PNG")`` writes, for any picture and level,
any number at a time, and the run's false-colour pictures written with it."""

import io

import numpy as np
import pytest
from PIL import Image

from gamma.driver.outputs.outputs import PILLOW_DEFAULT_LEVEL, FalseColourCanvas, encode_pngs


def pillow_png(pixels: np.ndarray, level: int) -> bytes:
    out = io.BytesIO()
    options = {} if level == PILLOW_DEFAULT_LEVEL else {"compress_level": level}
    Image.fromarray(pixels).save(out, format="PNG", **options)
    return out.getvalue()


def pictures():
    rng = np.random.default_rng(11)
    yy, xx = np.mgrid[0:200, 0:260]
    smooth = np.stack([(xx * 0.9) % 256, (yy * 1.3) % 256, (xx + yy) % 256], -1).astype(np.uint8)
    blotches = smooth.copy()
    blotches[rng.random((200, 260)) < 0.05] = (255, 0, 40)
    return {
        "one pixel": np.array([[[200, 10, 30]]], np.uint8),
        "black": np.zeros((17, 23, 3), np.uint8),
        "noise": rng.integers(0, 256, (130, 170, 3), dtype=np.uint8),       # several IDAT chunks
        "few levels": (rng.integers(0, 3, (90, 333, 3)) * 127).astype(np.uint8),
        "smooth": smooth,
        "blotches": blotches,
        "a column": rng.integers(0, 256, (400, 1, 3), dtype=np.uint8),
        # 4 * width > 65536: Pillow's buffer (so its IDAT chunks) grows with the width
        "wide": rng.integers(0, 256, (3, 17000, 3), dtype=np.uint8),
    }


@pytest.mark.parametrize("level", [PILLOW_DEFAULT_LEVEL, 0, 1, 6, 9])
def test_the_runtimes_png_files_are_pillows_bytes(level):
    cases = pictures()
    got = encode_pngs(list(cases.values()), level, threads=2)
    for (name, pixels), data in zip(cases.items(), got):
        assert data == pillow_png(pixels, level), name
        assert np.array_equal(np.asarray(Image.open(io.BytesIO(data))), pixels), name


def test_many_at_once_are_in_order_and_the_same_at_any_thread_count():
    cases = list(pictures().values())
    one_by_one = [encode_pngs([p], 1)[0] for p in cases]
    assert len(set(one_by_one)) == len(cases)
    for threads in (1, 2, 3, 0):
        assert encode_pngs(cases, 1, threads) == one_by_one
    # a Pillow image is taken as its pixels
    assert encode_pngs([Image.fromarray(cases[4])], 1) == [one_by_one[4]]
    assert encode_pngs([], 1, 2) == []


def test_bad_pictures_and_levels_are_refused():
    with pytest.raises((TypeError, ValueError)):
        encode_pngs([np.zeros((4, 4), np.uint8)], 1)           # not RGB
    with pytest.raises((TypeError, ValueError)):
        encode_pngs([np.zeros((4, 4, 4), np.uint8)], 1)        # RGBA
    with pytest.raises(ValueError):
        encode_pngs([np.zeros((4, 4, 3), np.uint8)], 10)
    with pytest.raises(ValueError):
        encode_pngs([np.zeros((0, 4, 3), np.uint8)], 1)


class FixedView:
    """FalseColourView's picture() from fixed pixels."""

    def picture(self, values, vmin, vmax, background, threads):
        return (np.clip(values[:32 * 40].reshape(32, 40, 1) * 255, 0, 255) * np.ones((1, 1, 3))).astype(np.uint8)


@pytest.mark.parametrize("threads", [1, 2])
def test_a_runs_false_colour_pictures_are_written_in_order_as_canvas_png_makes_them(tmp_path, threads):
    """The pictures after the loop (coloured, titled, then encoded together on
    the runtime's threads) are the files ``FalseColourCanvas.png`` makes one by
    one, each under its own name; that one is Pillow's drawing byte for byte
    (test_outputs)."""
    from gamma.driver.outputs.writers import _write_false_colour_views

    canvas = FalseColourCanvas(40, 32, -0.5, 2.0, "rust")
    rng = np.random.default_rng(7)
    values = [rng.random(32 * 40).astype(np.float32) for _ in range(5)]
    view = FixedView()
    want = [canvas.png(None, None, f"rust, iteration {i}", picture=view.picture(v, -0.5, 2.0, None, 1))
            for i, v in enumerate(values)]
    assert len(set(want)) == 5
    items = [(tmp_path / f"iter_{i:04d}.png", f"rust, iteration {i}", v) for i, v in enumerate(values)]
    _write_false_colour_views(items, canvas, view, -0.5, 2.0, threads)
    assert [path.read_bytes() for path, _, _ in items] == want
