"""How the points of a sweep go in batches (:mod:`tensegrity_ros.studies.sweep`): batches of one
network topology (:func:`topology_of`) sized by estimated work (:func:`point_cost`,
:func:`batches`) or shrinking as a Dask sweep goes (:func:`chunks`), and for the threads of this
process the dearest first (:func:`contact_cost`, :func:`dearest_first`)."""
from __future__ import annotations

from tensegrity_ros.studies.grid import canonical

GUIDED_SHARE = 3                 # a batch takes 1/(3 x workers) of the points still to run,
MAX_BATCH = 8                    # at most this many (Ctrl-C loses the rows of running batches)


def chunks(todo, workers, size=None):
    """``todo`` cut into consecutive batches, one Dask task each. With ``size`` every batch has
    ``size`` points; by default the batches shrink as the sweep goes (guided self-scheduling):
    each takes a third of the remaining points divided among the workers, at least one and at most
    :data:`MAX_BATCH`, so the early tasks are long (few round trips to the scheduler) and the last
    ones short (the workers finish together)."""
    todo = list(todo)
    out = []
    i = 0
    while i < len(todo):
        n = size or min(MAX_BATCH, max(1, (len(todo) - i) // (GUIDED_SHARE * max(workers, 1))))
        out.append(todo[i:i + n])
        i += n
    return out


BATCH_SECONDS = 2.0            # the estimated work of a batch, s (a Ctrl-C loses the running one)
STEP_SECONDS_PER_PRISM = 0.7e-6  # the estimate: a step of a sym3d column, per prism, s
# scene keys whose (non-float) values may change the network's topology or the kernels a point
# runs: points that differ in them go in different batches
TOPOLOGY_KEYS = ('structure.', 'model', 'contact.bars', 'contact.lock', 'loading.impact.mode',
                 'integrator.method')


def topology_of(overrides):
    """What of a point's ``overrides`` may change its network topology (a key of
    :data:`TOPOLOGY_KEYS` set to a value that is not a float): the points of a batch agree on it,
    so they share the topology's sym3d reduction (:mod:`solver.build.memo`)."""
    return tuple(sorted((k, repr(canonical(v))) for k, v in overrides.items()
                        if k.startswith(TOPOLOGY_KEYS) and not isinstance(canonical(v), float)))


def point_cost(scene):
    """The estimated time s of a point's run (``scene`` with its overrides): steps x prisms."""
    prisms = scene.structure.n_prisms * scene.structure.n_columns \
        if scene.structure.builder == 'column' else 50
    return scene.run.t_end / scene.integrator.dt * max(prisms, 1) * STEP_SECONDS_PER_PRISM


# the points of an impact meet bar contact, whose steps grow with the shot's speed: in the
# 1,024-point sweep of docs/sweeps.md a 1 s point took 2,400 accepted steps at 0.05 m/s and 6,600
# at 0.19 m/s, against 1,600 without contact. Only the order of in-process batches reads it
CONTACT_SPEED = 0.05             # m/s: the speed at which contact about doubles a point's steps


def contact_cost(scene):
    """:func:`point_cost` with the impacts' contact: times ``1 + |v| / CONTACT_SPEED``, ``v`` the
    fastest shot of the point's impacts (the run's steps grow with it, :data:`CONTACT_SPEED`)."""
    fastest = max((abs(float(v)) for _, v in scene.loading.impact.train()), default=0.0)
    return point_cost(scene) * (1.0 + fastest / CONTACT_SPEED)


def dearest_first(parts, costs):
    """The batches ``parts`` (lists of points) ordered by their estimated work (``costs``, one
    number per batch), the largest first: threads that each take the next batch when done then
    end on the cheapest ones, and finish close together (longest processing time first).
    Python's sort is stable: batches of equal cost keep their order."""
    order = sorted(range(len(parts)), key=lambda i: -costs[i])
    return [parts[i] for i in order]


def batches(todo, workers, costs, topologies, size=None, seconds=BATCH_SECONDS):
    """``todo`` cut into batches of points of one topology (``topologies``, one per point), one
    Dask task (or one in-process batch) each, in the order the topologies first appear. With
    ``size`` every batch has ``size`` points (fewer at the end of a topology); by default a batch
    holds about ``seconds`` of estimated work (``costs``, s per point), and, for Dask
    ``workers``, less as the sweep goes (guided self-scheduling: at most a third of the work left
    divided among the workers), so the workers finish together (``workers=None``: no shrinking,
    the batches of one process that runs them one after the other). Every batch has at least
    one point."""
    groups = {}
    for item, cost, topo in zip(todo, costs, topologies):
        groups.setdefault(topo, []).append((item, cost))
    left = sum(costs)
    out = []
    for members in groups.values():
        i = 0
        while i < len(members):
            if size:
                n = size
            else:
                budget = seconds if workers is None else min(
                    seconds, left / (GUIDED_SHARE * max(workers, 1)))
                n, work = 1, members[i][1]
                while i + n < len(members) and work + members[i + n][1] <= budget:
                    work += members[i + n][1]
                    n += 1
            part = members[i:i + n]
            out.append([item for item, _ in part])
            left -= sum(c for _, c in part)
            i += n
    return out
