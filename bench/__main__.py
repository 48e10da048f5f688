"""``python -m bench`` (what ``tensegrity bench`` runs): the benchmarks, from the source checkout.

    python -m bench [--only NAME ...] [--quick] [--peers] [--out DIR]

Each benchmark writes its CSV, JSON and PNG files into ``--out`` and prints their paths.
"""
from __future__ import annotations

import sys

from bench.main import main as bench_main
from tensegrity_ros.cli import OneLineParser

CHOICES = ('work_precision', 'stability', 'stiff', 'peers', 'rerun', 'sweep', 'soak', 'array',
           'trains', 'impacts', 'lanes', 'flops', 'node_array', 'shots')


def parser():
    p = OneLineParser(prog='python -m bench', description='work-precision chart, '
                                'stability map, peer comparison and adapter costs')
    p.add_argument('--quick', action='store_true',
                   help='small grids and short windows (smoke run)')
    p.add_argument('--out', default='bench/results', help='output directory (CSV and PNG)')
    p.add_argument('--peers', action='store_true', help='also run the peer comparison')
    p.add_argument('--only', action='append', choices=CHOICES,
                   help='run only this benchmark (repeatable); stiff: the stiff scenes of '
                        'work_precision and stability (both also run them); rerun: the cost of '
                        'a Rerun recording, sweep: a 256-point sweep, single runs against the '
                        'batched runner on one and two cores, '
                        'soak: the node under a command flood for 10 minutes, array: arrays of '
                        'columns per column, trains: pulse trains and strong impacts on the '
                        'default columns, impacts: 70 single impacts of 0.3-2 m/s with the steps '
                        'after a contact refined and not, lanes: B instances stepped together '
                        'against the scalar kernels, flops: the GFLOP/s of one evaluation, '
                        'scalar and per lane, against the core\'s peak, node_array: the node\'s '
                        'real-time factor on arrays of 10-50 distinct columns, lanes and not, '
                        'shots: 1 and 2 m/s shots on both default columns and a train then a '
                        'shot, against a refined reference (these ten only on request)')
    return p


def main(argv=None):
    args = parser().parse_args(argv)

    def log(msg):
        print(msg, file=sys.stderr, flush=True)

    only = None if args.only is None else set(args.only)
    for path in bench_main(args.out, quick=args.quick, peers=args.peers, only=only, log=log):
        print(path)
    return 0


if __name__ == '__main__':
    sys.exit(main())
