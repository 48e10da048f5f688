"""Reading Rerun recordings back in the tests, with rerun's own reader: rerun-sdk 0.41 has no
``rerun.dataframe`` module without the optional ``datafusion`` package, so a recording is read with
``rerun.chunk.RrdReader``, chunk by chunk, as Arrow record batches (``read``, and ``flat``, ``at``,
``strips_at``, ``tensor``, ``blueprint_views``, ``field_images`` on what it returns); and a small
recorded run of the FB column (``small_run``). Used by test_rerun.py, test_rerun_files.py,
test_rerun_node.py and test_logs.py."""
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

pytest.importorskip('rerun')
from rerun.chunk import RrdReader  # noqa: E402

from solver.simulate.runner import run  # noqa: E402
from solver.build.scene import Scene  # noqa: E402
from solver.simulate.array import simulation_for  # noqa: E402
from tensegrity_ros.io.rerun_sink import RerunRecorder  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
FB = ROOT / 'config' / 'scenes' / 'fb_column.yaml'


# -- reading a recording -----------------------------------------------------------------------
def flat(arr):
    """A nested Arrow list array -> 1-D numpy of its leaf values."""
    if isinstance(arr, pa.ChunkedArray):
        arr = arr.combine_chunks()
    while pa.types.is_list(arr.type) or pa.types.is_fixed_size_list(arr.type) \
            or pa.types.is_large_list(arr.type):
        arr = arr.flatten()
    return arr.to_numpy(zero_copy_only=False)


def read(path):
    """{entity_path: {'static': {component: row-0 Arrow value list}, 'rows': [(t_ns, {component:
    one-row Arrow slice})]}} of the first recording in ``path``, rows sorted by sim_time."""
    out = {}
    for chunk in RrdReader(path).stream():
        ent = out.setdefault(chunk.entity_path, {'static': {}, 'rows': []})
        rb = chunk.to_record_batch()
        comps = [n for n in rb.schema.names if n != 'sim_time' and not n.startswith('rerun.')]
        if chunk.is_static:
            for n in comps:
                ent['static'][n] = rb.column(n).slice(0, 1)
            continue
        assert chunk.timeline_names == ['sim_time']
        times = rb.column('sim_time').cast(pa.int64()).to_numpy()
        for i, t in enumerate(times):
            ent['rows'].append((int(t), {n: rb.column(n).slice(i, 1) for n in comps}))
    for ent in out.values():
        ent['rows'].sort(key=lambda r: r[0])
    return out


def at(ent, t, comp):
    """Leaf values of ``comp`` of the row at sim_time ``t`` s (exactly one row expected)."""
    ns = round(t * 1e9)
    rows = [r for tt, r in ent['rows'] if tt == ns and comp in r]
    assert len(rows) == 1, f'{len(rows)} rows at t = {t}'
    return flat(rows[0][comp])


def strips_at(ent, t):
    """The line strips of the row at sim_time ``t``: a list of (n_points, 3) float32 arrays."""
    ns = round(t * 1e9)
    rows = [r for tt, r in ent['rows'] if tt == ns]
    assert len(rows) == 1
    return [np.array(strip, dtype=np.float32)
            for strip in rows[0]['LineStrips3D:strips'].flatten().to_pylist()]


def tensor(ent, row=-1):
    """(shape, float64 values) of the Tensor logged in row ``row``; by default the last one (the
    heat map at the last frame: the whole wave)."""
    data = ent['rows'][row][1]['Tensor:data'].flatten().to_pylist()
    assert len(data) == 1
    return tuple(data[0]['shape']), np.array(data[0]['buffer'], dtype=np.float64)


def symlog(strain):
    """The recorder's symmetric-log scale of strain, written out: sign(s) log10(1 + |s| / 0.01)
    (linear within 1 % strain)."""
    s = np.asarray(strain, dtype=np.float64)
    return np.sign(s) * np.log10(1.0 + np.abs(s) / 0.01)


def blueprint_views(path):
    """{(view class, origin)} of the blueprint stored in the recording file ``path`` (the last
    one sent: the recorder sends it again on close when a series stayed constant)."""
    reader = RrdReader(path)
    store = reader.blueprints()[-1]
    views = set()
    for chunk in reader.stream(store=store):
        rb = chunk.to_record_batch()
        if 'ViewBlueprint:class_identifier' in rb.schema.names:
            for cls, origin in zip(rb.column('ViewBlueprint:class_identifier').to_pylist(),
                                   rb.column('ViewBlueprint:space_origin').to_pylist()):
                views.add((cls[0], origin[0]))
    return views


def field_images(ent):
    """[(t_ns, (height, width) float32 image)] of an Image entity."""
    out = []
    for t, row in ent['rows']:
        fmt = row['Image:format'].flatten().to_pylist()[0]
        assert fmt['color_model'] == 1                       # L: one channel
        raw = np.array(row['Image:buffer'].flatten().flatten().to_pylist(), dtype=np.uint8)
        out.append((t, raw.view(np.float32).reshape(fmt['height'], fmt['width'])))
    return out


# -- a recorded run ----------------------------------------------------------------------------
def small_run(tmp_path, n_prisms=8, t_end=0.1, v0=0.1, **kw):
    scene = Scene.load(FB).with_overrides([f'structure.n_prisms={n_prisms}',
                                           f'run.t_end={t_end}', 'model=full3d'])
    sim = simulation_for(scene)
    sim.apply_impact(v0)
    frames = []
    path = tmp_path / 'run.rrd'
    with RerunRecorder(sim.network, path, **kw) as rec:
        rec.command(0.0, f'impact v0 = {v0} m/s')
        run(sim, t_end, scene['run.output_dt'], on_frame=lambda f: (frames.append(f),
                                                                        rec.frame(f)))
    return sim, frames, path
