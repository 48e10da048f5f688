"""Where a step should end: the next cable slack/taut kink or contact kink. Shared by every
explicit integrator family (through :mod:`solver.kernels.effects`)."""
import math

from solver.compiled import jit
from solver.kernels import dynamics as dyn
from solver.kernels.contact import contact_kink, gap_kink


@jit
def next_kink(x, v, acc, m, d, h, ignore):
    """Earliest time in ``(ignore, h)`` at which a cable is predicted to go slack or taut, from a
    quadratic Taylor model of ``s - L`` (position, velocity, acceleration); ``h`` if none.

    The tension-only cable law has a kink at ``s = L``; a Runge-Kutta step whose stages straddle it
    loses its order. Landing steps on kinks restores it (a kink closer than ``ignore`` is taken as
    already crossed)."""
    cable_a, cable_b, cable_rot = m.topo.cable_a, m.topo.cable_b, m.topo.cable_rot
    rest = d.rest
    t_best = h
    rotated = cable_rot.shape[0] > 0
    for c in range(cable_a.shape[0]):
        a = cable_a[c]
        b = cable_b[c]
        if rotated:         # a cable to the image R^r x_b (sym3d)
            cr = dyn.ROT_C[cable_rot[c]]
            sr = dyn.ROT_S[cable_rot[c]]
            dx = cr * x[b, 0] - sr * x[b, 1] - x[a, 0]
            dy = sr * x[b, 0] + cr * x[b, 1] - x[a, 1]
            vx = cr * v[b, 0] - sr * v[b, 1] - v[a, 0]
            vy = sr * v[b, 0] + cr * v[b, 1] - v[a, 1]
            ax = cr * acc[b, 0] - sr * acc[b, 1] - acc[a, 0]
            ay = sr * acc[b, 0] + cr * acc[b, 1] - acc[a, 1]
        else:
            dx = x[b, 0] - x[a, 0]
            dy = x[b, 1] - x[a, 1]
            vx = v[b, 0] - v[a, 0]
            vy = v[b, 1] - v[a, 1]
            ax = acc[b, 0] - acc[a, 0]
            ay = acc[b, 1] - acc[a, 1]
        dz = x[b, 2] - x[a, 2]
        vz = v[b, 2] - v[a, 2]
        az = acc[b, 2] - acc[a, 2]
        bb = dx * dx + dy * dy + dz * dz
        bbd = dx * vx + dy * vy + dz * vz
        bdbd = vx * vx + vy * vy + vz * vz
        bbdd = dx * ax + dy * ay + dz * az
        s = math.sqrt(bb)
        g = s - rest[c]
        # far from its kink: |s'| s = |b.b'| and |s''| s <= |b'.b' + b.b''| + |b'|^2 (Cauchy-
        # Schwarz: s'^2 <= |b'|^2) bound the model's change within t_best, so it has no root
        # there (with a margin far above round-off: the same t_best as the full test)
        if abs(g) * s > 1.000001 * (abs(bbd) * t_best
                                    + 0.5 * (abs(bdbd + bbdd) + bdbd) * t_best * t_best):
            continue
        sd = bbd / s
        sdd = (bdbd + bbdd - sd * sd) / s
        t_best = gap_kink(g, sd, sdd, t_best, ignore)
    if m.stops.height.shape[0] != 0 or m.strikers.row.shape[0] != 0:   # kernels.contact
        t_best = contact_kink(x, v, acc, m, t_best, ignore)
    return t_best

