#!/usr/bin/env python3
"""Writes a bookshelf as an OFF mesh, deterministically (no downloaded data), for the bake's broken-mesh benchmark.

  python3 bench/make_shelf.py broken OUT.off    # open, self-intersecting, non-manifold, ~150 components
  python3 bench/make_shelf.py clean OUT.off     # the same shelf closed and apart: same size, about the same area
                                                # and triangle count

Both are a 1.6 x 2.0 x 0.4 m shelf of 18 mm boards (5 uprights, 6 shelves, a back panel) holding ~140 books,
about 10,000 triangles. The broken one is what CAD exports and game assets look like: the shelves run through
the uprights, the uprights are open channels (no front face), the back panel is a single sheet, the books have no
top, lean into each other and sink into their shelf, and some stand face to face on exactly the same plane. The
clean one is the same parts as closed boxes that do not touch: the shelves cut between the uprights, the back
panel a thin box, the books upright and apart.
"""
import random
import sys

FACES = ("-x", "+x", "-y", "+y", "-z", "+z")


class Mesh:
    def __init__(self):
        self.vertices = []
        self.triangles = []

    def box(self, centre, half, subdivisions, omit=(), lean=0.0):
        """An axis-aligned box (leaning by `lean` radians about z, around its bottom), faces subdivided into
        n_u x n_v quads of two triangles, outward oriented; `omit` names faces left out (open borders)."""
        import math

        c, s = math.cos(lean), math.sin(lean)
        bottom = centre[1] - half[1]

        def place(p):
            x, y = p[0] - centre[0], p[1] - bottom
            return (centre[0] + c * x - s * y, bottom + s * x + c * y, p[2])

        for face in FACES:
            if face in omit:
                continue
            axis = "xyz".index(face[1])
            sign = 1 if face[0] == "+" else -1
            u, v = [a for a in range(3) if a != axis]
            if sign < 0:  # outward: u x v along the face's normal
                u, v = v, u
            nu, nv = subdivisions[u], subdivisions[v]
            base = len(self.vertices)
            for j in range(nv + 1):
                for i in range(nu + 1):
                    p = [0.0, 0.0, 0.0]
                    p[axis] = centre[axis] + sign * half[axis]
                    p[u] = centre[u] - half[u] + 2 * half[u] * i / nu
                    p[v] = centre[v] - half[v] + 2 * half[v] * j / nv
                    self.vertices.append(place(p))
            for j in range(nv):
                for i in range(nu):
                    a = base + j * (nu + 1) + i
                    b, d = a + 1, a + nu + 1
                    self.triangles.append((a, b, d + 1))
                    self.triangles.append((a, d + 1, d))

    def sheet(self, centre, half, axis, subdivisions):
        """A single open sheet: the box's +axis face only."""
        flat = list(half)
        flat[axis] = 0.0
        self.box(centre, flat, subdivisions, omit=[f for f in FACES if f != "+" + "xyz"[axis]])

    def write(self, path):
        with open(path, "w") as f:
            f.write(f"OFF\n{len(self.vertices)} {len(self.triangles)} 0\n")
            for p in self.vertices:
                f.write(f"{p[0]:.9g} {p[1]:.9g} {p[2]:.9g}\n")
            for t in self.triangles:
                f.write(f"3 {t[0]} {t[1]} {t[2]}\n")


def shelf(broken):
    rng = random.Random(20240)
    m = Mesh()
    width, height, depth, board = 1.6, 2.0, 0.4, 0.018
    uprights = [i * width / 4 for i in range(5)]
    levels = [i * (height - board) / 5 + board / 2 for i in range(6)]
    t = board / 2
    for x in uprights:  # 2.0 m tall, open at the front when broken
        m.box((x, height / 2, depth / 2), (t, height / 2, depth / 2), (1, 16, 4), omit=["+z"] if broken else [])
    for y in levels:
        if broken:  # one board through every upright, its ends open
            m.box((width / 2, y, depth / 2), (width / 2 + 0.02, t, depth / 2 - 0.01), (16, 1, 4), omit=["-x", "+x"])
        else:  # four boards between the uprights
            for i in range(4):
                x0, x1 = uprights[i] + t + 0.001, uprights[i + 1] - t - 0.001
                m.box(((x0 + x1) / 2, y, depth / 2), ((x1 - x0) / 2, t, depth / 2 - 0.01), (4, 1, 4))
    if broken:
        m.sheet((width / 2, height / 2, 0.0), (width / 2, height / 2, 0.002), 2, (8, 10, 1))
    else:
        m.box((width / 2, height / 2, -0.003), (width / 2 + t, height / 2, 0.002), (8, 10, 1))
    # Books: on each of the 20 compartments' floors, side by side from the left upright.
    for level in range(5):
        floor = levels[level] + t
        room = levels[level + 1] - t - floor
        for bay in range(4):
            x = uprights[bay] + t + 0.002
            right = uprights[bay + 1] - t - 0.002
            twin = False
            for _ in range(7):
                thick = rng.uniform(0.015, 0.05)
                tall = rng.uniform(0.5, 0.9) * room
                deep = rng.uniform(0.15, 0.3)
                if x + thick > right:
                    break
                # Broken: books overlap their neighbour by 4 mm and lean, except pairs of upright twins that stand
                # face to face on exactly the same plane.
                gap = 0.0 if twin else (-0.004 if broken else 0.003)
                x += gap
                upright = twin or (broken and rng.random() < 0.15)
                lean = 0.0 if upright or not broken else rng.uniform(-0.08, 0.08)
                twin = broken and upright and not twin
                sink = 0.005 if broken else -0.001  # broken books stand 5 mm into the shelf
                centre = (x + thick / 2, floor - sink + tall / 2, 0.02 + deep / 2)
                m.box(centre, (thick / 2, tall / 2, deep / 2), (1, 3, 2), omit=["+y"] if broken else [], lean=lean)
                x += thick
    return m


def main():
    if len(sys.argv) != 3 or sys.argv[1] not in ("broken", "clean"):
        sys.exit(__doc__)
    m = shelf(sys.argv[1] == "broken")
    m.write(sys.argv[2])
    print(f"{sys.argv[2]}: {len(m.vertices)} vertices, {len(m.triangles)} triangles", file=sys.stderr)


if __name__ == "__main__":
    main()
