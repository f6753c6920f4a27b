"""Build the Blender extension: ``dist/gamma-blender-VERSION.zip`` from
``blender/gamma_blender/`` (the manifest at the zip's root, as Blender's
"Install from Disk" and ``bpy.ops.extensions.package_install_files`` want).

    python blender/build_extension.py [--out dist]

The version is the project's one (CMakeLists.txt's ``project(VERSION)``);
the manifest must say the same, so the add-on and the gammac it runs are
released together.
"""

from __future__ import annotations

import argparse
import re
import sys
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SOURCE = ROOT / "blender" / "gamma_blender"


def project_version() -> str:
    match = re.search(r"project\(\s*\w+\s+VERSION\s+([0-9.]+)", (ROOT / "CMakeLists.txt").read_text())
    if not match:
        raise SystemExit("CMakeLists.txt has no project(... VERSION x.y.z)")
    return match.group(1)


def manifest_version() -> str:
    match = re.search(r'^version\s*=\s*"([^"]+)"', (SOURCE / "blender_manifest.toml").read_text(), re.M)
    if not match:
        raise SystemExit("blender_manifest.toml has no version")
    return match.group(1)


def build(out: Path) -> Path:
    version = project_version()
    if manifest_version() != version:
        raise SystemExit(f"blender_manifest.toml says version {manifest_version()}, the project {version}: "
                         "make them the same")
    out.mkdir(parents=True, exist_ok=True)
    target = out / f"gamma-blender-{version}.zip"
    files = sorted(p for p in SOURCE.rglob("*") if p.is_file() and "__pycache__" not in p.parts
                   and p.suffix in (".py", ".toml"))
    partial = target.with_suffix(".zip.partial")
    with zipfile.ZipFile(partial, "w", zipfile.ZIP_DEFLATED) as z:
        for path in files:
            z.write(path, path.relative_to(SOURCE).as_posix())
    partial.replace(target)
    return target


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "dist")
    print(build(ap.parse_args().out))


if __name__ == "__main__":
    sys.exit(main())
