"""The paper's results and the standard library's recipes, each as a run:
one table of scenes, effects and cameras shared by the make targets, the
README gallery and the tests.

    python examples/gallery.py run NAME [--out DIR] [gammac run options ...]
    python examples/gallery.py pictures [NAME ...]   # docs/gallery/NAME.png
    python examples/gallery.py list

`run` builds the scene if its script is newer, then runs the example at full
scale (what `make NAME` does).  `pictures` runs every entry at gallery scale
and writes a small PNG of its last iteration to docs/gallery/.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SCENES = ROOT / "examples" / "scenes"
GALLERY = ROOT / "docs" / "gallery"


@dataclass
class Entry:
    name: str
    effect: str                      # relative to ROOT
    scene: str                       # relative to ROOT
    title: str                       # caption in the README gallery
    args: list[str] = field(default_factory=list)      # camera, binding, ...
    full: list[str] = field(default_factory=list)      # extra options at full scale
    small: list[str] = field(default_factory=list)     # extra options for the gallery picture
    compare: list[str] | None = None  # options of a second run shown on the left of the picture

    @property
    def script(self) -> Path | None:
        """The script that generates the scene, if it is generated."""
        path = ROOT / self.scene
        script = path.with_name(f"make_{path.stem}.py")
        return script if script.exists() else None


EXAMPLES = [
    Entry("patina", "examples/patina-spot.gamma", "examples/scenes/spot.obj",
          "Metallic patina on Spot, texture blended toward verdigris (Fig. 7)",
          ["--view", "0.7,0.35,-1"], ["--surfels", "100000", "--iterations", "10"],
          ["--surfels", "60000", "--iterations", "10", "--tons", "1500000"]),
    Entry("stain", "examples/stain-bleeding.gamma", "examples/scenes/staircase.obj",
          "Stain-bleeding: rust from a chain runs down a cement staircase (Fig. 8)",
          ["--assign", "chain=Iron", "--assign", "*=Cement", "--view", "1,0.7,0.9"],
          ["--surfels", "100000", "--iterations", "30"],
          ["--surfels", "100000", "--iterations", "30"]),
    Entry("moss-dirt", "examples/moss-dirt.gamma", "examples/scenes/courtyard.obj",
          "Moss on the ground suppresses the dirt rain splashes onto a wall (Fig. 9)",
          ["--view", "0.5,0.45,1"], ["--surfels", "100000", "--iterations", "30"],
          ["--surfels", "100000", "--iterations", "30"], compare=["--param", "moss=0"]),
    Entry("leak-stain", "examples/leak-stain.gamma", "examples/scenes/leak.obj",
          "A stain from water dripping out of a leaking pipe (Fig. 10, spot source)",
          ["--view", "0.35,0.2,1"], ["--surfels", "100000", "--iterations", "30"],
          ["--surfels", "100000", "--iterations", "30"]),
    Entry("hydrant", "examples/hydrant.gamma", "examples/scenes/street.obj",
          "Rust and dust on a hydrant, moss in the joints of the floor (Fig. 1)",
          ["--view", "0.8,0.75,1"], ["--surfels", "100000", "--iterations", "30"],
          ["--surfels", "100000", "--iterations", "30"]),
    Entry("erosion", "examples/erosion.gamma", "examples/scenes/arch.obj",
          "Erosion: wind-driven sand wears a sandstone arch, after 1 and 30 iterations (Fig. 11)",
          ["--assign", "ground=Ground", "--assign", "arch=Sandstone",
           "--view", "-1,0.45,0.9"], ["--surfels", "60000", "--iterations", "30"],
          ["--surfels", "60000", "--iterations", "30"], compare=["--iterations", "1"]),
]

# Recipes: each stdlib recipe imported alone, on a scene that shows it.
RECIPE_SCENES = {
    "patina": ("examples/scenes/stanford-bunny.obj", ["--view", "-0.6,0.35,1"]),
    "rust": ("examples/scenes/teapot.obj", ["--view", "-0.6,0.5,1"]),
    "dust": ("examples/scenes/stanford-bunny.obj", ["--view", "-0.6,0.45,1"]),
    "moss": ("examples/scenes/staircase.obj", ["--view", "1,0.7,0.9"]),
    "water-streaks": ("examples/scenes/leak.obj", ["--view", "0.35,0.2,1"]),
    "soot": ("examples/scenes/staircase.obj", ["--view", "1,0.5,0.9"]),
    "sun-bleaching": ("examples/scenes/teapot.obj", ["--view", "-0.6,0.35,1"]),
    "efflorescence": ("examples/scenes/courtyard.obj", ["--view", "0.5,0.45,1"]),
    "lichen": ("examples/scenes/fandisk.obj", ["--view", "-0.6,0.5,1"]),
    "erosion": ("examples/scenes/stanford-bunny.obj", ["--view", "-0.6,0.35,1"]),
}


def recipe_entries() -> list[Entry]:
    entries = []
    for stem, (scene, args) in RECIPE_SCENES.items():
        entries.append(Entry(f"recipe-{stem}", f"stdlib/{stem}.gamma", scene, f"`{stem}.gamma`", args,
                             ["--surfels", "100000", "--iterations", "10"],
                             ["--surfels", "60000", "--iterations", "10"]))
    return entries


def entries() -> dict[str, Entry]:
    return {e.name: e for e in EXAMPLES + recipe_entries()}


def gammac() -> list[str]:
    return [sys.executable, "-m", "gamma.cli"]


def ensure_scene(entry: Entry) -> Path:
    scene = ROOT / entry.scene
    script = entry.script
    if script and (not scene.exists() or scene.stat().st_mtime < script.stat().st_mtime):
        subprocess.run([sys.executable, str(script), str(scene)], check=True)
    return scene


def run(entry: Entry, out: Path, extra: list[str], scale: str = "full") -> subprocess.CompletedProcess:
    scene = ensure_scene(entry)
    options = entry.full if scale == "full" else entry.small
    cmd = gammac() + ["run", str(ROOT / entry.effect), "--scene", str(scene), "--out", str(out),
                      *entry.args, *options, *extra]
    return subprocess.run(cmd, check=True)


def picture(entry: Entry, out_root: Path, size: int) -> Path:
    """docs/gallery/NAME.png: the last iteration, size x size pixels (two
    side by side for an entry that compares), reduced to 256 colours."""
    from PIL import Image

    runs = [[]] if entry.compare is None else [entry.compare, []]
    images = []
    for k, options in enumerate(runs):
        out = out_root / f"{entry.name}-{k}"
        run(entry, out, ["--size", str(size), "--quiet", *options], scale="small")
        renders = sorted((out / "renders").glob("iter_*.png"))
        images.append(Image.open(renders[-1]).convert("RGB"))
    sheet = Image.new("RGB", (size * len(images), size))
    for k, image in enumerate(images):
        sheet.paste(image, (k * size, 0))
    GALLERY.mkdir(parents=True, exist_ok=True)
    target = GALLERY / f"{entry.name}.png"
    sheet.quantize(256, dither=Image.Dither.NONE).save(target, optimize=True)
    return target


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="command", required=True)
    r = sub.add_parser("run")
    r.add_argument("name", choices=sorted(entries()))
    r.add_argument("--out")
    g = sub.add_parser("pictures")
    g.add_argument("names", nargs="*")
    g.add_argument("--size", type=int, default=288)
    g.add_argument("--work", default=str(ROOT / "out" / "gallery"))
    sub.add_parser("list")
    args, extra = p.parse_known_args(argv)
    table = entries()
    if args.command == "list":
        for e in table.values():
            print(f"{e.name:24} {e.effect:34} {e.scene}")
        return 0
    if args.command == "run":
        entry = table[args.name]
        out = Path(args.out or ROOT / "out" / entry.name)
        run(entry, out, extra)
        print(f"{entry.title}: {out}/renders/")
        return 0
    names = args.names or list(table)
    for name in names:
        target = picture(table[name], Path(args.work), args.size)
        print(f"wrote {target}")
    shutil.rmtree(args.work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
