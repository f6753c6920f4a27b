"""The output contract of ``gammac run`` (maps, renders, summary)."""

import json

import numpy as np
import pytest
from PIL import Image

from conftest import ROOT, run_gammac
from gamma.driver.outputs.outputs import read_ply


@pytest.fixture(scope="module")
def patina_run(tmp_path_factory, bumpy_obj):
    out = tmp_path_factory.mktemp("patina") / "out"
    r = run_gammac("run", ROOT / "examples" / "patina.gamma", "--scene", bumpy_obj,
                   "--surfels", 8000, "--tons", 40000, "--iterations", 3, "--size", 200,
                   "--seed", 3, "--out", out)
    assert r.returncode == 0, r.stderr
    return out, r


def test_maps_are_ply_point_clouds_with_every_column(patina_run):
    out, _ = patina_run
    for i in (1, 2, 3):
        cols = read_ply(out / "maps" / f"iter_{i:04d}.ply")
        assert list(cols) == ["x", "y", "z", "nx", "ny", "nz", "surface", "patina", "reflectance_straight",
                              "reflectance_parabolic", "reflectance_flow"]
        assert len(cols["x"]) == 8000
        n = np.stack([cols["nx"], cols["ny"], cols["nz"]], 1)
        assert np.allclose(np.linalg.norm(n, axis=1), 1, atol=1e-5)
        assert np.all(cols["reflectance_straight"] == np.float32(0.5))


def test_patina_grows_and_matches_the_summary(patina_run):
    out, _ = patina_run
    summary = json.loads((out / "summary.json").read_text())
    sums = [it["property_sums"]["patina"] for it in summary["iterations"]]
    assert sums[0] > 0 and sums[0] < sums[1] < sums[2]
    last = read_ply(out / "maps" / "iter_0003.ply")["patina"]
    assert float(np.sum(last, dtype=np.float64)) == pytest.approx(sums[2], rel=1e-9)
    for key in ("surfels", "triangles", "threads", "seed", "versions"):
        assert key in summary
    assert summary["surfels"] == 8000 and summary["seed"] == 3
    for it in summary["iterations"]:
        assert it["emitted"] == 40000
        assert it["emitted"] == it["settled"] + it["escaped"] + it["capped"]
        assert it["trace_seconds"] > 0 and it["update_seconds"] >= 0


def test_one_render_per_iteration_with_colour_bar(patina_run):
    out, _ = patina_run
    for i in (1, 2, 3):
        img = Image.open(out / "renders" / f"iter_{i:04d}.png")
        assert img.size[1] == 200 and img.size[0] > 200   # picture plus the colour bar
        pixels = np.asarray(img.convert("RGB")).astype(int)
        assert len(np.unique(pixels.reshape(-1, 3), axis=0)) > 50   # not blank


def test_a_rerun_replaces_the_earlier_run(tmp_path, bumpy_obj):
    for iterations in (3, 1):
        r = run_gammac("run", ROOT / "examples" / "patina.gamma", "--scene", bumpy_obj, "--surfels", 500,
                       "--tons", 1000, "--iterations", iterations, "--size", 32, "--quiet",
                       "--out", tmp_path)
        assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in (tmp_path / "maps").iterdir()) == ["iter_0001.ply"]
    assert sorted(p.name for p in (tmp_path / "renders").iterdir() if p.is_file()) == ["iter_0001.png"]


def test_no_temporary_files_left(patina_run):
    out, _ = patina_run
    leftovers = [p for p in out.rglob("*") if p.name.startswith(".")]
    assert leftovers == []


def test_progress_is_shown(patina_run):
    _, r = patina_run
    assert "3/3" in r.stderr and "γ-tons/s" in r.stderr


def test_non_finite_results_are_reported_once_and_kept_out_of_the_maps(tmp_path, bumpy_obj):
    (tmp_path / "nan.gamma").write_text(
        "ton T { motion straight = 0.5 carry a = 1 }\nsurface S { property p = 0, q = 0 }\n"
        "source s = environment(sphere) emits T count 5000\n"
        "on settle(t: T, s: S) {\n    s.p += t.a\n    s.q += t.a / (s.p - s.p)\n}\n")
    r = run_gammac("run", tmp_path / "nan.gamma", "--scene", bumpy_obj, "--surfels", 500,
                   "--iterations", 2, "--size", 32, "--out", tmp_path / "o")
    assert r.returncode == 0, r.stderr
    warnings = [line for line in r.stderr.splitlines() if "NaN or infinity" in line]
    assert len(warnings) == 1 and "nan.gamma:6:5" in warnings[0]
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    settled = sum(it["settled"] for it in summary["iterations"])
    assert summary["nonfinite"] == [{"where": str(tmp_path / "nan.gamma") + ":6:5",
                                     "rule": "on settle(T, S)", "count": settled,
                                     "first_iteration": 1}]
    cols = read_ply(tmp_path / "o" / "maps" / "iter_0002.ply")
    assert np.all(np.isfinite(cols["q"])) and np.all(cols["q"] == 0) and cols["p"].sum() > 0


def test_appearance_renders_sequence_and_false_colour(tmp_path):
    """An effect with an appearance block: textured pictures per iteration,
    an animated GIF, a strip, and the false colour beside them."""
    verts = np.array([[-1, 0, -1], [1, 0, -1], [1, 0, 1], [-1, 0, 1], [0, 1, 0]], float)
    faces = [(0, 2, 1), (0, 3, 2), (0, 1, 4), (1, 2, 4), (2, 3, 4), (3, 0, 4)]
    lines = [f"v {x} {y} {z}" for x, y, z in verts] + ["vt 0 0", "vt 1 0", "vt 1 1", "vt 0 1", "vt 0.5 0.5"]
    lines += [f"f {a + 1}/{[1, 2, 3, 4, 5][a]} {b + 1}/{[1, 2, 3, 4, 5][b]} {c + 1}/{[1, 2, 3, 4, 5][c]}"
              for a, b, c in faces]
    (tmp_path / "pyramid.obj").write_text("\n".join(lines) + "\n")
    Image.new("RGB", (4, 4), (200, 40, 40)).save(tmp_path / "red.png")
    (tmp_path / "look.gamma").write_text(
        "ton T { motion straight = 0.5 carry a = 1 }\nsurface S { property p = 0 }\n"
        "source s = environment(sphere) emits T count 20000\non settle(t: T, s: S) { s.p += 0.01 * t.a }\n"
        'appearance(s: S) {\n    color = mix(texture("red.png"), rgb(0, 0.5, 1), clamp(s.p, 0, 1))\n}\n')
    out = tmp_path / "out"
    r = run_gammac("run", tmp_path / "look.gamma", "--scene", tmp_path / "pyramid.obj", "--surfels", 2000,
                   "--iterations", 3, "--size", 64, "--quiet", "--out", out)
    assert r.returncode == 0, r.stderr
    for i in (1, 2, 3):
        assert Image.open(out / "renders" / f"iter_{i:04d}.png").size == (64, 64)
        assert (out / "renders" / "false_colour" / f"iter_{i:04d}.png").is_file()
    gif = Image.open(out / "renders" / "sequence.gif")
    assert gif.n_frames == 3
    import imageio.v2 as imageio

    video = imageio.get_reader(out / "renders" / "sequence.mp4")
    assert video.count_frames() == 3 and video.get_data(0).shape == (64, 64, 3)
    mp4 = (out / "renders" / "sequence.mp4").read_bytes()
    assert 0 < mp4.index(b"moov") < mp4.index(b"mdat")     # +faststart: the index first, so it streams
    assert Image.open(out / "renders" / "strip.png").size == (64 * 3, 64)
    pixels = np.asarray(Image.open(out / "renders" / "iter_0001.png").convert("RGB")).reshape(-1, 3).astype(int)
    assert np.any(pixels[:, 0] > pixels[:, 2] + 40)     # the red texture shows somewhere
    assert json.loads((out / "summary.json").read_text())["appearance"] is True


def _false_colour_reference(value, shade, vmin, vmax, label, title) -> bytes:
    """The false-colour picture drawn in one go, every part of it (the way
    ``false_colour_png`` drew it before the frame was shared between pictures)."""
    import io

    from PIL import ImageDraw, ImageFont

    from gamma.driver.outputs.outputs import viridis
    from gamma.driver.outputs.outputs import PNG_COMPRESS_LEVEL

    h, w = value.shape
    span = vmax - vmin if vmax > vmin else 1.0
    rgb = viridis((np.nan_to_num(value, nan=vmin) - vmin) / span) * shade[..., None]
    background = np.linspace(0.97, 0.85, h)[:, None, None] * np.ones((1, w, 3))
    rgb = np.where(np.isnan(value)[..., None], background, rgb)
    canvas = Image.new("RGB", (w + 150, h), (255, 255, 255))
    canvas.paste(Image.fromarray((rgb * 255 + 0.5).astype(np.uint8)), (0, 0))
    draw = ImageDraw.Draw(canvas)
    font = ImageFont.load_default(size=max(11, h // 40))
    top, bottom = int(h * 0.12), int(h * 0.88)
    x0 = w + 20
    ramp = viridis(np.linspace(1.0, 0.0, bottom - top))
    canvas.paste(Image.fromarray((np.repeat(ramp[:, None, :], 24, axis=1) * 255 + 0.5).astype(np.uint8)),
                 (x0, top))
    draw.rectangle([x0 - 1, top - 1, x0 + 24, bottom], outline=(0, 0, 0))
    for k in range(5):
        y = bottom - k / 4 * (bottom - top)
        draw.line([x0 + 24, y, x0 + 30, y], fill=(0, 0, 0))
        draw.text((x0 + 34, y), f"{vmin + k / 4 * span:.3g}", fill=(0, 0, 0), font=font, anchor="lm")
    draw.text((x0 - 4, top - 10), label, fill=(0, 0, 0), font=font, anchor="lb")
    draw.text((10, 10), title, fill=(0, 0, 0), font=font)
    out = io.BytesIO()
    canvas.save(out, format="PNG", compress_level=PNG_COMPRESS_LEVEL)   # the encoding gammac uses
    return out.getvalue()


@pytest.mark.parametrize("size", [(64, 90), (200, 200), (12, 30), (512, 512)])
def test_a_shared_false_colour_frame_gives_the_bytes_of_drawing_everything(size):
    """The run draws the colour bar once and only the picture per iteration:
    the files are byte for byte those of drawing each picture whole, also with
    NaN background, infinite values and an empty scale."""
    from gamma.driver.outputs.outputs import FalseColourCanvas

    rng = np.random.default_rng(7)
    h, w = size
    for vmin, vmax in ((0.0, 1.7), (-0.25, 0.5), (0.3, 0.3)):
        canvas = FalseColourCanvas(w, h, vmin, vmax, "patina")
        for it in range(3):
            value = (rng.random((h, w)) * 2.5 - 0.5).astype(np.float32)
            value[rng.random((h, w)) < 0.5] = np.nan
            value[1, 2], value[2, 1] = np.inf, -np.inf
            shade = np.where(np.isnan(value), np.nan, 0.25 + 0.75 * rng.random((h, w))).astype(np.float32)
            title = f"patina, iteration {it + 1}" if it < 2 else "a longer title over the colour bar: Wg,|^ 1099"
            with np.errstate(over="ignore", invalid="ignore"):
                want = _false_colour_reference(value, shade, vmin, vmax, "patina", title)
            assert canvas.png(value, shade, title) == want


def test_the_scales_percentile_is_numpys_bit_for_bit():
    """writers.percentile_995 is np.percentile(values, 99.5) to the bit, on
    sizes where (n - 1) * 0.995 is whole, below and above a half, with ties,
    zeros of both signs, subnormals and wide ranges."""
    from gamma.driver.outputs.writers import percentile_995

    rng = np.random.default_rng(7)
    sizes = [1, 2, 3, 7, 100, 101, 199, 200, 201, 401, 1000, 1001, 4097, 100_000]
    cases = 0
    for n in sizes:
        for kind in range(6):
            if kind == 0:
                v = rng.random(n, dtype=np.float32)
            elif kind == 1:
                v = rng.integers(0, 4, n).astype(np.float32)          # many ties
            elif kind == 2:
                v = (rng.standard_normal(n) * 1e30).astype(np.float32)
            elif kind == 3:
                v = np.where(rng.random(n) < 0.5, -0.0, 0.0).astype(np.float32)
            elif kind == 4:
                v = (rng.random(n) * 1e-40).astype(np.float32)        # subnormals
            else:
                v = np.exp(rng.standard_normal(n) * 10).astype(np.float32)
            mine, numpys = percentile_995(v.copy()), float(np.percentile(v, 99.5))
            assert np.float64(mine).tobytes() == np.float64(numpys).tobytes() or mine == numpys == 0.0, (n, kind)
            cases += 1
    assert cases == len(sizes) * 6


def test_unique_rows_is_numpys_unique_over_rows():
    from gamma.driver.running.scene import unique_rows

    rng = np.random.default_rng(3)
    for n in (0, 1, 5, 300):
        for high in (0, 1, 4, 40):
            labels = rng.integers(-1, high + 1, size=(n, 3)).astype(np.int64)
            keys, inverse = unique_rows(labels)
            want_keys, want_inverse = np.unique(labels, axis=0, return_inverse=True)
            assert np.array_equal(keys, want_keys)
            assert np.array_equal(inverse, want_inverse.reshape(-1))
    huge = np.array([[2**40, 2**40, 2**40], [-1, 0, 0]], np.int64)    # too wide for one number
    keys, inverse = unique_rows(huge)
    assert np.array_equal(keys, np.unique(huge, axis=0)) and list(inverse) == [1, 0]


def test_summary_splits_the_wall_time(patina_run):
    """summary.json reports where the run's time went (bench_endtoend.py prints it)."""
    out, _ = patina_run
    summary = json.loads((out / "summary.json").read_text())
    traced = sum(it["trace_seconds"] + it["update_seconds"] for it in summary["iterations"])
    assert summary["startup_seconds"] > 0 and summary["scene_seconds"] > 0
    assert summary["start_seconds"] >= (summary["scene_seconds"] + summary["compile_seconds"]
                                        + summary["setup_seconds"])
    assert summary["loop_seconds"] >= traced
    assert summary["finish_seconds"] > 0 and summary["writer_wait_seconds"] >= 0
    assert set(summary["output_seconds"]) == {"maps", "summary", "renders"}
    assert all(seconds > 0 for seconds in summary["output_seconds"].values())


def _frames(n=4, size=(48, 30)):
    rng = np.random.default_rng(5)
    return [Image.fromarray(rng.integers(0, 256, (size[1], size[0], 3), dtype=np.uint8)) for _ in range(n)]


def test_the_sequence_files_are_made_side_by_side_as_one_after_the_other(tmp_path):
    """GIF here, MP4 and strip on threads of their own: the GIF and the strip
    are the bytes of making each alone, the MP4 plays (index first)."""
    import io

    from gamma.driver.outputs.writers import write_sequence, write_strip

    frames = _frames()
    write_sequence(frames, tmp_path)
    alone = io.BytesIO()
    frames[0].save(alone, format="GIF", save_all=True, append_images=frames[1:], duration=400, loop=0)
    assert (tmp_path / "sequence.gif").read_bytes() == alone.getvalue()
    (tmp_path / "alone").mkdir()
    write_strip(frames, tmp_path / "alone" / "strip.png")
    assert (tmp_path / "strip.png").read_bytes() == (tmp_path / "alone" / "strip.png").read_bytes()
    assert Image.open(tmp_path / "strip.png").size == (48 * 4, 30)
    mp4 = (tmp_path / "sequence.mp4").read_bytes()
    assert 0 < mp4.index(b"moov") < mp4.index(b"mdat")
    assert sorted(p.name for p in tmp_path.iterdir() if p.is_file()) == ["sequence.gif", "sequence.mp4", "strip.png"]


def test_a_failing_sequence_file_is_raised_once_the_others_are_whole(tmp_path, monkeypatch):
    from gamma.driver.outputs import writers

    def no_ffmpeg(frames, path, fps=4):
        raise OSError(2, "ffmpeg not found")

    monkeypatch.setattr(writers, "write_mp4", no_ffmpeg)
    with pytest.raises(OSError, match="ffmpeg not found"):
        writers.write_sequence(_frames(), tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sequence.gif", "strip.png"]   # whole, no temporary
    assert Image.open(tmp_path / "strip.png").size == (48 * 4, 30)
    monkeypatch.undo()

    class Unsavable(Image.Image):
        def save(self, *args, **kwargs):
            raise OSError(28, "No space left on device")

    frames = _frames()
    broken = Unsavable()
    broken.__dict__.update(frames[0].__dict__)
    folder = tmp_path / "gif"
    folder.mkdir()
    with pytest.raises(OSError, match="No space left"):
        writers.write_sequence([broken] + frames[1:], folder)
    # the MP4 and the strip were finished (not abandoned half-written) before the error came back
    assert sorted(p.name for p in folder.iterdir()) == ["sequence.mp4", "strip.png"]
