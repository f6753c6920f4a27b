"""`gammac watch` in a real headless browser: Debian's chromium, driven by
Playwright's Python API (never Playwright's own browser download).  The page
loads, shows the mesh, follows an edit of the effect and shows a compile
error after a broken edit."""

import os
import queue
import re
import shutil
import subprocess
import sys
import threading
import time
import urllib.request
from io import BytesIO

import numpy as np
import pytest
from PIL import Image


CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
playwright_api = pytest.importorskip("playwright.sync_api")

EFFECT = """\
ton Weather {
    motion straight = 1.0
    carry patina = 1.0
}

surface Copper {
    reflectance straight = 0.5
    property patina = 0.0
}

source air = environment(sphere) emits Weather count 20000

on settle(t: Weather, s: Copper) {
    s.patina += RATE * t.patina
}
"""


#: The same effect with an appearance: a constant look, ROUGHNESS and METALLIC to fill in.
LOOK_EFFECT = EFFECT.replace("RATE", "0.05") + """
appearance(s: Copper) {
    color = rgb(0.8, 0.55, 0.4)
    roughness = ROUGHNESS
    metallic = METALLIC
    occlusion = 0.75
}
"""


@pytest.fixture()
def watched(tmp_path, bumpy_obj):
    """A running `gammac watch` on an effect in tmp_path: (url, effect path, log)."""
    effect = tmp_path / "effect.gamma"
    effect.write_text(EFFECT.replace("RATE", "0.05"))
    yield from watching(effect, bumpy_obj)


@pytest.fixture()
def watched_look(tmp_path, bumpy_obj):
    """As ``watched``, on LOOK_EFFECT as a rough dielectric (roughness 1, metallic 0)."""
    effect = tmp_path / "effect.gamma"
    effect.write_text(LOOK_EFFECT.replace("ROUGHNESS", "1.0").replace("METALLIC", "0.0"))
    yield from watching(effect, bumpy_obj)


def watching(effect, bumpy_obj):
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.Popen([sys.executable, "-m", "gamma.cli", "watch", str(effect), "--scene", str(bumpy_obj),
                             "--surfels", "4000", "--iterations", "3", "--port", "0", "--threads", "2"],
                            stderr=subprocess.PIPE, text=True, env=env)
    lines: queue.Queue = queue.Queue()
    log: list[str] = []

    def pump():
        for line in proc.stderr:
            log.append(line)
            lines.put(line)

    threading.Thread(target=pump, daemon=True).start()
    url, deadline = None, time.monotonic() + 60
    while url is None and time.monotonic() < deadline:
        try:
            match = re.search(r"viewer at (http://127\.0\.0\.1:\d+/)", lines.get(timeout=1))
        except queue.Empty:
            if proc.poll() is not None:
                break
            continue
        url = match and match.group(1)
    assert url, "".join(log)
    yield url, effect, log
    proc.terminate()
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def coloured_fraction(png: bytes) -> float:
    """Share of pixels that are not grey (the page's background is grey)."""
    rgb = np.asarray(Image.open(BytesIO(png)).convert("RGB"), np.int16)
    return float(np.mean(rgb.max(axis=2) - rgb.min(axis=2) > 25))


def wait_for(page, expression: str, timeout: float = 60_000):
    page.wait_for_function(expression, timeout=timeout)


def test_page_shows_the_mesh_follows_edits_and_shows_errors(watched):
    url, effect, log = watched
    with playwright_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, headless=True,
                                    args=["--enable-unsafe-swiftshader", "--use-angle=swiftshader",
                                          "--no-sandbox"])
        try:
            page = browser.new_page(viewport={"width": 900, "height": 600})
            page.goto(url)
            # the first full-quality result, drawn
            wait_for(page, "window.gammaViewer && gammaViewer.shown && gammaViewer.shown.quality === 'final'")
            viewer = page.evaluate("({v: gammaViewer.vertices, g: gammaViewer.shown.generation,"
                                   " sums: gammaViewer.state.run.records.map(r => r.property_sums.patina)})")
            assert viewer["v"] > 100
            assert page.locator("#status").inner_text() == "ready"
            shot = page.locator("#view canvas").screenshot()
            assert coloured_fraction(shot) > 0.05, "the mesh is not on the canvas"
            # the property switch shows the colour bar and the run's range
            page.select_option("#show", "patina")
            wait_for(page, "gammaViewer.shown.show === 'patina'")
            assert page.locator("#colourbar").is_visible()
            low, high = float(page.locator("#range-min").inner_text()), float(page.locator("#range-max").inner_text())
            assert 0 <= low < high
            # the iteration slider shows earlier iterations
            page.locator("#iteration").fill("1")
            wait_for(page, "gammaViewer.shown.iteration === 1")

            # an edit: twice the rate, twice the patina, without a reload
            effect.write_text(EFFECT.replace("RATE", "0.1"))
            wait_for(page, f"gammaViewer.shown.generation > {viewer['g']} && gammaViewer.shown.quality === 'final'")
            after = page.evaluate("gammaViewer.state.run.records.map(r => r.property_sums.patina)")
            assert after == pytest.approx([2 * s for s in viewer["sums"]], rel=1e-4)
            assert page.locator("#errors").is_hidden()

            # a broken edit: the error with file:line:col and the source line
            effect.write_text(EFFECT.replace("RATE", "0.1 +"))
            wait_for(page, "!document.getElementById('errors').hidden")
            text = page.locator("#errors").inner_text()
            assert re.search(r"effect\.gamma:14:23: error: syntax error", text), text
            assert "s.patina += 0.1 +" in text
            assert page.locator("#status").inner_text() == "error"
        finally:
            browser.close()


def launch(p):
    return p.chromium.launch(executable_path=CHROMIUM, headless=True,
                             args=["--enable-unsafe-swiftshader", "--use-angle=swiftshader", "--no-sandbox"])


def frame_of(url: str, page) -> dict:
    """The shown frame's bytes from the server, cut up as the page reads them."""
    state = page.evaluate("gammaViewer.state")
    n = state["mesh"]["vertices"]
    with urllib.request.urlopen(f"{url}api/frame?generation={state['generation']}"
                                f"&iteration={state['iterations']}") as response:
        data = np.frombuffer(response.read(), "<f4")
    assert [p["name"] for p in state["properties"]] == ["patina"]
    assert data.size == (3 + 3 + 1) * n, "colour (3n), roughness, metallic, occlusion, one property (n each)"
    return {"colour": data[:3 * n].reshape(n, 3), "roughness": data[3 * n:4 * n], "metallic": data[4 * n:5 * n],
            "occlusion": data[5 * n:6 * n], "patina": data[6 * n:]}


def test_the_look_roughness_metallic_and_occlusion_reach_the_frame_and_the_pixels(watched_look):
    url, effect, log = watched_look
    with playwright_api.sync_playwright() as p:
        browser = launch(p)
        try:
            page = browser.new_page(viewport={"width": 900, "height": 600})
            page.goto(url)
            shots, frames = {}, {}
            generation = 0
            for name, roughness, metallic in (("matte", "1.0", "0.0"), ("metal", "0.2", "1.0")):
                if name == "metal":     # an edit: the page follows it
                    effect.write_text(LOOK_EFFECT.replace("ROUGHNESS", roughness).replace("METALLIC", metallic))
                wait_for(page, f"gammaViewer.shown && gammaViewer.shown.generation > {generation}"
                               " && gammaViewer.shown.quality === 'final'")
                generation = page.evaluate("gammaViewer.shown.generation")
                frames[name] = frame_of(url, page)
                for show in ("appearance", "patina"):
                    page.select_option("#show", show)
                    wait_for(page, f"gammaViewer.shown.show === '{show}'"
                                   f" && gammaViewer.shown.generation === {generation}")
                    shots[name, show] = np.asarray(Image.open(BytesIO(page.locator("#view canvas").screenshot()))
                                                   .convert("RGB"), np.float64)
            assert page.locator("#errors").is_hidden(), "".join(log)
        finally:
            browser.close()

    # the frames carry the appearance block's constants
    for name, roughness, metallic in (("matte", 1.0, 0.0), ("metal", 0.2, 1.0)):
        frame = frames[name]
        assert frame["colour"] == pytest.approx(np.tile(np.float32([0.8, 0.55, 0.4]), (len(frame["patina"]), 1)))
        assert frame["roughness"] == pytest.approx(np.full_like(frame["roughness"], roughness))
        assert frame["metallic"] == pytest.approx(np.full_like(frame["metallic"], metallic))
        assert frame["occlusion"] == pytest.approx(np.full_like(frame["occlusion"], 0.75))
    assert frames["matte"]["patina"].max() > 0
    assert np.array_equal(frames["matte"]["patina"], frames["metal"]["patina"])   # the rules did not change

    # the mesh's pixels: not grey in the false-colour view (viridis)
    patina = shots["matte", "patina"]
    mask = patina.max(axis=2) - patina.min(axis=2) > 25
    assert mask.mean() > 0.05, "the mesh is not on the canvas"
    brightness = {name: shots[name, "appearance"].mean(axis=2)[mask] for name in ("matte", "metal")}
    # the polished metal looks different from the matte paint ...
    difference = np.abs(shots["metal", "appearance"] - shots["matte", "appearance"]).mean(axis=2)[mask]
    assert difference.mean() > 20, difference.mean()
    # ... is not black (it reflects the sky) and has highlights (the sky's bright panels, sharp)
    assert brightness["metal"].mean() > 60, brightness["metal"].mean()
    assert np.percentile(brightness["metal"], 99) > np.percentile(brightness["matte"], 99) + 20, \
        (np.percentile(brightness["metal"], 99), np.percentile(brightness["matte"], 99))
    # the property views ignore the look (a matte dielectric, unoccluded, whatever the effect says)
    assert np.abs(shots["metal", "patina"] - shots["matte", "patina"]).mean() < 1.0


#: A look from a mask: green where the mask is white.
MASK_EFFECT = EFFECT.replace("RATE", "0.05") + """
appearance(s: Copper) {
    color = mix(rgb(0.8, 0.8, 0.8), rgb(0.1, 0.6, 0.1), mask("paint.png"))
}
"""


def test_a_brush_stroke_changes_the_mask_file_and_the_picture(tmp_path):
    """The page's brush paints paint.png (read by the effect through mask())
    at the texture coordinates under the pointer; Undo takes a stroke back;
    Save replaces the file beside the effect, which then runs again."""
    n = 8
    lines = [f"v {x} 0 {z}" for z in range(n + 1) for x in range(n + 1)]
    lines += [f"vt {x / n} {1 - z / n}" for z in range(n + 1) for x in range(n + 1)]
    for z in range(n):
        for x in range(n):
            a, b, c, d = (z * (n + 1) + x + 1, z * (n + 1) + x + 2, (z + 1) * (n + 1) + x + 1,
                          (z + 1) * (n + 1) + x + 2)
            lines += [f"f {a}/{a} {c}/{c} {b}/{b}", f"f {b}/{b} {c}/{c} {d}/{d}"]
    plane = tmp_path / "plane.obj"
    plane.write_text("\n".join(lines) + "\n")
    Image.fromarray(np.zeros((64, 64), np.uint8)).save(tmp_path / "paint.png")
    before = (tmp_path / "paint.png").read_bytes()
    effect = tmp_path / "effect.gamma"
    effect.write_text(MASK_EFFECT)
    for url, _, log in watching(effect, plane):
        with playwright_api.sync_playwright() as p:
            browser = launch(p)
            try:
                page = browser.new_page(viewport={"width": 900, "height": 600})
                page.goto(url)
                wait_for(page, "gammaViewer.shown && gammaViewer.shown.quality === 'final'"
                               " && gammaViewer.paint.index === 0")
                generation = page.evaluate("gammaViewer.shown.generation")
                first = frame_of(url, page)
                page.check("#paint")
                page.fill("#brush-size", "12")
                box = page.locator("#view canvas").bounding_box()
                cx, cy = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2

                def stroke():
                    page.mouse.move(cx - 40, cy)
                    page.mouse.down()
                    for k in range(9):
                        page.mouse.move(cx - 40 + 10 * k, cy)
                    page.mouse.up()

                stroke()
                painted = page.evaluate("gammaViewer.maskSum()")
                assert painted > 0, "the stroke painted nothing"
                page.click("#undo")
                assert page.evaluate("gammaViewer.maskSum()") == 0, "undo takes the stroke back"
                stroke()
                assert page.evaluate("gammaViewer.maskSum()") == painted
                page.click("#save-mask")
                wait_for(page, "gammaViewer.paint.saved === 1")
                wait_for(page, f"gammaViewer.shown.generation > {generation}"
                               " && gammaViewer.shown.quality === 'final'")
                second = frame_of(url, page)
            finally:
                browser.close()
        assert "".join(log).count("error") == 0, "".join(log)
    saved = Image.open(tmp_path / "paint.png")
    assert (tmp_path / "paint.png").read_bytes() != before and saved.size == (64, 64)
    assert np.asarray(saved.convert("L")).max() > 100, "the file holds the stroke"
    # the picture: vertices under the stroke turned green, the others stayed grey
    green = second["colour"][:, 1] - second["colour"][:, 0]
    assert np.all(first["colour"][:, 1] - first["colour"][:, 0] < 1e-6)
    assert green.max() > 0.2 and (green > 0.05).mean() < 0.5, (green.max(), (green > 0.05).mean())


def _components(painted: np.ndarray) -> int:
    """Connected regions (8-neighbours) of the True texels."""
    seen = np.zeros_like(painted)
    count = 0
    h, w = painted.shape
    for start in zip(*np.nonzero(painted)):
        if seen[start]:
            continue
        count += 1
        stack = [start]
        seen[start] = True
        while stack:
            i, j = stack.pop()
            for di in (-1, 0, 1):
                for dj in (-1, 0, 1):
                    a, b = i + di, j + dj
                    if 0 <= a < h and 0 <= b < w and painted[a, b] and not seen[a, b]:
                        seen[a, b] = True
                        stack.append((a, b))
    return count


def test_a_mesh_without_uvs_is_painted_in_its_atlas_across_chart_seams(tmp_path, bumpy_obj):
    """A mesh without texture coordinates (the bumpy sphere): the watch makes
    the missing paint.png, black and laid out in the scene's chart atlas; the
    brush paints in space, so one stroke lands on several charts of the
    image while on the mesh it stays one spot; the saved file keeps its
    atlas record and the picture follows it."""
    from gamma.driver.running import mask_atlas
    from gamma.driver.running.runner import runtime_module
    from gamma.driver.running.scene import load_scene
    from gamma.frontend.checker import load

    effect = tmp_path / "effect.gamma"
    effect.write_text(MASK_EFFECT)
    for url, _, log in watching(effect, bumpy_obj):
        with playwright_api.sync_playwright() as p:
            browser = launch(p)
            try:
                page = browser.new_page(viewport={"width": 900, "height": 600})
                page.goto(url)
                wait_for(page, "gammaViewer.shown && gammaViewer.shown.quality === 'final'"
                               " && gammaViewer.paint.index === 0 && gammaViewer.paint.points !== null")
                assert page.evaluate("gammaViewer.paint.atlas")
                generation = page.evaluate("gammaViewer.shown.generation")
                first = frame_of(url, page)
                page.check("#paint")
                page.fill("#brush-size", "60")
                box = page.locator("#view canvas").bounding_box()
                cx, cy = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
                page.mouse.move(cx - 30, cy)
                page.mouse.down()
                for k in range(7):
                    page.mouse.move(cx - 30 + 10 * k, cy)
                page.mouse.up()
                assert page.evaluate("gammaViewer.maskSum()") > 0, "the stroke painted nothing"
                page.click("#save-mask")
                wait_for(page, "gammaViewer.paint.saved === 1")
                wait_for(page, f"gammaViewer.shown.generation > {generation}"
                               " && gammaViewer.shown.quality === 'final'")
                second = frame_of(url, page)
            finally:
                browser.close()
        text = "".join(log)
        assert "made paint.png, a black 1024x1024 mask in the scene's atlas" in text, text
        assert text.count("error") == 0, text
    record = mask_atlas.layout(tmp_path / "paint.png")
    assert record is not None and record["size"] == 1024, "the saved mask keeps its atlas record"
    painted = np.asarray(Image.open(tmp_path / "paint.png").convert("L")) > 0
    scene = load_scene(runtime_module(), str(bumpy_obj), load(str(effect)), [])
    points, _ = mask_atlas.texel_points(scene.mesh, scene.triangle_has_uv, 1024)
    spot = points[painted]
    assert np.isfinite(spot).all(), "only texels with a place on the mesh are painted"
    lo, hi = (np.asarray(b) for b in scene.bounds)
    spread = np.linalg.norm(spot.max(axis=0) - spot.min(axis=0))
    assert spread < 0.6 * np.linalg.norm(hi - lo), "one spot on the mesh"
    assert _components(painted) >= 2, "the stroke crossed a chart seam and was painted on both charts"
    green = second["colour"][:, 1] - second["colour"][:, 0]
    assert np.all(first["colour"][:, 1] - first["colour"][:, 0] < 1e-6)
    assert green.max() > 0.2 and (green > 0.05).mean() < 0.5, (green.max(), (green > 0.05).mean())
