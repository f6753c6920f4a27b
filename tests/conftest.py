"""Shared helpers for the pytest suite (runs against the installed package)."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
# The suite never touches the user's kernel cache (~/.cache/gamma).
os.environ.setdefault("GAMMA_CACHE_DIR", __import__("tempfile").mkdtemp(prefix="gamma-test-cache-"))


#: Patina and grime on copper from two sources, with random() in both kinds of rule:
#: the determinism and Ray tests' effect.
GRIMY_COPPER = """
ton Weather { motion straight = 1.0  carry patina = 1.0, grime = 0.0 }
surface Copper { reflectance straight = 0.5  property patina = 0.0, grime = 0.5 }
source air = environment(sphere) emits Weather count 30000
source drip = point(0, 1, 0) emits Weather count 10000
on hit(t: Weather, s: Copper) {
    t.grime += 0.1 * s.grime * random()
    s.grime -= 0.01 * s.grime
}
on settle(t: Weather, s: Copper) { s.patina += 0.05 * t.patina + 0.01 * t.grime }
update(s: Copper) {
    s.reflectance.straight = clamp(0.5 + s.patina, 0, 1)
    s.grime = max(s.grime, 0) + 0.001 * random()
}
"""


def run_gammac(*args, cwd=None, timeout=600):
    """Run the CLI as a user would; returns the CompletedProcess."""
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    return subprocess.run([sys.executable, "-m", "gamma.cli", *map(str, args)], cwd=cwd,
                          capture_output=True, text=True, timeout=timeout, env=env)


@pytest.fixture(scope="session")
def rt():
    import gamma._runtime as runtime

    return runtime


@pytest.fixture(scope="session")
def bumpy_obj(tmp_path_factory):
    """A generated closed mesh with concave and convex regions (OBJ path)."""
    from meshes import bumpy_sphere, write_obj

    return write_obj(tmp_path_factory.mktemp("mesh") / "bumpy.obj", *bumpy_sphere())


@pytest.fixture(scope="session")
def box_obj():
    return Path(__file__).parent / "golden" / "open_box.obj"


@pytest.fixture(scope="session")
def ray_local():
    """One local Ray (loopback, 2 CPUs) for the whole session: Ray's start-up
    takes seconds, so every test that needs it shares this one.  Skipped, with
    the install command as the reason, where the optional extra is missing."""
    from gamma.driver.distributed import cluster

    if not cluster.available():
        pytest.skip(cluster.INSTALL_HINT)
    with cluster.connect(num_cpus=2) as connection:
        yield connection.ray
