"""What an array's frame shows of the lanes of a lane group, in one call: each lane's state
expanded to the full network as its model expands it (``sym3d``:
:func:`solver.kernels.rotation.expand`; ``full3d``: its rows as they are), and
its cable tensions as :func:`solver.kernels.summary.cable_tensions` computes them from those
positions; both with the same operations, so the same values, bit for bit, as the frame of each
column simulation by itself (:meth:`solver.simulate.simulation.Simulation.frame`)."""
from __future__ import annotations

import math

from solver.compiled import jit
from solver.kernels.rotation import expand


@jit
def frame_rows(x, rep, cos, sin, rotate, cable_a, cable_b, cable_map, rest, EA, first, cols,
               offset, pos, out_x, out_t):
    """For every lane ``k`` of the lane-outer states ``x`` (B, rows, 3), rest lengths and ``EA``
    (B, reduced cables): its full positions (full node ``p`` is ``R_p x[k, rep[p]]``, the
    rotation of cosine ``cos[p]`` and sine ``sin[p]`` about z where ``rotate``) into the scratch
    ``pos`` (n_nodes, 3), then, for each column ``c`` of ``cols[first[k]:first[k + 1]]`` (the
    columns that lane shows), ``pos + offset[c]`` into ``out_x[c]`` and the tension of every
    full cable ``j`` (of reduced cable ``cable_map[j]``) into ``out_t[c]``, N, zero when
    slack."""
    n = rep.shape[0]
    for k in range(x.shape[0]):
        if first[k + 1] == first[k]:
            continue
        if rotate:
            expand(x[k], rep, cos, sin, pos)
        else:
            for p in range(n):
                for d in range(3):
                    pos[p, d] = x[k, rep[p], d]
        c0 = cols[first[k]]
        for j in range(cable_a.shape[0]):
            a = cable_a[j]
            b = cable_b[j]
            r = rest[k, cable_map[j]]
            s = math.sqrt((pos[b, 0] - pos[a, 0]) ** 2 + (pos[b, 1] - pos[a, 1]) ** 2
                          + (pos[b, 2] - pos[a, 2]) ** 2)
            out_t[c0, j] = EA[k, cable_map[j]] / r * (s - r) if s > r else 0.0
        for i in range(first[k], first[k + 1]):
            c = cols[i]
            for p in range(n):
                for d in range(3):
                    out_x[c, p, d] = pos[p, d] + offset[c, d]
            if c != c0:
                for j in range(cable_a.shape[0]):
                    out_t[c, j] = out_t[c0, j]
