"""A small OBJ writer for the scene scripts in this folder: named objects,
quads, boxes, surfaces of revolution and cylinders, triangles only, y up.

Boxes and flat parts get their own vertices per face (so a renderer that
averages normals over shared vertices keeps their edges sharp); surfaces of
revolution share vertices around the axis (so they shade smoothly) and
duplicate them at profile corners sharper than 40 degrees.
"""

import math


class Obj:
    def __init__(self, comment):
        self.lines = [f"# {comment}"]
        self.count = 0

    def object(self, name):
        self.lines.append(f"o {name}")

    def vertex(self, p):
        self.lines.append("v {:.6f} {:.6f} {:.6f}".format(*p))
        self.count += 1
        return self.count

    def tri(self, a, b, c):
        self.lines.append(f"f {a} {b} {c}")

    def quad(self, a, b, c, d, n=1, m=1):
        """Counter-clockwise seen from the side the face looks at, split into
        n x m quads (a->b is the first direction, b->c the second)."""
        def lerp(p, q, t):
            return tuple(p[k] + (q[k] - p[k]) * t for k in range(3))

        grid = []
        for i in range(n + 1):
            lo, hi = lerp(a, b, i / n), lerp(d, c, i / n)
            grid.append([self.vertex(lerp(lo, hi, j / m)) for j in range(m + 1)])
        for i in range(n):
            for j in range(m):
                v00, v10, v11, v01 = grid[i][j], grid[i + 1][j], grid[i + 1][j + 1], grid[i][j + 1]
                self.tri(v00, v10, v11)
                self.tri(v00, v11, v01)

    def box(self, lo, hi, bottom=True, split=1):
        """Axis-aligned box, faces outward; without its bottom if it rests on something."""
        x0, y0, z0 = lo
        x1, y1, z1 = hi
        s = split
        self.quad((x0, y1, z1), (x1, y1, z1), (x1, y1, z0), (x0, y1, z0), s, s)   # top
        self.quad((x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1), s, 1)   # +z
        self.quad((x1, y0, z0), (x0, y0, z0), (x0, y1, z0), (x1, y1, z0), s, 1)   # -z
        self.quad((x1, y0, z1), (x1, y0, z0), (x1, y1, z0), (x1, y1, z1), s, 1)   # +x
        self.quad((x0, y0, z0), (x0, y0, z1), (x0, y1, z1), (x0, y1, z0), s, 1)   # -x
        if bottom:
            self.quad((x0, y0, z0), (x1, y0, z0), (x1, y0, z1), (x0, y0, z1), s, s)

    def lathe(self, profile, centre=(0, 0, 0), segments=48, axis="y"):
        """Surface of revolution of `profile` [(radius, height), ...] listed
        from bottom to top, outward normals when the profile runs up the
        outside.  A radius of 0 closes the surface with a fan."""
        cx, cy, cz = centre

        def point(r, h, a):
            c, s = math.cos(a), math.sin(a)
            if axis == "y":
                return (cx + r * c, cy + h, cz - r * s)
            if axis == "x":
                return (cx + h, cy + r * c, cz + r * s)
            if axis == "-x":
                return (cx - h, cy + r * c, cz - r * s)
            return (cx - r * s, cy + r * c, cz + h)  # along z

        # Split the profile at sharp corners so each piece shares its own ring.
        pieces, current = [], [profile[0]]
        for i in range(1, len(profile)):
            current.append(profile[i])
            if 0 < i < len(profile) - 1:
                (r0, h0), (r1, h1), (r2, h2) = profile[i - 1], profile[i], profile[i + 1]
                a1, a2 = math.atan2(h1 - h0, r1 - r0), math.atan2(h2 - h1, r2 - r1)
                turn = abs((a2 - a1 + math.pi) % (2 * math.pi) - math.pi)
                if turn > math.radians(40):
                    pieces.append(current)
                    current = [profile[i]]
        pieces.append(current)
        for piece in pieces:
            rings = []
            for r, h in piece:
                if r == 0:
                    rings.append([self.vertex(point(0, h, 0))] * segments)
                else:
                    rings.append([self.vertex(point(r, h, 2 * math.pi * k / segments)) for k in range(segments)])
            for lo, hi in zip(rings, rings[1:]):
                for k in range(segments):
                    a, b = lo[k], lo[(k + 1) % segments]
                    c, d = hi[(k + 1) % segments], hi[k]
                    if a != b:
                        self.tri(a, b, c)
                    if c != d:
                        self.tri(a, c, d)

    def write(self, path):
        path.write_text("\n".join(self.lines) + "\n")
        print(f"wrote {path}")
