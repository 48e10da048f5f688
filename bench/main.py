"""Entry point of ``tensegrity bench``: work-precision chart, stability map, optional peers and
Rerun recording cost."""
from __future__ import annotations

from pathlib import Path


def main(out_dir='bench/results', quick=False, peers=False, only=None, log=print):
    """Run the benchmarks into ``out_dir``; ``only`` is None or a subset of
    ``{'work_precision', 'stability', 'stiff', 'peers', 'rerun', 'sweep', 'soak', 'array',
    'trains', 'impacts', 'lanes', 'flops', 'node_array', 'shots'}`` (``stiff``: the
    stiff scenes of both, which ``work_precision`` and ``stability`` also run; ``peers=True`` adds
    the peer comparison, which :mod:`bench.peers` provides; ``rerun``, only on request, the cost of
    a Rerun recording, :mod:`bench.rerun_overhead`; ``sweep``, only on request, a sweep's
    single runs against the batched runner, :mod:`bench.sweep`; ``soak``, only on request, the
    node under a command flood for 10 minutes, 20 s with ``quick``, :mod:`bench.soak`;
    ``node_array``, only on request, the node's real-time factor on arrays of distinct columns
    per way of stepping them, :mod:`bench.node_array`, 2 s windows with ``quick``; ``shots``, only
    on request, strong shots on the default columns against a refined reference,
    :mod:`bench.shots`). Returns the files written."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    if only is None or 'work_precision' in only:
        from . import work_precision
        written += work_precision.main(out, quick=quick, log=log)
    if only is None or 'stability' in only:
        from . import stability
        written += stability.main(out, quick=quick, log=log)
    if only is not None and 'stiff' in only and not {'work_precision', 'stability'} & only:
        from . import stability, work_precision
        written += stability.stiff_main(out, quick=quick, log=log)
        written += work_precision.stiff_main(out, quick=quick, log=log)
    if peers or (only is not None and 'peers' in only):
        from . import peers as peer_bench  # lazy: optional dependencies
        result = peer_bench.main(out, quick)
        if isinstance(result, (list, tuple)):
            written += [str(p) for p in result]
    if only is not None and 'sweep' in only:
        from . import sweep
        written += sweep.main(out, quick=quick, log=log)
    if only is not None and 'array' in only:           # arrays of columns (on request)
        from . import array
        written += array.main(out, quick=quick, log=log)
    if only is not None and 'rerun' in only:
        from . import rerun_overhead
        written += rerun_overhead.main(out, quick=quick, log=log)
    if only is not None and 'trains' in only:          # pulse trains, strong impacts
        from . import trains
        written += trains.main(out, quick=quick, log=log)
    if only is not None and 'impacts' in only:         # single impacts, refined or not
        from . import impacts
        written += impacts.main(out, quick=quick, log=log)
    if only is not None and 'soak' in only:
        from . import soak
        written += soak.main(out, quick=quick, log=log)
    if only is not None and 'lanes' in only:           # instances stepped together
        from . import lanes
        written += lanes.main(out, log=log)
    if only is not None and 'flops' in only:           # GFLOP/s of one evaluation, peak
        from . import flops
        written += flops.main(out, log=log)
    if only is not None and 'node_array' in only:      # the node on arrays of columns
        from . import node_array
        written += node_array.main(out, log=log, **({'window_s': 2.0, 'ramp_s': 0.05}
                                                    if quick else {}))
    if only is not None and 'shots' in only:           # strong shots, real-time factor
        from . import shots
        written += shots.main(out, quick=quick, log=log)
    return written
