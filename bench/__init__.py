"""Benchmarks of the solver: work-precision chart, stability map, peer comparison.

Each script reports ratios measured side by side in one run (the machine may be busy), writes CSV
and PNG files into ``bench/results/`` (or ``--out DIR``) and is run through ``tensegrity bench``.
"""
