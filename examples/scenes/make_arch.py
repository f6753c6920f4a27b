"""A sandstone arch on a ground plate, for examples/erosion.gamma (paper Fig. 11).

    python examples/scenes/make_arch.py examples/scenes/arch.obj

The arch is one closed, consistently outward-wound solid: an inverted U
(two legs and a round-topped opening) extruded along z.  The ground plate
is a separate open square around it.  Objects: `arch` and `ground`
(assign them with --assign ground=Ground --assign arch=Sandstone; in that
order, as a pattern also matches the file's name, `arch`, and the first rule
that matches wins).
Units are metres: the arch is 2.0 m wide, 1.6 m high and 0.6 m deep.
"""

import math
import sys
from pathlib import Path

WIDTH, HEIGHT, DEPTH = 2.0, 1.6, 0.6
LEG = 0.5              # leg width at the foot
OPENING = WIDTH - 2 * LEG   # 1.0: the opening's width; its top is a half circle
SPRING = 0.7           # height where the half circle starts
N_ARC = 24             # segments of the half circle (and of the matching outer run)
N_LEG = 8              # segments up each leg
N_DEPTH = 6            # segments through the depth
GROUND = 4.0           # side of the ground plate
N_GROUND = 16


def arch_outline():
    """Outer and inner curves, both from the left foot to the right foot, with
    the same number of points: the cap between them is a strip of quads."""
    inner, outer = [], []
    r = OPENING / 2
    xl, xr = -r, r
    # Left leg: inner edge x = xl, outer edge x = -WIDTH/2; y from 0 to SPRING.
    for k in range(N_LEG):
        y = SPRING * k / N_LEG
        inner.append((xl, y))
        outer.append((-WIDTH / 2, y))
    # Arc over the opening; the outer run goes up the side, over the top and down.
    top_path = [(-WIDTH / 2, SPRING), (-WIDTH / 2, HEIGHT), (WIDTH / 2, HEIGHT), (WIDTH / 2, SPRING)]
    lengths = [math.dist(top_path[i], top_path[i + 1]) for i in range(3)]
    total = sum(lengths)
    for k in range(N_ARC + 1):
        a = math.pi * (1 - k / N_ARC)
        inner.append((r * math.cos(a), SPRING + r * math.sin(a)))
        s = total * k / N_ARC
        for i in range(3):
            if s <= lengths[i] or i == 2:
                f = min(s / lengths[i], 1.0)
                p, q = top_path[i], top_path[i + 1]
                outer.append((p[0] + f * (q[0] - p[0]), p[1] + f * (q[1] - p[1])))
                break
            s -= lengths[i]
    for k in range(1, N_LEG + 1):
        y = SPRING * (1 - k / N_LEG)
        inner.append((xr, y))
        outer.append((WIDTH / 2, y))
    return inner, outer


def build():
    verts, faces, groups = [], [], []

    def v(p):
        verts.append(p)
        return len(verts)  # OBJ indices are 1-based

    inner, outer = arch_outline()
    n = len(inner)
    zs = [-DEPTH / 2 + DEPTH * k / N_DEPTH for k in range(N_DEPTH + 1)]
    # Grid of vertices on the inner and outer walls: [layer][k].
    inner_ids = [[v((x, y, z)) for (x, y) in inner] for z in zs]
    outer_ids = [[v((x, y, z)) for (x, y) in outer] for z in zs]
    arch = []
    front, back = len(zs) - 1, 0
    for k in range(n - 1):
        # Caps (front at +z faces +z, back faces -z): quads between outer and inner.
        a, b, c, d = outer_ids[front][k], outer_ids[front][k + 1], inner_ids[front][k + 1], inner_ids[front][k]
        arch += [(a, d, c), (a, c, b)]
        a, b, c, d = outer_ids[back][k], outer_ids[back][k + 1], inner_ids[back][k + 1], inner_ids[back][k]
        arch += [(a, b, c), (a, c, d)]
        for j in range(len(zs) - 1):
            # Outer wall faces away from the opening, inner wall towards it.
            a, b = outer_ids[j][k], outer_ids[j][k + 1]
            c, d = outer_ids[j + 1][k + 1], outer_ids[j + 1][k]
            arch += [(a, c, b), (a, d, c)]
            a, b = inner_ids[j][k], inner_ids[j][k + 1]
            c, d = inner_ids[j + 1][k + 1], inner_ids[j + 1][k]
            arch += [(a, b, c), (a, c, d)]
    # Feet (y = 0), facing down: quads between inner[0]/outer[0] and inner[-1]/outer[-1].
    for k in (0, n - 1):
        for j in range(len(zs) - 1):
            a, b = outer_ids[j][k], inner_ids[j][k]
            c, d = inner_ids[j + 1][k], outer_ids[j + 1][k]
            arch += [(a, b, c), (a, c, d)] if k == 0 else [(a, c, b), (a, d, c)]
    groups.append(("arch", arch))
    ground = []
    g = [[v((-GROUND / 2 + GROUND * i / N_GROUND, 0.0, -GROUND / 2 + GROUND * j / N_GROUND))
          for j in range(N_GROUND + 1)] for i in range(N_GROUND + 1)]
    for i in range(N_GROUND):
        for j in range(N_GROUND):
            a, b, c, d = g[i][j], g[i + 1][j], g[i + 1][j + 1], g[i][j + 1]
            ground += [(a, c, b), (a, d, c)]   # facing +y
    groups.append(("ground", ground))
    return verts, groups


def main(path: str) -> None:
    verts, groups = build()
    lines = ["# Sandstone arch on a ground plate (examples/scenes/make_arch.py)"]
    lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in verts]
    for name, faces in groups:
        lines.append(f"o {name}")
        lines += [f"f {a} {b} {c}" for a, b, c in faces]
    Path(path).write_text("\n".join(lines) + "\n")
    print(f"wrote {path}: {len(verts)} vertices, {sum(len(f) for _, f in groups)} triangles")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "examples/scenes/arch.obj")
