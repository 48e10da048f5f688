"""What the soak (bench/soak.py) reports: both recordings read back (``check_files``: complete,
every frame finite, frame counts and sizes) and its report as a short Markdown table
(``table``)."""
from __future__ import annotations

import warnings

import numpy as np


def check_files(mcap, rrd):
    """Read both recordings back: complete (MCAP summary present, no Rerun reader warning), every
    frame finite, frame counts, sizes. A file given as None is not checked (``None`` in the
    result)."""
    out = {'mcap': _check_mcap(mcap) if mcap is not None else None,
           'rerun': _check_rerun(rrd) if rrd is not None else None}
    return out


def _check_mcap(mcap):
    from tensegrity_ros.io.mcap_reader import McapLog, cloud_xyz, multi_array_values
    log = McapLog(mcap)
    frames = non_finite = diag = cmds = 0
    for m in log.messages():
        leaf = m.topic.rsplit('/', 1)[-1]
        if leaf in ('strain', 'cable_tension'):
            frames += leaf == 'strain'
            non_finite += not np.all(np.isfinite(multi_array_values(log.decode(m))[1]))
        elif leaf == 'nodes':
            non_finite += not np.all(np.isfinite(cloud_xyz(log.decode(m))))
        elif leaf == 'diagnostics':
            diag += 1
        elif '/cmd/' in m.topic:
            cmds += 1
    return {'complete': not log.truncated, 'frames': frames, 'non_finite': non_finite,
            'diagnostics': diag, 'commands': cmds,
            'mb': sum(f.stat().st_size for f in log.files) / 2**20}


def _check_rerun(rrd):
    import pyarrow as pa
    from rerun.chunk import RrdReader
    from tensegrity_ros.io.rerun_sink import segment_files
    rows, bad, complete = 0, 0, True
    files = segment_files(rrd)
    chunks = (chunk for f in files for chunk in RrdReader(f).stream())
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        try:
            for chunk in chunks:
                if chunk.entity_path.lstrip('/') == 'world/nodes' and not chunk.is_static:
                    rb = chunk.to_record_batch()
                    rows += rb.num_rows
                    col = rb.column(rb.schema.names.index('Points3D:positions'))
                    vals = pa.concat_arrays([c for c in col.chunks]) if hasattr(col, 'chunks') \
                        else col
                    while pa.types.is_list(vals.type) or pa.types.is_fixed_size_list(vals.type):
                        vals = vals.flatten()
                    bad += int(not np.all(np.isfinite(vals.to_numpy(zero_copy_only=False))))
        except Warning:
            complete = False
    return {'complete': complete, 'frames': rows, 'non_finite': bad, 'files': len(files),
            'mb': sum(f.stat().st_size for f in files) / 2**20}


def table(r):
    """The report as a short markdown table."""
    s, e, f = r['start'], r.get('end', {}), r['files']
    pr = r['publish_rate']
    c = r['commands']
    m, rr = f['mcap'], f['rerun']
    cpu = r.get('cpu_per_s', {})
    rows = [
        ('duration, flood', f"{r['duration_s']:g} s, {r['sent']['per_s']:.0f} commands/s "
                            f"({r['sent']['total']} sent, {r.get('mix', 'soak')} mix)"),
        ('node alive at the end', 'yes' if r['node_alive'] else 'NO'),
        ('non-finite frames (MCAP, Rerun, received strain, received nodes)',
         f"{m['non_finite'] if m else '-'}, {rr['non_finite'] if rr else '-'}, "
         f"{r['strain_non_finite_received']}, {r.get('nodes_non_finite_received', '-')}"),
        (f"publish rate while running (target {pr['target_hz']:g} Hz)",
         f"mean {pr['mean_hz']:.1f} Hz, 5th percentile of diagnostics periods "
         f"{pr['p05_hz'] or 0:.1f} Hz; running {100 * r['running_fraction']:.0f} % of the time; "
         f"longest tick per period: median {pr.get('tick_max_ms_median') or 0:.1f} ms, "
         f"max {pr.get('tick_max_ms_max') or 0:.1f} ms"),
        ('commands received: accepted / superseded / rejected; not taken (QoS keep last 10)',
         f"{c['accepted']} / {c['superseded']} / {c['rejected']}; {c['qos_dropped']}"),
        ('divergences (on_divergence reset: back to rest); pauses',
         f"{r.get('divergences', '-')}; {r['pauses']}"),
        ('frames per wall second over the flood (node), strain received per second',
         f"{r.get('frames_per_s', 0):.1f}, {r.get('strain_received_per_s', 0):.1f}"),
        ('RSS start -> end', f"{s['rss_mb']:.0f} -> {e.get('rss_mb', float('nan')):.0f} MB "
                             f"({100 * (e.get('rss_mb', 0) / s['rss_mb'] - 1):+.1f} %)"),
        ('open files, threads start -> end', f"{s['open_files']} -> {e.get('open_files')}, "
                                             f"{s['threads']} -> {e.get('threads')}"),
        ('helper processes (RSS) during, after shutdown',
         f"{len(s['helpers'])} ({', '.join(f'{m:.0f} MB' for _, m in e.get('helpers', []))}), "
         f"{len(r['helpers_left'])}"),
        ('CPU s per s: node, Rerun helper, flood client',
         ', '.join(f"{cpu[k]:.2f}" if k in cpu else '-'
                   for k in ('node', 'rerun_helper', 'flood_client'))),
        ('MCAP', f"complete {m['complete']}, {m['frames']} frames, {m['commands']} commands, "
                 f"{m['diagnostics']} diagnostics, {m['mb']:.0f} MB" if m else 'not recorded'),
        ('Rerun', f"complete {rr['complete']}, {rr['frames']} frames, {rr['mb']:.0f} MB in "
                  f"{rr.get('files', 1)} file(s)"
         if rr else 'not recorded'),
        ('node log', f"{r['log_bytes'] / 1024:.0f} KiB"),
        ('node exit code (SIGINT)', str(r['node_exit_code'])),
        ('load average (1, 5, 15 min) at the end',
         ', '.join(f'{x:.1f}' for x in r.get('load_average', ()))),
    ]
    return '\n'.join(['| | |', '|---|---|'] + [f'| {a} | {b} |' for a, b in rows])
