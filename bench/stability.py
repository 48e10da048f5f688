"""Placeholder: filled in by the next commit."""


def main(out, quick=False, log=print):
    log('stability: not implemented yet')
    return []
